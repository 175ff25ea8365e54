"""A thrown device with a flywheel (issue 58's synthetic truth), made without rbjax's integrator.

The body-frame equations of a gyrostat with one rotor of inertia ``J`` about the
unit axis ``a`` spinning at ``Ω(t)`` relative to the body (``h = J Ω a``):

    I ω̇ = -ω × (I ω + h) - ḣ,   q̇ = ½ q ⊗ (0, ω),

integrated by scipy's DOP853 at rtol = atol = 1e-12 in float64 with ``Ω(t)`` a
known smooth function of time (``ḣ = J Ω'(t) a`` exactly).
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

# a 0.1 kg device: principal moments 22, 76, 88 kg mm², its principal frame turned against the IMU's
MOMENTS = np.array([76e-6, 22e-6, 88e-6])
TURN = Rotation.from_rotvec([0.3, -0.2, 0.25]).as_matrix()
I_DEVICE = TURN @ np.diag(MOMENTS) @ TURN.T
J_FLYWHEEL = 1.7e-6  # kg m²
AXIS = np.array([0.0, 0.0, -1.0])  # the flywheel's axis in the IMU (body) frame
DURATION = 0.5  # s of free flight


def rotor_rate(t, start=170.0, peak=1300.0, end=210.0, duration=DURATION):
    """``Ω(t)`` (rad/s) and ``Ω'(t)``: from ``start`` up to about ``peak`` and down to ``end`` within ``duration``."""
    s = np.pi * np.asarray(t) / duration
    base = start + (end - start) * np.asarray(t) / duration
    amp = peak - 0.5 * (start + end)
    return base + amp * np.sin(s) ** 2, (end - start) / duration + amp * np.pi / duration * np.sin(2 * s)


def _qmul(p, q):
    pw, pv, qw, qv = p[0], p[1:], q[0], q[1:]
    return np.concatenate([[pw * qw - pv @ qv], pw * qv + qw * pv + np.cross(pv, qv)])


def throw(times, w0, I=I_DEVICE, J=J_FLYWHEEL, axis=AXIS, rate=rotor_rate, q0=(1.0, 0.0, 0.0, 0.0)):
    """Orientations ``(T, 4)`` (body to world), body rates ``(T, 3)`` and rotor rates ``(T,)`` at ``times``."""
    I = np.asarray(I, np.float64)
    Iinv = np.linalg.inv(I)
    a = np.asarray(axis, np.float64)

    def rhs(t, y):
        q, w = y[:4] / np.linalg.norm(y[:4]), y[4:]
        W, Wd = rate(t)
        h, hd = J * W * a, J * Wd * a
        return np.concatenate([0.5 * _qmul(q, np.concatenate([[0.0], w])), Iinv @ (-np.cross(w, I @ w + h) - hd)])

    y0 = np.concatenate([np.asarray(q0, np.float64), np.asarray(w0, np.float64)])
    sol = solve_ivp(rhs, (times[0], times[-1]), y0, method="DOP853", t_eval=times, rtol=1e-12, atol=1e-12)
    assert sol.success, sol.message
    q = sol.y[:4].T / np.linalg.norm(sol.y[:4].T, axis=1, keepdims=True)
    return q, sol.y[4:].T, rate(times)[0]


def accelerations(times, w, I=I_DEVICE, J=J_FLYWHEEL, axis=AXIS, rate=rotor_rate, lever=(0.01, -0.004, 0.002)):
    """Free-flight accelerometer ``ω̇ × r + ω × (ω × r)`` ``(T, 3)`` at ``lever`` (m) from the centre of mass."""
    W, Wd = rate(times)
    h, hd = J * W[:, None] * axis, J * Wd[:, None] * axis
    wd = -np.linalg.solve(I, (np.cross(w, w @ I.T + h) + hd).T).T
    r = np.asarray(lever)
    return np.cross(wd, r) + np.cross(w, np.cross(w, r))


def random_throw(rng, rate_hz=4000.0, duration=DURATION):
    """A throw at body rates of 8-33 rad/s about a random direction: ``(times, q, w, Ω)``.

    The rotor's run-up varies too (start 150-190, peak 1200-1400, end 190-230 rad/s): with one
    profile for all throws a quantised rate would err alike in every throw (the same steps at the
    same times), a bias shared by the whole set instead of noise.
    """
    times = np.arange(int(round(duration * rate_hz)) + 1) / rate_hz
    d = rng.normal(size=3)
    w0 = rng.uniform(8.0, 33.0) * d / np.linalg.norm(d)
    start, peak, end = rng.uniform(150, 190), rng.uniform(1200, 1400), rng.uniform(190, 230)
    rate = lambda t: rotor_rate(t, start=start, peak=peak, end=end, duration=duration)
    return (times, *throw(times, w0, rate=rate))


# Calibration (issue 58, item 5): the device's mass and centre of mass, a proof body and an object.
# Positions are relative to the IMU's accelerometer, in the IMU frame (m); the device's centre of mass
# is where accelerations()'s default lever arm puts the IMU: lever = -centre of mass.
DEVICE_MASS = 0.1  # kg
DEVICE_COM = np.array([-0.01, 0.004, -0.002])
PROOF_MASS = 0.2  # kg: a brass cylinder 2 cm across, 8 cm long, on a jig below the IMU, its axis along x
PROOF_INERTIA = np.diag([0.5 * 0.2 * 0.01**2, 0.2 * (3 * 0.01**2 + 0.08**2) / 12, 0.2 * (3 * 0.01**2 + 0.08**2) / 12])
PROOF_POSITION = np.array([0.0, 0.0, -0.025])
OBJECT_MASS = 0.6  # kg: a 8 x 5 x 3 cm block, turned against the IMU's axes
_BLOCK = np.diag([0.05**2 + 0.03**2, 0.08**2 + 0.03**2, 0.08**2 + 0.05**2]) * OBJECT_MASS / 12
_TURN_BLOCK = Rotation.from_rotvec([0.4, 0.1, -0.3]).as_matrix()
OBJECT_INERTIA = _TURN_BLOCK @ _BLOCK @ _TURN_BLOCK.T
OBJECT_POSITION = np.array([0.005, -0.01, -0.03])


def combine(I1, m1, c1, I2, m2, c2):
    """Two rigid bodies as one (Steiner, in NumPy): its inertia about its centre of mass, mass, centre of mass."""

    def steiner(m, d):
        return m * (d @ d * np.eye(3) - np.outer(d, d))

    M = m1 + m2
    c = (m1 * np.asarray(c1) + m2 * np.asarray(c2)) / M
    return np.asarray(I1) + steiner(m1, c1 - c) + np.asarray(I2) + steiner(m2, c2 - c), M, c
