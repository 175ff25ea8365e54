"""The code base stays ruff-clean (lint rules and formatting in pyproject.toml)."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _ruff() -> list[str]:
    exe = shutil.which("ruff") or str(Path(sys.executable).parent / "ruff")
    if not Path(exe).exists():
        pytest.skip("ruff not installed (it is in the 'test' extra)")
    return [exe]


def test_ruff_check_is_clean():
    r = subprocess.run([*_ruff(), "check", "."], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-3000:]


def test_ruff_format_is_clean():
    r = subprocess.run([*_ruff(), "format", "--check", "."], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-3000:]


def _pyright() -> list[str]:
    exe = shutil.which("pyright") or str(Path(sys.executable).parent / "pyright")
    if not Path(exe).exists():
        pytest.skip("pyright not installed (pyright[nodejs] is in the 'test' extra)")
    return [exe]


def test_pyright_is_clean():
    # settings in [tool.pyright] of pyproject.toml; --pythonpath points pyright at the interpreter
    # running the tests, so it resolves jax, equinox, ... from this environment whatever venv it is
    r = subprocess.run(
        [*_pyright(), "--pythonpath", sys.executable, "--outputjson"], cwd=ROOT, capture_output=True, text=True
    )
    try:
        report = json.loads(r.stdout)
    except json.JSONDecodeError:
        pytest.fail(f"pyright did not run: {r.stdout[-2000:]}{r.stderr[-2000:]}")
    errors = [d for d in report["generalDiagnostics"] if d["severity"] == "error"]
    shown = "\n".join(f"{d['file']}:{d['range']['start']['line'] + 1}: {d['message']}" for d in errors[:20])
    assert report["summary"]["filesAnalyzed"] > 20, "pyright checked too few files: is [tool.pyright] include right?"
    assert not errors, f"{len(errors)} pyright errors:\n{shown}"
