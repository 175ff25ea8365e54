"""The compiled solver of :func:`rbjax.fit_inertia` and one packed problem through it.

:func:`pack` checks and packs one recording (NumPy, :mod:`._problem`);
:func:`solve` runs a packed :class:`._problem.Problem` (one recording, a
batch, or a joint problem) through two compiled programs: the solver,
Levenberg–Marquardt (:mod:`._solver`) per recording and a work queue
(:mod:`._queue`) for a batch; then the result pass, the covariance and
diagnostics (:mod:`._result`).
"""

from __future__ import annotations

import concurrent.futures
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from .._pytree import new_unchecked, replace
from . import _robust
from ._checks import check_arrays, check_options
from ._model import SegmentJacobian, densify, model_residuals, model_shapes, normal_equations
from ._problem import prepare
from ._queue import run_queue
from ._result import CONSISTENCY_ALPHA, FitResult, consistency, summarise
from ._solver import LMMember, after

__all__ = [
    "NOT_JOINT",
    "OPTION_NAMES",
    "compiled_programs",
    "fit_batch_jit",
    "is_small",
    "summary_jit",
    "fit_regular",
    "pack",
    "sample_weights",
    "solve",
    "solve_with_starts",
]


def fit_batch_jit(backend: str, small: bool = False):
    """The jitted solver for ``backend``; made on first use, so importing rbjax starts no backend.

    On CPU it is compiled with XLA's classic loop emitters instead of the MLIR
    fusion emitters: for the 4 s @ 1 kHz fit that halved the compile (10.6 → 5.1
    CPU-s) and made the solve faster too (3.1 → 2.0 CPU-s), same result.
    ``small`` (a problem whose solve is short: :func:`is_small`) also turns
    LLVM's optimisation off (``xla_backend_optimization_level=0``): it cuts the
    compile by ~40% and slows the solve, which for a short throw is a few ms;
    :func:`solve` also has such a problem's model loop over the RK4 stages
    (``looped``, :func:`._flow.flow`), which halves the compile again.
    """
    key = ("solve", backend, small)
    if key not in _JITS:
        static = ("model_opts", "loss", "rtol", "atol", "max_steps", "unbatch")
        _JITS[key] = jax.jit(_fit_batch, static_argnames=static, compiler_options=_compiler_options(backend, small))
    return _JITS[key]


def summary_jit(backend: str):
    """The jitted result pass (:func:`_summarise_batch`) for ``backend``, always built for a short compile.

    A program of its own, run once on the solver's output: it runs once per
    recording (SVDs, eigenvectors, a few small solves), not once per solver step,
    so LLVM's optimisation buys it nothing. Inside a batch's optimised solver
    program (twice: full slices and the partial one, :func:`_map_in_order`) it
    took about a quarter of the compile. The two compile at once
    (:func:`_compile_side_by_side`).
    """
    key = ("summary", backend)
    if key not in _JITS:
        static = ("model_opts", "loss", "unbatch")
        options = _compiler_options(backend, small=True)
        _JITS[key] = jax.jit(_summarise_batch, static_argnames=static, compiler_options=options)
    return _JITS[key]


def _compiler_options(backend: str, small: bool) -> dict | None:
    if backend != "cpu":
        return None
    options: dict[str, object] = {"xla_cpu_use_fusion_emitters": False}
    if small:
        options["xla_backend_optimization_level"] = 0
    return options


_JITS: dict = {}


def compiled_programs() -> int:
    """How many solver programs have been compiled in this process (all variants): tests check reuse.

    (Each comes with one result-pass program, :func:`summary_jit`, for the same shapes.)
    """
    return sum(f._cache_size() for key, f in _JITS.items() if key[0] == "solve")


def is_small(prob) -> bool:
    """Whether ``prob``'s solve is cheap next to its compile: one recording, a joint problem or a
    batch of at most ``_SMALL_INTERVALS`` sample intervals in all (members x segments x padded
    intervals)."""
    return math.prod(prob.data["seg"].dt.shape) <= _SMALL_INTERVALS


# a throw, a few seconds at 200 Hz, a joint fit or a list of up to ~12 throws of <= 100 samples. Measured
# (2026-12-02, 2-core EPYC, quiet): 5 throws joint, compile 2.4 -> 1.4 s, solve 0.06-0.08 ->
# 0.10-0.12 CPU-s; 4 s @ 1 kHz (4096 intervals, left optimised): compile 2.8 -> 1.7-1.9 s but the
# solve 0.14 -> 0.28-0.52 s, which repeated fits would pay every time
_SMALL_INTERVALS = 1536


def _member(tree, i):
    return jax.tree.map(lambda a: a[i], tree)


def _keeps_jacobian(y0, data, model_opts, unbatch: bool) -> bool:
    """Whether every solve keeps ``J`` at its accepted point: where the batch's ``J`` fit in
    ``_KEEP_J_BYTES``. Then the result pass needs no model (its compile), see :func:`_summarise_batch`."""
    _, J = model_shapes(y0[0], _member(data, 0), **dict(model_opts))  # dense: the kept J's size
    assert not isinstance(J, SegmentJacobian)
    n, C = y0.shape[0], min(_SLOTS, y0.shape[0])
    return unbatch or (n + 1 + C) * J.size * J.dtype.itemsize <= _KEEP_J_BYTES


def _fit_batch(y0, data, *, model_opts, loss, rtol, atol, max_steps, unbatch):
    """Solve ``N`` recordings (leading axes of ``y0``, ``data``); ``model_opts``: sorted ``(name, value)`` pairs.

    Each recording is one Levenberg–Marquardt solve (:class:`._solver.LMMember`),
    repeated with new weights for a robust loss (IRLS, :mod:`._robust`). A batch
    runs through a work queue (:mod:`._queue`): every recording stops on its own
    instead of being stepped until the slowest one stops. Returns each solve's
    ``y``, ``converged``, ``iterations``, final weights ``rw`` and, where kept
    (:func:`_keeps_jacobian`), ``r`` and ``J`` at ``y``: the input of :func:`_summarise_batch`.
    """
    opts = dict(model_opts, dense=False)  # J as its nonzero blocks: JᵀJ from those alone
    model, shapes = (functools.partial(f, **opts) for f in (model_residuals, model_shapes))
    keep = _keeps_jacobian(y0, data, model_opts, unbatch)
    lm = LMMember(model, rtol, atol, max_steps, keep_jacobian=keep, shapes=shapes, normal=normal_equations)
    zero = jnp.zeros((), jnp.int32)

    def start(y, d, round=zero, total=zero):
        return dict(lm.start(y, d), round=round, total=total)

    def retire(slot):
        """``(again, next round's slot, solution)`` of a stopped solve."""
        d, y, total = slot["data"], slot["y"], slot["total"] + slot["steps"]
        rw = d["seg"].rw
        out = dict(y=y, converged=lm.converged(slot), iterations=total, rw=rw)
        if lm.keep_jacobian:
            J = slot["J"]
            out.update(r=slot["r"], J=densify(J) if isinstance(J, SegmentJacobian) else J)
        if loss == "squared":
            return jnp.array(False), slot, out
        rw_new = _robust.weights(slot["r"], rw, loss, d["loss_scale"])
        again = _robust.another_round(rw, rw_new, slot["round"])
        restarted = start(y, {**d, "seg": replace(d["seg"], rw=rw_new)}, slot["round"] + 1, total)
        return again, restarted, out

    if not unbatch:
        return run_queue(
            y0.shape[0],
            lambda i: start(y0[i], _member(data, i)),
            lm.advance,
            lm.running,
            retire,
            slots=_SLOTS,
            chunk=_CHUNK,
            steps_per_round=_STEPS_PER_ROUND,
        )
    # one recording: no queue (and no vmap, whose batching of the solver's loops doubles tracing)

    def body(c):
        slot = jax.lax.while_loop(lm.running, lm.advance, c[1])
        return retire(slot)

    first = start(y0[0], _member(data, 0))
    if loss == "squared":  # one round: no loop over the rounds
        return retire(jax.lax.while_loop(lm.running, lm.advance, first))[2]
    out0 = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), jax.eval_shape(lambda s: retire(s)[2], first))
    return jax.lax.while_loop(lambda c: c[0], body, (jnp.array(True), first, out0))[2]


def _summarise_batch(sols, data, *, model_opts, loss, unbatch):
    """FitResult fields of each solution of :func:`_fit_batch` (``sols``), with its final weights.

    From the solve's kept ``J``; without it (a batch whose ``J`` would not fit)
    the model is evaluated again at the solution. (The covariance is formed
    from ``J``'s SVD; ``JᵀJ`` would square its condition number.) A batch runs
    in slices of ``_SLOTS`` members (:func:`_map_in_order`).
    """
    opts = dict(model_opts)
    model = functools.partial(model_residuals, **opts)
    kw = {k: opts[k] for k in _SUMMARY_OPTS}
    outlier_weight = _robust.outlier_weight(loss)

    def summary(sol, d):
        d = {**d, "seg": replace(d["seg"], rw=sol["rw"])}
        r, J = (sol["r"], sol["J"]) if "J" in sol else model(sol["y"], d)
        out = summarise(sol["y"], r, J, d, sol["converged"], sol["iterations"], **kw, outlier_weight=outlier_weight)
        return dict(out, robust_weights=sol["rw"])

    if unbatch:
        return summary(sols, _member(data, 0))
    # in slices: the memory of one model evaluation (if any) per slice, few LAPACK calls
    return _map_in_order(lambda a: summary(*a), (sols, data), min(_SLOTS, sols["y"].shape[0]))


def _map_in_order(f, xs, size: int):
    """``vmap(f)(xs)`` in slices of ``size`` members, one slice after another.

    ``lax.map(f, xs, batch_size=size)``, except that the last, partial slice runs after the full
    ones: lax.map computes it beside its loop, independently, and the two slices' batched SVDs
    then ran at once and starved each other of XLA's intra-op threads (a hang: a batch of 100
    recordings on 2 cores, 1 process in 3, jaxlib 0.10.2; see :func:`._solver.after`).
    """
    n = jax.tree.leaves(xs)[0].shape[0]
    k = n - n % size
    if k == 0:
        return jax.vmap(f)(xs)
    full = jax.tree.map(lambda a: a[:k].reshape(k // size, size, *a.shape[1:]), xs)
    out = jax.tree.map(lambda a: a.reshape(k, *a.shape[2:]), jax.lax.map(jax.vmap(f), full))
    if k == n:
        return out
    tail = jax.vmap(f)(after(out, jax.tree.map(lambda a: a[k:], xs)))
    return jax.tree.map(lambda a, b: jnp.concatenate([a, b]), out, tail)


_SUMMARY_OPTS = ("scale_fixed", "use_rates", "use_orientations", "layout")
# Levenberg–Marquardt steps per round of the queue between retiring and refilling slots
_STEPS_PER_ROUND = 4
# the queue's width (members in flight, each slot keeping its J) and the members stepped together:
# per recording, the model of 1 s @ 200 Hz costs about the same at 4 to 64 at once
_SLOTS = 64
_CHUNK = 16
# the most memory the kept Jacobians of a batch may take (the slots' and the solutions')
_KEEP_J_BYTES = 256 * 2**20


def fit_regular(times, arrays, options) -> FitResult:
    """:func:`fit_inertia` on one recording or a regular batch ``(N, T, ...)``: any bad input raises."""
    stds = {k: options[k] for k in ("initial_inertia", "orientation_std", "rate_std", "acceleration_std")}
    check_arrays(times=times, **arrays, **stds)
    check_options(**{k: options[k] for k in OPTION_NAMES})
    return solve(pack(times, arrays, options), options)


OPTION_NAMES = (
    "orientation_std",
    "rate_std",
    "continuity_weight",
    "excitation_tol",
    "rtol",
    "atol",
    "max_steps",
    "segments",
    "substeps",
    "loss",
    "loss_scale",
    "acceleration_std",
)


def solve(prob, options, per_sample: bool = True) -> FitResult:
    """Run the compiled solver on a packed :class:`._problem.Problem`; ``options``: loss, tolerances.

    ``per_sample=False`` leaves ``robust_weights`` as the solver's per-segment
    rows (``(N, S, B, K+1)``) for the caller to map member by member.
    """
    return solve_with_starts(prob, options, per_sample)[0]


def solve_with_starts(prob, options, per_sample: bool = True) -> tuple[FitResult, dict]:
    """:func:`solve`, and every segment's fitted start: ``q``, ``q_std``, ``w``, ``w_std`` ``(*N, S, ...)``.

    For one problem (not batched) ``starts`` also holds ``"r"`` and ``"J"``, the
    whitened residuals and their Jacobian at the solution (NumPy), which the
    solve keeps: the joint fit's per-recording tests refit them linearly.
    """
    loss = options["loss"]
    data = dict(prob.data, loss_scale=np.full(prob.y0.shape[0], float(options["loss_scale"]), prob.y0.dtype))
    small, backend = is_small(prob), jax.default_backend()
    model_opts = tuple(sorted({**prob.static, "looped": small}.items()))
    solver, summary = fit_batch_jit(backend, small), summary_jit(backend)
    summary_kw = dict(model_opts=model_opts, loss=loss, unbatch=not prob.batched)
    solver_kw = dict(
        summary_kw, rtol=float(options["rtol"]), atol=float(options["atol"]), max_steps=int(options["max_steps"])
    )
    _compile_side_by_side(solver, summary, (prob.y0, data), solver_kw, summary_kw)
    sols = solver(prob.y0, data, **solver_kw)
    out = summary(sols, data, **summary_kw)
    p_value = consistency(out.pop("consistency"))  # on the host: see ._tails
    consistent = p_value >= CONSISTENCY_ALPHA
    # host arrays go back with device_put: jnp.asarray compiles a small program per new shape (jax
    # 0.10, ~10 ms each: a fit's first call paid for six)
    out.update(
        consistency_pvalue=jax.device_put(p_value.astype(out["chi2"].dtype)),
        model_consistent=jax.device_put(consistent),
    )
    starts = jax.tree.map(np.asarray, out.pop("segment_start"))  # (*N, S, ...) per segment
    if not prob.batched and "J" in sols:
        starts.update(r=np.asarray(sols["r"]), J=np.asarray(sols["J"]))
    # one recording (or a batch of them): its first segment's start; a joint fit puts in each member's
    out.update(
        member_initial_orientation=jax.device_put(starts["q"][..., :1, :]),
        member_initial_orientation_std=jax.device_put(starts["q_std"][..., :1, :]),
        member_initial_angular_velocity=jax.device_put(starts["w"][..., :1, :]),
        member_initial_angular_velocity_std=jax.device_put(starts["w_std"][..., :1, :]),
    )
    rw = np.asarray(out.pop("robust_weights"))
    if per_sample:
        out["robust_weights"], out["outliers"] = sample_weights(prob, rw, _robust.outlier_weight(loss))
    else:
        out["robust_weights"], out["outliers"] = jax.device_put(rw), jax.device_put(np.zeros(rw.shape[0], bool))
    out["failed"] = jax.device_put(np.zeros(prob.y0.shape[0] if prob.batched else (), bool))
    res = new_unchecked(
        FitResult,
        **out,
        scale_fixed=prob.static["scale_fixed"],
        segments=prob.segments,
        member_errors=(),
        **NOT_JOINT,
    )
    return res, starts


def _compile_side_by_side(solver, summary, args: tuple, solver_kw: dict, summary_kw: dict) -> None:
    """Compile the solver (``solver(*args, **solver_kw)``) and its result pass at once, before their first call.

    Left to their calls, jax makes the two programs one after the other, on this
    thread: the solver's trace, lowering and compile, then the result pass's. XLA's
    compile does not hold Python's GIL, so here the solver's compile runs in a
    worker thread while this thread traces and lowers the result pass (from the
    solver's output shapes), and the result pass's compile runs in a second worker.
    The calls that follow find both programs in jax's caches (trace, lowering and
    executable: nothing is made twice). For a signature seen before this does
    nothing; where jax's caches were cleared since, the calls compile as usual.
    """
    signature = (solver, summary, jax.tree.structure(args), tuple(map(jax.typeof, jax.tree.leaves(args))))
    key = signature + tuple(sorted(solver_kw.items()))
    if key in _COMPILED:
        return
    traced = solver.trace(*args, **solver_kw)
    pool = _compile_pool()
    building = [pool.submit(traced.lower().compile)]
    building.append(pool.submit(summary.trace(traced.out_info, args[1], **summary_kw).lower().compile))
    for b in building:
        b.result()  # a compile error is raised here, on the caller's thread
    _COMPILED.add(key)


_COMPILED: set = set()


@functools.cache
def _compile_pool() -> concurrent.futures.ThreadPoolExecutor:
    return concurrent.futures.ThreadPoolExecutor(max_workers=2, thread_name_prefix="rbjax-compile")


# the static fields of a FitResult of recordings fitted one by one (see FitResult.joint)
NOT_JOINT = dict(joint=False, member_rms=(), member_chi2=(), member_dof=(), member_pvalue=())


def pack(t, arrays, options, **fixed):
    """:func:`fit_inertia`'s checks and packing of one recording (NumPy only, nothing compiled).

    ``fixed``: ``segments``, ``substeps``, ``pad_intervals`` overriding the options.
    """
    check_arrays(times=t, **arrays)
    options = {**options, **{k: v for k, v in fixed.items() if k != "pad_intervals"}}
    return prepare(
        t,
        arrays["orientations"],
        arrays["body_rates"],
        arrays["torques"],
        initial_inertia=options["initial_inertia"],
        method=options["method"],
        segments=options["segments"],
        substeps=options["substeps"],
        orientation_std=options["orientation_std"],
        rate_std=options["rate_std"],
        continuity_weight=options["continuity_weight"],
        excitation_tol=options["excitation_tol"],
        check_gyro_frame=bool(options["check_gyro_frame"]),
        gyro_bias=options["gyro_bias"],
        body_torques=arrays["body_torques"],
        gyro_rotation=options["gyro_rotation"],
        accelerations=arrays["accelerations"],
        acceleration_std=None if options["acceleration_std"] is None else float(options["acceleration_std"]),
        pad_intervals=fixed.get("pad_intervals"),
        drag=options["drag"],
        drag_axes=options.get("drag_axes", False),
        gyro_scale=options.get("gyro_scale", False),
        rotor_momentum=arrays.get("rotor_momentum"),
    )


def sample_weights(prob, rw: np.ndarray, outlier_weight: float):
    """Segment-row weights ``(*N, S, B, K+1)`` as ``(*N, T, 3)`` [orientation, gyro, accelerometer]
    (1 for a sensor not fitted), and the outliers ``(*N, T)``."""
    rw = rw if prob.batched else rw[None]
    idx, valid = prob.sample_index[prob.sample_valid], prob.sample_valid
    T = int(idx.max()) + 1
    W = np.ones((rw.shape[0], T, 3), rw.dtype)
    for b, name in enumerate(prob.sensors):
        W[:, idx, ("orientation", "gyro", "accelerometer").index(name)] = rw[:, :, b, :][:, valid]
    outliers = np.any(W < outlier_weight, -1)
    if not prob.batched:
        W, outliers = W[0], outliers[0]
    return jax.device_put(W), jax.device_put(outliers)
