"""Recording: one recorded motion (times and sensor arrays), checked once, and its readers.

Three file formats are read: rbjax's own CSV/NPZ table (:mod:`rbjax._recording`,
the format of ``python -m rbjax fit``) and the CSV export of the phyphox app
(a directory or ``.zip`` of CSV files, or one CSV). phyphox writes each
sensor with its own time column (gyroscope and accelerometer are sampled on
different clocks); :meth:`Recording.from_phyphox` keeps the gyro's times and
interpolates the accelerometer onto them. The third is the CSV that Betaflight's
``blackbox_decode`` writes from a flight controller's log (:meth:`Recording.from_blackbox`,
:mod:`rbjax._blackbox`).
"""

from __future__ import annotations

import csv
import dataclasses
import re
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .._recording import RecordingError, read_recording
from ._checks import coarse_clock_hint

__all__ = ["Recording"]

# optional (T, k) arrays of a recording: field name -> width
_WIDTHS = {"gyro": 3, "orientations": 4, "accelerations": 3, "torques": 3, "body_torques": 3}
# phyphox column headers, lower-cased: "Time (s)", "Gyroscope x (rad/s)", "Acceleration x (m/s^2)"
_TIME = re.compile(r"^time\s*\((?P<unit>[^)]*)\)$")
_AXIS = re.compile(r"^(?P<what>gyroscope|acceleration)\s+(?P<axis>[xyz])\s*\((?P<unit>[^)]*)\)$")
_UNITS = {"gyroscope": ("rad/s",), "acceleration": ("m/s^2", "m/s²", "m/s2")}
_GROUP = {"gyroscope": "gyro", "acceleration": "accelerations"}


def _rotor_rates(value: object, t: np.ndarray) -> np.ndarray:
    """``Recording.rotor_rates`` checked: ``(T,)`` or ``(T, k)``, real, finite, as float64."""
    a = _real_array("rotor_rates", value)
    T = t.shape[0]
    if not (a.shape == (T,) or (a.ndim == 2 and a.shape[0] == T and a.shape[1] >= 1)):
        raise ValueError(
            f"Recording: rotor_rates must have shape (T,) = ({T},) for one rotor or (T, k) = ({T}, k) for k rotors "
            f"(rad/s relative to the body, at the sample times), got {a.shape}: resample the rotor's rate onto "
            "the times (np.interp)"
        )
    finite = np.isfinite(a) if a.ndim == 1 else np.all(np.isfinite(a), axis=1)
    if not np.all(finite):
        i = int(np.flatnonzero(~finite)[0])
        raise ValueError(
            f"Recording: rotor_rates has a non-finite value at sample {i} (t = {t[i]:g} s): "
            "interpolate over the gap (np.interp on the valid samples) or cut the recording"
        )
    return a


def _real_array(name: str, value: object) -> np.ndarray:
    """``value`` as a float64 array; ``TypeError`` for what is not real numbers (complex, text, objects)."""
    try:
        a = np.asarray(value)
    except (TypeError, ValueError) as e:  # ragged nested lists
        raise TypeError(f"Recording: {name} must be an array of real numbers, got {type(value).__name__}: {e}") from e
    if a.dtype.kind not in "iuf" or a.dtype == np.float16:
        raise TypeError(
            f"Recording: {name} must be an array of real numbers (float32 or float64), got dtype {a.dtype}: "
            "pass the sensor's readings as floats (a phyphox export: Recording.from_phyphox)"
        )
    return a.astype(np.float64)


@dataclasses.dataclass(frozen=True, eq=False)
class Recording:
    """One recorded motion: sample times and the sensor readings at them (NumPy float64).

    Attributes:
        times: ``(T,)`` sample times (s), strictly increasing, possibly irregular; ``T ≥ 2``.
        gyro: ``(T, 3)`` angular velocity ``ω`` in the body (gyro) frame (rad/s), or ``None``.
        orientations: ``(T, 4)`` unit quaternions ``[w, x, y, z]``, body to world, or ``None``.
        accelerations: ``(T, 3)`` accelerometer readings, body frame (m/s²): the
            specific force ``a - g`` (about 0 in free flight, ``-g`` rotated into the
            body frame, magnitude 9.81, when held still), or ``None``.
        torques: ``(T, 3)`` known torques about the centre of mass, world frame (N m), or ``None``.
        body_torques: ``(T, 3)`` known torques, body frame (N m), or ``None``.
        rotor_rates: ``(T,)`` (one rotor) or ``(T, k)`` (``k`` rotors) the rates ``Ω`` of
            rotors the body carries (a flywheel), relative to the body (rad/s), or ``None``.
            :func:`rbjax.fit_inertia` needs their ``rotor_axis=`` (and ``rotor_inertia=``
            for kg m²) with such a recording.
        source: where the data came from (a path), for messages; ``""`` if made in memory.

    Every array is converted to float64 and checked at construction
    (``ValueError`` naming the argument: shape, finiteness, increasing times).
    ``dataclasses.replace(rec, accelerations=None)`` drops a sensor (e.g. to
    fit the gyro alone with :func:`rbjax.fit_inertia`).
    """

    times: np.ndarray
    gyro: np.ndarray | None = None
    orientations: np.ndarray | None = None
    accelerations: np.ndarray | None = None
    torques: np.ndarray | None = None
    body_torques: np.ndarray | None = None
    source: str = ""
    rotor_rates: np.ndarray | None = None

    def __post_init__(self) -> None:
        t = _real_array("times", self.times)
        if t.size == 0:
            where = f" in {self.source}" if self.source else ""
            raise ValueError(
                f"Recording: times is empty (shape {t.shape}): no samples{where}; "
                "a recording needs at least 2 sample times (s): check that the data were read"
            )
        if t.ndim != 1 or t.shape[0] < 2:
            raise ValueError(
                f"Recording: times must be a 1-D array of at least 2 sample times (s), got shape {t.shape}"
            )
        if not np.all(np.isfinite(t)):
            raise ValueError(f"Recording: times has a non-finite entry at index {int(np.argmin(np.isfinite(t)))}")
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            i = int(bad[0])
            raise ValueError(
                f"Recording: times must be strictly increasing; times[{i + 1}] = {float(t[i + 1])} follows "
                f"times[{i}] = {float(t[i])}: sort the samples and drop repeated ones{coarse_clock_hint(self.times, t)}"
            )
        object.__setattr__(self, "times", t)
        for name, width in _WIDTHS.items():
            v = getattr(self, name)
            if v is None:
                continue
            a = _real_array(name, v)
            if a.shape != (t.shape[0], width):
                raise ValueError(
                    f"Recording: {name} must have shape (T, {width}) = ({t.shape[0]}, {width}) to match times, "
                    f"got {a.shape}"
                )
            if not np.all(np.isfinite(a)):
                i = int(np.flatnonzero(~np.all(np.isfinite(a), axis=1))[0])
                raise ValueError(
                    f"Recording: {name} has a non-finite value at sample {i} (t = {t[i]:g} s): "
                    "drop or interpolate that sample"
                )
            object.__setattr__(self, name, a)
        if self.rotor_rates is not None:
            object.__setattr__(self, "rotor_rates", _rotor_rates(self.rotor_rates, t))

    def __len__(self) -> int:
        return int(self.times.shape[0])

    @property
    def duration(self) -> float:
        """``times[-1] - times[0]`` (s)."""
        return float(self.times[-1] - self.times[0])

    def window(self, t0: float, t1: float) -> Recording:
        """The samples with ``t0 ≤ times ≤ t1`` (s), as a new :class:`Recording` (times unchanged, not shifted).

        Raises ``ValueError`` when fewer than 2 samples fall in ``[t0, t1]``.
        """
        keep = (self.times >= t0) & (self.times <= t1)
        if np.count_nonzero(keep) < 2:
            raise ValueError(
                f"Recording.window: [{t0:g}, {t1:g}] s holds {np.count_nonzero(keep)} sample(s) of a recording "
                f"spanning [{self.times[0]:g}, {self.times[-1]:g}] s; choose a window with at least 2 samples"
            )
        parts = {k: None if getattr(self, k) is None else getattr(self, k)[keep] for k in (*_WIDTHS, "rotor_rates")}
        return Recording(self.times[keep], **parts, source=self.source)

    @classmethod
    def from_file(cls, path, time_unit: str = "s") -> Recording:
        """Read rbjax's recording format: a ``.csv`` (columns ``t, qw..qz, gx..gz, ...``) or ``.npz``.

        The format is that of ``python -m rbjax fit`` (see :mod:`rbjax._recording`);
        ``time_unit`` (``"s"``, ``"ms"``, ``"us"``) is the unit of the ``t`` column.
        Raises :class:`rbjax.RecordingError` (a ``ValueError``) naming the file,
        the line and the remedy for a malformed file.
        """
        if time_unit not in ("s", "ms", "us"):
            raise ValueError(f"Recording.from_file: time_unit must be 's', 'ms' or 'us', got {time_unit!r}")
        rec = read_recording(Path(path), time_unit)
        try:
            return cls(
                rec["times"],
                gyro=rec.get("gyro"),
                orientations=rec.get("quaternions"),
                accelerations=rec.get("accelerations"),
                torques=rec.get("torques"),
                body_torques=rec.get("body_torques"),
                source=str(path),
            )
        except ValueError as e:
            raise RecordingError(f"{path}: {e}") from None

    @classmethod
    def from_blackbox(
        cls,
        path: str | Path,
        *,
        gyro_scale: float | None = None,
        acc_1g: float | None = None,
        motor_poles: int = 14,
        axes: ArrayLike | None = None,
        rotor: int | str | None = 0,
        rotor_sign: float = 1.0,
    ) -> Recording:
        """Read the CSV that ``blackbox_decode`` writes from a Betaflight or INDIflight flight log.

        A thrown inertia-measurement device (a flight controller with one motor driving a
        flywheel) logs its gyro, accelerometer and the motor's speed; this gives them in SI
        units, with the flywheel's rate as ``rotor_rates`` for :func:`rbjax.fit_inertia`
        (``rotor_axis=``, ``rotor_inertia=``) or ``python -m rbjax fit LOG.csv --rotor-axis ...``.

        Columns, found by name in the header (case-insensitive; quoted or not; ``", "``
        between them, as ``blackbox_decode`` writes), with what Betaflight logs in them
        (its ``src/main/blackbox/blackbox.c``; betaflight/blackbox-tools' decoder):

        - ``time (us)`` (or ``time``): the flight controller's clock in µs (``time (ms)``,
          ``time (s)`` also read). ``times`` start at 0 at the first line.
        - ``gyroADC[0..2]`` (needed): raw, in whole deg/s (Betaflight logs the filtered gyro,
          rounded, with ``gyro_scale`` 1.0 in the log's header); ``gyro_scale`` deg/s per
          count, default 1.0 (0.1 with ``blackbox_high_resolution = ON``). Columns decoded
          with ``--unit-rotation`` say their unit (``gyroADC[0] (deg/s)``, ``(rad/s)``)
          and are read in it (then leave ``gyro_scale`` out).
        - ``accSmooth[0..2]`` (optional): raw counts, ``acc_1g`` counts per g, default
          2048 (the ±16 g range of MPU6000, ICM426xx, BMI270; the log's header line
          ``H acc_1G:`` says yours); g = 9.80665 m/s², as the decoder takes it. The
          specific force (``+1 g`` up when held still), as :attr:`accelerations` wants.
          ``(g)`` and ``(m/s/s)`` columns are read in their unit.
        - ``eRPM[k]`` (optional; ``erpm[k]`` too): motor ``k``'s DShot telemetry in units
          of 100 electrical rpm, so the motor's rate relative to the body (its stator) is
          ``Ω = eRPM[k] · 100 / (motor_poles / 2) · 2π/60`` rad/s, in steps of
          ``100 / (motor_poles / 2)`` rpm (1.50 rad/s for 14 poles).

        Args:
            path: the ``.csv`` file (one log: ``blackbox_decode`` writes ``LOG.01.csv``,
                ``LOG.02.csv``, ... for the logs of one flight-controller file).
            gyro_scale: deg/s per count of raw ``gyroADC`` columns (default 1.0, Betaflight).
            acc_1g: accelerometer counts per g of raw ``accSmooth`` columns (default 2048).
            motor_poles: the motor's magnet poles (Betaflight's ``motor_poles``, default 14).
            axes: ``(3, 3)`` rotation from the board's (logged) axes to the body frame the
                fit uses, ``body = axes @ board``, applied to the gyro and the accelerometer;
                default the identity. A signed permutation, e.g. ``[[0, 1, 0], [1, 0, 0],
                [0, 0, -1]]``; det must be +1. Give ``rotor_axis`` in the body frame.
            rotor: which motor drives the flywheel: ``k`` reads ``eRPM[k]`` (default 0); a
                column name reads that column, in rad/s unless it is an ``eRPM[k]`` column
                (INDIflight's ``omega[k]``, in rad/s); ``None`` reads no rotor. With no eRPM
                column in the file the default reads none (``rotor_rates`` is ``None``).
            rotor_sign: DShot telemetry is a speed, not a direction (``eRPM`` is logged
                unsigned), so ``rotor_rates = rotor_sign · Ω ≥ 0`` for ``+1``, the default:
                give :func:`rbjax.fit_inertia` the ``rotor_axis`` about which the rotor turns
                right-handedly (along its angular velocity). ``-1`` flips the rates instead.

        Returns:
            A :class:`Recording` with ``times`` (s), ``gyro`` (rad/s), ``accelerations``
            (m/s², or ``None``), ``rotor_rates`` ``(T,)`` (rad/s, or ``None``), ``source``.

        Raises:
            RecordingError: (a ``ValueError``) naming the file, the line and the remedy: no
                such file; no ``time`` or ``gyroADC`` columns; a partial axis group; the
                asked-for rotor column absent; a cell that is not a number; a cut-off line;
                time that repeats or goes back (two logs in one file, or the 32-bit µs clock
                wrapped after 71.6 min: decode each log to its own file, or cut it); another unit.
            ValueError: a ``gyro_scale``/``acc_1g`` given for columns with a unit, or bad
                arguments (``axes`` not a rotation, odd ``motor_poles``, ``rotor_sign`` not ±1).
        """
        from .._blackbox import read_blackbox

        data = read_blackbox(
            Path(path),
            gyro_scale=gyro_scale,
            acc_1g=acc_1g,
            motor_poles=motor_poles,
            axes=axes,
            rotor=rotor,
            rotor_sign=rotor_sign,
        )
        try:
            return cls(**data, source=str(path))
        except ValueError as e:
            raise RecordingError(f"{path}: {e}") from None

    @classmethod
    def from_phyphox(cls, path) -> Recording:
        """Read a phyphox CSV export: a directory or ``.zip`` of CSV files, or one CSV file.

        Columns are found by their headers (quoted or not): ``Time (s)``,
        ``Gyroscope x (rad/s)`` .. ``z`` (``gyro``, body frame, rad/s) and
        ``Acceleration x (m/s^2)`` .. ``z`` (``accelerations``, body frame,
        m/s², gravity included as phyphox's "Accelerometer" reports it). Each
        sensor group uses the nearest ``Time`` column to its left, so both a
        file per sensor ("Gyroscope rotation rate.csv", "Accelerometer.csv")
        and one combined table work; a shorter sensor's trailing empty cells
        end its samples. Other files and columns ("Linear Acceleration",
        "Absolute ...", the ``meta/`` folder) are ignored. Comma-separated
        with decimal points, or tab- or semicolon-separated with decimal points
        or commas (phyphox's CSV export formats).

        The accelerometer and the gyroscope run on different clocks: the
        result's ``times`` are the gyro's, restricted to the span the
        accelerometer covers, and ``accelerations`` are linearly interpolated
        onto them, ``a(t) = a_i + (t - t_i)(a_{i+1} - a_i)/(t_{i+1} - t_i)``.
        Without a gyroscope the accelerometer's own times are used. They serve
        :func:`rbjax.find_throws`; fit the throws from the gyro alone
        (``dataclasses.replace(rec.window(t0, t1), accelerations=None)``, as
        ``python -m rbjax fit`` does): interpolation averages neighbouring samples,
        so their noise is smoothed and correlated: the level
        :func:`rbjax.fit_inertia` estimates from them falls below their actual
        scatter, and a fit with them says ``model_consistent=False``.

        Raises :class:`rbjax.RecordingError` naming the file, the line and the
        remedy: no file, no gyro or accelerometer columns, a half group (x and
        y without z), a cell that is not a number, a gap inside a column, times
        not increasing, another unit, or the same sensor in two files.
        """
        path = Path(path)
        if not path.exists():
            raise RecordingError(f"no such file or directory: {path}")
        if path.is_dir():
            files = [(str(p), p.read_bytes()) for p in sorted(path.rglob("*.csv"))]
        elif path.suffix.lower() == ".zip":
            try:
                with zipfile.ZipFile(path) as z:
                    names = sorted(n for n in z.namelist() if n.lower().endswith(".csv"))
                    files = [(f"{path}:{n}", z.read(n)) for n in names]
            except zipfile.BadZipFile as e:
                raise RecordingError(f"{path}: not a readable .zip file ({e}); export again from phyphox") from None
        elif path.suffix.lower() == ".csv":
            files = [(str(path), path.read_bytes())]
        else:
            raise RecordingError(
                f"{path}: expected a phyphox export (a directory or .zip of CSV files, or a .csv), "
                f"got '{path.suffix or 'no suffix'}'"
            )
        found: dict[str, tuple[str, np.ndarray, np.ndarray]] = {}
        for name, data in files:
            for group, (t, v) in _read_phyphox_csv(name, data).items():
                if group in found:
                    raise RecordingError(
                        f"{name}: holds {group} columns, and so does {found[group][0]}; "
                        "pass the one file (or directory) to read"
                    )
                found[group] = (name, t, v)
        if not found:
            raise RecordingError(
                f"{path}: no gyroscope or accelerometer columns found (expected headers such as "
                "'Time (s)', 'Gyroscope x (rad/s)', 'Acceleration x (m/s^2)'); export the experiment's "
                "raw data as CSV from phyphox ('Linear Acceleration' columns are not read: with gravity removed, "
                "free flight does not show as |a| ≈ 0; record 'Accelerometer' instead)"
            )
        if "gyro" not in found:
            _, t, a = found["accelerations"]
            return cls(t, accelerations=a, source=str(path))
        _, t, g = found["gyro"]
        acc = None
        if "accelerations" in found:
            aname, ta, a = found["accelerations"]
            keep = (t >= ta[0]) & (t <= ta[-1])
            if np.count_nonzero(keep) < 2:
                raise RecordingError(
                    f"{aname}: the accelerometer's times [{ta[0]:g}, {ta[-1]:g}] s do not overlap the gyroscope's "
                    f"[{t[0]:g}, {t[-1]:g}] s; export both sensors from the same run"
                )
            t, g = t[keep], g[keep]
            acc = np.stack([np.interp(t, ta, a[:, k]) for k in range(3)], -1)
        return cls(t, gyro=g, accelerations=acc, source=str(path))


def _read_phyphox_csv(name: str, data: bytes) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The sensor groups of one phyphox CSV: ``{"gyro" | "accelerations": (times (n,), values (n, 3))}``."""
    text = data.decode("utf-8-sig", errors="replace")
    lines = [(n, ln) for n, ln in enumerate(text.splitlines(), 1) if ln.strip()]
    if not lines:
        return {}
    header_no, header_line = lines[0]
    # phyphox exports comma-, tab- or semicolon-separated: the header's most frequent of the three
    delimiter = max((",", "\t", ";"), key=header_line.count)
    # with tabs or semicolons the decimal mark may be a comma (phyphox's "decimal comma" exports)
    decimal_comma = delimiter != ","
    header = [c.strip().lower() for c in next(csv.reader([header_line], delimiter=delimiter))]
    groups: dict[str, dict] = {}
    time_col = None
    for i, col in enumerate(header):
        if _TIME.match(col):
            unit = _TIME.match(col)["unit"].strip()  # type: ignore[index]
            if unit != "s":
                raise RecordingError(f"{name}: line {header_no}: column {col!r} is in {unit!r}; rbjax reads 'Time (s)'")
            time_col = i
            continue
        m = _AXIS.match(col)
        if m is None:
            continue
        what, unit = m["what"], m["unit"].strip()
        if unit not in _UNITS[what]:
            raise RecordingError(
                f"{name}: line {header_no}: column {col!r} is in {unit!r}; rbjax reads {what} in {_UNITS[what][0]}"
            )
        if time_col is None:
            raise RecordingError(
                f"{name}: line {header_no}: column {col!r} has no 'Time (s)' column to its left; phyphox writes "
                "each sensor's time first: export the raw data again (or move the time column first)"
            )
        g = groups.setdefault(_GROUP[what], {"time": time_col, "axes": {}})
        if m["axis"] in g["axes"]:
            raise RecordingError(
                f"{name}: line {header_no}: column {col!r} appears twice after one time column; "
                "give each sensor's x, y, z once, after its 'Time (s)'"
            )
        g["axes"][m["axis"]] = i
    for group, g in groups.items():
        missing = [a for a in "xyz" if a not in g["axes"]]
        if missing:
            raise RecordingError(
                f"{name}: line {header_no}: the {group} columns lack axis {missing}; export all of x, y and z"
            )
    if not groups:
        return {}
    rows: dict[str, list] = {k: [] for k in groups}
    line_of: dict[str, list] = {k: [] for k in groups}  # file line of each sample, for messages
    ended: dict[str, int] = {}
    for n, line in lines[1:]:
        fields = next(csv.reader([line], delimiter=delimiter))
        for group, g in groups.items():
            cols = [g["time"]] + [g["axes"][a] for a in "xyz"]
            cells = [fields[c].strip() if c < len(fields) else "" for c in cols]
            if not any(cells):
                ended.setdefault(group, n)  # a shorter sensor's buffer ends here
                continue
            if group in ended or not all(cells):
                where = f"after its samples ended at line {ended[group]}" if group in ended else "a missing value"
                raise RecordingError(
                    f"{name}: line {n}: the {group} columns have {where}; every sample needs its time and x, y, z"
                )
            try:
                rows[group].append([float(c.replace(",", ".") if decimal_comma else c) for c in cells])
                line_of[group].append(n)
            except ValueError:
                bad = next(c for c in cells if not _is_number(c.replace(",", ".") if decimal_comma else c))
                raise RecordingError(
                    f"{name}: line {n}: {bad[:30]!r} in the {group} columns is not a number "
                    "(export as 'CSV (Comma, decimal point)')"
                ) from None
    out = {}
    for group, r in rows.items():
        if not r:
            raise RecordingError(
                f"{name}: the {group} columns have a header and no samples (an empty export); "
                "export again from phyphox after recording, or record for longer"
            )
        if len(r) < 2:
            raise RecordingError(f"{name}: the {group} columns hold {len(r)} sample(s); record for longer")
        a = np.asarray(r)
        bad = np.flatnonzero(np.diff(a[:, 0]) <= 0)
        if bad.size:
            i = int(bad[0])
            raise RecordingError(
                f"{name}: line {line_of[group][i + 1]}: the {group} time {a[i + 1, 0]:.10g} s does not follow "
                f"{a[i, 0]:.10g} s (line {line_of[group][i]}); the times must increase (was the file edited or merged?)"
            )
        out[group] = (a[:, 0], a[:, 1:])
    return out


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def to_fit_arguments(recordings) -> tuple[Any, dict[str, Any]]:
    """``(times, {keyword: data})`` for :func:`rbjax.fit_inertia` from a :class:`Recording` or a list of them."""
    if isinstance(recordings, Recording):
        return recordings.times, {kw: getattr(recordings, f) for f, kw in _FIT_KEYWORDS.items()}
    recs = list(recordings)
    out: dict[str, Any] = {}
    for field_name, keyword in _FIT_KEYWORDS.items():
        have = [getattr(r, field_name) is not None for r in recs]
        if any(have) and not all(have):
            missing = [i for i, h in enumerate(have) if not h]
            raise ValueError(
                f"fit_inertia: recordings {missing} have no {field_name} but others do; give every recording "
                f"the same sensors (dataclasses.replace(rec, {field_name}=None) drops one)"
            )
        out[keyword] = [getattr(r, field_name) for r in recs] if all(have) else None
    return [r.times for r in recs], out


# Recording field -> fit_inertia keyword
_FIT_KEYWORDS = {
    "orientations": "orientations",
    "gyro": "body_rates",
    "torques": "torques",
    "body_torques": "body_torques",
    "accelerations": "accelerations",
    "rotor_rates": "rotor_rates",
}
