"""Chunked runs: run record, interrupted runs told apart, inconsistent chunks refused, resume bitwise."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb

STEPS, CHUNK, SAVE, DT = 40, 10, 2, 0.01


def _state():
    rng = np.random.default_rng(5)
    body = rb.box(jnp.asarray(rng.uniform(0.5, 2, 3)), jnp.asarray(rng.uniform(0.3, 1.5, (3, 3))))
    return rb.State.create(body, angular_velocity=jnp.asarray(rng.normal(size=(3, 3))))


FORCES = rb.Gravity() + rb.LinearDrag(0.1, angular=0.05)


def _run(directory, writer=None, **kw):
    writer = writer if writer is not None else rb.ChunkWriter(directory)
    return rb.simulate_chunked(
        _state(), FORCES, DT, STEPS, "rk4", save_every=SAVE, chunk_steps=CHUNK, progress=False, writer=writer, **kw
    )


def _bitwise(a, b) -> bool:
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    return len(la) == len(lb) and all(
        x.dtype == y.dtype and x.shape == y.shape and np.asarray(x).tobytes() == np.asarray(y).tobytes()
        for x, y in zip(la, lb, strict=True)
    )


class _Crash(Exception):
    pass


class _CrashingWriter(rb.ChunkWriter):
    """Dies (an exception, as a crash would) after writing ``after`` chunks."""

    def __init__(self, directory, after):
        super().__init__(directory)
        self.after = after

    def write(self, trajectory, **kw):
        if self.count == self.after:
            raise _Crash
        return super().write(trajectory, **kw)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    d = tmp_path_factory.mktemp("whole") / "run"
    return _run(d), d


def test_a_finished_run_is_recorded_complete(reference):
    traj, d = reference
    meta = rb.read_metadata(d)
    assert meta["complete"] is True and meta["chunks"] == 4
    run = meta["run"]
    assert (run["steps"], run["dt"], run["method"], run["save_every"], run["chunk_steps"]) == (STEPS, DT, "rk4", 2, 10)
    assert run["state_fingerprint"] == rb._chunk_dir.fingerprint(_state())
    assert run["forces_fingerprint"] == rb._chunk_dir.fingerprint(FORCES) is not None
    assert _bitwise(rb.load(d), traj)


@pytest.mark.parametrize("after", [0, 1, 3])
def test_an_interrupted_run_is_told_apart_and_resumes_bitwise(tmp_path, reference, after):
    whole, whole_dir = reference
    d = tmp_path / "run"
    with pytest.raises(_Crash):
        _run(d, writer=_CrashingWriter(d, after))
    assert rb.read_metadata(d)["complete"] is False if after else not list(d.glob("chunk_*"))
    if after:
        with pytest.raises(
            ValueError, match=rf"interrupted run: {after} of 4 chunks \({after * CHUNK} of {STEPS} steps\)"
        ):
            rb.load(d)
        part = rb.load(d, allow_incomplete=True)
        assert part.position.shape[0] == after * CHUNK // SAVE + 1
    # a crash inside a write leaves an orphan: load ignores it with a note, a writer deletes it
    (d / f"chunk_{after:06d}.npz.x1y2.tmp").write_bytes(b"partial")
    if after:
        with pytest.warns(UserWarning, match="ignoring 1 unfinished chunk file"):
            rb.load(d, allow_incomplete=True)
    with pytest.warns(UserWarning, match="deleting 1 unfinished chunk file"):
        writer = rb.ChunkWriter(d, resume=True)
    assert writer.count == after
    resumed = _run(d, writer=writer, resume=True)
    assert _bitwise(resumed, whole)
    assert _bitwise(rb.load(d), rb.load(whole_dir)) and rb.read_metadata(d)["complete"] is True
    # only the last frames are wanted: keep=False resumes as well (nothing left to do here)
    final = _run(d, writer=rb.ChunkWriter(d, resume=True), resume=True, keep=False)
    assert _bitwise(final, rb._chunked._frames(whole, -1))


def test_resume_with_other_arguments_is_refused(tmp_path):
    d = tmp_path / "run"
    with pytest.raises(_Crash):
        _run(d, writer=_CrashingWriter(d, 2))

    def resume_with(forces, dt):
        return rb.simulate_chunked(
            _state(), forces, dt, STEPS, "rk4", save_every=SAVE, chunk_steps=CHUNK, progress=False,
            writer=rb.ChunkWriter(d, resume=True), resume=True,
        )  # fmt: skip

    with pytest.raises(ValueError, match=r"resume=True\): dt is 0.02 but the interrupted run .* had 0.01"):
        resume_with(FORCES, 0.02)
    with pytest.raises(ValueError, match=r"resume=True\): forces_fingerprint is"):
        resume_with(rb.Gravity(), DT)
    with pytest.raises(ValueError, match=r"already holds 2 chunk\(s\); pass resume=True"):
        rb.ChunkWriter(d)
    with pytest.raises(ValueError, match=r"resume=True needs writer="):
        rb.simulate_chunked(_state(), None, DT, STEPS, progress=False, resume=True)


def _rewrite_meta(path: Path, **changes):
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays["__rbjax__"]))
    meta.update(changes)
    arrays["__rbjax__"] = np.array(json.dumps(meta))
    with open(path, "wb") as f:
        np.savez(f, **arrays)


@pytest.mark.parametrize(
    "changes, match",
    [
        ({"dt": 0.02}, r"has dt=0.02 but chunk_000000.npz has 0.01: chunks of different runs"),
        ({"method": "euler"}, r"has method='euler' but chunk_000000.npz has 'rk4'"),
        ({"first_step": 12}, r"starts at step 12, but the chunks before it end at step 20: it repeats frames"),
        ({"first_step": 30}, r"starts at step 30, .* it leaves a gap"),
    ],
)
def test_inconsistent_chunks_are_refused(tmp_path, reference, changes, match):
    _, whole = reference
    d = tmp_path / "run"
    d.mkdir()
    for f in whole.iterdir():
        (d / f.name).write_bytes(f.read_bytes())
    _rewrite_meta(d / "chunk_000002.npz", **changes)
    with pytest.raises(ValueError, match=match):
        rb.load(d)


_CHILD = textwrap.dedent(
    """
    import sys, time
    import jax
    jax.config.update("jax_enable_x64", True)
    sys.path.insert(0, {tests!r})
    import rbjax as rb
    from test_resume import _state, FORCES, STEPS, SAVE, DT

    class Slow(rb.ChunkWriter):
        def write(self, traj, **kw):
            out = super().write(traj, **kw)
            time.sleep(0.4)  # room for the parent's kill between (and during) chunks
            return out

    rb.simulate_chunked(_state(), FORCES, DT, STEPS * 2, "rk4", save_every=SAVE, chunk_steps=10,
                        progress=False, writer=Slow({d!r}))
    """
)


@pytest.mark.slow
def test_sigkill_mid_run_then_resume_is_bitwise_equal(tmp_path):
    # the real thing: a subprocess killed with SIGKILL at several points, resumed here
    ref_dir = tmp_path / "ref"
    whole = rb.simulate_chunked(
        _state(),
        FORCES,
        DT,
        STEPS * 2,
        "rk4",
        save_every=SAVE,
        chunk_steps=10,
        progress=False,
        writer=rb.ChunkWriter(ref_dir),
    )
    rng = np.random.default_rng(17)
    for trial, after in enumerate([1, 3, 6]):
        d = tmp_path / f"run{trial}"
        env = {**os.environ, "JAX_PLATFORMS": "cpu"}
        code = _CHILD.format(tests=str(Path(__file__).parent), d=str(d))
        child = subprocess.Popen([sys.executable, "-c", code], env=env, cwd=Path(__file__).parent.parent)
        deadline = time.time() + 120
        while len(list(d.glob("chunk_*.npz"))) < after and time.time() < deadline and child.poll() is None:
            time.sleep(0.02)
        time.sleep(rng.uniform(0, 0.4))
        child.send_signal(signal.SIGKILL)
        child.wait()
        got = len(list(d.glob("chunk_*.npz")))
        assert after <= got < 8, f"trial {trial}: the child wrote {got} chunks"
        with pytest.raises(ValueError, match="interrupted run"):
            rb.load(d)
        with pytest.warns() if list(d.glob("*.tmp")) else _nothing():
            writer = rb.ChunkWriter(d, resume=True)
        resumed = rb.simulate_chunked(
            _state(),
            FORCES,
            DT,
            STEPS * 2,
            "rk4",
            save_every=SAVE,
            chunk_steps=10,
            progress=False,
            writer=writer,
            resume=True,
        )
        assert _bitwise(resumed, whole) and _bitwise(rb.load(d), rb.load(ref_dir))


class _nothing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False
