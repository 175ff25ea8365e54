"""``python -m rbjax``: subcommands, --help, one-line errors (exit 2), --debug tracebacks."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _run(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu"}
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
    res = json.loads(out.read_text())
    assert res["scale_fixed"] is False
    I_fit = np.asarray(res["inertia"])
    I_ref = I_true / np.trace(I_true)
    assert np.linalg.norm(I_fit - I_ref) / np.linalg.norm(I_ref) < 1e-4
    assert "principal moments" in capsys.readouterr().out
