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


@pytest.mark.slow  # ~20 s on one core: the whole suite (CI) runs it
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


def _imports(path: Path, module: str, modules: set[str]) -> set[str]:
    """The rbjax modules ``module`` (at ``path``) imports, at the top or inside functions."""
    import ast

    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package
                for _ in range(node.level - 1):
                    parent = parent.rpartition(".")[0]
                base = parent + ("." + node.module if node.module else "")
            subs = {f"{base}.{a.name}" for a in node.names} & modules
            # `from . import x` of submodules imports them, not the package's own names
            found |= subs if len(subs) == len(node.names) else subs | {base}
        elif isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
    return (found & modules) - {module}


def test_no_import_circle_among_rbjax_modules():
    files = {}
    for p in (ROOT / "rbjax").rglob("*.py"):
        parts = p.relative_to(ROOT).with_suffix("").parts
        files[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    graph = {m: _imports(p, m, set(files)) for m, p in files.items()}

    def reaches(start: str, goal: str) -> bool:
        seen, todo = set(), [start]
        while todo:
            m = todo.pop()
            if m == goal:
                return True
            if m not in seen:
                seen.add(m)
                todo += graph[m]
        return False

    # a package's __init__ may import its submodules; nothing else may come back round
    circles = sorted(f"{a} -> {b}" for a in graph for b in graph[a] if not b.startswith(a + ".") and reaches(b, a))
    assert not circles, f"import circles (function-level imports count): {circles}"
