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

    for sub, word in (("demo", "--bodies"), ("bench", "--quick"), ("fit", "not yet available")):
        with pytest.raises(SystemExit) as e:
            main([sub, "--help"])
        assert e.value.code == 0 and word in capsys.readouterr().out, sub
    r = _run("bench", "--list")
    assert r.returncode == 0 and "checked_cost" in r.stdout.split()


@pytest.mark.parametrize(
    "args, message",
    [
        (("frobnicate",), "invalid choice: 'frobnicate'"),
        (("fit",), "'fit' is not yet available"),
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
