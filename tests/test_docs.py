"""The documentation: the site builds with ``mkdocs build --strict``, and every Python example runs.

Every ```` ```python ```` block of README.md and docs/*.md is executed, the blocks of one page in
order in one namespace (so a page's set-up is visible on the page), with JAX's default
configuration (float32, standard dtype promotion) as a reader would have it, in a temporary
working directory. A block preceded by ``<!-- skip: reason -->`` is not run (cluster launches); the
reason is part of the page. The site build is offline (mkdocs-material's ``offline`` plugin, no
web fonts) and fails on any warning: a broken link or anchor, a missing cross-reference, a
docstring griffe cannot parse, a page missing from the navigation.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest

import rbjax as rb

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
_FENCE = re.compile(r"^```python[^\n]*\n(.*?)^```[ \t]*$", re.S | re.M)
_SKIP = re.compile(r"<!--\s*skip:\s*(.+?)\s*-->\s*$")


def blocks(page: Path) -> list[tuple[int, str, str | None]]:
    """``(line, source, skip_reason)`` of each Python block of ``page``."""
    text = page.read_text()
    out = []
    for m in _FENCE.finditer(text):
        before = text[: m.start()].rstrip("\n").rsplit("\n", 1)[-1]
        skip = _SKIP.search(before)
        out.append((text.count("\n", 0, m.start()) + 1, m.group(1), skip.group(1) if skip else None))
    return out


def test_every_page_is_collected_and_skips_are_explained():
    names = {p.name for p in PAGES}
    assert {"README.md", "getting-started.md", "physics.md", "integrators.md"} <= names
    n_run = sum(1 for p in PAGES for *_, skip in blocks(p) if skip is None)
    skipped = [(p.name, line, why) for p in PAGES for line, _, why in blocks(p) if why is not None]
    print(f"{n_run} executed blocks, {len(skipped)} skipped: {skipped}")
    assert n_run >= 25, n_run  # 29 when written: a broken extractor would find none
    assert all(len(why) > 10 for *_, why in skipped)  # a skip says why
    # an unclosed fence turns the rest of a page into one code block (and hides its examples)
    odd = [p.name for p in PAGES if sum(ln.startswith("```") for ln in p.read_text().splitlines()) % 2]
    assert not odd, odd


# the README's example runs in the quick suite (~6 s); the docs pages' (~60 s together, most of it
# compiling) with --runslow
_PAGE_PARAMS = [pytest.param(p, id=p.name, marks=() if p.name == "README.md" else pytest.mark.slow) for p in PAGES]


@pytest.mark.parametrize("page", _PAGE_PARAMS)
def test_page_examples_run(page, tmp_path, monkeypatch):
    todo = [(line, src) for line, src, skip in blocks(page) if skip is None]
    if not todo:
        pytest.skip(f"{page.name} has no Python blocks")
    monkeypatch.chdir(tmp_path)  # files the examples write land here
    monkeypatch.setenv("MPLBACKEND", "Agg")
    saved = {k: getattr(jax.config, k) for k in ("jax_enable_x64", "jax_numpy_dtype_promotion")}
    # a reader's JAX: the suite's conftest switches on float64 and strict promotion
    jax.config.update("jax_enable_x64", False)
    jax.config.update("jax_numpy_dtype_promotion", "standard")
    namespace: dict = {"__name__": "__docs__"}
    t0 = time.perf_counter()
    try:
        for line, src in todo:
            # as a reader's script runs it: without this file's `from __future__ import annotations`
            # (string annotations in a class the example defines would send dataclasses looking for
            # a module named "__docs__")
            code = compile(src, f"{page.relative_to(ROOT)}:{line}", "exec", dont_inherit=True)
            exec(code, namespace)  # noqa: S102 - the examples are the repository's own
    finally:
        for k, v in saved.items():
            jax.config.update(k, v)
    print(f"{page.name}: {len(todo)} blocks in {time.perf_counter() - t0:.1f} s")
    # beyond running (and the examples' own asserts): no float array an example computed and kept
    # is NaN or infinite, so a page never shows a silent wrong number
    arrays = {k: np.asarray(v) for k, v in namespace.items() if isinstance(v, (jax.Array, np.ndarray))}
    bad = [k for k, a in arrays.items() if np.issubdtype(a.dtype, np.floating) and not np.isfinite(a).all()]
    assert not bad, f"{page.name}: the examples left non-finite values in {bad}"


def test_readme_is_a_short_front_door_whose_links_resolve():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 250
    # the two set-up commands, byte for byte (.ci/run runs the second)
    assert "python3 -m venv .venv && .venv/bin/pip install -q -e '.[demo]' && .venv/bin/python -m rbjax demo" in text
    ci = (
        "python3 -m venv .venv && .venv/bin/pip install -q -e '.[test]' && .venv/bin/python -m pytest -n auto --runslow"
    )
    assert ci in text and ci in (ROOT / ".ci" / "run").read_text()
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    local = [t for t in targets if not t.startswith(("http://", "https://"))]
    assert len(local) >= 10 and not [t for t in local if not (ROOT / t).exists()]


def test_api_reference_lists_every_public_name():
    text = "\n".join(p.read_text() for p in sorted((ROOT / "docs" / "api").glob("*.md")))
    listed = re.findall(r"^::: rbjax\.(\w+)", text, re.M)
    missing = sorted(set(rb.__all__) - set(listed))
    assert not missing, f"add '::: rbjax.NAME' for {missing} to a page of docs/api/"
    assert len(listed) == len(set(listed)), "a name is documented twice"


def _cell_key(cell) -> tuple[str, str]:
    if cell.cell_type != "code":
        return cell.cell_type, cell.source
    lines = [ln for ln in cell.source.splitlines() if not ln.lstrip().startswith("%")]  # IPython magics
    return "code", ast.dump(ast.parse("\n".join(lines)))


def test_notebooks_are_stored_with_outputs_of_the_current_cells():
    nbformat = pytest.importorskip("nbformat")
    sys.path.insert(0, str(ROOT / "notebooks"))
    try:
        import _make
    finally:
        sys.path.pop(0)
    for name, cells in _make.NOTEBOOKS.items():
        nb = nbformat.read(ROOT / "notebooks" / name, as_version=4)
        # the stored cells are ruff-formatted (test_lint), _make.py's are not: compare code by its AST
        assert [_cell_key(c) for c in nb.cells] == [_cell_key(c) for c in cells], (
            f"{name} differs from notebooks/_make.py: run `python notebooks/_make.py --execute {name[:2]}`"
        )
        mimes = {k for c in nb.cells if c.cell_type == "code" for o in c.outputs for k in o.get("data", {})}
        assert "image/png" in mimes, f"{name} is stored without its plots"
        last = "".join(o.get("text", "") for o in nb.cells[-1].get("outputs", []))
        assert "all checks passed" in last, f"{name} was stored from a run whose checks failed"
    nb1 = nbformat.read(ROOT / "notebooks" / "01_tumbling_t_handle.ipynb", as_version=4)
    outs = [o for c in nb1.cells if c.cell_type == "code" for o in c.outputs]
    html = [o["data"].get("text/html", "") for o in outs if "data" in o]
    assert any("data:image/gif;base64" in h for h in html), "the first notebook is stored without its animation"


def test_site_builds_strict_offline(tmp_path):
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings")
    site = tmp_path / "site"
    t0 = time.perf_counter()
    r = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        env={**__import__("os").environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    elapsed = time.perf_counter() - t0
    assert r.returncode == 0, r.stderr[-4000:]
    assert "WARNING" not in r.stderr, r.stderr[-4000:]
    print(f"mkdocs build: {elapsed:.1f} s")
    api = (site / "api" / "simulation.html").read_text()
    assert 'id="rbjax.simulate"' in api and "checkpoint" in api  # the docstring rendered
    assert 'href="states.html#rbjax.State"' in (site / "api" / "simulation.html").read_text()  # a role became a link
    nb = (site / "notebooks" / "01_tumbling_t_handle.html").read_text()
    assert nb.count("data:image/png;base64") >= 3 and "data:image/gif;base64" in nb  # plots without running
    assert (site / "assets" / "t_handle.gif").exists()
