"""Gradients of a gyrostat's final state through ``rb.simulate`` against central finite differences.

One scalar of the final state (the sum of its attitude's quaternion vector part, a weighted body
rate and the kinetic energy, so that every part of the state is reached) is differentiated with
respect to (a) the body's inertia tensor, (b) the rotors' axial inertias ``J`` and (c) a
piecewise-constant rotor-torque schedule, each entry of each separately, in float64. ``J`` enters
the motion through the initial momenta ``h_k = J_k Ω_k`` (the state is built from rotor rates)
and the kinetic energy through ``½ Σ h_k² / J_k``; the schedule enters as a per-step
``Forces(rotor_torque=(steps, k))`` series built inside the differentiated function (the
documented time-series form), so gradients flow to each segment.

Tolerance: central differences with a relative step ``ε`` have truncation error ``~ ε² x² f'''`` and
round-off ``~ u |f| / (ε x)`` (``u`` = 2.2e-16); ``ε = u^(1/3) ≈ 6e-6`` balances them near
``u^(2/3) ≈ 4e-11`` relative. Here ``|f|`` is ~30 (the wheels' spin energy) while the schedule's
entries are 0.02 N m, so round-off sets the floor: measured 2026-12-07 (relative to the largest
|gradient| of each group) 6e-9 (inertia), 4e-12 (J), 1e-8 (schedule) with rk4 and 6e-9, 4e-12,
4e-9 with splitting. The check allows 1e-7: a lost rotor term or a dropped cotangent is O(1).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb

INERTIA = np.array([[0.80, 0.05, -0.02], [0.05, 1.30, 0.04], [-0.02, 0.04, 1.90]])  # kg m²
AXES = np.eye(3)  # three orthogonal wheels along the body axes
J = np.array([4e-3, 2e-3, 7e-3])  # kg m²
RATES0 = np.array([120.0, -60.0, 30.0])  # rad/s, relative to the body
W0 = np.array([0.2, -0.1, 0.3])  # rad/s, world frame
Q0 = np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2])
DT, SEGMENTS, PER_SEGMENT = 0.02, 4, 5  # 20 steps, the torque held over 5 steps at a time
SCHEDULE = np.array([[0.02, -0.01, 0.005], [-0.01, 0.02, 0.0], [0.0, -0.015, 0.01], [0.01, 0.005, -0.02]])  # N m
C = np.array([0.3, -0.7, 0.5])  # weights of the body rate in the scalar
EPS_REL = float(np.finfo(np.float64).eps) ** (1 / 3)
RTOL = 1e-7


def final(inertia, J_, schedule, method):
    """A scalar of the final state: the quaternion's vector part, the body rate and the kinetic energy.

    The kinetic energy brings in ``J`` beyond the initial momenta (``½ Σ h_k² / J_k``)."""
    rotors = rb.Rotors(AXES, J_)
    s = rb.State.create(rb.Body(3.0, inertia), orientation=Q0, angular_velocity=W0, rotors=rotors, rotor_rates=RATES0)
    tau = jnp.repeat(schedule, PER_SEGMENT, axis=0)  # (steps, k): one torque per step, piecewise constant
    steps = SEGMENTS * PER_SEGMENT
    traj = rb.simulate(s, rb.Forces(rotor_torque=tau), DT, steps, method, save_every=steps)
    end = traj[-1]
    q = end.orientation
    q = q * jnp.sign(q[0])  # the attitude, not the quaternion's sign
    return jnp.sum(q[1:]) + jnp.dot(rb.body_angular_velocity(end), C) + rb.kinetic_energy(end)


def central_differences(f, x):
    """∂f/∂x_i by central differences, each entry with its own step ``ε_rel · max(|x_i|, scale)``."""
    x = np.asarray(x, np.float64)
    scale = np.max(np.abs(x))
    out = np.zeros_like(x)
    for i in np.ndindex(x.shape):
        h = EPS_REL * max(abs(x[i]), scale)
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        out[i] = (float(f(jnp.asarray(xp))) - float(f(jnp.asarray(xm)))) / (2 * h)
    return out


def _relative_error(ad, fd, what):
    """``max |AD - FD| / max |FD|``, after checking that the scalar depends on the argument at all."""
    scale = np.max(np.abs(fd))
    assert scale > 1e-3, f"{what}: the scalar barely depends on it ({scale}); the test would prove nothing"
    return float(np.max(np.abs(np.asarray(ad) - fd))) / scale


@pytest.mark.parametrize("method", ["rk4", "splitting"])
def test_gradients_match_central_differences(method):
    f = jax.jit(final, static_argnums=3)
    I0, J0, S0 = jnp.asarray(INERTIA), jnp.asarray(J), jnp.asarray(SCHEDULE)
    gI, gJ, gS = jax.grad(f, argnums=(0, 1, 2))(I0, J0, S0, method)

    # (a) the inertia: perturbed symmetrically (I_ij and I_ji together), as a physical inertia is;
    # the gradient of the symmetric perturbation is g_ij + g_ji off the diagonal
    def f_sym(upper):
        M = jnp.zeros((3, 3)).at[np.triu_indices(3)].set(upper)
        return f(M + jnp.triu(M, 1).T, J0, S0, method)

    fd_I = central_differences(f_sym, INERTIA[np.triu_indices(3)])
    ad_I = (gI + gI.T - jnp.diag(jnp.diag(gI)))[np.triu_indices(3)]
    errs = {"inertia": _relative_error(ad_I, fd_I, "d/d inertia")}
    # (b) the rotors' axial inertias
    errs["J"] = _relative_error(gJ, central_differences(lambda x: f(I0, x, S0, method), J), "d/d J")
    # (c) every entry of the torque schedule
    errs["schedule"] = _relative_error(
        gS, central_differences(lambda x: f(I0, J0, x, method), SCHEDULE), "d/d schedule"
    )
    print(method, "relative |AD - FD|:", {k: f"{e:.1e}" for k, e in errs.items()})
    assert all(e < RTOL for e in errs.values()), f"|AD - FD| / scale above {RTOL}: {errs}"


def test_the_inertia_gradient_is_symmetric():
    # the scalar depends on I only through a symmetric matrix (Body symmetrises or checks it): an
    # asymmetric gradient would mean the two triangles are read differently
    gI = jax.grad(final)(jnp.asarray(INERTIA), jnp.asarray(J), jnp.asarray(SCHEDULE), "rk4")
    np.testing.assert_allclose(gI, gI.T, atol=1e-12 * float(jnp.max(jnp.abs(gI))))
