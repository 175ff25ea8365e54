"""A synthetic phyphox recording of a tossed phone: several throws and catches, truth known.

The phone (moments ``MOMENTS``, kg m², principal axes along the body axes)
tumbles torque-free in each flight (Euler's equations integrated by scipy's
DOP853 at rtol = atol = 1e-12, float64); between flights it is held: the
accelerometer reads the specific force ``-g`` rotated into the body frame plus
hand motion, the gyro small rates. Release and catch are spikes of ±30 m/s².
Samples at ~100 Hz with jittered intervals; gyro and accelerometer on clocks
offset by half a sample, as phyphox records them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

MOMENTS = np.array([1.0, 3.2, 4.1]) * 1e-4  # kg m², a phone-like flat box
GYRO_STD = 0.005  # rad/s
ACCEL_STD = 0.05  # m/s²
LEVER = np.array([0.01, -0.02, 0.003])  # accelerometer from the centre of mass (m, body frame)


def _euler(_, w):
    I1, I2, I3 = MOMENTS
    return [(I2 - I3) / I1 * w[1] * w[2], (I3 - I1) / I2 * w[2] * w[0], (I1 - I2) / I3 * w[0] * w[1]]


def make_recording(
    seed=0, flights=((1.0, 0.6), (2.4, 0.8), (4.0, 0.5)), hold_end=1.0, dt=0.01, spin_up=0.0, spin_down=0.0
):
    """``(times_g, gyro, times_a, accel, flights)``: the sensors' samples and the true (release, catch) times.

    ``spin_up``, ``spin_down`` (s): the hand's wind-up before release, ``ω`` growing linearly from
    0 to the release rate, and the catch's braking, ``ω`` falling linearly to 0 (gyro only): fast
    rotation under torque on both sides of each flight.
    """
    rng = np.random.default_rng(seed)
    t_end = flights[-1][0] + flights[-1][1] + hold_end
    n = int(t_end / dt) + 1
    tg = np.cumsum(np.full(n, dt) + rng.uniform(-0.2, 0.2, n) * dt)  # jittered sampling
    ta = tg + 0.5 * dt + rng.uniform(-0.1, 0.1, n) * dt  # the accelerometer's own clock
    gyro = 0.2 * np.sin(np.outer(tg, [1.3, 2.1, 0.7])) + rng.normal(0, GYRO_STD, (n, 3))
    # held: the specific force is -g in the body frame (phone tilted a little) plus the hand's motion
    tilt = np.array([0.3, -0.2, 9.81 * 0.99])
    accel = tilt / np.linalg.norm(tilt) * 9.81 + 1.0 * np.sin(np.outer(ta, [2.0, 3.0, 1.5]))
    accel = accel + rng.normal(0, ACCEL_STD, (n, 3))
    out_flights = []
    for t_rel, length in flights:
        t_catch = t_rel + length
        w0 = rng.normal(0, 1, 3)
        w0 = w0 / np.linalg.norm(w0) * rng.uniform(8, 12)
        inside_g = (tg >= t_rel) & (tg <= t_catch)
        sol = solve_ivp(_euler, (t_rel, t_catch), w0, method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True)
        gyro[inside_g] = sol.sol(tg[inside_g]).T + rng.normal(0, GYRO_STD, (inside_g.sum(), 3))
        up = (tg > t_rel - spin_up) & (tg < t_rel)
        gyro[up] = np.outer(1 - (t_rel - tg[up]) / spin_up, w0) + rng.normal(0, GYRO_STD, (up.sum(), 3))
        down = (tg > t_catch) & (tg < t_catch + spin_down)
        w_end = sol.sol(t_catch)
        gyro[down] = np.outer((t_catch + spin_down - tg[down]) / spin_down, w_end) + rng.normal(
            0, GYRO_STD, (down.sum(), 3)
        )
        inside_a = (ta >= t_rel) & (ta <= t_catch)
        w = sol.sol(ta[inside_a]).T
        wdot = np.array([_euler(0, x) for x in w])
        centripetal = np.cross(wdot, LEVER) + np.cross(w, np.cross(w, LEVER))
        accel[inside_a] = centripetal + rng.normal(0, ACCEL_STD, (inside_a.sum(), 3))
        # the hand's last push just before release, the catch just after
        before = np.flatnonzero(ta < t_rel)[-2:]
        after = np.flatnonzero(ta > t_catch)[:2]
        accel[before] = accel[before] + rng.choice([-30.0, 30.0], (2, 3))
        accel[after] = accel[after] + rng.choice([-30.0, 30.0], (2, 3))
        out_flights.append((t_rel, t_catch, w0))
    return tg, gyro, ta, accel, out_flights


def write_phyphox(directory: Path, tg, gyro, ta, accel, *, combined=False) -> Path:
    """Write phyphox-style CSVs into ``directory``; returns the directory (or the combined file)."""
    directory.mkdir(parents=True, exist_ok=True)
    gh = '"Time (s)","Gyroscope x (rad/s)","Gyroscope y (rad/s)","Gyroscope z (rad/s)"'
    ah = '"Time (s)","Acceleration x (m/s^2)","Acceleration y (m/s^2)","Acceleration z (m/s^2)"'
    fmt = "{:.9E},{:.9E},{:.9E},{:.9E}"
    g_rows = [fmt.format(t, *v) for t, v in zip(tg, gyro)]
    a_rows = [fmt.format(t, *v) for t, v in zip(ta, accel)]
    if combined:
        path = directory / "Raw Data.csv"
        n = max(len(g_rows), len(a_rows))
        g_rows += [",,,"] * (n - len(g_rows))
        a_rows += [",,,"] * (n - len(a_rows))
        path.write_text("\n".join([gh + "," + ah] + [g + "," + a for g, a in zip(g_rows, a_rows)]) + "\n")
        return path
    (directory / "Gyroscope rotation rate.csv").write_text("\n".join([gh] + g_rows) + "\n")
    (directory / "Accelerometer.csv").write_text("\n".join([ah] + a_rows) + "\n")
    meta = directory / "meta"
    meta.mkdir(exist_ok=True)
    (meta / "device.csv").write_text('"property","value"\n"deviceModel","synthetic"\n')
    return directory
