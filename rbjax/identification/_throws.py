"""Finding the free flights (throws) in a continuous recording, and a plot to inspect them.

In free flight an accelerometer reads the specific force ``a - g ≈ 0`` (plus
the centripetal term ``ω × (ω × r)`` of its offset ``r`` from the centre of
mass, a few m/s² at most for a hand-thrown phone); held in the hand it reads
about ``g = 9.81 m/s²``, and release and catch show as spikes. A throw is a
run of samples with ``|a|`` below a threshold.
"""

from __future__ import annotations

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
) -> list[tuple[float, float]]:
    """Free-flight windows ``[(t0, t1), ...]`` (s, ascending) of a recording with throws and catches.

    A sample is in free flight when the 3-sample running median of the
    accelerometer magnitude ``|a|`` (body frame, m/s²) is below ``threshold``
    (the median sets single-sample glitches aside without moving the edges of
    a flight). Each run of such samples from ``t_a`` to ``t_b`` gives the
    window ``(t_a + margin, t_b - margin)``, trimmed so that the hand's last
    push and the catch stay out; windows shorter than ``min_duration`` are
    dropped.

    Args:
        recording: a :class:`rbjax.Recording` with ``accelerations`` ``(T, 3)``
            (gravity included, as a phone's accelerometer reports it).
        threshold: ``|a|`` below which a sample counts as free fall (m/s²);
            default ``0.4 g`` ≈ 3.9 m/s²: held, ``|a| ≈ g``; flying, ``|a|``
            is the noise plus the centripetal term of the sensor's offset
            (``|ω|² |r|`` = 1 m/s² for 10 rad/s at 1 cm).
        margin: time trimmed at both ends of each flight (s, ≥ 0).
        min_duration: shortest window kept, after trimming (s, > 0).

    Returns:
        A list of ``(t0, t1)`` pairs in seconds on the recording's clock; pass
        them to :meth:`Recording.window`. Empty when there is no flight.

    Raises:
        ValueError: a recording without ``accelerations``, or a ``threshold``,
            ``margin`` or ``min_duration`` that is not finite and positive
            (``margin`` may be 0).
    """
    _check_recording("find_throws", recording)
    if recording.accelerations is None:
        raise ValueError(
            "find_throws: the recording has no accelerations; free flight is found from the accelerometer "
            "(|a| ≈ 0), so record the accelerometer with the gyroscope (Recording(accelerations=...), "
            "or phyphox's 'Accelerometer' sensor), or give the windows yourself"
        )
    for name, value, low in (("threshold", threshold, 0.0), ("min_duration", min_duration, 0.0)):
        if not (np.isfinite(value) and value > low):
            raise ValueError(f"find_throws: {name} must be finite and > 0, got {value!r}")
    if not (np.isfinite(margin) and margin >= 0):
        raise ValueError(f"find_throws: margin must be finite and >= 0 (s), got {margin!r}")
    t = recording.times
    mag = np.linalg.norm(recording.accelerations, axis=-1)
    padded = np.concatenate([mag[:1], mag, mag[-1:]])
    smooth = np.median(np.stack([padded[:-2], padded[1:-1], padded[2:]]), axis=0)
    free = np.concatenate([[False], smooth < threshold, [False]])
    edges = np.flatnonzero(np.diff(free.astype(np.int8)))
    windows = []
    for start, stop in zip(edges[::2], edges[1::2]):  # samples start .. stop - 1 are free
        t0, t1 = t[start] + margin, t[stop - 1] - margin
        if t1 - t0 >= min_duration:
            windows.append((float(t0), float(t1)))
    return windows


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
