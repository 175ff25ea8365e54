"""The benchmarks' --quick modes run and write well-formed, physically sane output.

They check that the scripts keep working as rbjax changes (new methods appear
automatically), not how fast anything is: timings on a shared machine are noise.
The quick runs start together (separate processes) to keep this file near a minute.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import re
import subprocess
import sys

import numpy as np
import pytest

import rbjax as rb

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
BENCH = os.path.join(ROOT, "benchmarks")


def _work_precision():
    sys.path.insert(0, BENCH)
    import work_precision

    return work_precision


@pytest.fixture(scope="module")
def quick_runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    env = dict(os.environ, PYTHONPATH=ROOT, JAX_PLATFORMS="cpu")
    cmds = {
        "work_precision": [
            sys.executable,
            os.path.join(BENCH, "work_precision.py"),
            "--quick",
            "--out",
            str(out),
        ],
        "throughput": [
            sys.executable,
            os.path.join(BENCH, "throughput.py"),
            "--quick",
            "--json",
            str(out / "throughput.json"),
        ],
        "memory": [sys.executable, os.path.join(BENCH, "memory.py"), "--quick", "--out", str(out / "memory.json")],
    }
    procs = {
        k: subprocess.Popen(c, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        for k, c in cmds.items()
    }
    logs = {k: p.communicate(timeout=300)[0] for k, p in procs.items()}
    for k, p in procs.items():
        assert p.returncode == 0, f"{k} --quick failed:\n{logs[k][-3000:]}"
    return out, logs


def test_work_precision_full_run_covers_every_method():
    assert set(_work_precision().default_methods(quick=False)) == set(rb.methods(rb.State))


@pytest.mark.slow  # the three benchmarks' quick modes run as subprocesses (~45 s together)
def test_work_precision_quick_output(quick_runs):

    out, _ = quick_runs
    data = json.loads((out / "work_precision_quick.json").read_text())
    assert (out / "work_precision_quick.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = (out / "work_precision_quick.md").read_text()
    assert "| 1e-3 |" in md and "| 1e-10 |" in md
    for name, rows in data["results"].items():
        methods = {r["method"] for r in rows if r["solver"] == "rbjax" and not r["method"].endswith(" native")}
        assert methods == set(_work_precision().default_methods(quick=True)), name
        # a second curve only where the method has a kernel that steps this problem's forces
        native = {r["method"].removesuffix(" native") for r in rows if r["method"].endswith(" native")}
        assert native <= set(rb.native_status().methods) & methods, name
        for r in rows:
            assert r["time_per_body_s"] > 0 and r["compile_s"] > 0
        rk4 = sorted(
            (r["steps"], r["err_angle"])
            for r in rows
            if r["solver"] == "rbjax" and r["method"] == "rk4" and r["dtype"] == "float64"
        )
        errs = [e for _, e in rk4]
        # RK4 is 4th order: each 4x refinement divides the error by ~256 in the asymptotic range; asking only
        # for > 30x per 4x (order > 2.4) between the two finest float64 points leaves room for the
        # pre-asymptotic regime of the separatrix problem while failing for any first- or second-order bug.
        assert errs[-2] / errs[-1] > 30, f"{name}: rk4 angle errors {errs}"
        assert all(a > b for a, b in zip(errs, errs[1:], strict=False)), (
            f"{name}: rk4 error must fall as dt falls: {errs}"
        )
        # float32 cannot beat its own rounding: the best float32 angle error stays above ~eps32 = 1.2e-7
        e32 = [r["err_angle"] for r in rows if r["solver"] == "rbjax" and r["dtype"] == "float32"]
        assert min(e32) > 1e-8
        peer = sorted((r["tol"], r["err_angle"]) for r in rows if r["solver"] == "diffrax")
        if peer:  # a tighter tolerance gives a smaller error (1e-4 -> 1e-7: at least 10x)
            assert peer[0][1] * 10 < peer[-1][1], f"{name}: diffrax errors {peer}"


@pytest.mark.slow  # the three benchmarks' quick modes run as subprocesses (~45 s together)
def test_throughput_quick_output(quick_runs):
    out, _ = quick_runs
    data = json.loads((out / "throughput.json").read_text())
    rows = data["rows"]
    ours = [r for r in rows if r["engine"] == "rbjax"]
    assert {r["method"] for r in ours} == {"euler", "rk4"}  # --quick's subset
    for r in rows:
        assert math.isfinite(r["body_steps_per_s"]) and r["body_steps_per_s"] > 0
    for r in ours:
        assert r["flops"] > 0 and 0 < r["roofline_fraction"]
        # state read + written (13 values) and I_L^-1 read (9), 4 bytes each in float32
        assert r["bytes_per_body_step"] == (2 * 13 + 9) * (4 if r["dtype"] == "float32" else 8)
    assert data["hardware"]["bandwidth_Bps"] > 1e8 and data["hardware"]["flops_per_s"] > 1e8
    assert {"euler_vs_numpy", "euler_vs_mujoco", "euler_bandwidth_fraction"} <= set(data["goals"])
    assert (out / "throughput.md").read_text().count("| euler |") >= 2
    if importlib.util.find_spec("numba") is not None:  # the hand-written limit (bench extra)
        limit = [r for r in rows if r["engine"] == "numba-limit"]
        assert [r["bodies"] for r in limit] == [10_000]  # --quick's N >= 1e4
        # the script raises unless the loop agrees with rbjax's Euler (64 eps); the row records by how much
        assert all(r["agreement_eps"] <= 64 for r in limit)
        assert {"jax float32 N=10000"} <= set(data["goals"]["euler_vs_limit"])


@pytest.mark.slow  # the three benchmarks' quick modes run as subprocesses (~45 s together)
def test_memory_quick_output(quick_runs):
    out, _ = quick_runs
    rows = json.loads((out / "memory.json").read_text())
    assert [(r["n"], r["save_every"]) for r in rows] == [(10_000, 20), (100_000, 20), (100_000, 1)]
    for r in rows:
        # the compiled program's accounting is there (it once failed silently), and outputs = the trajectory
        assert r["xla_temp_MB"] > 0 and abs(r["xla_out_MB"] - r["traj_MB"]) < 1e-3 * r["traj_MB"]
        assert r["frames"] == 20 // r["save_every"] + 1 and r["finite"]
        assert r["peak_rss_MB"] > r["base_rss_MB"] and r["peak_over_data"] > 0


def test_run_all_lists_every_benchmark():
    res = subprocess.run(
        [sys.executable, os.path.join(BENCH, "run_all.py"), "--list"],
        capture_output=True,
        text=True,
        check=True,
    )
    names = {os.path.basename(p) for p in res.stdout.split()}
    assert {"work_precision.py", "throughput.py"} <= names and "run_all.py" not in names
    assert not any(n.startswith("_") for n in names)


def test_every_benchmark_takes_quick():
    # run_all --quick (and `python -m rbjax bench --quick`) passes --quick to every script: one without
    # the option stops there with argparse's error, or ignores it and runs its full study (four did)
    import ast

    sys.path.insert(0, BENCH)
    import run_all

    lacking = []
    for path in run_all.scripts():
        tree = ast.parse(open(path).read())
        options = {
            a.value
            for node in ast.walk(tree)
            if isinstance(node, ast.Call) and getattr(node.func, "attr", None) == "add_argument"
            for a in node.args
            if isinstance(a, ast.Constant)
        }
        if "--quick" not in options:
            lacking.append(os.path.basename(path))
    assert not lacking, f"benchmarks without --quick: {lacking}"


def test_fit_accuracy_bound_maps_the_shape_covariance_to_the_moments_by_their_derivative():
    # fit_accuracy's Cramér–Rao bound pushes the covariance of the five shape parameters p to the
    # principal moments with dλ_k/dp_e = v_kᵀ E_e v_k (first-order perturbation of a symmetric
    # matrix). Held to central differences of eigvalsh: h = 1e-6 leaves an O(h²) ≈ 1e-12 error.
    sys.path.insert(0, BENCH)
    import fit_accuracy as fa

    base = fa.INERTIA / np.trace(fa.INERTIA)
    E = fa._traceless_basis()
    h = 1e-6
    fd = np.stack([(np.linalg.eigvalsh(base + h * e) - np.linalg.eigvalsh(base - h * e)) / (2 * h) for e in E], 1)
    rng = np.random.default_rng(0)
    A = rng.normal(size=(5, 5))
    cov = A @ A.T
    np.testing.assert_allclose(fa._moment_sigma(cov), np.sqrt(np.einsum("ke,ef,kf->k", fd, cov, fd)), rtol=1e-8)


@pytest.mark.slow  # two fresh processes simulate, one in a git worktree of HEAD (~10 s)
def test_ab_throughput_quick_compares_the_working_tree_with_head():
    # `python -m rbjax bench --quick` runs every script's --quick mode: ab_throughput's compares
    # this checkout with its HEAD (no --base needed) on the JAX path, and saves nothing
    if not os.path.exists(os.path.join(ROOT, ".git")):
        pytest.skip("not a git checkout")
    results = os.path.join(BENCH, "results")
    before = {f: os.stat(os.path.join(results, f)).st_mtime_ns for f in os.listdir(results)}
    r = subprocess.run(
        [sys.executable, os.path.join(BENCH, "ab_throughput.py"), "--quick"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    m = re.search(r"euler float32 N=\s*10000: base (\S+)\s+new (\S+)\s+new/base (\S+)", r.stdout)
    assert m, r.stdout
    base, new, ratio = map(float, m.groups())
    # body-steps/s of 1e4 bodies: both sides ran (any working step is far above 1e5 on one core)
    assert base > 1e5 and new > 1e5
    np.testing.assert_allclose(ratio, new / base, rtol=5e-3)  # printed to 4 digits and 3 decimals
    after = {f: os.stat(os.path.join(results, f)).st_mtime_ns for f in os.listdir(results)}
    assert after == before
    worktrees = subprocess.run(["git", "-C", ROOT, "worktree", "list"], capture_output=True, text=True).stdout
    assert "rbjax_base_" not in worktrees  # the base's worktree is removed
