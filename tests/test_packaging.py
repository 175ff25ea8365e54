"""Packaging: one version source, the files a release carries, and a wheel that works outside the checkout.

The wheel test builds the wheel and the sdist with ``python -m build`` (in the test environment),
installs the wheel into a fresh virtual environment in a temporary folder (its dependencies from the
package index, through pip's cache), and runs a simulation and a fit there, far from the checkout,
so nothing can come from the source tree by accident.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tarfile
import textwrap
import venv
import zipfile
from pathlib import Path

import pytest

import rbjax

ROOT = Path(__file__).resolve().parent.parent


def test_version_has_one_source():
    from rbjax._version import __version__

    assert rbjax.__version__ == __version__
    project = (ROOT / "pyproject.toml").read_text().split("[project]", 1)[1].split("\n[", 1)[0]
    assert 'dynamic = ["version"]' in project and "\nversion =" not in project
    assert f"version: {__version__}" in (ROOT / "CITATION.cff").read_text()


def test_release_files_exist():
    assert "MIT License" in (ROOT / "LICENSE").read_text()
    assert 'license = { text = "MIT" }' in (ROOT / "pyproject.toml").read_text()
    assert (ROOT / "rbjax" / "py.typed").exists()
    assert "cff-version" in (ROOT / "CITATION.cff").read_text()
    assert "## 0.1.0" in (ROOT / "CHANGELOG.md").read_text()


def test_bench_without_benchmarks_says_where_they_live(tmp_path, monkeypatch, capsys):
    # what an installed wheel sees: no benchmarks/ next to the package
    from rbjax._cli import main

    monkeypatch.setenv("RBJAX_BENCHMARKS", str(tmp_path / "none"))
    assert main(["bench", "--list"]) == 2
    err = capsys.readouterr().err
    assert "benchmarks/ of the rbjax source repository" in err and "RBJAX_BENCHMARKS" in err


_SMOKE = textwrap.dedent(
    """
    import pathlib, sys
    import jax
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np
    import rbjax as rb

    here = pathlib.Path(rb.__file__).resolve()
    assert "site-packages" in here.parts, here
    assert (here.parent / "py.typed").exists()

    # a simulation: torque-free box, splitting conserves |L| to round-off
    body = rb.box(mass=1.0, size=[0.1, 0.2, 0.4])
    state = rb.State.create(body, angular_velocity=[0.1, 3.0, 0.1])
    traj = rb.simulate(state, None, dt=1e-3, steps=2000, method="splitting", save_every=20)
    L = np.linalg.norm(np.asarray(rb.angular_momentum(traj)), axis=-1)
    assert L.shape == (101,) and np.max(np.abs(L / L[0] - 1)) < 1e-12

    # a fit: recover the unit-trace inertia of a recorded tumble from its orientations
    I_true = jnp.diag(jnp.array([1.0, 2.0, 2.8]))
    # 2 s at 200 Hz, spun near the intermediate axis: a tumble that excites all three axes
    rec = rb.simulate(rb.State.create(rb.Body(1.0, I_true), angular_velocity=[0.3, 3.0, 0.4]),
                      None, dt=1e-3, steps=2000, method="rk8", save_every=5)
    times = np.arange(401) * 5e-3
    res = rb.fit_inertia(times, rb.orientation(rec))
    got = np.asarray(res.principal_moments)
    want = np.array([1.0, 2.0, 2.8]) / 5.8
    assert np.allclose(np.sort(got), want, rtol=1e-3), (got, want)
    print("WHEEL OK", rb.__version__, float(L[-1]), got.tolist())
    """
)


@pytest.mark.slow
def test_wheel_installs_in_a_fresh_venv_and_runs(tmp_path):
    pytest.importorskip("build")
    dist = tmp_path / "dist"
    r = subprocess.run(
        # sdist first, then the wheel from the unpacked sdist (build's default): the wheel holds only what
        # the sdist ships, and no build/ folder is left in the checkout. In this environment, after
        # build's check that it holds pyproject's build requirements: an isolated build installed
        # jaxlib twice (sdist, wheel), half of this test's time. The README's `pip install -e`
        # builds in isolation from those requirements, so their being enough is tested there.
        [sys.executable, "-m", "build", "--no-isolation", "--outdir", str(dist), str(ROOT)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    (wheel,) = dist.glob("rbjax-*.whl")
    (sdist,) = dist.glob("rbjax-*.tar.gz")
    assert wheel.name.startswith(f"rbjax-{rbjax.__version__}-")
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
    assert "rbjax/py.typed" in names and any(n.endswith("/licenses/LICENSE") or n.endswith("/LICENSE") for n in names)
    assert not any(n.startswith(("tests/", "benchmarks/")) for n in names)
    with tarfile.open(sdist) as t:
        members = t.getnames()
    top = members[0].split("/")[0]
    for f in ("LICENSE", "CHANGELOG.md", "CITATION.cff", "benchmarks/throughput.py", "rbjax/py.typed"):
        assert f"{top}/{f}" in members, f

    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    py = env_dir / "bin" / "python"
    clean = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    # --no-compile: pip byte-compiles every installed module (jax's thousands) up front, ~7 of its
    # ~12 s here; Python compiles the ones the smoke run imports as it imports them
    r = subprocess.run(
        [str(py), "-m", "pip", "install", "-q", "--no-compile", str(wheel)],
        capture_output=True,
        text=True,
        timeout=900,
        env=clean,
    )
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    work = tmp_path / "elsewhere"
    work.mkdir()
    r = subprocess.run([str(py), "-c", _SMOKE], capture_output=True, text=True, timeout=600, cwd=work, env=clean)
    assert r.returncode == 0 and "WHEEL OK" in r.stdout, r.stdout[-3000:] + r.stderr[-3000:]
    # the CLI's bench subcommand from the wheel: no benchmarks there, and it says where they are
    r = subprocess.run(
        [str(py), "-m", "rbjax", "bench", "--list"], capture_output=True, text=True, timeout=120, cwd=work, env=clean
    )
    assert r.returncode == 2 and "benchmarks/ of the rbjax source repository" in r.stderr, r.stderr
    print(r.stdout, r.stderr)
