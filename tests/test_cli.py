"""``python -m rbjax``: subcommands, --help, one-line errors (exit 2), --debug tracebacks."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _run(*args: str, timeout: float = 120, extra: dict | None = None) -> subprocess.CompletedProcess:
    # no compile cache in ~/.cache from the tests (test_fit_keeps_compiled_programs_on_disk sets its own)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu", "RBJAX_CACHE_DIR": "off", **(extra or {})}
    return subprocess.run(
        [sys.executable, "-m", "rbjax", *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
        timeout=timeout,
    )


def test_help_lists_the_subcommands_and_each_has_help(capsys):
    r = _run("--help")
    assert r.returncode == 0 and all(c in r.stdout for c in ("demo", "bench", "fit", "--debug"))
    # in-process for the subcommands' --help (no jax work, saves three interpreter starts)
    from rbjax._cli import main

    for sub, word in (("demo", "--bodies"), ("bench", "--quick"), ("fit", "recording")):
        with pytest.raises(SystemExit) as e:
            main([sub, "--help"])
        assert e.value.code == 0 and word in capsys.readouterr().out, sub
    r = _run("bench", "--list")
    assert r.returncode == 0 and "checked_cost" in r.stdout.split()


@pytest.mark.parametrize(
    "args, message",
    [
        (("frobnicate",), "invalid choice: 'frobnicate'"),
        (("fit",), "the following arguments are required: recording"),
        (("fit", "no_such_recording.csv"), "no such file: no_such_recording.csv"),
        (("bench", "no_such_benchmark"), "unknown benchmark(s) ['no_such_benchmark']"),
    ],
)
def test_errors_are_one_line_with_exit_status_2(args, message, capsys):
    from rbjax._cli import main

    assert main(list(args)) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("rbjax: error: ") and message in err


def test_library_errors_become_one_line_unless_debug(capsys):
    # a ValueError raised deep inside rbjax.simulate (dt <= 0), reached through the demo;
    # in-process: interpreter start-up costs seconds, the subprocess path is tested above
    from rbjax._cli import main

    args = ["demo", "--bodies", "2", "--seconds", "0.01", "--dt", "-1"]
    assert main(args) == 2
    assert capsys.readouterr().err == "rbjax: error: ValueError: dt must be finite and > 0, got -1.0\n"
    with pytest.raises(ValueError, match="dt must be finite"):
        main(["--debug", *args])


@pytest.mark.slow
def test_fit_reads_a_csv_recording_and_recovers_the_inertia(tmp_path, capsys):
    """A torque-free recording made by scipy's DOP853 (not rbjax), written as CSV.

    Clean data: the unit-trace inertia is recovered to 1e-4 relative (the library's
    own target for clean data; the fit is far better, ~1e-9, on noise-free samples).
    """
    import json

    import numpy as np
    from reference import reference_rotation, to_body

    from rbjax._cli import main

    I_true = np.diag([1.0, 2.0, 2.6])
    t = np.linspace(0.0, 1.0, 201)
    q, w = reference_rotation(I_true, np.array([1.0, 0, 0, 0]), np.array([1.0, 0.3, -2.0]), t)
    gyro = to_body(q, w)
    path = tmp_path / "rec.csv"
    np.savetxt(path, np.column_stack([t, q, gyro]), delimiter=",", header="t,qw,qx,qy,qz,gx,gy,gz", comments="")
    out = tmp_path / "fit.json"
    assert main(["fit", str(path), "--out", str(out)]) == 0
    # standard JSON (inf and NaN as null, test_json_text_writes_standard_json): strict readers
    # (JSON.parse, jq) refuse Python's Infinity/NaN tokens
    res = json.loads(out.read_text(), parse_constant=_not_json)
    # noise-free data leave nothing for drag or a gyro bias to explain: not supported (the score
    # statistic over a residual variance at round-off read ΔBIC = 4e301 for the bias)
    assert all(v < 0 for v in res["delta_bic"].values()), res["delta_bic"]
    assert res["scale_fixed"] is False
    I_fit = np.asarray(res["inertia"])
    I_ref = I_true / np.trace(I_true)
    assert np.linalg.norm(I_fit - I_ref) / np.linalg.norm(I_ref) < 1e-4
    assert "principal moments" in capsys.readouterr().out


_GOOD = "t,qw,qx,qy,qz,gx,gy,gz\n0,1,0,0,0,0.1,0.2,0.3\n0.01,1,0,0,0,0.1,0.2,0.3\n"


@pytest.mark.parametrize(
    "text, message",
    [
        ("", "the file is empty; expected a header row ('t,qw,qx,qy,qz,gx,gy,gz')"),
        ("\n\n# only a comment\n", "the file is empty"),
        ("t,qw,qx,qy,qz\n", "only a header, no samples"),
        (
            "t;qw;qx;qy;qz\n0;1;0;0;0\n",
            "line 1: the header 't;qw;qx;qy;qz' is not comma-separated (it is separated by semicolons)",
        ),
        ("t\tqw\tqx\tqy\tqz\n0\t1\t0\t0\t0\n", "(it is separated by tabs)"),
        ("t,qw,qx,qy,qz\n0,1,0,0,0\n0.01,1,0,0\n", "line 3 has 4 fields but the header has 5 (a ragged row"),
        ("t,qw,qx,qy,qz\n0,1,0,0,0\n0.01,1,zero,0,0\n", "line 3, column 'qx': 'zero' is not a number"),
        (
            "t,qw,qx,qy,qz,gx,gy\n0,1,0,0,0,1,2\n",
            "columns ['gx', 'gy'] of the gyro group are there but ['gz'] are missing",
        ),
        ("time,qw,qx,qy,qz\n0,1,0,0,0\n1,1,0,0,0\n", "no 't' column (sample times) in the header"),
        ("t,t,qw,qx,qy,qz\n0,0,1,0,0,0\n", "column(s) ['t'] appear more than once"),
        ("t,qw,qx,qy,qz\n0,1,0,0,0\n", "1 sample(s); a fit needs a recording of many samples"),
        ("t,x,y\n0,1,2\n1,1,2\n", "has neither quaternions (qw,qx,qy,qz) nor gyro (gx,gy,gz)"),
        # a 200 Hz recording with its times in milliseconds: 5 "s" between samples at |ω| = 0.37 rad/s
        (_GOOD.replace("0.01,", "5,"), "the times look like milliseconds; pass --time-unit ms"),
        (_GOOD, "--accelerometer needs the accelerations columns"),
    ],
)
def test_malformed_recordings_get_one_line_and_exit_status_2(tmp_path, capsys, text, message):
    """Each malformed CSV is refused before any fitting, in one line naming the file, the line and the remedy."""
    from rbjax._cli import main

    path = tmp_path / "rec.csv"
    path.write_text(text)
    extra = ["--accelerometer"] if "--accelerometer" in message else []
    assert main(["fit", str(path), *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"rbjax: error: {path}: "), err
    assert message in err, err


def test_malformed_npz_recordings_are_refused(tmp_path, capsys):
    import numpy as np

    from rbjax._cli import main

    cases = {
        "noarrays.npz": ({"quaternions": np.ones((3, 4))}, "missing arrays ['times']"),
        "shape.npz": (
            {"times": np.arange(3.0), "gyro": np.ones((3, 2))},
            "array 'gyro' has shape (3, 2), expected (3, 3)",
        ),
    }
    for name, (arrays, message) in cases.items():
        np.savez(tmp_path / name, **arrays)
        assert main(["fit", str(tmp_path / name)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
    (tmp_path / "broken.npz").write_bytes(b"not a zip")
    assert main(["fit", str(tmp_path / "broken.npz")]) == 2
    assert "not a readable .npz file" in capsys.readouterr().err


def test_time_unit_converts_to_seconds_and_slow_samples_get_a_note(tmp_path):
    """``--time-unit ms`` divides by 1000 exactly as documented; a 1 s interval with a slow gyro is only a note."""
    import numpy as np

    from rbjax._recording import read_recording, time_unit_hint

    path = tmp_path / "rec.csv"
    path.write_text(_GOOD.replace("0.01,", "5,"))
    rec = read_recording(path, "ms")
    np.testing.assert_array_equal(rec["times"], [0.0, 0.005])
    assert time_unit_hint(rec) is None
    np.testing.assert_array_equal(rec["gyro"][1], [0.1, 0.2, 0.3])
    slow = {"times": np.arange(3.0), "gyro": np.full((3, 3), 0.01)}  # a satellite at 1 Hz, 0.017 rad per sample
    assert time_unit_hint(slow).startswith("note: the median sample interval is 1 s")


@pytest.mark.slow
def test_fit_options_reach_the_sensor_models(tmp_path, capsys):
    """Gyro-only CSV input, ``--gyro-bias`` and ``--loss huber`` through the command line.

    One torque-free tumble by scipy's DOP853 (1 s @ 200 Hz, |ω| ≈ 3.4 rad/s), gyro noise
    0.01 rad/s, a constant bias (0.02, -0.01, 0.015) rad/s, and three orientation glitches of
    1 rad. Tolerances are the library's own: the fitted moments and bias within 4 reported σ
    (a 1-in-10⁴ miss for a calibrated σ), and the robust loss names the three glitched samples.
    """
    import json

    import numpy as np
    from reference import qmul, reference_rotation, to_body

    from rbjax._cli import main

    rng = np.random.default_rng(3)
    I_true = np.diag([1.0, 2.0, 2.6])
    t = np.linspace(0.0, 1.0, 201)
    q, w = reference_rotation(I_true, np.array([1.0, 0, 0, 0]), np.array([1.0, 3.0, -1.0]), t)
    bias = np.array([0.02, -0.01, 0.015])
    gyro = to_body(q, w) + bias + rng.normal(0, 0.01, (len(t), 3))
    lam = np.linalg.eigvalsh(I_true / np.trace(I_true))

    def fit(columns, header, *flags):
        path = tmp_path / "rec.csv"
        np.savetxt(path, np.column_stack([t, *columns]), delimiter=",", header=header, comments="")
        out = tmp_path / "fit.json"
        code = main(["fit", str(path), "--out", str(out), *flags])
        return code, json.loads(out.read_text())

    # gyro only, bias fitted: the shape of I from body rates alone
    code, res = fit([gyro], "t,gx,gy,gz", "--gyro-bias")
    assert code == 0 and res["converged"] and res["scale_fixed"] is False
    assert np.all(np.abs(np.asarray(res["principal_moments"]) - lam) < 4 * np.asarray(res["moment_std"]))
    assert np.all(np.abs(np.asarray(res["gyro_bias"]) - bias) < 4 * np.asarray(res["gyro_bias_std"]))
    # quaternion columns present but ignored: the same fit
    code, res2 = fit([q, gyro], "t,qw,qx,qy,qz,gx,gy,gz", "--gyro-only", "--gyro-bias")
    np.testing.assert_allclose(res2["principal_moments"], res["principal_moments"], rtol=1e-10)
    # orientations with three 1-rad glitches, robust loss: the glitches are named
    glitched = q.copy()
    bad = [40, 100, 160]
    for i in bad:  # a 1 rad turn about the body x axis
        glitched[i] = qmul(q[i], np.array([np.cos(0.5), np.sin(0.5), 0.0, 0.0]))
    code, res = fit([glitched, gyro], "t,qw,qx,qy,qz,gx,gy,gz", "--gyro-bias", "--loss", "huber")
    assert set(bad) <= set(res["outliers"]), res["outliers"]
    assert "down-weighted samples" in capsys.readouterr().out


def _not_json(token):
    raise AssertionError(f"--out wrote {token}, which is not JSON")


def test_json_text_writes_standard_json():
    import jax.numpy as jnp
    import numpy as np

    from rbjax._cli_fit import json_text

    text = json_text({"a": float("inf"), "b": np.array([1.0, np.nan]), "c": jnp.float32(2.5), "d": [True, None, "x"]})
    assert json.loads(text, parse_constant=_not_json) == {"a": None, "b": [1.0, None], "c": 2.5, "d": [True, None, "x"]}


@pytest.mark.parametrize("drag", [(float("nan"), float("nan")), (0.05, 0.01)], ids=["torque-free", "drag"])
def test_plotted_fit_rates_are_the_fitted_model(drag):
    # the curves `fit --plot` draws: body rates of I ω̇ = (I ω) × ω - (c1 + c2|ω|) ω (unit-trace I)
    # against scipy's DOP853 (rtol = atol = 1e-12) at jittered sample times. Torque-free they come
    # from the exact solution (1e-9: elliptic functions in float64 over 0.8 s); with drag from RK4
    # at 20 steps per sample, interpolated linearly: O(h²|ω̈|) ≈ (4e-4 s)² x 100 rad/s³ ≈ 2e-5 rad/s.
    import numpy as np
    from scipy.integrate import solve_ivp

    from rbjax._cli_plot import fitted_rates

    I = np.diag([1.0, 3.2, 4.1]) * 1e-4
    In = I / np.trace(I)
    c1, c2 = np.nan_to_num(drag)
    w0 = np.array([0.4, 9.0, 1.5])
    t = np.linspace(0.0, 0.8, 81) + np.r_[0.0, np.random.default_rng(0).uniform(-2e-3, 2e-3, 79), 0.0]

    def rhs(_, w):
        return np.linalg.solve(In, np.cross(In @ w, w) - (c1 + c2 * np.linalg.norm(w)) * w)

    ref = solve_ivp(rhs, (t[0], t[-1]), w0, "DOP853", t_eval=t, rtol=1e-12, atol=1e-12).y.T
    got = fitted_rates(I, w0, t, np.asarray(drag))
    tol = 1e-9 if np.isnan(drag[0]) else 5e-5
    np.testing.assert_allclose(got, ref, rtol=0, atol=tol)


@pytest.mark.slow  # two interpreters, each fitting
def test_fit_keeps_compiled_programs_on_disk(tmp_path):
    # python -m rbjax fit is a new process each time: its programs go to the persistent compile
    # cache, and the second run reads them back and gives the same result
    import json

    import numpy as np
    from scipy.integrate import solve_ivp

    moments = np.array([1.0, 3.2, 4.1])

    def euler(_, w):
        return [
            (moments[1] - moments[2]) / moments[0] * w[1] * w[2],
            (moments[2] - moments[0]) / moments[1] * w[2] * w[0],
            (moments[0] - moments[1]) / moments[2] * w[0] * w[1],
        ]

    t = np.arange(80) * 0.01
    w = solve_ivp(euler, (0, t[-1]), [2.0, 6.0, 5.0], method="DOP853", rtol=1e-12, atol=1e-12, t_eval=t).y.T
    w = w + np.random.default_rng(0).normal(0, 0.005, w.shape)
    csv = tmp_path / "throw.csv"
    np.savetxt(csv, np.column_stack([t, w]), delimiter=",", header="t,gx,gy,gz", comments="")
    cache = tmp_path / "cache"
    outs = []
    for k in range(2):
        out = tmp_path / f"fit{k}.json"
        r = _run("fit", str(csv), "--out", str(out), timeout=300, extra={"RBJAX_CACHE_DIR": str(cache)})
        assert r.returncode == 0, r.stderr
        assert any(cache.iterdir()), "no program kept after the first run"
        outs.append(json.loads(out.read_text()))
    assert outs[0] == outs[1]
    got = np.sort(np.asarray(outs[0]["principal_moments"]))
    np.testing.assert_allclose(got, moments / moments.sum(), atol=4 * max(outs[0]["moment_std"]))


@pytest.mark.parametrize(
    "x, s, printed",
    [
        # σ to two significant digits, the value to the same decimal place (at least four decimals)
        (0.1204771, 3.71e-5, "0.120477 ± 0.000037"),
        (0.385528, 1.04e-4, "0.38553 ± 0.00010"),
        (0.12594, 0.00481, "0.1259 ± 0.0048"),
        (0.5, 0.25, "0.5000 ± 0.2500"),
        # no σ (a direction the data leave undetermined): said, not printed as a number
        (0.3, float("inf"), "0.3000 ± inf"),
        (0.3, float("nan"), "0.3000 ± nan"),
    ],
)
def test_fit_prints_sigma_to_its_significant_digits(x, s, printed):
    from rbjax._cli_fit import _pm

    assert _pm(x, s) == printed


@pytest.mark.parametrize(
    "converged, joint, status",
    [
        # one recording, or a phyphox export of one throw: no joint fit
        ([True], None, 0),
        ([False], None, 1),
        # several throws, --separate: the median of those that converged
        ([True, True, True], None, 0),
        ([True, False, True], None, 3),
        ([False, False, False], None, 1),
        # several throws, joint (the default): the joint fit is the answer asked for
        ([True, True, True], True, 0),
        ([True, False, True], True, 3),
        ([False, False, False], True, 3),
        ([True, True, True], False, 1),
        ([True, False, True], False, 1),
        ([False, False, False], False, 1),
    ],
)
def test_exit_status_says_whether_what_was_asked_for_converged(converged, joint, status, capsys):
    from rbjax._cli import main
    from rbjax._cli_fit import exit_status

    assert exit_status(converged, joint) == status
    # every status is explained in fit --help
    with pytest.raises(SystemExit):
        main(["fit", "--help"])
    text = capsys.readouterr().out
    assert "exit status:" in text and all(f"\n  {k}  " in text for k in (0, 1, 2, 3))


def test_a_phyphox_export_of_throws_none_converged_exits_1(tmp_path, capsys):
    # two throws and --gyro-bias, each fit and the joint one stopped after one step: nothing the
    # script asked for converged, so the status must not be 0 (it was: the joint fit's report
    # counted as a combination whether or not it converged)
    from _phyphox_data import make_recording, write_phyphox

    from rbjax._cli import main

    tg, gyro, ta, accel, _ = make_recording(seed=3, flights=((1.0, 0.5), (2.0, 0.5)), hold_end=0.5)
    export = write_phyphox(tmp_path / "export", tg, gyro, ta, accel)
    assert main(["fit", str(export), "--gyro-bias", "--max-steps", "1"]) == 1
    text = capsys.readouterr().out
    assert "2 throw(s)" in text and "converged (trust) False" in text and "joint fit converged (trust): False" in text
    assert text.count("    diagnosis: ") == 3  # each throw's and the joint fit's
    assert main(["fit", str(export), "--gyro-bias", "--max-steps", "1", "--separate"]) == 1
    assert "no throw converged" in capsys.readouterr().out


@pytest.mark.parametrize("flag", ["--out", "--plot"])
def test_an_output_path_that_cannot_be_written_is_refused_before_the_fit(tmp_path, capsys, flag):
    from rbjax._cli import main

    csv = tmp_path / "rec.csv"
    csv.write_text(_GOOD)
    missing = tmp_path / "missing" / "fit.json"
    # the recording is not even read: the fit would take its time and then fail to write
    assert main(["fit", str(tmp_path / "not_read.csv"), flag, str(missing)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rbjax: error: ") and err.count("\n") == 1
    assert f"{flag} {missing}: no directory {missing.parent}; create it first" in err
    assert main(["fit", str(csv), flag, str(tmp_path)]) == 2
    assert f"{flag} {tmp_path} is a directory" in capsys.readouterr().err


def test_plot_has_residual_panels_and_says_why_a_fit_was_rejected(tmp_path):
    # two throws with the same measured rates (scipy's DOP853, torque-free) plus 0.01 rad/s on ωy:
    # their residual panels hold measured - fitted = that offset (the fitted model is the exact
    # solution, 1e-9); the first fit's verdict is "converged", the second's names its failed checks
    import types

    import numpy as np
    from scipy.integrate import solve_ivp

    import rbjax as rb
    from rbjax._cli_plot import plot_throw_fits

    pytest.importorskip("matplotlib")
    In = np.diag([1.0, 3.2, 4.1]) / 8.3
    w0 = np.array([0.4, 9.0, 1.5])
    t = np.linspace(0.0, 0.5, 51)

    def rhs(_, w):
        return np.linalg.solve(In, np.cross(In @ w, w))

    gyro = solve_ivp(rhs, (0, t[-1]), w0, "DOP853", t_eval=t, rtol=1e-12, atol=1e-12).y.T + [0.0, 0.01, 0.0]
    throws = [rb.Recording(t, gyro=gyro)] * 2

    def both(*values):
        return np.array(values)

    res = types.SimpleNamespace(
        failed=both(False, False),
        inertia=np.stack([In, In]),
        initial_angular_velocity=np.stack([w0, w0]),
        drag=np.full((2, 2), np.nan),
        gyro_bias=np.zeros((2, 3)),
        converged=both(True, False),
        solver_converged=both(True, False),
        model_consistent=both(True, False),
        well_determined=both(True, True),
        consistency_pvalue=both(0.4, 1e-30),
        iterations=both(12, 200),
        on_boundary=both(False, True),
        misfit_structured=both(False, False),
        diagnosis=("residuals like the noise", "misfit 3x the gyro noise"),
    )
    joint = types.SimpleNamespace(**{k: v[1] for k, v in vars(res).items()})
    png = tmp_path / "fits.png"
    fig = plot_throw_fits(str(png), throws, res, joint)
    assert png.read_bytes()[:4] == b"\x89PNG"
    axes = fig.axes
    assert [ax.get_ylabel() for ax in axes] == ["ω (rad/s, body)", "residual (rad/s)"] * 2
    for ax in axes[1::2]:
        residuals = np.stack([line.get_ydata() for line in ax.get_lines()[:3]], -1)
        np.testing.assert_allclose(residuals, np.broadcast_to([0.0, 0.01, 0.0], gyro.shape), atol=1e-8)
    # the verdict is FitResult.converged's "trust this fit", with its reasons, the white-noise χ² p-value
    # as a diagnostic and the one-line diagnosis
    title = axes[0].get_title().replace("\n", " ")
    assert title == "throw 1: converged, trusted (white-noise χ² p-value 0.4); residuals like the noise"
    rejected = axes[2].get_title().replace("\n", " ")
    assert rejected.startswith("throw 2: NOT trusted: solver stopped short of its tolerances (200 steps)")
    assert "on the edge of physical inertias" in rejected and "(white-noise χ² p-value 1e-30)" in rejected
    assert rejected.endswith("misfit 3x the gyro noise")
    assert fig.get_suptitle().replace("\n", " ").startswith("joint fit of 2 throws: NOT trusted")
