"""Two processes on localhost (``jax.distributed``, gloo CPU collectives, 2 devices each) against one.

docs/devices.md's multi-host recipe, run for real: tests/_multiprocess_worker.py
is started as processes 0 and 1 of a 2-process job (a body-sharded batch over
4 devices, a ``Spring`` between bodies owned by different processes, fits
sharded over recordings) and once more as a single unsharded process; the
results must agree.

Tolerances: float64 throughout. The uncoupled batch is elementwise per body,
the same kernels on the same data, so it must agree bit for bit. The spring's
gather / scatter of its two bodies and the batched fits (2 recordings per
process vs 4 in one ``vmap``) may round differently: 1e-12 relative for 200
RK4 steps (measured ~2e-16), and 1e-10 relative for the fitted moments
(measured ~1e-15; the fit's own tolerance is 1e-8).
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys

import numpy as np
import pytest
from conftest import default_xla_env

HERE = os.path.dirname(os.path.abspath(__file__))
WORKER = os.path.join(HERE, "_multiprocess_worker.py")
TIMEOUT_S = 240  # a hung collective fails the test instead of hanging CI


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def _run_all(cmds: list[list[str]]) -> list[str]:
    # XLA's default flags, not the suite's fast-compile ones: "bit for bit" above is a property of
    # the programs XLA compiles by default (unoptimised, the sharded and unsharded ones differ by an ulp)
    base = default_xla_env()
    flags = base.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
    env = dict(base, JAX_PLATFORMS="cpu", XLA_FLAGS=flags.strip(), PYTHONPATH=os.path.dirname(HERE))
    procs = [subprocess.Popen(c, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) for c in cmds]
    logs = []
    try:
        for p in procs:
            logs.append(p.communicate(timeout=TIMEOUT_S)[0])
    except subprocess.TimeoutExpired:
        for p in procs:
            p.kill()
        pytest.fail(f"a process of the 2-process run did not finish in {TIMEOUT_S} s (hung collective?)")
    for c, p, log in zip(cmds, procs, logs):
        assert p.returncode == 0, f"{c[2:]} failed:\n{log[-3000:]}"
    return logs


@pytest.mark.slow  # ~1 min on 2 cores: three JAX processes compile the same programs and fits
def test_two_processes_match_one_process(tmp_path):
    sys.path.insert(0, HERE)
    import _multiprocess_worker as w

    port = str(_free_port())
    multi, ref = tmp_path / "multi.npz", tmp_path / "ref.npz"
    _run_all(
        [
            [sys.executable, WORKER, "0", port, str(multi)],
            [sys.executable, WORKER, "1", port, str(multi)],
            [sys.executable, WORKER, "ref", str(ref)],
        ]
    )
    got, want = np.load(multi), np.load(ref)
    for f in ("position", "orientation"):
        assert got[f"free_{f}"].shape == (w.STEPS // w.SAVE + 1, w.N, 4 if f == "orientation" else 3)
        np.testing.assert_array_equal(got[f"free_{f}"], want[f"free_{f}"])
        np.testing.assert_allclose(got[f"spring_{f}"], want[f"spring_{f}"], rtol=0, atol=1e-12)
    # the spring does couple the two processes' bodies (and only them): a run that dropped it would fail
    moved = np.abs(want["spring_position"][-1] - want["free_position"][-1]).max(axis=-1)
    # (the others only to round-off: with a torque in the model they take the torque-carrying kernel)
    assert moved[0] > 1e-4 and moved[-1] > 1e-4 and moved[1:-1].max() < 1e-12
    true_inertia, _ = w.recordings()
    truth = np.linalg.eigvalsh(true_inertia / np.trace(true_inertia, axis1=1, axis2=2)[:, None, None])
    np.testing.assert_allclose(got["fit"], want["fit"], rtol=1e-10)
    np.testing.assert_allclose(want["fit"], truth, rtol=1e-6)  # clean data: the fits are right, not just equal
