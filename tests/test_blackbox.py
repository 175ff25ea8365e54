"""Blackbox logs (issue 58, item 6): the CSV that ``blackbox_decode`` writes from a thrown device's flight log.

The log is made here from the synthetic gyrostat throw of tests/_gyrostat_truth.py (scipy's DOP853,
a 0.1 kg device with a flywheel of J = 1.7e-6 kg m² about body -z spinning 170 -> 1300 -> 210 rad/s),
held still before the release and after the catch, and written as Betaflight logs it: time in µs
from an arbitrary start, gyroADC in whole deg/s, accSmooth in counts of acc_1G = 2048 per g, eRPM
in units of 100 electrical rpm of a 14-pole motor, at 2 kHz (a common logging rate).
"""

from __future__ import annotations

import functools
import json
import math

import _gyrostat_truth as g
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import rbjax as rb
from rbjax._cli import main

RATE = 2000.0  # Hz
HOLD = 0.3  # s held still before the throw and after the catch
W0 = np.array([10.0, 20.0, 12.0])  # rad/s at the release, as tests/test_fit_rotor.py
G0 = 9.80665  # m/s² per g, as blackbox_decode converts
POLES = 14
ACC_1G = 2048
GYRO_STD = 0.02  # rad/s
ACC_STD = 0.05  # m/s²
START_US = 123_456_789  # the flight controller's clock when logging began
ERPM_STEP = 100 / (POLES / 2) * 2 * math.pi / 60  # rad/s per logged eRPM unit: 1.496 rad/s
HEADER = [
    "loopIteration",
    "time (us)",
    "axisP[0]",
    "gyroADC[0]",
    "gyroADC[1]",
    "gyroADC[2]",
    "accSmooth[0]",
    "accSmooth[1]",
    "accSmooth[2]",
    "motor[0]",
    "eRPM[0]",
]


@functools.cache
def _truth(seed: int = 0):
    """Times (s from the first sample), gyro + noise (rad/s), specific force + noise (m/s²), rotor rate (rad/s)."""
    rng = np.random.default_rng(seed)
    tf = np.arange(int(round(g.DURATION * RATE)) + 1) / RATE
    q, w, W = g.throw(tf, W0)
    n = int(round(HOLD * RATE))
    up = np.array([0.0, 0.0, G0])  # a body at rest reads the specific force -g: up
    end = Rotation.from_quat(q[-1][[1, 2, 3, 0]]).as_matrix()  # body to world at the catch
    gyro = np.concatenate([np.zeros((n, 3)), w, np.zeros((n, 3))])
    force = np.concatenate([np.tile(up, (n, 1)), np.zeros_like(w), np.tile(end.T @ up, (n, 1))])
    rotor = np.concatenate([np.full(n, W[0]), W, np.full(n, W[-1])])
    t = np.arange(gyro.shape[0]) / RATE
    gyro = gyro + rng.normal(0, GYRO_STD, gyro.shape)
    force = force + rng.normal(0, ACC_STD, force.shape)
    return t, gyro, force, rotor


def _write(path, t, gyro, force, rotor, *, quote=False, time_us=None):
    """The decoder's CSV: ``", "`` between cells, gyro rounded to deg/s, accelerometer to counts, eRPM/100."""
    us = START_US + np.round(t * 1e6).astype(np.int64) if time_us is None else time_us
    g_counts = np.round(np.degrees(gyro)).astype(int)
    a_counts = np.round(force / G0 * ACC_1G).astype(int)
    erpm = np.round(rotor / ERPM_STEP).astype(int)
    head = [f'"{h}"' if quote else h for h in HEADER]
    lines = [", ".join(head)]
    for i in range(len(t)):
        cells = [i, us[i], 3, *g_counts[i], *a_counts[i], 1200, erpm[i]]
        lines.append(", ".join(str(c) for c in cells))
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    t, gyro, force, rotor = _truth()
    path = _write(tmp_path_factory.mktemp("bb") / "LOG00001.01.csv", t, gyro, force, rotor)
    return path, (t, gyro, force, rotor)


@pytest.mark.parametrize("quote", [False, True])
def test_the_log_reads_back_to_the_truth_within_its_quantisation(tmp_path, quote):
    t, gyro, force, rotor = _truth()
    rec = rb.Recording.from_blackbox(_write(tmp_path / "log.csv", t, gyro, force, rotor, quote=quote))
    # whole µs from START_US, shifted to 0 and scaled: only float rounding is left (~1e-16 s)
    np.testing.assert_allclose(rec.times, t, rtol=0, atol=1e-12)
    # rounding to whole deg/s errs by at most half a degree per second: 0.0087 rad/s
    err = np.abs(rec.gyro - gyro)
    assert err.max() <= np.radians(0.5) + 1e-12 and err.max() > 0.9 * np.radians(0.5), err.max()
    # rounding to counts of 1/2048 g errs by at most half a count: 0.0024 m/s²
    err = np.abs(rec.accelerations - force)
    assert err.max() <= 0.5 * G0 / ACC_1G + 1e-12 and err.max() > 0.9 * 0.5 * G0 / ACC_1G, err.max()
    # eRPM in steps of 100 electrical rpm = 100/7 rpm of a 14-pole motor = 1.496 rad/s: half a step
    err = np.abs(rec.rotor_rates - rotor)
    assert err.max() <= 0.5 * ERPM_STEP + 1e-9 and err.max() > 0.9 * 0.5 * ERPM_STEP, err.max()
    assert rec.rotor_rates.shape == (len(t),) and rec.source.endswith("log.csv")
    # the steps are exactly the eRPM resolution: every rate is a whole number of them
    steps = rec.rotor_rates / ERPM_STEP
    np.testing.assert_allclose(steps, np.round(steps), rtol=0, atol=1e-9)


def test_arguments_scale_remap_and_flip(log):
    path, (t, gyro, force, rotor) = log
    base = rb.Recording.from_blackbox(path)
    # a board mounted turned: body x = board y, body y = board x, body z = -board z (a rotation, det +1)
    R = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
    turned = rb.Recording.from_blackbox(path, axes=R)
    np.testing.assert_array_equal(turned.gyro, base.gyro @ R.T)
    np.testing.assert_array_equal(turned.accelerations, base.accelerations @ R.T)
    # high-resolution gyro logging (tenths of deg/s), another IMU's acc_1G, a 12-pole motor, reversed spin
    other = rb.Recording.from_blackbox(path, gyro_scale=0.1, acc_1g=4096, motor_poles=12, rotor_sign=-1)
    np.testing.assert_allclose(other.gyro, 0.1 * base.gyro, rtol=1e-15)
    np.testing.assert_allclose(other.accelerations, 0.5 * base.accelerations, rtol=1e-15)
    np.testing.assert_allclose(other.rotor_rates, -14 / 12 * base.rotor_rates, rtol=1e-14)
    assert rb.Recording.from_blackbox(path, rotor=None).rotor_rates is None
    # a column named by the caller is read in rad/s (INDIflight's omega[k]); an eRPM column by name as eRPM
    np.testing.assert_array_equal(rb.Recording.from_blackbox(path, rotor="eRPM[0]").rotor_rates, base.rotor_rates)
    assert base.rotor_rates is not None
    np.testing.assert_array_equal(
        rb.Recording.from_blackbox(path, rotor="motor[0]").rotor_rates, np.full(len(base), 1200.0)
    )
    # the rotor rates travel with window() and into fit_inertia's keyword
    win = base.window(0.4, 0.5)
    np.testing.assert_array_equal(win.rotor_rates, base.rotor_rates[(base.times >= 0.4) & (base.times <= 0.5)])
    with pytest.raises(ValueError, match="det"):
        rb.Recording.from_blackbox(path, axes=np.diag([1, 1, -1]))
    with pytest.raises(ValueError, match="motor_poles"):
        rb.Recording.from_blackbox(path, motor_poles=13)


def test_decoded_units_in_the_header_are_read_in_them(tmp_path):
    t, gyro, force, rotor = _truth()
    n = 50
    lines = [
        "time (ms), gyroADC[0] (rad/s), gyroADC[1] (rad/s), gyroADC[2] (rad/s), accSmooth[0] (g), "
        "accSmooth[1] (g), accSmooth[2] (g)"
    ]
    for i in range(n):
        lines.append(", ".join(f"{v:.6f}" for v in (1000 * t[i] + 5.0, *gyro[i], *(force[i] / G0))))
    path = tmp_path / "decoded.csv"
    path.write_text("\n".join(lines) + "\n")
    rec = rb.Recording.from_blackbox(path)
    # printed to 6 decimals: errors up to 5e-7 in the file's units
    np.testing.assert_allclose(rec.times, t[:n], atol=1e-9)
    np.testing.assert_allclose(rec.gyro, gyro[:n], atol=5e-7)
    np.testing.assert_allclose(rec.accelerations, force[:n], atol=5e-7 * G0)
    assert rec.rotor_rates is None  # no eRPM column: no rotor, no error
    with pytest.raises(ValueError, match="gyro_scale"):
        rb.Recording.from_blackbox(path, gyro_scale=1.0)


def _lines(path):
    return path.read_text().splitlines()


def _cell(line: str, i: int, text: str) -> str:
    cells = line.split(", ")
    cells[i] = text
    return ", ".join(cells)


@pytest.mark.parametrize(
    "edit, match",
    [
        # no gyro at all: the file, the missing columns and the remedy (decode with blackbox_decode)
        (lambda L: [L[0].replace("gyroADC", "gyroXYZ")] + L[1:], r"no 'gyroADC\[0\.\.2\]'.*blackbox_decode"),
        # one axis missing: named
        (lambda L: [L[0].replace("gyroADC[2]", "debug[0]")] + L[1:], r"lack gyroADC\[2\].*blackbox_decode"),
        # a second log appended: its time starts again
        (lambda L: L + L[1:], r"line \d+: time \d+ us goes back.*two logs in one file.*wrapped"),
        # a repeated line
        (lambda L: L[:5] + [L[4]] + L[5:], r"line 6: time \d+ us repeats"),
        # text in a number cell (blackbox_decode --debug, or an edited file)
        (lambda L: L[:9] + [_cell(L[9], 4, "n/a")] + L[10:], r"line 10: 'n/a' in column 'gyroADC\[1\]'"),
        # a cut-off last line
        (lambda L: L + [L[-1][:12]], r"line \d+: 2 cells, the header has 11"),
        # a rotor motor that the log does not have
        (None, r"no column 'erpm\[3\]'.*eRPM columns: eRPM\[0\]"),
    ],
    ids=["no-gyro", "gyro-axis", "second-log", "repeat", "text", "cut-off", "rotor"],
)
def test_bad_files_are_refused_naming_the_file_the_line_and_the_remedy(log, tmp_path, edit, match):
    path, _ = log
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(edit(_lines(path)) if edit else _lines(path)) + "\n")
    with pytest.raises(rb.RecordingError, match=match) as e:
        rb.Recording.from_blackbox(bad, **({} if edit else {"rotor": 3}))
    assert str(bad) in str(e.value)
    assert isinstance(e.value, ValueError)


def test_rotor_rates_of_a_recording_are_checked_and_need_an_axis_to_fit():
    t = np.arange(6) / 100
    w = np.zeros((6, 3))
    with pytest.raises(ValueError, match=r"rotor_rates must have shape \(T,\) = \(6,\).*got \(5,\)"):
        rb.Recording(t, gyro=w, rotor_rates=np.ones(5))
    with pytest.raises(ValueError, match=r"rotor_rates must have shape.*got \(6, 2, 1\)"):
        rb.Recording(t, gyro=w, rotor_rates=np.ones((6, 2, 1)))
    with pytest.raises(ValueError, match=r"rotor_rates has a non-finite value at sample 2"):
        rb.Recording(t, gyro=w, rotor_rates=[1.0, 1.0, np.nan, 1.0, 1.0, 1.0])
    with pytest.raises(TypeError, match="rotor_rates must be an array of real numbers"):
        rb.Recording(t, gyro=w, rotor_rates=np.ones(6) * 1j)
    rec = rb.Recording(t, gyro=w, rotor_rates=np.ones((6, 2)))  # two rotors
    # fitting needs the axis: refused before any work, naming rotor_axis and the way out
    with pytest.raises(ValueError, match=r"rotor_axis is needed.*rotor_rates=None"):
        rb.fit_inertia(rec)
    with pytest.raises(TypeError, match="do not also pass rotor_rates"):
        rb.fit_inertia(rec, rotor_rates=np.ones((6, 2)), rotor_axis=np.eye(3)[:2])
    with pytest.raises(ValueError, match=r"recordings \[1\] have no rotor_rates"):
        rb.fit_inertia([rec, rb.Recording(t, gyro=w)], rotor_axis=np.eye(3)[:2])


def test_the_cli_refuses_a_log_with_erpm_without_the_rotor_axis(log, capsys):
    path, _ = log
    assert main(["fit", str(path)]) == 2
    err = capsys.readouterr().err
    assert "--rotor-axis" in err and "--no-rotor" in err and str(path) in err
    # contradictory or incomplete rotor flags, and a plot that would draw the body without its flywheel
    for extra, said in (
        (["--no-rotor", "--rotor-axis", "0,0,-1"], "leave --rotor-axis/--rotor-inertia out"),
        (["--rotor-inertia", "1.7e-6"], "--rotor-inertia needs --rotor-axis"),
        (["--rotor-axis", "0,0,-1", "--plot", "fit.png"], "--plot does not draw fits with a rotor"),
        (["--rotor-axis", "0,0"], "expected 3 finite comma-separated numbers"),
        (["--rotor-axis", "0,0,-1", "--rotor-motor", "2"], "no column 'erpm[2]'"),
    ):
        assert main(["fit", str(path), *extra]) == 2, extra
        assert said in capsys.readouterr().err, extra
    # and the blackbox flags are refused on other files
    assert main(["fit", str(path.with_suffix(".npz")), "--rotor-axis", "0,0,-1"]) == 2
    assert "--rotor-axis appl(ies) to blackbox logs" in capsys.readouterr().err


# ~9 s, most of it compiling the fit: the file's tests take ~11 s together
def test_the_cli_finds_the_throw_and_recovers_the_absolute_inertia(log, tmp_path, capsys):
    path, _ = log
    out = tmp_path / "fit.json"
    args = ["fit", str(path), "--rotor-axis", "0,0,-1", "--rotor-inertia", str(g.J_FLYWHEEL), "--out", str(out)]
    status = main(args)
    said = capsys.readouterr()
    printed = said.out
    assert out.exists(), said.err
    report = json.loads(out.read_text())
    assert len(report["throws"]) == 1, printed  # the held stretches are not flights
    row = report["throws"][0]
    # the window: the flight (0.3-0.8 s) less find_throws' 0.03 s margin at either end, to a sample or two
    assert abs(row["t0"] - (HOLD + 0.03)) < 2 / RATE and abs(row["t1"] - (HOLD + g.DURATION - 0.03)) < 2 / RATE
    assert report["inertia_units"] == "kg m^2" and "kg m²" in printed
    true = np.linalg.eigvalsh(g.I_DEVICE)
    m, s = np.asarray(row["principal_moments"]), np.asarray(row["principal_moment_std"])
    # measured z = -2.3, -2.7, -2.6 (relative errors 2.9e-4, 4.3e-4, 2.4e-4). The fit takes the rotor's
    # rate as exact (fit_inertia's docstring): with the exact rate the same data give z = -0.9, -1.3, -1.3,
    # and the eRPM rounding of this one rotor profile adds about -1.3σ, the same in every seed (seeds
    # 1-8: |z| <= 2.7, mean -1.2; relative errors <= 4.2e-4)
    z = (m - true) / s
    assert np.all(np.abs(z) < 3), z
    # 880 samples at 2 kHz, 0.02 rad/s of gyro noise plus whole-deg/s rounding: 4.3e-4 at most in 9 seeds
    np.testing.assert_allclose(m, true, rtol=1e-3)
    assert row["converged"] and status == 0, printed  # trusted: residuals like the noise (p = 0.48)
