"""The traced model of inertia fitting: residuals and their dense Jacobian.

One recording (``vmap``-ped for batches) cut into ``S`` multiple-shooting
segments; see :mod:`._fit` for the residuals and the solver.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .. import _methods
from .._body import Body, inverse_3x3
from .._inertia_param import inertia_from_params
from .._math import (
    matvec3,
    quat_conjugate,
    quat_exp,
    quat_log,
    quat_multiply,
    quat_rotate_inverse_unchecked,
    quat_rotate_unchecked,
)
from .._pytree import new_unchecked
from .._state import Forces, State
from ._flow import flow
from ._layout import Layout
from ._sensors import accelerometer_reading, gyro_reading

# Layout: S segments of K sample intervals (padding intervals have dt = 0 and
# mask 0). Segment s has local parameters p_s = (δ_s, ω_s) (6) and shares the
# inertia parameters θ (5 or 6). Its data residuals depend on (θ, p_s) only and
# a join's continuity residuals on (θ, p_s, p_{s+1}) only, so the Jacobian is
# formed from (n_θ + 6) forward tangents per segment, all segments stepped
# together, and scattered into the dense matrix: the cost does not grow with S.


def _inertia(theta: Array, scale_fixed: bool) -> Array:
    theta = theta[: 6 if scale_fixed else 5]  # the shared block may go on with the gyro bias
    if not scale_fixed:  # gauge: log L00 = 0 (Σ_xx = 1); reported normalised to tr I = 1
        theta = jnp.concatenate([jnp.zeros_like(theta[:1]), theta])
    return inertia_from_params(theta)


def unpack(y: Array, n_theta: int, S: int):
    return y[:n_theta], y[n_theta:].reshape(S, 6)


def _start(x, d, *, n_theta, scale_fixed):
    """Start state of one segment from ``x = (θ, δ_s, ω_s)``: ``q = q_start ⊗ exp(δ_s)``, ``L = R (I ω_s + h)``
    (``h``: the rotors' body-frame momentum at the segment's first sample, none without rotors)."""
    I = _inertia(x[:n_theta], scale_fixed)
    # delta_free = 0 pins segment 0's rotation where no orientation data fix the world frame
    delta, w0 = d.delta_free * x[n_theta : n_theta + 3], x[n_theta + 3 :]
    q0 = quat_multiply(d.q_start, quat_exp(delta))
    one = jnp.ones((), I.dtype)
    body = new_unchecked(Body, mass=one, inertia=I, _inverse=inverse_3x3(I))
    zero = jnp.zeros(3, I.dtype)
    Lb = matvec3(I, w0) if d.h is None else matvec3(I, w0) + d.h[0]  # with rotors: I ω + h
    L0 = quat_rotate_unchecked(q0, Lb)
    return new_unchecked(
        State, body=body, position=zero, velocity=zero, orientation=q0, angular_momentum=L0, time=zero[0]
    )


def _observe(q, L, inv, o, c):
    """Weighted residuals of one sample (orientation (3,), rate (3,)) and the body rate ``ω = I⁻¹ Rᵀ L``.

    ``q``, ``L``: the simulated attitude and world-frame angular momentum;
    ``inv``: body-frame ``I⁻¹``; ``o``: the sample (``q_meas``, ``w_meas``,
    ``weight``, and with rotors ``h``, their body-frame momentum: then
    ``ω = I⁻¹ (Rᵀ L - h)``); ``c``: the segment's inverse noise levels (``wq``, ``ww``).
    """
    Lb = quat_rotate_inverse_unchecked(q, L)
    w = matvec3(inv, Lb if "h" not in o else Lb - o["h"])
    r_q = o["weight"] * c["wq"] * quat_log(quat_multiply(quat_conjugate(q), o["q_meas"]))
    return r_q, o["weight"] * c["ww"] * (w - o["w_meas"]), w


# methods whose fit model runs through :mod:`._flow` (the same map as rbjax.step's)
_FLOW_METHODS = frozenset({"rk4"})


def _pushforward(f, x, tx):
    """``f(x)`` and its derivatives along the rows of ``tx`` (each leaf ``(n, *x.shape)``)."""
    return jax.vmap(lambda v: jax.jvp(f, (x,), (v,)), out_axes=(None, 0))(tx)


def _segments(X, seg, *, layout: Layout, scale_fixed, method, substeps, use_rates, use_orientations=True, looped=False):
    """Data residuals ``(S, m)`` and end states ``(q, ω_body)`` ``(S, 7)`` of all segments, and
    their derivatives ``(S, m, n)``, ``(S, 7, n)`` in each segment's ``x_s = X[s]`` (``n = n_θ + 6``).

    Forward-mode sensitivities carried through one ``lax.scan`` of
    ``step ∘ vmap(segments) ∘ vmap(tangents)``: the same numbers as
    ``vmap(jacfwd(segment))``, but the scan is traced once instead of batched
    twice (jacfwd's and the segments' ``vmap`` each re-trace a scan's body to a
    fixed point); that cut the model's tracing from 1.3 s to 0.3 s.

    ``seg`` holds the recording cut into segments of ``K`` intervals. Torques
    (world) are linear in time between samples. Residual rows per segment:
    ``[first-sample orientation (3), orientations (K, 3)]`` and, with rates,
    ``[first-sample rate (3), rates (K, 3)]``, each weighted by its inverse
    noise; the first-sample rows are non-zero in segment 0 only.
    """
    step_fn = _methods.get(method, State)
    n_theta = layout.shared
    start = functools.partial(_start, n_theta=n_theta, scale_fixed=scale_fixed)
    basis = jnp.eye(X.shape[1], dtype=X.dtype)
    s0, ds0 = jax.vmap(lambda x, d: _pushforward(lambda x: start(x, d), x, basis))(X, seg)

    def forces(d):
        if d.tau is not None:  # world frame
            ts, tau = d.t_samples, d.tau
            return lambda st, t: Forces(torque=jnp.stack([jnp.interp(t, ts, tau[:, i]) for i in range(3)]))
        if d.tau_b is not None:  # body frame: turned into the world by the simulated attitude
            ts, tau_b = d.t_samples, d.tau_b

            def body(st, t):
                tb = jnp.stack([jnp.interp(t, ts, tau_b[:, i]) for i in range(3)])
                return Forces(torque=quat_rotate_unchecked(st.orientation, tb))

            return body
        return lambda st, t: Forces()

    # Only the rotation (q, L) is carried through the scan: the fit's bodies have no force, so
    # position and velocity stay zero, and the body is the same at every step, so its tangents
    # are loop invariants. Carrying the whole State and its tangents moved ~5x the numbers per
    # step; measured on the model of 1,000 1 s @ 200 Hz recordings: 0.64 s -> 0.56 s.
    zero = jnp.zeros(3, X.dtype)

    def rotation_step(r, body, t, dt, d):
        s = new_unchecked(
            State, body=body, position=zero, velocity=zero, orientation=r[0], angular_momentum=r[1], time=t
        )
        out = step_fn(s, forces(d), t, dt)
        return out.orientation, out.angular_momentum

    def advance(r, dr, body, dbody, t, dt, d):
        push = lambda tr, tb: jax.jvp(lambda r, b: rotation_step(r, b, t, dt, d), (r, body), (tr, tb))
        return jax.vmap(push, out_axes=(None, 0))(dr, dbody)

    body, dbody = s0.body, ds0.body

    def sub(carry, dt):  # one step of every segment, dt (S,)
        r, dr, t = carry
        r, dr = jax.vmap(advance)(r, dr, body, dbody, t, dt, seg)
        return (r, dr, t + dt), None

    def row(carry, dts):  # one sample interval: substeps steps
        carry, _ = jax.lax.scan(sub, carry, dts)
        return carry, carry[:2]

    r0 = (s0.orientation, s0.angular_momentum)
    dr0 = (ds0.orientation, ds0.angular_momentum)
    inv, dinv = body.inverse_inertia, dbody.inverse_inertia
    const = dict(wq=seg.wq, ww=seg.ww)
    obs = dict(q_meas=seg.q_meas, w_meas=seg.w_meas, weight=seg.mask)  # samples 1..K
    if seg.h is not None:  # the rotors' momentum at samples 1..K
        obs["h"] = seg.h[:, 1:]

    def observe(r, dr, obs):  # every segment's observations of one sample, tangents (S, n, ...)
        def one(r, dr, inv, dinv, obs, c):
            look = lambda tr, ti: jax.jvp(lambda r, i: _observe(r[0], r[1], i, obs, c), (r, inv), (tr, ti))
            return jax.vmap(look, out_axes=(None, 0))(dr, dinv)

        return jax.vmap(one)(r, dr, inv, dinv, obs, const)

    if method in _FLOW_METHODS:  # structure of arrays; a batch's recordings folded into the body axis
        frame = "world" if seg.tau is not None else "body" if seg.tau_b is not None else None
        args = dict(q=r0[0], L=r0[1], inv=inv, dq=dr0[0], dL=dr0[1], dinv=dinv, dt=seg.dt, obs=obs, const=const)
        if frame is not None:
            args["tau"] = seg.tau if frame == "world" else seg.tau_b
        if layout.drag:  # the coefficients (c₁, c₂) (S, 2) and their tangents (S, n, 2); per axis 6
            coefficients = lambda x: _drag_model(x, scale_fixed, layout)
            k, dk = jax.vmap(lambda x: _pushforward(coefficients, x, basis))(X)
            args.update(drag=k, ddrag=dk)
        if seg.h is not None:
            args["h"] = seg.h
        rotor = seg.h is not None
        (q_end, dq_end), y, dy = flow(substeps, frame, _observe, bool(layout.drag), looped, rotor)(args)
    else:
        K = seg.dt.shape[1]
        dts = jnp.broadcast_to((seg.dt / substeps).T[:, None], (K, substeps, X.shape[0]))
        (r_end, dr_end, _), (r_k, dr_k) = jax.lax.scan(row, (r0, dr0, seg.t0), dts)
        q_end, dq_end = r_end[0], dr_end[0]
        over_samples = jax.vmap(observe, in_axes=(0, 0, jax.tree.map(lambda _: 1, obs)), out_axes=(1, 2))
        y, dy = over_samples(r_k, dr_k, obs)

    # samples 0..K of every segment: the first sample, then those after each interval
    first = dict(q_meas=seg.q_first, w_meas=seg.w_first, weight=seg.first)
    if seg.h is not None:  # each segment's start sample (the recording's first in segment 0)
        first["h"] = seg.h[:, 0]
    y0, dy0 = observe(r0, dr0, first)
    (r_q, r_w, w), (dr_q, dr_w, dw) = jax.tree.map(
        lambda a0, a, axis: jnp.concatenate([jnp.expand_dims(a0, axis), a], axis),
        (y0, dy0),
        (y, dy),
        ((1,) * 3, (2,) * 3),
    )
    w_meas = jnp.concatenate([seg.w_first[:, None], seg.w_meas], 1)
    weight = jnp.concatenate([seg.first[:, None], seg.mask], 1)
    S, n = X.shape
    if layout.gyro_rotation:  # gyro = R_gᵀ ω (+ b): R_g = exp(ρ) maps gyro-frame vectors to body-frame ones
        at = layout.span("gyro_rotation")
        g = weight[:, :, None] * seg.ww[:, None, None]  # (S, K+1, 1)
        rho = X[0, at]

        wg = jax.vmap(jax.vmap(lambda w: gyro_reading(rho, w)))(w)
        Fw = jax.vmap(jax.vmap(lambda w: jax.jacfwd(gyro_reading, argnums=1)(rho, w)))(w)  # (S, K+1, 3, 3)
        Fr = jax.vmap(jax.vmap(lambda w: jax.jacfwd(gyro_reading, argnums=0)(rho, w)))(w)
        r_w = g * (wg - w_meas)
        dr_w = g[:, None] * jnp.einsum("skij,snkj->snki", Fw, dw)
        dr_w = dr_w.at[:, at].add(jnp.moveaxis(g[..., None] * Fr, -1, 1))
    if layout.gyro_scale:  # gyro = (1 + s) R_gᵀ ω (+ b): one factor on the reading before its bias
        at = layout.span("gyro_scale")
        g = weight[:, :, None] * seg.ww[:, None, None]  # (S, K+1, 1)
        reading = r_w + g * w_meas  # g (R_gᵀ) ω: the weighted reading so far, without w_meas
        # the parameter is u = log(1 + s): the factor stays positive whatever step the solver tries
        # (a factor ≤ 0, a gyro reading against the rotation, is never physical)
        u = X[:, at][:, None, :]  # (S, 1, 1)
        factor = jnp.exp(u)
        r_w = r_w + jnp.expm1(u) * reading
        dr_w = factor[:, None] * dr_w  # u's own column was zero
        dr_w = dr_w.at[:, at].add((factor * reading)[:, None])
    if layout.gyro_bias:  # gyro = ω + b (body frame, constant): b enters the rate rows linearly
        at = layout.span("gyro_bias")
        g = weight[:, :, None] * seg.ww[:, None, None]  # (S, K+1, 1)
        r_w = r_w + g * X[:, None, at]
        eye = jnp.eye(3, dtype=X.dtype)
        dr_w = dr_w.at[:, at].add(jnp.einsum("skc,bc->sbkc", g * jnp.ones(3, X.dtype), eye))
    use_accel = bool(layout.accelerometer)
    if use_accel:  # free flight: a = ω̇ × r + ω × (ω × r) + b_a (body frame), ω̇ = -I⁻¹ (ω × I ω)
        n_I, n_A = layout.inertia, layout.span("accelerometer").start
        g = weight[:, :, None] * seg.wa[:, None, None]  # (S, K+1, 1)
        th, ra, ba = X[0, :n_I], X[0, n_A : n_A + 3], X[0, n_A + 3 : n_A + 6]

        def accel(th, w, ra, ba, *spin):  # spin: the rotors' (h, ḣ) at the sample, if any
            return accelerometer_reading(_inertia(th, scale_fixed), w, ra, ba, *spin)

        spins = () if seg.h is None else (seg.h, seg.h_rate)  # (S, K+1, 3) each
        each = lambda f: jax.vmap(jax.vmap(f))(w, *spins)
        a_pred = each(lambda w, *sp: accel(th, w, ra, ba, *sp))
        Fth, Fw, Fr, Fb = each(lambda w, *sp: jax.jacfwd(accel, argnums=(0, 1, 2, 3))(th, w, ra, ba, *sp))
        a_meas = jnp.concatenate([seg.a_first[:, None], seg.a_meas], 1)
        r_a = g * (a_pred - a_meas)
        dr_a = g[:, None] * jnp.einsum("skij,snkj->snki", Fw, dw)
        dr_a = dr_a.at[:, :n_I].add(jnp.moveaxis(g[..., None] * Fth, -1, 1))
        dr_a = dr_a.at[:, n_A : n_A + 3].add(jnp.moveaxis(g[..., None] * Fr, -1, 1))
        dr_a = dr_a.at[:, n_A + 3 : n_A + 6].add(jnp.moveaxis(g[..., None] * Fb, -1, 1))
    rows, drows = [], []
    if use_orientations:
        rows.append(r_q.reshape(S, -1))
        drows.append(dr_q.reshape(S, n, -1))
    if use_rates:
        rows.append(r_w.reshape(S, -1))
        drows.append(dr_w.reshape(S, n, -1))
    if use_accel:
        rows.append(r_a.reshape(S, -1))
        drows.append(dr_a.reshape(S, n, -1))
    end = jnp.concatenate([q_end, w[:, -1]], -1)  # padding (dt = 0) keeps the end
    d_end = jnp.concatenate([dq_end, dw[:, :, -1]], -1)
    return (
        jnp.concatenate(rows, -1),
        end,
        jnp.swapaxes(jnp.concatenate(drows, -1), 1, 2),
        jnp.swapaxes(d_end, 1, 2),
    )


def _continuity(end, p_next, d_next, continuity_weight):
    """Join residuals (6,): orientation gap (rad) and rate gap, weighted."""
    q_next = quat_multiply(d_next.q_start, quat_exp(p_next[:3]))
    gap = quat_log(quat_multiply(quat_conjugate(end[:4]), q_next))
    return continuity_weight * jnp.concatenate([d_next.wcq * gap, d_next.wc * (end[4:] - p_next[3:])])


def model_residuals(
    y,
    data,
    *,
    scale_fixed,
    method,
    substeps,
    use_rates,
    layout: Layout,
    use_orientations=True,
    joins=None,
    looped=False,
    dense=True,
):
    """Residual vector ``r`` (segments' data rows, then join rows) and its Jacobian ``∂r/∂y``.

    ``dense``: ``J`` as an ``(m, n)`` matrix; else, for several segments, as a
    :class:`SegmentJacobian` of the nonzero blocks, from which the solver forms
    ``JᵀJ`` in ``O(m (n_θ + 6)²)`` instead of ``O(m n²)`` (:func:`normal_equations`).

    ``y = (shared block, p_0, ..., p_{S-1})`` as ``layout`` places them
    (:class:`._layout.Layout`: inertia θ, gyro bias, gyro rotation, accelerometer,
    drag), then 6 per segment. ``joins``: the segments ``s`` whose end is joined to the start of ``s + 1``
    (a static tuple); ``None``: every one (one recording). ``looped``: the RK4
    stages as a loop (:func:`._flow.flow`), for a program that compiles faster and runs slower.
    """
    seg = data["seg"]
    S = seg.dt.shape[0]
    n_theta = layout.shared
    theta, P = unpack(y, n_theta, S)
    X = jnp.concatenate([jnp.broadcast_to(theta, (S, n_theta)), P], -1)  # x_s = (θ, p_s)
    r_seg, ends, J_seg, J_end = _segments(
        X,
        seg,
        layout=layout,
        scale_fixed=scale_fixed,
        method=method,
        substeps=substeps,
        use_rates=use_rates,
        use_orientations=use_orientations,
        looped=looped,
    )
    m = r_seg.shape[1]
    # robust (IRLS) weights per sample and sensor block, rw (S, blocks, K+1): rows scaled by √w
    sw = jnp.sqrt(seg.rw)
    B, K1 = sw.shape[1:]
    r_seg = (r_seg.reshape(S, B, K1, 3) * sw[..., None]).reshape(S, m)
    J_seg = (J_seg.reshape(S, B, K1, 3, -1) * sw[..., None, None]).reshape(S, m, -1)
    # the joined segments s -> s + 1: all, or (several recordings of one body) those inside a recording
    at = np.arange(S - 1) if joins is None else np.asarray(joins, int)
    if S == 1:  # single shooting: no joins
        return r_seg.reshape(-1), J_seg.reshape(m, -1)
    eye = jnp.eye(S, dtype=y.dtype)
    blocks = lambda B, E: jnp.einsum("sra,st->srta", B, E).reshape(B.shape[0] * B.shape[1], -1)
    if at.size == 0:  # recordings of one segment each: nothing joined
        J = SegmentJacobian(J_seg, jnp.zeros((0, y.shape[0]), y.dtype), n_theta)
        return r_seg.reshape(-1), J if not dense else densify(J)
    c = functools.partial(_continuity, continuity_weight=data["continuity_weight"])  # traced: no recompile
    nxt = jax.tree.map(lambda a: a[at + 1], seg)
    cj = jax.jacfwd(lambda e, pn, dn: (c(e, pn, dn),) * 2, argnums=(0, 1), has_aux=True)
    (Dc_end, Dc_p), r_c = jax.vmap(cj)(ends[at], P[at + 1], nxt)
    Je = J_end[at]  # chain rule through the end state of segment s
    Jc_theta = jnp.einsum("sre,sea->sra", Dc_end, Je[..., :n_theta]).reshape(-1, n_theta)
    Jc_p = blocks(jnp.einsum("sre,sea->sra", Dc_end, Je[..., n_theta:]), eye[at]) + blocks(Dc_p, eye[at + 1])
    J = SegmentJacobian(J_seg, jnp.concatenate([Jc_theta, Jc_p], -1), n_theta)
    return jnp.concatenate([r_seg.reshape(-1), r_c.reshape(-1)]), J if not dense else densify(J)


@functools.partial(jax.tree_util.register_dataclass, data_fields=["seg", "joins"], meta_fields=["n_theta"])
@dataclasses.dataclass(frozen=True)
class SegmentJacobian:
    """The nonzero blocks of a multiple-shooting Jacobian: ``seg`` ``(S, m, n_θ + 6)``, segment ``s``'s
    data rows against ``(θ, p_s)``; ``joins`` ``(6 · joins, n)``, the join rows against all of ``y``
    (dense: they are few); ``n_theta`` (static), the shared block's size."""

    seg: Array
    joins: Array
    n_theta: int


def densify(J: SegmentJacobian) -> Array:
    """The ``(S m + 6 · joins, n)`` matrix of :class:`SegmentJacobian` ``J``: ``[θ columns | blockdiag(p_s columns)]``
    over the data rows (segment-major), then the join rows."""
    S, m, _ = J.seg.shape
    nt = J.n_theta
    local = jnp.einsum("sra,st->srta", J.seg[..., nt:], jnp.eye(S, dtype=J.seg.dtype)).reshape(S * m, -1)
    top = jnp.concatenate([J.seg[..., :nt].reshape(S * m, nt), local], -1)
    return jnp.concatenate([top, J.joins], 0)


def normal_equations(r: Array, J: Array | SegmentJacobian) -> tuple[Array, Array]:
    """``(JᵀJ, Jᵀr)`` of a dense ``J`` or, block by block, of a :class:`SegmentJacobian`.

    Blocks: ``G_θθ = Σ_s A_sᵀA_s``, ``G_θs = A_sᵀB_s``, ``G_ss = B_sᵀB_s`` (``A_s``, ``B_s``:
    segment ``s``'s columns of θ and of ``p_s``), plus the join rows' ``J_cᵀJ_c``: the
    products of the nonzero blocks only, ``O(m (n_θ + 6)²)`` instead of ``O(m n²)`` (a joint
    fit of 82 throws: 29,664 rows, 581 columns).
    """
    if not isinstance(J, SegmentJacobian):
        return J.T @ J, J.T @ r
    S, m, _ = J.seg.shape
    nt = J.n_theta
    A, B = J.seg[..., :nt], J.seg[..., nt:]
    r_seg = r[: S * m].reshape(S, m)
    G_tt = jnp.einsum("sra,srb->ab", A, A)
    G_tp = jnp.einsum("sra,srb->asb", A, B).reshape(nt, -1)
    G_pp = jnp.einsum("sab,st->satb", jnp.einsum("sra,srb->sab", B, B), jnp.eye(S, dtype=A.dtype)).reshape(S * 6, -1)
    G = jnp.concatenate([jnp.concatenate([G_tt, G_tp], 1), jnp.concatenate([G_tp.T, G_pp], 1)], 0)
    g = jnp.concatenate([jnp.einsum("sra,sr->a", A, r_seg), jnp.einsum("sra,sr->sa", B, r_seg).reshape(-1)])
    r_c = r[S * m :]
    return G + J.joins.T @ J.joins, g + J.joins.T @ r_c


def model_shapes(y, data, *, joins=None, dense=True, layout: Layout | None = None, **_):
    """The shapes of :func:`model_residuals`' ``(r, J)`` as ``jax.ShapeDtypeStruct``, without tracing it.

    ``S`` segments of ``B`` sensor blocks of ``K + 1`` samples give ``3 S B (K+1)``
    data rows, and each join 6 more; ``J`` has one column per entry of ``y``.
    The solver sizes its slots from these: ``jax.eval_shape`` of the model
    would trace the whole flow once more just to learn them.
    """
    S, B, K1 = data["seg"].rw.shape
    n_joins = 0 if S == 1 else S - 1 if joins is None else len(joins)
    m = 3 * S * B * K1 + 6 * n_joins
    r = jax.ShapeDtypeStruct((m,), y.dtype)
    if dense or S == 1:
        return r, jax.ShapeDtypeStruct((m, y.shape[0]), y.dtype)
    assert layout is not None
    seg = jax.ShapeDtypeStruct((S, 3 * B * K1, layout.shared + 6), y.dtype)
    return r, SegmentJacobian(seg, jax.ShapeDtypeStruct((6 * n_joins, y.shape[0]), y.dtype), layout.shared)  # type: ignore[arg-type]


# where the drag parameters' map bends (1/s for c₁ / tr I, 1/rad for c₂ / tr I): well below the drag
# of a tossed phone (c₂ / tr I ~ 0.02), so above it c / tr I is the parameter itself to 1e-3, and the
# start, the parameter 0, is c / tr I = 5e-4, next to no drag
_DRAG_BEND = 1e-3


def _nonnegative(p):
    """``(p + sqrt(p² + b²)) / 2`` (``b`` = ``_DRAG_BEND``): ``≈ p`` above ``b``, ``b² / 4|p|`` below ``-b``.

    It approaches 0 as a power of ``p``; a softplus would approach it exponentially, and fitted to
    data without drag its parameter runs to ``p / b ≈ -700``, where it and its derivative underflow
    to 0 and the coefficient reads ``0 ± 0``. Here the derivative stays representable, so the covariance (taken
    through it) keeps the linearised σ of ``c`` itself. Written without the cancellation of
    ``p + sqrt(p² + b²)`` for negative ``p``.
    """
    h = jnp.hypot(p, _DRAG_BEND)
    return jnp.where(p > 0, 0.5 * (p + h), 0.5 * _DRAG_BEND**2 / (h - p))


def _drag_model(x, scale_fixed, layout: Layout):
    """The damping coefficients ``(c₁, c₂)`` the model integrates, from the parameters ``x`` (``y`` or
    one segment's ``x_s``: the shared block first); per body axis (``layout.drag_axes``) the six
    ``(c1_x, c1_y, c1_z, c2_x, c2_y, c2_z)`` of ``τ_b,a = -(c₁ₐ + c₂ₐ |ω|) ω_a``.

    ``c = tr I · (p + sqrt(p² + b²)) / 2`` of the free parameter ``p`` (:func:`_nonnegative`): never
    negative, so a fitted drag is one :class:`rbjax.QuadraticDrag` and :class:`rbjax.LinearDrag`
    accept (a free ``c`` fitted ``c₂ < 0`` on real throws, an energy source). The factor ``tr I``
    keeps ``p ≈ c / tr I`` in the same units with or without torques (kg m² absolute, the gauge
    ``Σ_xx = 1`` without), so one bend suits a phone and a robot alike. Near ``c = 0`` the map
    flattens; the covariance is taken in ``c`` (:func:`drag_coefficients`' Jacobian), where it does not.
    """
    p = x[layout.span("drag")]
    # per body axis (layout.drag 3 or 6): (c1_x, c1_y, c1_z, c2_x, c2_y, c2_z), c₂ₐ = 0 for the linear law
    c = jnp.zeros(6 if layout.drag_axes else 2, x.dtype).at[: layout.drag].set(_nonnegative(p))
    return jnp.trace(_inertia(x[: 6 if scale_fixed else 5], scale_fixed)) * c


def drag_coefficients(y, scale_fixed, layout: Layout):
    """The fitted drag coefficients (``layout``'s ``drag`` block of ``y``) padded to ``(c₁, c₂)`` (per body
    axis: to the six ``(c1_x, c1_y, c1_z, c2_x, c2_y, c2_z)``), in reported units.

    Without torques only ``I / tr I`` is identifiable and the damping torque
    scales with the inertia (``I ω̇ + ω × I ω = -(c₁ + c₂|ω|) ω`` is unchanged by
    ``(I, c) → (λI, λc)``): the coefficients are reported relative to ``tr I``
    (``c₁ / tr I`` in 1/s, ``c₂ / tr I`` in 1/rad); with torques absolute
    (N m s, N m s²).
    """
    c = _drag_model(y, scale_fixed, layout)
    if scale_fixed:
        return c
    return c / jnp.trace(_inertia(y[:5], scale_fixed))


def normalised_inertia(y, scale_fixed):
    """The fitted inertia ``(3, 3)`` of parameter vector ``y``: ``I``, or ``I / tr I`` without torques."""
    I = _inertia(y[: 6 if scale_fixed else 5], scale_fixed)
    return I if scale_fixed else I / jnp.trace(I)
