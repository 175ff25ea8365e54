"""The hand-written CPU limit for ``benchmarks/throughput.py``: explicit Euler as one fused Numba loop.

The same algorithm on the same data as ``rbjax.simulate(state, forces, dt,
steps, "euler")`` with constant force and torque arrays: the notes' ``(x, v, q,
L)`` loop over a structure of arrays ((3, N) rows per component), per body

    I_w⁻¹ = R I_b⁻¹ Rᵀ   (the full 3x3 body-frame inverse inertia, R from q)
    ω = I_w⁻¹ L
    x += v dt;  v += F/m dt;  q += ½ (0, ω) ⊗ q dt, q ← q/‖q‖;  L += τ dt

reading the forces each step, every update from the old state, the bodies of a
step split over threads (``prange``) and each step a pass over memory, as a
``lax.scan`` step is. Compiled per dtype (float32 and float64: constants are
passed in the arrays' dtype so that float32 stays float32). Needs ``numba``
(the ``bench`` extra); :func:`available` says whether it is installed.
"""

from __future__ import annotations

from typing import Any

import numpy as np

try:
    import numba
except ImportError:  # an optional peer: throughput.py reports it missing
    numba = None

_KERNEL: Any = None


def available() -> bool:
    return numba is not None


def _kernel() -> Any:
    global _KERNEL
    if _KERNEL is not None:
        return _KERNEL
    prange = numba.prange

    # S (13, N): rows x 0-2, v 3-5, q 6-9, L 10-12; P (10, N): I_b⁻¹ row-major 0-8, mass 9; F (6, N):
    # force 0-2, torque 3-5. Three arrays, not eleven: LLVM vectorises the body loop only when it can
    # rule out aliasing between every pair of arrays written and read, with a few run-time checks.
    @numba.njit(parallel=True, fastmath=False, error_model="numpy")
    def euler(S, P, F, dt, hdt, one, two, steps):  # pragma: no cover (compiled)
        n = S.shape[1]
        for _ in range(steps):
            for i in prange(n):
                qw, qx, qy, qz = S[6, i], S[7, i], S[8, i], S[9, i]
                r00 = one - two * (qy * qy + qz * qz)
                r01 = two * (qx * qy - qw * qz)
                r02 = two * (qx * qz + qw * qy)
                r10 = two * (qx * qy + qw * qz)
                r11 = one - two * (qx * qx + qz * qz)
                r12 = two * (qy * qz - qw * qx)
                r20 = two * (qx * qz - qw * qy)
                r21 = two * (qy * qz + qw * qx)
                r22 = one - two * (qx * qx + qy * qy)
                # A = R I_b⁻¹, then I_w⁻¹ = A Rᵀ
                a00 = r00 * P[0, i] + r01 * P[3, i] + r02 * P[6, i]
                a01 = r00 * P[1, i] + r01 * P[4, i] + r02 * P[7, i]
                a02 = r00 * P[2, i] + r01 * P[5, i] + r02 * P[8, i]
                a10 = r10 * P[0, i] + r11 * P[3, i] + r12 * P[6, i]
                a11 = r10 * P[1, i] + r11 * P[4, i] + r12 * P[7, i]
                a12 = r10 * P[2, i] + r11 * P[5, i] + r12 * P[8, i]
                a20 = r20 * P[0, i] + r21 * P[3, i] + r22 * P[6, i]
                a21 = r20 * P[1, i] + r21 * P[4, i] + r22 * P[7, i]
                a22 = r20 * P[2, i] + r21 * P[5, i] + r22 * P[8, i]
                w00 = a00 * r00 + a01 * r01 + a02 * r02
                w01 = a00 * r10 + a01 * r11 + a02 * r12
                w02 = a00 * r20 + a01 * r21 + a02 * r22
                w10 = a10 * r00 + a11 * r01 + a12 * r02
                w11 = a10 * r10 + a11 * r11 + a12 * r12
                w12 = a10 * r20 + a11 * r21 + a12 * r22
                w20 = a20 * r00 + a21 * r01 + a22 * r02
                w21 = a20 * r10 + a21 * r11 + a22 * r12
                w22 = a20 * r20 + a21 * r21 + a22 * r22
                l0, l1, l2 = S[10, i], S[11, i], S[12, i]
                o0 = w00 * l0 + w01 * l1 + w02 * l2
                o1 = w10 * l0 + w11 * l1 + w12 * l2
                o2 = w20 * l0 + w21 * l1 + w22 * l2
                # ½ (0, ω) ⊗ q
                nw = qw - hdt * (o0 * qx + o1 * qy + o2 * qz)
                nx = qx + hdt * (qw * o0 + (o1 * qz - o2 * qy))
                ny = qy + hdt * (qw * o1 + (o2 * qx - o0 * qz))
                nz = qz + hdt * (qw * o2 + (o0 * qy - o1 * qx))
                s = one / np.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
                S[6, i], S[7, i], S[8, i], S[9, i] = nw * s, nx * s, ny * s, nz * s
                m = P[9, i]
                v0, v1, v2 = S[3, i], S[4, i], S[5, i]
                S[0, i] += v0 * dt
                S[1, i] += v1 * dt
                S[2, i] += v2 * dt
                S[3, i] = v0 + F[0, i] / m * dt
                S[4, i] = v1 + F[1, i] / m * dt
                S[5, i] = v2 + F[2, i] / m * dt
                S[10, i] = l0 + F[3, i] * dt
                S[11, i] = l1 + F[4, i] * dt
                S[12, i] = l2 + F[5, i] * dt

    _KERNEL = euler
    return euler


def soa_data(state: Any, forces: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(S, P, F)`` of an rbjax ``State`` and ``Forces``: one C-contiguous row per component (see the kernel)."""
    rows = lambda a: np.asarray(a).reshape(np.shape(a)[0], -1).T
    s, b = state, state.body
    S = np.concatenate([rows(a) for a in (s.position, s.velocity, s.orientation, s.angular_momentum)])
    P = np.concatenate([rows(b.inverse_inertia), np.asarray(b.mass)[None]])
    F = np.concatenate([rows(forces.force), rows(forces.torque)])
    return np.ascontiguousarray(S), np.ascontiguousarray(P), np.ascontiguousarray(F)


def run(data: tuple[np.ndarray, ...], dt: float, steps: int) -> tuple[np.ndarray, ...]:
    """``steps`` Euler steps in place on ``data`` (from :func:`soa_data`); returns ``(x, v, q, L)`` as rows."""
    S, P, F = data
    t = S.dtype.type
    _kernel()(S, P, F, t(dt), t(0.5) * t(dt), t(1), t(2), steps)
    return S[0:3], S[3:6], S[6:10], S[10:13]


def check_and_time(state: Any, steps: int, dt: float, best_time: Any, check_steps: int = 20) -> dict:
    """The loop against rbjax's Euler on the same data (zero force and torque arrays, read every step).

    Raises ``AssertionError`` unless the two agree to round-off after
    ``check_steps`` steps (64 eps of the largest value; measured ≤ 9 eps after 20
    steps); returns both rates (body-steps/s), the loop's better thread count
    and the agreement in eps.
    """
    import jax
    import jax.numpy as jnp

    import rbjax as rb

    n, dtype = state.batch_shape[0], state.dtype
    forces = rb.Forces(force=jnp.zeros((n, 3), dtype), torque=jnp.zeros((n, 3), dtype))
    x, v, q, L = run(soa_data(state, forces), dt, check_steps)
    ref = rb.simulate(state, forces, dt, check_steps, "euler", save_every=check_steps)
    eps = float(np.finfo(dtype).eps)
    err = 0.0
    for ours, theirs in ((x, ref.position), (v, ref.velocity), (q, ref.orientation), (L, ref.angular_momentum)):
        want = np.asarray(theirs[-1]).T
        err = max(err, float(np.max(np.abs(ours - want))) / (eps * max(1.0, float(np.max(np.abs(want))))))
    assert err <= 64, f"the Numba loop and rbjax's Euler differ by {err:.1f} eps after {check_steps} steps"
    data = soa_data(state, forces)
    # all threads and one: each step ends at a barrier, and on a shared machine a thread descheduled
    # by another job stalls every step (measured 1e3x slower at N = 1e4); the limit is the better one
    threads, rates = numba.get_num_threads(), {}
    for k in sorted({1, threads}):
        numba.set_num_threads(k)
        rates[k] = n * steps / best_time(lambda: run(data, dt, steps))
    numba.set_num_threads(threads)
    out = dict(limit=max(rates.values()), threads=max(rates, key=rates.get), agreement_eps=err)
    # rbjax's two paths: the JAX steps, and the native kernel where it was built
    for key, native in (("rbjax_jax", False), ("rbjax_native", True)):
        if native and not rb.native_status().available:
            continue
        f = jax.jit(lambda s, fs, nat=native: rb.simulate(s, fs, dt, steps, "euler", save_every=steps, native=nat))
        jax.block_until_ready(f(state, forces))
        out[key] = n * steps / best_time(f, state, forces)
    # the call as most users write it: eager, every check of simulate on each call (the default path)
    eager = lambda s, fs: rb.simulate(s, fs, dt, steps, "euler", save_every=steps)
    jax.block_until_ready(eager(state, forces))
    out["rbjax_eager"] = n * steps / best_time(eager, state, forces)
    return out


def limit_rows(state: Any, steps: int, dt: float, best_time: Any) -> list[dict]:
    """throughput.py's rows: ``numba-limit``, and rbjax's euler on the loop's data through its JAX
    steps (``rbjax-forces-jax``) and its native kernel (``rbjax-forces-native``, where built), both
    under ``jit``, and eager with the default path (``rbjax-forces-eager``)."""
    n, dname = state.batch_shape[0], np.dtype(state.dtype).name
    lim = check_and_time(state, steps, dt, best_time)
    common = dict(method="euler", dtype=dname, bodies=n, steps=steps)
    native = lim.get("rbjax_native")
    print(
        f"numba limit euler {dname} N={n:>8}: {lim['limit']:.3e} body-steps/s ({lim['threads']} threads); "
        f"rbjax on its data: JAX {lim['rbjax_jax']:.3e} ({lim['rbjax_jax'] / lim['limit']:.2f}x), "
        + (f"native {native:.3e} ({native / lim['limit']:.2f}x)" if native else "native not built")
        + f"; eager {lim['rbjax_eager']:.3e} ({lim['rbjax_eager'] / lim['limit']:.2f}x)"
        + f"; agree to {lim['agreement_eps']:.1f} eps",
        flush=True,
    )
    limit = dict(engine="numba-limit", body_steps_per_s=lim["limit"], threads=lim["threads"], **common)
    rows = [
        dict(limit, agreement_eps=lim["agreement_eps"]),
        dict(engine="rbjax-forces-jax", body_steps_per_s=lim["rbjax_jax"], **common),
    ]
    if native:
        rows.append(dict(engine="rbjax-forces-native", body_steps_per_s=native, **common))
    rows.append(dict(engine="rbjax-forces-eager", body_steps_per_s=lim["rbjax_eager"], **common))
    return rows
