"""Recordings from phyphox exports: reading, finding the throws, fitting each, saving the result, the CLI."""

from __future__ import annotations

import dataclasses
import re
import warnings
import zipfile

import jax
import numpy as np
import pytest
from _phyphox_data import MOMENTS, make_recording, write_phyphox

import rbjax as rb
from rbjax._cli import main

jax.config.update("jax_enable_x64", True)

TRUTH = MOMENTS / MOMENTS.sum()  # gyro-only fits give I / tr I


@pytest.fixture(scope="module")
def synthetic():
    return make_recording(seed=0)


@pytest.fixture(scope="module")
def export(synthetic, tmp_path_factory):
    tg, gyro, ta, accel, _ = synthetic
    return write_phyphox(tmp_path_factory.mktemp("phyphox"), tg, gyro, ta, accel)


@pytest.fixture(scope="module")
def throws_fit(export):
    rec = rb.Recording.from_phyphox(export)
    windows = rb.find_throws(rec)
    throws = [dataclasses.replace(rec.window(*w), accelerations=None) for w in windows]
    return windows, rb.fit_inertia(throws)


# --- Recording ---------------------------------------------------------------------------------


def test_recording_checks_its_arrays():
    t = np.linspace(0, 1, 11)
    rec = rb.Recording(t, gyro=np.zeros((11, 3)))
    assert rec.gyro.dtype == np.float64 and len(rec) == 11 and rec.duration == 1.0
    with pytest.raises(ValueError, match=r"gyro must have shape \(T, 3\) = \(11, 3\)"):
        rb.Recording(t, gyro=np.zeros((10, 3)))
    with pytest.raises(ValueError, match=r"strictly increasing; times\[3\]"):
        rb.Recording(np.array([0, 1, 2, 2, 3.0]))
    # phone uptime stamps in float32 (spacing 0.0625 s near 1e6 s) merge 100 Hz samples: the hint says so
    with pytest.raises(ValueError, match=r"float32 times near 1e\+06 s are only 0.062 s apart.*float64"):
        rb.Recording((1e6 + t / 10).astype(np.float32))
    with pytest.raises(ValueError, match="orientations has a non-finite value at sample 2"):
        q = np.tile([1.0, 0, 0, 0], (11, 1))
        q[2, 1] = np.nan
        rb.Recording(t, orientations=q)
    with pytest.raises(ValueError, match="at least 2 sample times"):
        rb.Recording(np.array([0.0]))


def test_window_keeps_the_samples_inside():
    t = np.linspace(0, 1, 11)
    rec = rb.Recording(t, gyro=np.arange(33.0).reshape(11, 3))
    w = rec.window(0.25, 0.65)
    np.testing.assert_array_equal(w.times, t[3:7])
    np.testing.assert_array_equal(w.gyro, rec.gyro[3:7])
    assert w.accelerations is None
    with pytest.raises(ValueError, match="holds 0 sample"):
        rec.window(0.31, 0.39)


def _as_written(a):
    return np.vectorize(lambda x: float(f"{x:.9E}"))(a)


def test_from_phyphox_reads_a_directory_a_zip_and_a_combined_csv(synthetic, export, tmp_path):
    tg, gyro, ta, accel, _ = synthetic
    from_dir = rb.Recording.from_phyphox(export)
    archive = tmp_path / "export.zip"
    with zipfile.ZipFile(archive, "w") as z:
        for p in export.rglob("*.csv"):
            z.write(p, p.relative_to(export))
    from_zip = rb.Recording.from_phyphox(archive)
    combined = rb.Recording.from_phyphox(write_phyphox(tmp_path / "raw", tg, gyro, ta, accel, combined=True))
    # the gyro's times, restricted to the accelerometer's span (its clock starts half a sample later)
    keep = (tg >= ta[0]) & (tg <= ta[-1])
    for rec in (from_dir, from_zip, combined):
        # the CSVs hold 10 significant digits: relative 5e-10
        np.testing.assert_allclose(rec.times, tg[keep], rtol=1e-9)
        np.testing.assert_allclose(rec.gyro, gyro[keep], rtol=1e-9, atol=1e-12)
        # linear interpolation of the accelerometer (as written: 10 digits) onto the gyro's times
        tw, aw = _as_written(ta), _as_written(accel)
        want = np.stack([np.interp(rec.times, tw, aw[:, k]) for k in range(3)], -1)
        np.testing.assert_allclose(rec.accelerations, want, rtol=1e-12, atol=1e-12)
    assert from_dir.orientations is None


def test_from_phyphox_reads_semicolons_with_decimal_commas(tmp_path):
    p = tmp_path / "Gyroscope rotation rate.csv"
    p.write_text(
        '"Time (s)";"Gyroscope x (rad/s)";"Gyroscope y (rad/s)";"Gyroscope z (rad/s)"\n'
        "0,01;1,5;2;3\n0,02;1,25;2;3\n0,03;1;2;3\n"
    )
    rec = rb.Recording.from_phyphox(p)
    np.testing.assert_allclose(rec.times, [0.01, 0.02, 0.03])
    np.testing.assert_allclose(rec.gyro[:, 0], [1.5, 1.25, 1.0])
    assert rec.accelerations is None


@pytest.mark.parametrize("decimal", [".", ","])
def test_from_phyphox_reads_tab_separated_exports(export, tmp_path, decimal):
    # phyphox's "CSV (Tabulator, decimal point)" and "(Tabulator, decimal comma)": the same samples
    # as the comma-separated export (they read "no gyroscope or accelerometer columns found" before)
    tabbed = tmp_path / "tabs"
    for f in export.rglob("*.csv"):
        out = tabbed / f.relative_to(export)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(f.read_text().replace(",", "\t").replace(".", decimal))
    rec, want = rb.Recording.from_phyphox(tabbed), rb.Recording.from_phyphox(export)
    np.testing.assert_array_equal(rec.times, want.times)
    np.testing.assert_array_equal(rec.gyro, want.gyro)
    np.testing.assert_array_equal(rec.accelerations, want.accelerations)


def test_from_phyphox_ignores_linear_acceleration_and_refuses_two_gyro_files(export, tmp_path):
    import shutil

    d = tmp_path / "export"
    shutil.copytree(export, d)
    (d / "Linear Acceleration.csv").write_text(
        '"Time (s)","Linear Acceleration x (m/s^2)","Linear Acceleration y (m/s^2)","Linear Acceleration z (m/s^2)"\n'
        "0.01,0,0,-9.81\n0.02,0,0,-9.81\n"
    )
    rec = rb.Recording.from_phyphox(d)
    np.testing.assert_array_equal(rec.accelerations, rb.Recording.from_phyphox(export).accelerations)
    shutil.copy(d / "Gyroscope rotation rate.csv", d / "Gyroscope copy.csv")
    with pytest.raises(rb.RecordingError, match="holds gyro columns, and so does"):
        rb.Recording.from_phyphox(d)


def test_a_combined_table_with_a_shorter_sensor_ends_its_samples_at_the_empty_cells(synthetic, tmp_path):
    tg, gyro, ta, accel, _ = synthetic
    path = write_phyphox(tmp_path, tg[:200], gyro[:200], ta[:150], accel[:150], combined=True)
    rec = rb.Recording.from_phyphox(path)
    # the gyro's samples inside the accelerometer's 150
    tw = _as_written(tg)
    assert rec.times[-1] <= ta[149] < tw[tw > rec.times[-1]][0]
    lines = path.read_text().splitlines()
    lines[160] = lines[160] + "1"  # a value after the accelerometer's buffer ended
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(rb.RecordingError, match=r"line 161: the accelerations columns have after its samples ended"):
        rb.Recording.from_phyphox(path)


GYRO_HEADER = '"Time (s)","Gyroscope x (rad/s)","Gyroscope y (rad/s)","Gyroscope z (rad/s)"\n'


@pytest.mark.parametrize(
    "text, message",
    [
        (GYRO_HEADER + "0.01,1,2,3\n0.02,1,x2,3\n", r"line 3: 'x2' in the gyro columns is not a number"),
        (GYRO_HEADER + "0.01,1,2,3\n0.02,1,,3\n0.03,1,2,3\n", r"line 3: the gyro columns have a missing value"),
        (
            GYRO_HEADER + "0.01,1,2,3\n0.02,1,2,3\n0.015,1,2,3\n",
            r"line 4: the gyro time 0.015 s does not follow 0.02 s \(line 3\)",
        ),
        ('"Time (s)","Gyroscope x (rad/s)","Gyroscope y (rad/s)"\n0.01,1,2\n', r"line 1: .* lack axis \['z'\]"),
        ('"Time (s)","Gyroscope x (deg/s)","Gyroscope y (deg/s)","Gyroscope z (deg/s)"\n0,1,2,3\n', "'deg/s'"),
        ('"Time (s)","Pressure (hPa)"\n0.01,1000\n0.02,1000\n', "no gyroscope or accelerometer columns"),
        (GYRO_HEADER + "0.01,1,2,3\n", "1 sample"),
    ],
)
def test_malformed_phyphox_files_name_the_file_and_line(tmp_path, text, message):
    p = tmp_path / "Gyroscope rotation rate.csv"
    p.write_text(text)
    with pytest.raises(rb.RecordingError, match=message) as e:
        rb.Recording.from_phyphox(p)
    assert str(p) in str(e.value)


def test_from_file_reads_rbjax_recordings_with_the_cli_reader(tmp_path):
    p = tmp_path / "rec.csv"
    p.write_text("t,gx,gy,gz\n0,1,2,3\n10,1,2,3.5\n20,1,2,4\n")
    rec = rb.Recording.from_file(p, time_unit="ms")
    np.testing.assert_array_equal(rec.times, [0, 0.01, 0.02])
    np.testing.assert_array_equal(rec.gyro[:, 2], [3, 3.5, 4])
    p.write_text("t,gx,gy,gz\n0,1,2,3\n10,1,oops,3.5\n")
    with pytest.raises(rb.RecordingError, match=r"line 3, column 'gy': 'oops' is not a number"):
        rb.Recording.from_file(p)
    p.write_text("t,gx,gy,gz\n0,1,2,3\n0,1,2,3.5\n")  # the reader's table is fine; the times are not
    with pytest.raises(rb.RecordingError, match=r"rec.csv: Recording: times must be strictly increasing"):
        rb.Recording.from_file(p)


# --- finding the throws ------------------------------------------------------------------------


def test_find_throws_matches_the_true_flights(synthetic, export):
    *_, flights = synthetic
    rec = rb.Recording.from_phyphox(export)
    margin = 0.03
    windows = rb.find_throws(rec, margin=margin)
    assert len(windows) == len(flights)
    dt = np.median(np.diff(rec.times))
    for (t0, t1), (t_rel, t_catch, _) in zip(windows, flights):
        # never a sample of the hand's push or the catch inside a window
        assert t_rel < t0 and t1 < t_catch
        # the edges are the first/last free samples, trimmed by margin: within 2.5 samples of the truth.
        # The first gyro sample after release lies up to 1.2 intervals later (jitter ±20%), and the
        # accelerometer's clock, half a sample off, is interpolated onto the gyro's (one more interval)
        assert abs(t0 - (t_rel + margin)) < 2.5 * dt
        assert abs(t1 - (t_catch - margin)) < 2.5 * dt


def test_find_throws_drops_short_flights_and_needs_accelerations(export):
    rec = rb.Recording.from_phyphox(export)
    # the flights last 0.6, 0.8 and 0.5 s: a minimum of 0.6 s keeps only the 0.8 s one
    assert len(rb.find_throws(rec, min_duration=0.6)) == 1
    with pytest.raises(ValueError, match="no accelerations; pass sensor='gyro'"):
        rb.find_throws(dataclasses.replace(rec, accelerations=None), sensor="accelerometer")
    with pytest.raises(ValueError, match="neither accelerations nor gyro"):
        rb.find_throws(rb.Recording(rec.times, orientations=np.tile([1.0, 0, 0, 0], (len(rec.times), 1))))
    with pytest.raises(ValueError, match="sensor must be 'accelerometer', 'gyro' or None"):
        rb.find_throws(rec, sensor="gps")
    with pytest.raises(ValueError, match="rate_threshold must be finite and > 0"):
        rb.find_throws(rec, sensor="gyro", rate_threshold=np.nan)
    with pytest.raises(ValueError, match="margin must be finite and >= 0"):
        rb.find_throws(rec, margin=-0.1)


@pytest.mark.parametrize("hand", [(0.0, 0.0), (0.15, 0.05)], ids=["abrupt", "wind-up and braking"])
def test_find_throws_from_the_gyro_alone(hand):
    # continuous gyro recordings (DOP853 flights, 0.005 rad/s noise, ±20% dt jitter, held phases
    # turning at 0.2 rad/s); "wind-up and braking": before each release the hand spins the phone up
    # over 0.15 s and after each catch brakes it over 0.05 s, so the fast rotation under torque
    # around each flight must be cut off by the torque-free test, not by the rate threshold
    spin_up, spin_down = hand
    for seed in range(5):
        tg, gyro, _, _, flights = make_recording(seed=seed, spin_up=spin_up, spin_down=spin_down)
        windows = rb.find_throws(rb.Recording(tg, gyro=gyro), margin=0.0)
        assert len(windows) == len(flights), (seed, windows)
        dt = np.median(np.diff(tg))
        for (t0, t1), (t_rel, t_catch, _) in zip(windows, flights):
            # inside the flight (no torque in the window), and within 3 samples of its edges: the
            # central difference at an edge straddles it (1 sample), the 3-sample median of the
            # residual moves the cut by at most 1 more, and the jitter stretches a sample to 1.2 dt
            assert t_rel <= t0 < t_rel + 3 * dt, (seed, t0 - t_rel)
            assert t_catch - 3 * dt < t1 <= t_catch, (seed, t_catch - t1)


def test_the_gyro_finds_the_accelerometers_windows(export):
    # both sensors of one export: the gyro's windows lie within ~3 samples of the accelerometer's
    rec = rb.Recording.from_phyphox(export)
    by_accel = np.array(rb.find_throws(rec))
    by_gyro = np.array(rb.find_throws(rec, sensor="gyro"))
    assert by_gyro.shape == by_accel.shape
    np.testing.assert_allclose(by_gyro, by_accel, atol=3.5 * np.median(np.diff(rec.times)))


def _gyro_flights(pieces, dt=0.01, seed=0):
    """A gyro recording (0.005 rad/s noise, held phases at 0.2 rad/s) with back-to-back torque-free pieces.

    ``pieces``: ``[(t_start, duration, w_start), ...]``, each integrated by DOP853 (rtol = atol =
    1e-12) for ``MOMENTS``; a piece that starts where another ends is an impact: ``ω`` jumps."""
    from scipy.integrate import solve_ivp

    rng = np.random.default_rng(seed)
    t = np.arange(int(3.0 / dt)) * dt
    gyro = 0.2 * np.sin(np.outer(t, [1.3, 2.1, 0.7]))
    I1, I2, I3 = MOMENTS

    def euler(_, w):
        return [(I2 - I3) / I1 * w[1] * w[2], (I3 - I1) / I2 * w[2] * w[0], (I1 - I2) / I3 * w[0] * w[1]]

    for t0, length, w0 in pieces:
        inside = (t >= t0) & (t < t0 + length)
        sol = solve_ivp(euler, (t0, t0 + length), w0, method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True)
        gyro[inside] = sol.sol(t[inside]).T
    return rb.Recording(t, gyro=gyro + rng.normal(0, 0.005, gyro.shape))


def test_find_throws_splits_a_flight_at_an_impact():
    # a knock at t = 1.5 s (ω jumps from (4, 7, 5) rad/s's trajectory to (-6, 3, 8)) and free flight on
    # both sides: two windows, the knock in neither. The residual's 3-sample median hides a one-sample
    # jump, and one inertia fitted across it explained both sides (before the impact test: one window
    # over 1.0-1.9 s). Edges within 3 samples (0.03 s), as in the tests above, the half sample for rounding.
    rec = _gyro_flights([(1.0, 0.5, [4.0, 7.0, 5.0]), (1.5, 0.4, [-6.0, 3.0, 8.0])])
    windows = rb.find_throws(rec, margin=0.0)
    assert len(windows) == 2, windows
    (a0, a1), (b0, b1) = windows
    assert 1.0 <= a0 < 1.035 and 1.465 < a1 < 1.5, windows[0]
    assert 1.5 <= b0 < 1.535 and 1.865 < b1 < 1.9, windows[1]


def test_a_fast_run_of_two_samples_is_skipped_without_a_numpy_warning():
    # |ω| above the threshold for two samples only (a flick): no window, and none of numpy's "Mean of
    # empty slice" RuntimeWarnings, which the impact test's median of no second differences printed on
    # a real phone toss (12-37-15, 12-38-00) before 2026-12-08
    t = np.arange(200) * 0.01
    gyro = np.full((200, 3), 0.1)
    gyro[100:102] = [6.0, 0.0, 0.0]
    with warnings.catch_warnings(), pytest.warns(UserWarning, match="no free flight"):
        warnings.simplefilter("error", RuntimeWarning)
        assert rb.find_throws(rb.Recording(t, gyro=gyro)) == []


def test_the_hand_turning_a_body_about_is_not_a_flight():
    # 0.6 s of fast rotation that no inertia explains as torque-free, as a hand waving a phone about:
    # ω = 7 (sin 6.6t, cos 11.5t, sin 2.6t) + (-3.9, 2.7, 1.3) rad/s in the body, smooth and above
    # rate_threshold. Its Euler equations miss by 0.47 of their terms with the best inertia (a
    # torque-free flight's by the noise: 0.004-0.045 on real phone tosses). Before 2026-12-08 the cut,
    # relative to the stretch's own median residual, kept it as a window 0.74-1.21 s (and 16 such
    # stretches of the real tosses, which fitted as flat bodies)
    t = np.arange(0, 2.0, 0.01)
    gyro = np.full((len(t), 3), 0.1)
    moving = (t >= 0.7) & (t < 1.3)
    tm = t[moving]
    gyro[moving] = 7.0 * np.stack([np.sin(6.6 * tm), np.cos(11.5 * tm), np.sin(2.6 * tm)], -1) + [-3.9, 2.7, 1.3]
    gyro = gyro + np.random.default_rng(0).normal(0, 0.002, gyro.shape)
    with pytest.warns(UserWarning, match="no free flight"):
        assert rb.find_throws(rb.Recording(t, gyro=gyro)) == []
    # a torque-free flight of about the same length and rates is kept (this module's generator)
    rec = _gyro_flights([(0.7, 0.6, [4.0, 7.0, 5.0])])
    assert len(rb.find_throws(rec)) == 1


def test_find_throws_says_when_a_recording_has_no_flight():
    rec = _gyro_flights([])  # held all along: |ω| ≤ 0.35 rad/s
    with pytest.warns(UserWarning, match=r"no free flight in this recording: \|ω\| never exceeds rate_threshold"):
        assert rb.find_throws(rec) == []
    t = np.arange(100) * 0.01
    held = rb.Recording(t, accelerations=np.tile([0.0, 0.0, 9.81], (100, 1)))
    with pytest.warns(UserWarning, match="no free flight in this recording: .a. is not below threshold"):
        assert rb.find_throws(held) == []


def test_the_cli_says_why_a_gyro_only_export_has_no_flight(tmp_path, capsys):
    # the CLI's error gives find_throws' reason: a gyro-only export is judged by |ω|, not |a| (before:
    # "|a| below the threshold ... raise --threshold", options of a sensor the export does not have)
    rec = _gyro_flights([])
    export = tmp_path / "held"
    export.mkdir()
    rows = [f"{t:.9E},{w[0]:.9E},{w[1]:.9E},{w[2]:.9E}" for t, w in zip(rec.times, rec.gyro, strict=True)]
    header = '"Time (s)","Gyroscope x (rad/s)","Gyroscope y (rad/s)","Gyroscope z (rad/s)"'
    (export / "Gyroscope rotation rate.csv").write_text("\n".join([header, *rows]) + "\n")
    assert main(["fit", str(export)]) == 2
    err = capsys.readouterr().err
    assert "no free flight found (|ω| never exceeds rate_threshold = 3.0 rad/s" in err, err
    assert "--threshold" not in err


def test_a_glitch_in_flight_does_not_split_it():
    t = np.arange(200) * 0.01
    a = np.tile([0.0, 0.0, 9.81], (200, 1))
    a[50:150] = 0.0  # free from t = 0.50 to 1.49 s
    a[100] = [0.0, 0.0, 20.0]  # one sample's glitch: the 3-sample median sets it aside
    windows = rb.find_throws(rb.Recording(t, accelerations=a), margin=0.02)
    assert len(windows) == 1
    np.testing.assert_allclose(windows[0], (0.52, 1.47))


def test_plot_throws_shades_the_windows(export):
    pytest.importorskip("matplotlib")
    import matplotlib

    matplotlib.use("Agg")
    rec = rb.Recording.from_phyphox(export)
    windows = rb.find_throws(rec)
    ax = rb.plot_throws(rec, windows)
    assert len(ax.patches) == len(windows)
    import matplotlib.pyplot as plt

    plt.close(ax.figure)


# --- fitting the throws ------------------------------------------------------------------------


def test_each_throw_recovers_the_moment_ratios_within_its_sigma(throws_fit):
    _, res = throws_fit
    m = np.asarray(res.principal_moments)
    s = np.asarray(res.moment_std)
    assert np.all(np.asarray(res.converged)) and not np.any(np.asarray(res.failed))
    assert np.all(np.asarray(res.consistency_pvalue) > 1e-3)
    # 4 σ: 9 moments, P(|z| > 4) = 6e-5 each for a calibrated σ (measured |z| ≤ 1.9 with this seed)
    z = (m - TRUTH) / s
    assert np.all(np.abs(z) < 4), z
    # and the σ are meaningful: small against the moments (a 0.5 s toss resolves them to < 1%)
    assert np.all(s < 0.01)


def test_fit_inertia_takes_recordings(throws_fit, export):
    windows, res = throws_fit
    rec = rb.Recording.from_phyphox(export)
    with pytest.raises(TypeError, match="carries the data; do not also pass"):
        rb.fit_inertia(rec, body_rates=rec.gyro)
    mixed = [rec.window(*windows[0]), dataclasses.replace(rec.window(*windows[1]), accelerations=None)]
    with pytest.raises(ValueError, match=r"recordings \[1\] have no accelerations"):
        rb.fit_inertia(mixed)


def test_fit_inertia_passes_a_recordings_gyro_on():
    t = np.arange(5) * 0.01
    rec = rb.Recording(t, gyro=np.tile([1.0, 2.0, 3.0], (5, 1)))
    # a constant rate excites nothing: fit_inertia's own check of the body rates it was given
    with pytest.raises(ValueError, match="fit_inertia: too little excitation"):
        rb.fit_inertia(rec)


def test_a_fit_result_round_trips_bit_for_bit(throws_fit, tmp_path):
    _, res = throws_fit
    res = dataclasses.replace(res, member_errors=("recording 3: too few samples",))
    path = tmp_path / "fit.npz"
    rb.save(path, res)
    back = rb.load(path, expect=rb.FitResult)
    for f in dataclasses.fields(res):
        a, b = getattr(res, f.name), getattr(back, f.name)
        if f.metadata.get("static"):
            assert a == b and type(a) is type(b), f.name
        else:
            a, b = np.asarray(a), np.asarray(b)
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), f.name


# --- the command line --------------------------------------------------------------------------


@pytest.mark.slow  # fits each throw and draws a PNG per throw (~9 s); the joint CLI test stays quick
def test_cli_fits_each_throw_of_a_phyphox_export(export, tmp_path, capsys):
    pytest.importorskip("matplotlib")
    png, out = tmp_path / "fits.png", tmp_path / "fit.json"
    assert main(["fit", str(export), "--plot", str(png), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "3 throw(s)" in text and text.count("converged (trust) True") == 3
    assert png.read_bytes()[:4] == b"\x89PNG"
    import json

    report = json.loads(out.read_text())
    comb = report["combined"]
    assert comb["throws"] == 3
    # the median of 3 throws, each within ~1e-3 (its σ): within 2e-3 of the truth
    np.testing.assert_allclose(comb["moments"], TRUTH, atol=2e-3)
    np.testing.assert_allclose(comb["ratios"], TRUTH[:2] / TRUTH[2], atol=5e-3)
    # the printed combination is the report's, to the decimals its σ warrants, and its σ is not "0.0000"
    printed = re.search(r"combined: .*?I/trI = ([0-9.]+) ± ([0-9.]+)", text)
    decimals = len(printed[1].split(".")[1])
    assert abs(float(printed[1]) - comb["moments"][0]) <= 0.5 * 10.0**-decimals and float(printed[2]) > 0


def test_cli_refuses_options_that_do_not_apply(export, tmp_path, capsys):
    assert main(["fit", str(export), "--accelerometer"]) == 2
    assert "--accelerometer do(es) not apply to a phyphox export" in capsys.readouterr().err
    plain = tmp_path / "rec.csv"
    plain.write_text("t,gx,gy,gz\n0,1,2,3\n1,1,2,3\n")
    assert main(["fit", str(plain), "--plot", "x.png"]) == 2
    assert "--plot applies to phyphox exports" in capsys.readouterr().err


def test_cli_fits_the_throws_jointly_unless_separate(export, tmp_path, capsys):
    import json

    out = tmp_path / "joint.json"
    assert main(["fit", str(export), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "one inertia fitted to 3 throw(s) jointly" in text and text.count("in the joint fit: rms") == 3
    comb = json.loads(out.read_text())["combined"]
    assert comb["joint"] and comb["throws"] == 3 and comb["converged"]
    # one body, three throws of ~60-80 samples at 0.005 rad/s: the joint σ is ~5e-4 of tr I; within 3σ
    np.testing.assert_array_less(np.abs(np.array(comb["moments"]) - TRUTH), 3 * np.array(comb["moment_std"]))
    assert main(["fit", str(export), "--separate", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "jointly" not in text and "median ± spread" in text
    assert "joint" not in json.loads(out.read_text())["combined"]


def test_cli_with_one_converged_throw_prints_no_spread_of_zero(tmp_path, capsys):
    # a median of one throw has spread 0: the combined line read "I/trI = 0.1074 ± 0, ..." on a real
    # phone toss (12-16-50, one of two throws converged) before 2026-12-08, a σ of zero that no fit
    # supports. With one throw the line says so and points to that throw's own σ
    tg, gyro, ta, accel, _ = make_recording(seed=4, flights=((1.0, 0.7),))
    export = write_phyphox(tmp_path, tg, gyro, ta, accel)
    assert main(["fit", str(export), "--separate"]) == 0
    text = capsys.readouterr().out
    assert text.count("converged (trust) True") == 1, text
    assert "one converged throw" in text and "median ± spread" not in text, text
    assert not re.search(r"± 0(?![.0-9])", text), text


def test_lists_a_find_throws_user_may_pass_by_mistake_are_named(tmp_path):
    # find_throws gives (t0, t1) pairs, not recordings: fit_inertia names the mix-up and the remedy
    # before it builds anything (NumPy's own "inhomogeneous shape" error was what reached users)
    tg, gyro, ta, accel, _ = make_recording(seed=2)
    rec = rb.Recording.from_phyphox(write_phyphox(tmp_path, tg, gyro, ta, accel))
    windows = rb.find_throws(rec)
    remedy = r"\[rec.window\(t0, t1\) for t0, t1 in windows\]"
    with pytest.raises(TypeError, match=r"list of \(t0, t1\) pairs.*" + remedy):
        rb.fit_inertia(windows)
    with pytest.raises(TypeError, match=r"mixes Recordings with other things \(item 1 is a tuple\)"):
        rb.fit_inertia([rec.window(*windows[0]), windows[1]])
    with pytest.raises(ValueError, match=r"times must be 1-D.*pass gyro readings as body_rates="):
        rb.fit_inertia(rec.window(*windows[0]).gyro)


# --- empty recordings --------------------------------------------------------------------------


def test_empty_recordings_are_refused_in_rbjax_words(tmp_path, capsys):
    # a header and no rows reaches every entry as a ValueError naming the file or argument and the
    # remedy, never NumPy's "zero-size array" (which a reduction over no samples raises)
    export = tmp_path / "export"
    export.mkdir()
    phyphox = export / "Gyroscope rotation rate.csv"
    phyphox.write_text(GYRO_HEADER)
    with zipfile.ZipFile(tmp_path / "export.zip", "w") as z:
        z.write(phyphox, "Gyroscope rotation rate.csv")
    for path in (phyphox, export, tmp_path / "export.zip"):
        with pytest.raises(rb.RecordingError, match="the gyro columns have a header and no samples") as e:
            rb.Recording.from_phyphox(path)
        assert str(path) in str(e.value) and "export again from phyphox" in str(e.value)
    csv = tmp_path / "rec.csv"
    csv.write_text("t,qw,qx,qy,qz,gx,gy,gz\n")
    with pytest.raises(rb.RecordingError, match="rec.csv: only a header, no samples; write the samples below it"):
        rb.Recording.from_file(csv)
    npz = tmp_path / "rec.npz"
    np.savez(npz, times=np.zeros(0), gyro=np.zeros((0, 3)))
    with pytest.raises(rb.RecordingError, match=r"rec.npz: no samples \(empty arrays\); save the recording's data"):
        rb.Recording.from_file(npz)
    with pytest.raises(ValueError, match=r"Recording: times is empty \(shape \(0,\)\): no samples; .*at least 2"):
        rb.Recording(np.zeros(0), gyro=np.zeros((0, 3)))
    for path, message in (
        (phyphox, "the gyro columns have a header and no samples"),
        (export, "the gyro columns have a header and no samples"),
        (csv, "only a header, no samples"),
        (npz, "no samples (empty arrays)"),
    ):
        assert main(["fit", str(path)]) == 2
        err = capsys.readouterr().err
        assert err.startswith("rbjax: error: ") and err.count("\n") == 1 and message in err, err


def test_fit_inertia_refuses_empty_arrays_in_its_words():
    with pytest.raises(ValueError, match="fit_inertia: the recording has no samples"):
        rb.fit_inertia(np.zeros(0), body_rates=np.zeros((0, 3)))
    t = np.linspace(0.0, 1.0, 50)
    with pytest.raises(ValueError, match="fit_inertia: recording 1 has no samples"):
        rb.fit_inertia([t, np.zeros(0)], body_rates=[np.ones((50, 3)), np.zeros((0, 3))])
