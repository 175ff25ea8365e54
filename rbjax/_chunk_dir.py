"""Chunk directories of long runs: :class:`ChunkWriter`, the run record, and loading.

A directory holds numbered ``chunk_NNNNNN.npz`` files (each a complete
:func:`rbjax.save` file, written to a temporary name and renamed) and, when
:func:`rbjax.simulate_chunked` wrote it, ``run.json``: the planned run (steps,
``dt``, method, ``save_every``, ``chunk_steps``, ``t0``, dtype, fingerprints of
the initial state and of the forces) and whether it finished. Each chunk
records its number and the absolute step of its first frame.

:func:`load` of a directory then tells a complete run from an interrupted one
(refused unless ``allow_incomplete=True``), refuses chunks that disagree with
each other or with the plan (``dt``, method, ``save_every``, dtype, structure,
repeated or missing frames), and ignores orphaned ``*.tmp`` files of a chunk
that was being written when the process died, with a warning; a writer opened
on the directory deletes them. ``simulate_chunked(..., resume=True)``
continues such a run from its last complete chunk.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import warnings
from pathlib import Path
from typing import Any

import jax
import numpy as np

from ._io_check import check_arrays
from ._npz import check_expect, metadata, read_npz, rebuild, to_jax, write_atomic, write_npz
from ._pytree import is_rbjax_dataclass

__all__ = ["ChunkWriter", "chunk_files", "load_chunks", "fingerprint", "read_run", "RUN_FILE"]

_CHUNK = re.compile(r"^chunk_(\d{6,})\.npz$")
_ORPHAN = re.compile(r"^chunk_\d{6,}\.npz\..*\.tmp$")
RUN_FILE = "run.json"
_RUN_FORMAT = "rbjax-run"


def fingerprint(tree: Any) -> str | None:
    """SHA-256 of a pytree's structure, dtypes, shapes and bytes; ``None`` when not reproducible.

    The structure is part of it, so ``Forces(torque=None)`` and a zero torque
    differ. A static field holding a function (``ExternalForce``,
    ``CustomForce``) prints with its memory address, which changes between
    processes: such trees, and plain callables, get ``None`` (not checked).
    """
    if tree is None:
        return "none"
    if not is_rbjax_dataclass(tree):  # a plain callable: its code and closure cannot be hashed
        return None
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    structure = str(treedef)
    if " at 0x" in structure:
        return None
    h = hashlib.sha256(structure.encode())
    for leaf in leaves:
        a = np.asarray(leaf)
        h.update(f"{a.dtype}{a.shape}".encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _orphans(directory: Path) -> list[str]:
    return sorted(n for n in os.listdir(directory) if _ORPHAN.match(n))


def chunk_files(directory: Path) -> list[Path]:
    """The chunk files in order; ``ValueError`` if none or if one is missing in the sequence."""
    found = sorted((int(m.group(1)), directory / name) for name in os.listdir(directory) if (m := _CHUNK.match(name)))
    if not found:
        raise ValueError(f"load: {directory} holds no chunk_NNNNNN.npz files")
    numbers = [n for n, _ in found]
    if numbers != list(range(len(numbers))):
        missing = sorted(set(range(numbers[-1] + 1)) - set(numbers))
        raise ValueError(f"load: {directory} is missing chunk(s) {missing[:5]}")
    return [f for _, f in found]


def read_run(directory: Path) -> dict[str, Any] | None:
    """The run record of a directory, or ``None`` if it has none (a writer used on its own)."""
    path = directory / RUN_FILE
    if not path.exists():
        return None
    try:
        run = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ValueError(f"load: {path} is damaged: {e}") from None
    if not isinstance(run, dict) or run.get("format") != _RUN_FORMAT:
        raise ValueError(f"load: {path} is not an rbjax run record")
    return run


def _write_json(path: Path, obj: dict[str, Any]) -> None:
    write_atomic(path, lambda f: f.write(json.dumps(obj, indent=1).encode()))


# the chunk metadata that must agree across a directory
_SAME = ("method", "dt", "save_every", "dtype", "time_stacked")


def _check_consistent(directory: Path, files: list[Path], metas: list[dict], parts: list[dict], run) -> None:
    first = metas[0]
    for m, f in zip(metas[1:], files[1:], strict=True):
        for key in _SAME:
            if m.get(key) != first.get(key):
                raise ValueError(
                    f"load: {f} has {key}={m.get(key)!r} but {files[0].name} has {first.get(key)!r}: "
                    "chunks of different runs cannot be concatenated"
                )
        if m["tree"] != first["tree"]:
            raise ValueError(f"load: {f.name} holds a different pytree structure from the first chunk")
    if run is not None:
        for key in ("method", "dt", "save_every"):
            if run.get(key) != first.get(key):
                raise ValueError(f"load: {files[0]} has {key}={first.get(key)!r} but the run record plans {run[key]!r}")
    # frames: chunk k starts save_every after the last frame of chunk k-1 (no repeats, no gaps)
    stacked = first["time_stacked"]
    se = first.get("save_every") or 1
    expected_start = 0
    for m, p, f in zip(metas, parts, files, strict=True):
        start = m.get("first_step")
        frames = next((p[k].shape[0] for k in p if k.split(".", 1)[0] in stacked), 0)
        if start is not None and start != expected_start:
            what = "repeats frames" if start < expected_start else "leaves a gap"
            raise ValueError(
                f"load: {f} starts at step {start}, but the chunks before it end at step "
                f"{expected_start - se}: it {what} (save_every={se})"
            )
        expected_start = (expected_start if start is None else start) + frames * se


def load_chunks(directory: Path, expect: Any, allow_incomplete: bool) -> Any:
    """:func:`rbjax.load` of a chunk directory (see the module docstring)."""
    orphans = _orphans(directory)
    if orphans:
        warnings.warn(
            f"load: ignoring {len(orphans)} unfinished chunk file(s) in {directory} ({orphans[0]}, ...): "
            "left by a run killed while writing; a ChunkWriter on the directory deletes them",
            stacklevel=3,
        )
    run = read_run(directory)
    files = chunk_files(directory)
    read = [read_npz(f) for f in files]
    metas = [m for m, _ in read]
    parts = [a for _, a in read]
    for m, a, f in zip(metas, parts, files, strict=True):
        check_arrays(m, a, f)
    check_expect(metas[0], expect, directory)
    _check_consistent(directory, files, metas, parts, run)
    if run is not None and not run.get("complete") and not allow_incomplete:
        raise ValueError(
            f"load: {directory} holds an interrupted run: {len(files)} of {run['chunks_planned']} chunks "
            f"({min(len(files) * run['chunk_steps'], run['steps'])} of {run['steps']} steps). Continue it with "
            "rbjax.simulate_chunked(..., writer=rbjax.ChunkWriter(directory, resume=True), resume=True), "
            "or load what is there with rbjax.load(directory, allow_incomplete=True)"
        )
    if run is not None and run.get("complete") and len(files) != run["chunks_planned"]:
        raise ValueError(
            f"load: {directory} is marked complete with {run['chunks_planned']} chunks but holds {len(files)}"
        )
    stacked = metas[0]["time_stacked"]
    if not stacked and len(files) > 1:
        raise ValueError(f"load: the chunks in {directory} are not trajectories; nothing to concatenate")
    merged: dict[str, np.ndarray] = {}
    for key in parts[0]:
        top = key.split(".", 1)[0]
        if top in stacked:
            merged[key] = np.concatenate([p[key] for p in parts], axis=0)
        else:
            for p, f in zip(parts[1:], files[1:], strict=True):
                if not np.array_equal(p[key], parts[0][key], equal_nan=True):
                    raise ValueError(f"load: {key!r} in {f.name} differs from the first chunk's")
            merged[key] = parts[0][key]
    return rebuild(metas[0]["tree"], "", to_jax(merged, directory))


class ChunkWriter:
    """Write a long trajectory as numbered chunk files in a directory.

    ``writer.write(traj)`` stores one chunk, ``chunk_000000.npz``,
    ``chunk_000001.npz``, ..., each a complete :func:`save` file (written to a
    temporary name and renamed, so a crash loses at most the chunk being
    written). ``rbjax.load(directory)`` concatenates them along the time axis
    (leading axis of the changing fields; ``body`` must be the same in all).
    Chunks must not repeat frames: :func:`rbjax.simulate_chunked` passes the
    first chunk whole and later chunks without their initial frame, records the
    planned run in ``run.json`` and marks it complete at the end, so ``load``
    can tell a finished run from an interrupted one.

    Args:
        directory: created if missing. If it already holds chunks, pass
            ``resume=True`` to continue after them (with
            ``simulate_chunked(..., resume=True)``) or ``overwrite=True`` to
            delete them (and the run record); otherwise ``ValueError``.
            Orphaned ``*.tmp`` files of a chunk being written when a process
            died are deleted, with a warning.
        method, dt, save_every, t0: metadata written into every chunk
            (``dt``, ``t0`` in s); :func:`rbjax.simulate_chunked` fills them
            from its own arguments when left ``None``.
    """

    def __init__(
        self,
        directory: str | os.PathLike,
        *,
        method: str | None = None,
        dt: Any = None,
        save_every: int | None = None,
        t0: Any = None,
        overwrite: bool = False,
        resume: bool = False,
    ) -> None:
        if overwrite and resume:
            raise ValueError("ChunkWriter: pass overwrite=True or resume=True, not both")
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        orphans = _orphans(self.directory)
        if orphans:
            warnings.warn(
                f"ChunkWriter: deleting {len(orphans)} unfinished chunk file(s) in {self.directory} "
                f"({orphans[0]}, ...) left by a run killed while writing",
                stacklevel=2,
            )
            for n in orphans:
                os.unlink(self.directory / n)
        old = [n for n in os.listdir(self.directory) if _CHUNK.match(n)]
        self.count = 0
        if old and resume:
            self.count = len(chunk_files(self.directory))
        elif old or (self.directory / RUN_FILE).exists():
            if not overwrite and not (resume and not old):
                what = f"{len(old)} chunk(s)" if old else f"the record ({RUN_FILE}) of a run that wrote no chunk yet"
                raise ValueError(
                    f"ChunkWriter: {self.directory} already holds {what}; pass resume=True to "
                    "continue that run (with simulate_chunked(..., resume=True)), overwrite=True to delete "
                    "it, or choose another directory"
                )
            if overwrite:
                for n in old:
                    os.unlink(self.directory / n)
                if (self.directory / RUN_FILE).exists():
                    os.unlink(self.directory / RUN_FILE)
        self.resume = resume
        self.meta = {"method": method, "dt": dt, "save_every": save_every, "t0": t0}

    def set_defaults(self, **meta: Any) -> None:
        """Fill metadata fields that are still ``None`` (used by ``simulate_chunked``)."""
        for k, v in meta.items():
            if self.meta.get(k) is None:
                self.meta[k] = v

    @property
    def run(self) -> dict[str, Any] | None:
        """The directory's run record (``run.json``), or ``None``."""
        return read_run(self.directory)

    def start_run(self, plan: dict[str, Any]) -> None:
        """Record the planned run (``simulate_chunked`` calls this before its first chunk)."""
        _write_json(self.directory / RUN_FILE, {"format": _RUN_FORMAT, "version": 1, **plan, "complete": False})

    def finish(self) -> None:
        """Mark the recorded run complete (after its last chunk)."""
        run = self.run
        if run is not None:
            _write_json(self.directory / RUN_FILE, {**run, "complete": True})

    def write(self, trajectory: Any, *, first_step: int | None = None) -> Path:
        """Store one chunk ``(T_chunk, *B, ...)``; returns its path.

        ``first_step``: the absolute step number of its first frame, recorded so
        that ``load`` can refuse repeated or missing frames.
        """
        extra = {"chunk": self.count, "first_step": None if first_step is None else int(first_step)}
        meta = metadata(trajectory, trajectory=True, **self.meta, extra=extra)
        path = self.directory / f"chunk_{self.count:06d}.npz"
        write_npz(path, trajectory, meta)
        self.count += 1
        return path
