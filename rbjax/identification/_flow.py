"""The fit model's integrator: ``"rk4"`` on ``(q, L)`` and its tangents, for many bodies at once.

The same map as :func:`rbjax.step` with ``method="rk4"`` on a torque-free (or
known-torque) :class:`rbjax.State` (:mod:`rbjax._methods.explicit_rk`), written
for the fit, where it is nearly all of the work:

    q̇ = ½ (0, ω_w) ⊗ q,   ω_w = R(q) I⁻¹ R(q)ᵀ L,   L̇ = τ_w(t),

four classical stages, then ``q ← q/‖q‖``. Torques (world, or body turned into
the world by the stage attitude) are linear between samples, so a stage's
torque is interpolated between the ends of its sample interval.

Why not :func:`rbjax.step` itself: the fit differentiates the flow along
``n ≈ 11`` directions for every segment of every recording in a batch, and
``vmap`` puts those batch axes first, so each quaternion component is a
stride-4 column that XLA:CPU neither fuses nor vectorises (about 90 kernels
per step). Here every component of ``q``, ``L`` and ``I⁻¹`` is its own
contiguous row over the bodies (structure of arrays, tuples of ``(M,)``
arrays, tangents ``(n, M)``), so a step is a few long elementwise loops.
Measured on the model of 128 recordings of 1 s at 200 Hz (2-core EPYC,
float64): see :mod:`._model`. A batch of recordings reaches this module with
its recordings and segments flattened into one body axis by the
``custom_vmap`` rule of :func:`flow`, so the members of the fit's work queue
are stepped as one structure of arrays, not as ``C`` separate small ones.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax import Array

from .._math import apply3, cross_components, rotate_components
from .._methods.explicit_rk import CLASSICAL_RK4

__all__ = ["flow"]

_A, _B, _C = CLASSICAL_RK4


def _conj(q):
    return (q[0], -q[1], -q[2], -q[3])


def _apply(m, v):
    """``M v`` for a 3x3 matrix as a row-major 9-tuple."""
    return apply3((m[0:3], m[3:6], m[6:9]), v)


def _body_rate(q, L, inv, h=None):
    """``ω = I⁻¹ (Rᵀ L - h)`` (body frame); ``h``: the rotors' body-frame momentum, or ``None`` (no rotor)."""
    Lb = rotate_components(_conj(q), L)
    if h is not None:
        Lb = tuple(a - b for a, b in zip(Lb, h, strict=True))
    return _apply(inv, Lb)


def _q_rate(q, L, inv, h=None):
    """``½ (0, ω_w) ⊗ q`` with ``ω_w = R I⁻¹ (Rᵀ L - h)`` (world frame), as :func:`rbjax.derivative`."""
    w = rotate_components(q, _body_rate(q, L, inv, h))
    u = q[1:]
    c = cross_components(w, u)
    return (-0.5 * (w[0] * u[0] + w[1] * u[1] + w[2] * u[2]),) + tuple(0.5 * (q[0] * w[i] + c[i]) for i in range(3))


# Classical RK4's stage i reads only stage i-1 (A is zero below its first sub-diagonal), so one
# stage function serves all four: (a_i, b_i, c_i) = (A[i][i-1], b[i], c[i])
assert all(not any(row[:-1]) for row in _A[1:]), "the stage loop needs a sub-diagonal tableau"
_STAGES = tuple(zip((0.0,) + tuple(row[-1] for row in _A[1:]), _B, _C, strict=True))


def _rk4(q, L, inv, k, dt, torque, looped: bool = False, rotor=None):
    """One step; ``torque(q_stage, L_stage, inv, k, c)`` is the world torque at stage node ``c``, or ``None``.

    ``rotor(c)``: the rotors' body-frame momentum ``h`` at stage node ``c`` (a 3-tuple of rows), or
    ``None`` without rotors; it enters only the map ``ω = I⁻¹ (Rᵀ L - h)`` (world ``L`` is the total).

    ``k``: the drag coefficients ``(c₁, c₂)`` (rows over the bodies) or ``()``.
    ``looped``: the four stages as a ``lax.scan`` of one stage instead of
    written out. The same arithmetic; the program holds one copy of the stage
    and its tangents instead of four, which compiles faster and runs slower
    (docs/fitting.md, "Speed"), so the fit loops only where the compile is most
    of the call.
    """
    y = (q, L) if torque is not None else (q,)  # without a torque L is constant

    def stage(k_prev, acc, a, b, c):
        """Stage ``(a, b, c)`` after the rates ``k_prev`` (``None`` before the first): its rates, and
        ``acc + b k`` (``acc``: the weighted sum of the stages so far, ``None`` before the first)."""
        qs, *Ls = y if k_prev is None else jax.tree.map(lambda x, r: x + dt * (a * r), y, k_prev)
        Ls = Ls[0] if Ls else L
        hs = None if rotor is None else rotor(c)
        k_i = (_q_rate(qs, Ls, inv, hs),) + ((torque(qs, Ls, inv, k, c),) if torque is not None else ())
        weighted = jax.tree.map(lambda r: b * r, k_i)
        return k_i, weighted if acc is None else jax.tree.map(jnp.add, acc, weighted)

    if looped:
        # The carry (the stage's rates and the running sum, each component with its tangents) is one
        # stacked array: carried as separate components, XLA:CPU fused a copy of the whole stage
        # into the loop of each, eight copies (benchmarks/results/fit_stage_carry_stacked_2026-12-06.md)
        zero = jax.tree.map(jnp.zeros_like, y)
        leaves, tree = jax.tree.flatten((zero, zero))

        def body(carry, abc):
            k_prev, acc = jax.tree.unflatten(tree, list(carry))
            return jnp.stack(jax.tree.leaves(stage(k_prev, acc, *abc))), None

        carry, _ = jax.lax.scan(body, jnp.stack(leaves), tuple(jnp.asarray(_STAGES, dt.dtype).T))
        _, acc = jax.tree.unflatten(tree, list(carry))
    else:
        k_prev = acc = None
        for a, b, c in _STAGES:
            k_prev, acc = stage(k_prev, acc, a, b, c)
    q, *L_end = jax.tree.map(lambda x, s: x + dt * s, y, acc)
    L = L_end[0] if L_end else L
    norm = jnp.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return tuple(x / norm for x in q), L


def _stage_rotor(x, j, substeps, c):
    """The rotors' body-frame momentum ``h`` at node ``c`` of sub-step ``j``: linear over the sample interval."""
    f = (j + c) / substeps  # where the stage lies in its sample interval
    return tuple(a + f * (b - a) for a, b in zip(x["h_lo"], x["h_hi"], strict=True))


def _stage_torque(x, j, substeps, frame, drag, rotor, qs, Ls, inv, k, c):
    """World torque at node ``c`` of sub-step ``j``.

    Known torques: linear over the interval, turned by ``qs`` if body-frame.
    Drag: ``τ_b = -(c₁ + c₂ |ω|) ω`` with ``ω = I⁻¹ (Rᵀ L - h)`` (body frame; ``h = rotor(c)``, the
    rotors' momentum, or none), turned into the world; with six coefficients ``k`` per body axis,
    ``τ_b,a = -(c₁ₐ + c₂ₐ |ω|) ω_a``.
    """
    tau = (0.0, 0.0, 0.0)
    if frame is not None:
        f = (j + c) / substeps  # where the stage lies in its sample interval
        tau = tuple(a + f * (b - a) for a, b in zip(x["lo"], x["hi"], strict=True))
        tau = rotate_components(qs, tau) if frame == "body" else tau
    if drag:
        w = _body_rate(qs, Ls, inv, None if rotor is None else rotor(c))
        s2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
        # |ω| with the derivative 0 at ω = 0 (sqrt's is inf there, and inf·0 = NaN in the tangents):
        # the damping torque c₂|ω|ω is flat there (a segment that starts at rest)
        speed = jnp.where(s2 > 0, jnp.sqrt(jnp.where(s2 > 0, s2, 1)), 0)
        if len(k) == 2:  # the same about every axis
            damping = k[0] + k[1] * speed
            tau_b = tuple(-damping * wi for wi in w)
        else:  # per body axis: (c1_x, c1_y, c1_z, c2_x, c2_y, c2_z)
            tau_b = tuple(-(k[a] + k[3 + a] * speed) * w[a] for a in range(3))
        tau_d = rotate_components(qs, tau_b)
        tau = tuple(a + b for a, b in zip(tau, tau_d, strict=True))
    return tau


def _soa(a: Array, core: int) -> tuple:
    """``(M, [n,] *core)`` → tuple over the flattened core of ``(M,)`` / ``(n, M)`` rows."""
    rows = a.reshape(a.shape[: a.ndim - core] + (-1,))
    return tuple(jnp.moveaxis(rows[..., i], 0, -1) for i in range(rows.shape[-1]))


def _flow(
    args,
    *,
    substeps: int,
    torque_frame: str | None,
    observe,
    drag: bool = False,
    looped: bool = False,
    rotor: bool = False,
):
    q0, L0, inv = _soa(args["q"], 1), _soa(args["L"], 1), _soa(args["inv"], 2)
    dq0, dL0, dinv = _soa(args["dq"], 1), _soa(args["dL"], 1), _soa(args["dinv"], 2)
    k, dk = (_soa(args["drag"], 1), _soa(args["ddrag"], 1)) if drag else ((), ())
    # the body axis last: per sample (M, K, ...) -> (K, ..., M) for the scan, per body (..., M)
    xs = dict(dt=args["dt"].T, obs=jax.tree.map(lambda a: jnp.moveaxis(a, (0, 1), (-1, 0)), args["obs"]))
    const = jax.tree.map(lambda a: jnp.moveaxis(a, 0, -1), args["const"])
    if torque_frame is not None:
        tau = args["tau"]  # (M, K+1, 3) at the sample times
        xs["lo"] = tuple(tau[:, :-1, i].T for i in range(3))
        xs["hi"] = tuple(tau[:, 1:, i].T for i in range(3))
    if rotor:
        spin = args["h"]  # (M, K+1, 3) the rotors' body-frame momentum at the sample times
        xs["h_lo"] = tuple(spin[:, :-1, i].T for i in range(3))
        xs["h_hi"] = tuple(spin[:, 1:, i].T for i in range(3))

    def seen(q, L, inv, obs):
        """``observe`` of every body (one-body function lifted over the trailing body axis)."""
        per_body = (jnp.stack(q), jnp.stack(L), jnp.stack(inv).reshape(3, 3, -1), obs, const)
        return jax.vmap(observe, in_axes=-1, out_axes=-1)(*per_body)

    def interval(carry, x):
        h = x["dt"] / substeps

        def sub(carry, j):  # sub-step j of the interval, with its tangents
            torque = None
            spin = functools.partial(_stage_rotor, x, j, substeps) if rotor else None
            if torque_frame is not None or drag:
                torque = functools.partial(_stage_torque, x, j, substeps, torque_frame, drag, spin)
            (q, L), (dq, dL) = carry
            step = functools.partial(_rk4, dt=h, torque=torque, looped=looped, rotor=spin)
            push = lambda tq, tL, ti, tk: jax.jvp(step, (q, L, inv, k), (tq, tL, ti, tk))
            return jax.vmap(push, out_axes=(None, 0))(dq, dL, dinv, dk), None

        # a loop, not unrolled: the default substeps reach 32 on fast or glitched recordings
        steps = jnp.arange(substeps, dtype=h.dtype)
        carry = sub(carry, steps[0])[0] if substeps == 1 else jax.lax.scan(sub, carry, steps)[0]
        (q, L), (dq, dL) = carry
        look = functools.partial(seen, obs=x["obs"])
        tangents = lambda tq, tL, ti: jax.jvp(look, (q, L, inv), (tq, tL, ti))
        return carry, jax.vmap(tangents, out_axes=(None, 0))(dq, dL, dinv)

    ((q, _), (dq, _)), (y, dy) = jax.lax.scan(interval, ((q0, L0), (dq0, dL0)), xs)
    # back to the model's layout: observations (M, K, c), tangents (M, n, K, c); end (M, 4), (M, n, 4)
    y = jax.tree.map(lambda a: jnp.transpose(a, (2, 0, 1)), y)
    dy = jax.tree.map(lambda a: jnp.transpose(a, (3, 1, 0, 2)), dy)
    return (jnp.stack(q, -1), jnp.swapaxes(jnp.stack(dq, -1), 0, 1)), y, dy


@functools.cache
def flow(
    substeps: int, torque_frame: str | None, observe, drag: bool = False, looped: bool = False, rotor: bool = False
):
    """``rk4`` on ``M`` bodies' ``(q, L)`` over ``K`` sample intervals, observed after each, with tangents.

    ``flow(substeps, torque_frame, observe)(args)``; ``args`` is a dict of
    arrays with a leading body axis ``M``: ``q`` ``(M, 4)`` unit quaternions
    (body to world), ``L`` ``(M, 3)`` world angular momentum (kg m²/s),
    ``inv`` ``(M, 3, 3)`` body-frame ``I⁻¹``; their tangents ``dq``
    ``(M, n, 4)``, ``dL`` ``(M, n, 3)``, ``dinv`` ``(M, n, 3, 3)``; ``dt``
    ``(M, K)`` interval lengths (s, 0 for padding), each split into
    ``substeps`` steps; with ``torque_frame`` ``"world"`` or ``"body"``,
    ``tau`` ``(M, K+1, 3)`` (N m) at the interval ends; ``obs`` (leaves
    ``(M, K, ...)``, per sample) and ``const`` (leaves ``(M, ...)``, per body).

    ``observe(q, L, inv, obs, const)`` is a one-body function of the state
    after an interval and that interval's ``obs``, returning a tuple of
    arrays ``(c,)``. Returns ``(q_end (M, 4), dq_end (M, n, 4))``, the
    observations ``(M, K, c)`` and their tangents ``(M, n, K, c)``.

    ``drag``: add the body-frame damping torque ``τ_b = -(c₁ + c₂ |ω|) ω``
    (N m, ``ω`` in rad/s), ``args["drag"]`` ``(M, 2)`` the coefficients
    ``(c₁, c₂)`` and ``args["ddrag"]`` ``(M, n, 2)`` their tangents; or ``(M, 6)``,
    ``(c1_x, c1_y, c1_z, c2_x, c2_y, c2_z)``, for ``τ_b,a = -(c₁ₐ + c₂ₐ |ω|) ω_a`` per body axis.

    ``looped``: the RK4 stages as a loop of one stage (see :func:`_rk4`), for
    programs whose compile costs more than their run.

    ``rotor``: a gyrostat: ``args["h"]`` ``(M, K+1, 3)`` is the rotors' momentum
    relative to the body (body frame, kg m²/s) at the interval ends, linear in
    time between them (so the steps, which never straddle a sample, keep RK4's
    order), and the body rate is ``ω = I⁻¹ (Rᵀ L - h)`` with ``L`` the total
    world angular momentum, constant without torques. ``obs`` then carries
    ``h`` at each sample for ``observe``.

    Under ``vmap`` (the fit's work queue) the mapped axis is folded into the
    body axis instead of being batched op by op.
    """
    fn = jax.custom_batching.custom_vmap(
        functools.partial(
            _flow,
            substeps=substeps,
            torque_frame=torque_frame,
            observe=observe,
            drag=drag,
            looped=looped,
            rotor=rotor,
        )
    )

    @fn.def_vmap
    def _folded(axis_size, in_batched, args):
        args = jax.tree.map(lambda a, b: a if b else jnp.broadcast_to(a, (axis_size, *a.shape)), args, in_batched[0])
        out = fn(jax.tree.map(lambda a: a.reshape((-1, *a.shape[2:])), args))
        out = jax.tree.map(lambda a: a.reshape((axis_size, -1, *a.shape[1:])), out)
        return out, jax.tree.map(lambda _: True, out)

    return fn
