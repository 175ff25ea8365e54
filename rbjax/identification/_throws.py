"""Finding the free flights (throws) in a continuous recording, and a plot to inspect them.

With an accelerometer: in free flight it reads the specific force ``a - g ≈ 0``
(plus the centripetal term ``ω × (ω × r)`` of its offset ``r`` from the centre
of mass, a few m/s² at most for a hand-thrown phone); held in the hand it reads
about ``g = 9.81 m/s²``, and release and catch show as spikes. A throw is a
run of samples with ``|a|`` below a threshold.

With a gyro alone: in free flight the torque-free Euler equations
``I ω̇ + ω × I ω = 0`` (body frame) hold for the body's inertia ``I``, which
is unknown but the same all through the flight. A throw is a run of fast
samples (``|ω|`` above a rate threshold, the hand's own rotation being slow)
around whose middle one inertia explains the motion: the residual
``I ω̇_i + ω_i × I ω_i`` of the inertia fitted to the middle stays at the
noise level out to release and catch, where the hand's torque (or an impact)
makes it jump.
"""

from __future__ import annotations

import warnings

import numpy as np

from ._recording_data import Recording

__all__ = ["find_throws", "plot_throws"]

STANDARD_GRAVITY = 9.80665  # m/s²


def _check_recording(fn: str, recording: object) -> None:
    if not isinstance(recording, Recording):
        raise TypeError(
            f"{fn}: recording must be an rbjax.Recording, got {type(recording).__name__}: build one with "
            "rbjax.Recording(times=..., accelerations=...) or read a file with Recording.from_phyphox(path)"
        )


def find_throws(
    recording: Recording,
    *,
    threshold: float = 0.4 * STANDARD_GRAVITY,
    margin: float = 0.03,
    min_duration: float = 0.25,
    sensor: str | None = None,
    rate_threshold: float = 3.0,
) -> list[tuple[float, float]]:
    """Free-flight windows ``[(t0, t1), ...]`` (s, ascending) of a recording with throws and catches.

    From the accelerometer (``sensor="accelerometer"``, the default when the
    recording has one): a sample is in free flight when the 3-sample running median of the
    accelerometer magnitude ``|a|`` (body frame, m/s²) is below ``threshold``
    (the median sets single-sample glitches aside without moving the edges of
    a flight). Each run of such samples from ``t_a`` to ``t_b`` gives the
    window ``(t_a + margin, t_b - margin)``, trimmed so that the hand's last
    push and the catch stay out; windows shorter than ``min_duration`` are
    dropped.

    From the gyro alone (``sensor="gyro"``, the default without an
    accelerometer): a flight is a run of samples with ``|ω|`` (3-sample running
    median, rad/s) above ``rate_threshold``, cut to where the motion is
    torque-free, in two steps. First, impacts: torque-free, ``|ω̈| ≤ |ω|³``
    for any physical inertia (the triangle inequality bounds each
    ``|(I_j - I_k)/I_i|`` by 1), so a second difference of ``ω`` above
    ``5 |ω|³ h²`` (``h`` the sample spacing) plus the noise floor (ten times the run's median) is a
    knock, a catch the body rides through, or a glitch: the run is split there
    and that sample left out. Then, the hand: with ``ω̇_i`` from central
    differences (irregular times allowed), the inertia ``I`` (symmetric, up to
    scale) that best satisfies ``I ω̇_i + ω_i × I ω_i = 0`` (body frame) on the
    middle half of each piece is the smallest right singular vector of that
    homogeneous linear system; the flight extends from the middle while each
    sample's residual (3-sample running median) stays below 8 times the middle's
    median residual, the inertia is fitted again to what it explains, and the
    cut repeated (up to three times) so that a middle half with some of the
    hand in it gives way to the flight's own inertia. The first sample beyond is
    the release (or catch). A piece that one inertia cannot explain over at
    least ``min_duration`` gives no window, and neither does one whose Euler
    equations miss by more than a fifth of their terms (the median of
    ``|I ω̇_i + ω_i × I ω_i|`` over that of ``|I ω̇_i| + |ω_i × I ω_i|``, with the
    piece's own ``I``): the hand turning the body about, not a flight (measured on
    thirteen real phone tosses: 0.004-0.045 in the flights, 0.25-0.83 in the
    stretches of hand motion that passed the cut). ``margin`` and ``min_duration``
    apply as above.

    Args:
        recording: a :class:`rbjax.Recording` with ``accelerations`` ``(T, 3)``
            (gravity included, as a phone's accelerometer reports it) or ``gyro``
            ``(T, 3)`` (body frame, rad/s).
        threshold: ``|a|`` below which a sample counts as free fall (m/s²);
            default ``0.4 g`` ≈ 3.9 m/s²: held, ``|a| ≈ g``; flying, ``|a|``
            is the noise plus the centripetal term of the sensor's offset
            (``|ω|² |r|`` = 1 m/s² for 10 rad/s at 1 cm).
        margin: time trimmed at both ends of each flight (s, ≥ 0).
        min_duration: shortest window kept, after trimming (s, > 0).
        sensor: ``"accelerometer"``, ``"gyro"`` or ``None`` (the accelerometer
            if recorded, else the gyro).
        rate_threshold: gyro only: ``|ω|`` above which a sample may be in
            flight (rad/s, > 0); default 3 rad/s, half a turn per second: a
            tossed phone turns faster, a hand holding one slower.

    Returns:
        A list of ``(t0, t1)`` pairs in seconds on the recording's clock; pass
        them to :meth:`Recording.window`. Empty, with a ``UserWarning`` saying
        why and what to change, when there is no flight.

    Raises:
        ValueError: a recording without the sensor asked for (or with neither),
            an unknown ``sensor``, or a ``threshold``, ``rate_threshold``,
            ``margin`` or ``min_duration`` that is not finite and positive
            (``margin`` may be 0).
    """
    _check_recording("find_throws", recording)
    if sensor not in (None, "accelerometer", "gyro"):
        raise ValueError(f"find_throws: sensor must be 'accelerometer', 'gyro' or None, got {sensor!r}")
    if sensor is None:
        sensor = "accelerometer" if recording.accelerations is not None else "gyro"
    if sensor == "accelerometer" and recording.accelerations is None:
        raise ValueError(
            "find_throws: the recording has no accelerations; pass sensor='gyro' to find the flights from the "
            "gyroscope alone, or record the accelerometer too (Recording(accelerations=...), phyphox's "
            "'Accelerometer' sensor)"
        )
    gyro = recording.gyro
    if sensor == "gyro" and gyro is None:
        raise ValueError(
            "find_throws: the recording has neither accelerations nor gyro; free flight is found from the "
            "accelerometer (|a| ≈ 0) or the gyroscope (torque-free motion): record one of them"
        )
    checked = (("threshold", threshold), ("min_duration", min_duration), ("rate_threshold", rate_threshold))
    for name, value in checked:
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"find_throws: {name} must be finite and > 0, got {value!r}")
    if not (np.isfinite(margin) and margin >= 0):
        raise ValueError(f"find_throws: margin must be finite and >= 0 (s), got {margin!r}")
    t = recording.times
    if sensor == "gyro" and gyro is not None:
        windows = _windows(t, _torque_free_runs(t, gyro, float(rate_threshold)), margin, min_duration)
        if not windows:
            fast = float(np.max(np.linalg.norm(gyro, axis=-1), initial=0.0))
            why = (
                f"|ω| never exceeds rate_threshold = {rate_threshold} rad/s (largest {fast:.3g} rad/s)"
                if fast <= rate_threshold
                else f"no stretch of fast rotation is torque-free for min_duration = {min_duration} s after "
                f"trimming margin = {margin} s (the hand or an impact everywhere)"
            )
            _no_flight(why, "lower rate_threshold or min_duration")
        return windows
    free = _median3(np.linalg.norm(np.asarray(recording.accelerations), axis=-1)) < threshold  # checked above
    windows = _windows(t, _runs(free), margin, min_duration)
    if not windows:
        _no_flight(
            f"|a| is not below threshold = {threshold:.3g} m/s² for min_duration = {min_duration} s after "
            f"trimming margin = {margin} s",
            "raise threshold or lower min_duration",
        )
    return windows


class NoFlightWarning(UserWarning):
    """:func:`find_throws` found no free flight; ``reason`` says why (the CLI reports it as its error)."""

    def __init__(self, message: str, reason: str):
        super().__init__(message)
        self.reason = reason


def _no_flight(why: str, remedy: str) -> None:
    message = (
        f"find_throws: no free flight in this recording: {why}. Check it with rbjax.plot_throws; if it holds "
        f"a flight, {remedy}, or cut the window by hand with Recording.window(t0, t1)"
    )
    warnings.warn(NoFlightWarning(message, why), stacklevel=3)


def _median3(x: np.ndarray) -> np.ndarray:
    """3-sample running median along axis 0 (the ends repeated)."""
    padded = np.concatenate([x[:1], x, x[-1:]])
    return np.median(np.stack([padded[:-2], padded[1:-1], padded[2:]]), axis=0)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[(start, stop), ...]``: the runs of ``True`` in ``mask``, samples ``start .. stop - 1``."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def _windows(t, runs, margin, min_duration) -> list[tuple[float, float]]:
    windows = []
    for start, stop in runs:
        t0, t1 = t[start] + margin, t[stop - 1] - margin
        if t1 - t0 >= min_duration:
            windows.append((float(t0), float(t1)))
    return windows


# residual above this multiple of the flight's median residual: the torque-free law is broken
_TORQUE_FREE_LIMIT = 8.0
# a piece whose Euler equations miss by more than this share of their terms is not a free flight
_EULER_MISS = 0.2
# a torque-free second difference is about h² ω̈ with |ω̈| ≤ |ω|³ (see _impacts); this multiple of that
# bound leaves room for the Taylor remainder, of relative size (|ω| h)² (0.1 at 30 rad/s and 100 Hz)
_IMPACT_FACTOR = 5.0
# the noise floor of the second differences, in multiples of their median over the run
_IMPACT_NOISE = 10.0


def _euler_rows(w: np.ndarray, wdot: np.ndarray) -> np.ndarray:
    """``(n, 3, 6)``: ``A_i`` with ``A_i x = I ω̇_i + ω_i × I ω_i`` for ``x`` the 6 entries of symmetric ``I``
    (``Ixx, Iyy, Izz, Ixy, Ixz, Iyz``), body frame."""
    basis = np.zeros((6, 3, 3))
    for k, (i, j) in enumerate(((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))):
        basis[k, i, j] = basis[k, j, i] = 1.0
    Iwdot = np.einsum("kab,nb->nak", basis, wdot)
    Iw = np.einsum("kab,nb->nka", basis, w)
    return Iwdot + np.moveaxis(np.cross(w[:, None, :], Iw), 1, 2)


def _rate_derivative(t: np.ndarray, gyro: np.ndarray, i: np.ndarray) -> np.ndarray:
    """``ω̇`` at samples ``i`` by central differences on irregular times (exact for a quadratic)."""
    h0, h1 = t[i] - t[i - 1], t[i + 1] - t[i]
    return (
        -(h1 / (h0 * (h0 + h1)))[:, None] * gyro[i - 1]
        + ((h1 - h0) / (h0 * h1))[:, None] * gyro[i]
        + (h0 / (h1 * (h0 + h1)))[:, None] * gyro[i + 1]
    )


def _impacts(t: np.ndarray, gyro: np.ndarray, start: int, stop: int) -> np.ndarray:
    """Samples of ``start .. stop - 1`` where ``ω`` jumps more than any torque-free motion can.

    Torque-free, ``ω̇ = I⁻¹ (I ω × ω)``; with the triangle inequality each
    ``|(I_j - I_k) / I_i| ≤ 1`` in the principal frame, so ``|ω̇_i| ≤ |ω_j ω_k|``,
    ``|ω̈_i| ≤ |ω_i| (ω_j² + ω_k²)`` and ``|ω̈| ≤ |ω|³`` whatever the inertia. A second
    difference ``|ω_{i+1} - 2 ω_i + ω_{i-1}|`` above ``5 |ω|³ h²`` (``|ω|`` the
    largest of the three samples, ``h`` their mean spacing) plus ten times the run's
    median (the noise) is an impulse: an impact or a catch that the phone rides
    through, or a glitch. The 3-sample median of the torque-free residual
    below would hide a one-sample spike; this bound does not depend on a fitted
    inertia.
    """
    i = np.arange(start + 1, stop - 1)
    if i.size == 0:  # a run of 1-2 samples has no second difference (and is too short to keep anyway)
        return i
    h = 0.5 * (t[i + 1] - t[i - 1])
    jump = np.linalg.norm(gyro[i + 1] - 2 * gyro[i] + gyro[i - 1], axis=-1)
    rate = np.max(np.linalg.norm(gyro[np.stack([i - 1, i, i + 1])], axis=-1), axis=0)
    bound = _IMPACT_FACTOR * rate**3 * h**2 + _IMPACT_NOISE * np.median(jump)
    return i[jump > bound]


def _pieces(t: np.ndarray, gyro: np.ndarray, start: int, stop: int) -> list[tuple[int, int]]:
    """``start .. stop`` split at its impacts (each impact sample left out), pieces of 8 or more samples."""
    edges = [start]
    for j in _impacts(t, gyro, start, stop):
        edges += [int(j), int(j) + 1]
    edges.append(stop)
    return [(a, b) for a, b in zip(edges[::2], edges[1::2], strict=True) if b - a >= 8]


def _torque_free_part(t: np.ndarray, gyro: np.ndarray, a: int, b: int) -> tuple[int, int] | None:
    """The samples around the middle of ``a .. b - 1`` that one inertia explains as torque-free, or ``None``."""
    i = np.arange(a + 1, b - 1)
    A = _euler_rows(gyro[i], _rate_derivative(t, gyro, i))
    n = len(i)
    lo, hi = n // 4, n - n // 4
    # the inertia of the middle half, then of the part that it explains, until the part stops moving:
    # a middle half with a little of the hand in it gives way to the flight's own inertia
    for _ in range(3):
        x = np.linalg.svd(A[lo:hi].reshape(-1, 6), full_matrices=False)[2][-1]
        r = _median3(np.linalg.norm(A @ x, axis=-1))
        inside = r <= _TORQUE_FREE_LIMIT * np.median(r[lo:hi])
        first = last = n // 2
        if not inside[first]:
            return None
        while first > 0 and inside[first - 1]:
            first -= 1
        while last < n - 1 and inside[last + 1]:
            last += 1
        if (first, last + 1) == (lo, hi):
            break
        lo, hi = first, last + 1
    return int(i[lo]), int(i[hi - 1]) + 1


def _torque_free_runs(t: np.ndarray, gyro: np.ndarray, rate_threshold: float) -> list[tuple[int, int]]:
    """Sample runs of torque-free motion (see :func:`find_throws`) inside the fast runs of ``gyro``."""
    fast = _median3(np.linalg.norm(gyro, axis=-1)) > rate_threshold
    out = []
    for start, stop in _runs(fast):
        for a, b in _pieces(t, gyro, start, stop):
            part = _torque_free_part(t, gyro, a, b)
            if part is not None and _euler_miss(t, gyro, *part) <= _EULER_MISS:
                out.append(part)
    return out


def _euler_miss(t: np.ndarray, gyro: np.ndarray, a: int, b: int) -> float:
    """How far samples ``a .. b - 1`` are from torque-free motion: the median of ``|I ω̇ + ω × I ω|`` over that
    of ``|I ω̇| + |ω × I ω|``, ``I`` the inertia that best satisfies them (0: exact; ~1: no inertia does)."""
    i = np.arange(a + 1, b - 1)
    if i.size < 6:
        return 0.0  # too short to judge (and to keep: min_duration decides)
    wdot = _rate_derivative(t, gyro, i)
    A = _euler_rows(gyro[i], wdot)
    x = np.linalg.svd(A.reshape(-1, 6), full_matrices=False)[2][-1]
    I = x[[0, 3, 4, 3, 1, 5, 4, 5, 2]].reshape(3, 3)
    terms = np.linalg.norm(wdot @ I, axis=-1) + np.linalg.norm(np.cross(gyro[i], gyro[i] @ I), axis=-1)
    return float(np.median(np.linalg.norm(A @ x, axis=-1)) / max(float(np.median(terms)), np.finfo(np.float64).tiny))


def plot_throws(recording: Recording, windows, ax=None):
    """Plot ``|a|`` (m/s²) and ``|ω|`` (rad/s) against ``t`` (s) with the ``windows`` shaded.

    For checking (and overriding) :func:`find_throws`. Needs matplotlib (the
    ``demo`` extra). ``ax``: a matplotlib ``Axes`` to draw on (default: a new
    figure); ``|ω|`` goes on a twin axis. Returns the ``Axes``.
    """
    _check_recording("plot_throws", recording)
    try:
        import matplotlib.pyplot as plt
    except ImportError as e:
        raise ImportError("plot_throws needs matplotlib: pip install 'rbjax[demo]'") from e
    if ax is None:
        _, ax = plt.subplots(figsize=(10, 3.5))
    t = recording.times
    if recording.accelerations is not None:
        ax.plot(t, np.linalg.norm(recording.accelerations, axis=-1), color="C0", lw=0.8, label="|a| (m/s²)")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("|a| (m/s²)")
    for i, (t0, t1) in enumerate(windows):
        ax.axvspan(t0, t1, color="C2", alpha=0.2, label="throws" if i == 0 else None)
    if recording.gyro is not None:
        ax2 = ax.twinx()
        ax2.plot(t, np.linalg.norm(recording.gyro, axis=-1), color="C1", lw=0.8, label="|ω| (rad/s)")
        ax2.set_ylabel("|ω| (rad/s)")
    ax.legend(loc="upper left")
    return ax
