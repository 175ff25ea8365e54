"""The CSV that ``blackbox_decode`` writes from a Betaflight (or INDIflight) flight log, in SI units.

What the columns hold (Betaflight's ``src/main/blackbox/blackbox.c`` writes the log,
betaflight/blackbox-tools' ``src/blackbox_decode.c`` and ``src/units.h`` decode it):

- The header is the field names joined by ``", "``; a field decoded into a unit
  other than its raw one carries it in brackets (``gyroADC[0] (deg/s)``). By default
  the decoder writes ``time (us)`` and every other field raw.
- ``time``: the flight controller's clock in µs (a 32-bit counter: it wraps after
  2³² µs, 71.6 min); ``time (ms)`` or ``time (s)`` with ``--unit-frame-time``.
- ``gyroADC[0..2]``: the filtered gyro, logged as ``lrintf(gyro.gyroADCf[i] *
  blackboxHighResolutionScale)``, i.e. whole deg/s (tenths of a deg/s with
  ``blackbox_high_resolution = ON``); the log's header says ``gyro_scale`` 1.0.
  ``gyroADC[i] (deg/s)`` / ``(rad/s)`` with ``--unit-rotation``.
- ``accSmooth[0..2]``: the accelerometer in counts, ``acc_1G`` counts per g (the
  log's header ``H acc_1G:`` line; 2048 for the ±16 g range of the common IMUs,
  MPU6000, ICM426xx, BMI270); the specific force (a level board at rest reads
  ``+acc_1G`` on z). ``(g)`` / ``(m/s/s)`` with ``--unit-acceleration``; the
  decoder takes g as 9.80665 m/s².
- ``eRPM[k]``: motor ``k``'s bidirectional-DShot telemetry in units of 100 eRPM
  (``// eRPM / 100`` in blackbox.c; ``ERPM_PER_LSB = 100`` in ``drivers/dshot.c``,
  whose ``rpm = erpm * 100 / (motor_poles / 2)``), unsigned: a speed, not a direction.
  Mechanical ``Ω = value · 100 / (poles / 2) · 2π / 60`` rad/s, in steps of
  1.5 rad/s for 14 poles.
- INDIflight (tudelft's Betaflight fork) logs the same fields; its log tools
  convert ``gyro*`` from deg/s (x10 with high resolution), ``acc*`` with
  ``acc_1G`` and read its ``omega[k]`` motor rates as rad/s.
"""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from ._recording import RecordingError

__all__ = ["is_blackbox_csv", "read_blackbox"]

G0 = 9.80665  # m/s² per g, as blackbox_decode converts (units.h ACCELERATION_DUE_TO_GRAVITY)
_COLUMN = re.compile(r"^(?P<name>[^()]*?)\s*(?:\((?P<unit>[^)]*)\))?$")
_TIME_UNITS = {None: 1e-6, "us": 1e-6, "ms": 1e-3, "s": 1.0}
_ERPM = re.compile(r"^erpm\[(\d+)\]$")


def _header(line: str) -> list[tuple[str, str | None, str]]:
    """``(lower-case name, unit or None, the cell as written)`` of each column of a header line (quoted or
    not, ``", "`` between cells)."""
    out = []
    for cell in next(csv.reader([line], skipinitialspace=True)):
        text = cell.strip().strip('"').strip()
        m = _COLUMN.match(text)
        name, unit = (m["name"], m["unit"]) if m else (text, None)
        out.append((name.strip().lower(), None if unit is None else unit.strip().lower(), text))
    return out


def is_blackbox_csv(path: Path) -> bool:
    """A ``.csv`` whose first line names ``time`` and ``gyroADC[0]`` (``blackbox_decode``'s header)."""
    if path.suffix.lower() != ".csv" or not path.is_file():
        return False
    with path.open(encoding="utf-8-sig", errors="replace") as f:
        names = {n for n, *_ in _header(f.readline())}
    return "time" in names and "gyroadc[0]" in names


def _rotation(axes: Any) -> np.ndarray:
    if axes is None:
        return np.eye(3)
    try:
        R = np.asarray(axes, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise TypeError(f"Recording.from_blackbox: axes must be a 3x3 array of real numbers: {e}") from None
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ValueError(
            f"Recording.from_blackbox: axes must be a finite 3x3 matrix (board frame to body frame: "
            f"body = axes @ board), got shape {R.shape}"
        )
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
        raise ValueError(
            "Recording.from_blackbox: axes must be a rotation (orthonormal rows, det +1), e.g. a signed "
            f"permutation such as [[0, 1, 0], [1, 0, 0], [0, 0, -1]]; got det {np.linalg.det(R):.6g}. A reflection "
            "(det -1) would make the body frame left-handed, where the Euler equations change sign"
        )
    return R


def read_blackbox(
    path: Path,
    *,
    gyro_scale: float | None = None,
    acc_1g: float | None = None,
    motor_poles: int = 14,
    axes: Any = None,
    rotor: int | str | None = 0,
    rotor_sign: float = 1.0,
) -> dict[str, Any]:
    """``{"times", "gyro", "accelerations" or None, "rotor_rates" or None}`` in s, rad/s, m/s², rad/s.

    See :meth:`rbjax.Recording.from_blackbox` for the arguments; raises ``RecordingError``
    naming the file, the line and the remedy.
    """
    if gyro_scale is not None and not (isinstance(gyro_scale, (int, float)) and math.isfinite(gyro_scale)):
        raise TypeError(
            f"Recording.from_blackbox: gyro_scale must be a finite number (deg/s per count), got {gyro_scale!r}"
        )
    if gyro_scale is not None and gyro_scale <= 0:
        raise ValueError(f"Recording.from_blackbox: gyro_scale must be > 0 (deg/s per logged count), got {gyro_scale}")
    if acc_1g is not None and not (isinstance(acc_1g, (int, float)) and math.isfinite(acc_1g) and acc_1g > 0):
        raise ValueError(
            f"Recording.from_blackbox: acc_1g must be a finite number > 0 (accelerometer counts per g, the log "
            f"header's acc_1G), got {acc_1g!r}"
        )
    if (
        isinstance(motor_poles, bool)
        or not isinstance(motor_poles, (int, np.integer))
        or motor_poles < 2
        or motor_poles % 2
    ):
        raise ValueError(
            f"Recording.from_blackbox: motor_poles must be an even integer >= 2 (the motor's magnet poles, "
            f"Betaflight's motor_poles setting, 14 on most small outrunners), got {motor_poles!r}"
        )
    if rotor_sign not in (1, -1):
        raise ValueError(f"Recording.from_blackbox: rotor_sign must be +1 or -1, got {rotor_sign!r}")
    if rotor is not None and (isinstance(rotor, bool) or not isinstance(rotor, (int, np.integer, str))):
        raise TypeError(
            f"Recording.from_blackbox: rotor must be a motor index (eRPM[rotor]), a column name or None, got {rotor!r}"
        )
    R = _rotation(axes)
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"no such file: {path}")
    text = path.read_bytes().decode("utf-8-sig", errors="replace")
    lines = [(n, ln) for n, ln in enumerate(text.splitlines(), 1) if ln.strip()]
    if not lines:
        raise RecordingError(f"{path}: empty file; decode the flight log with blackbox_decode (LOG.BFL -> LOG.01.csv)")
    header_no, header_line = lines[0]
    header = _header(header_line)
    index = {name: i for i, (name, *_) in enumerate(header)}
    unit = {name: u for name, u, _ in header}

    def group(prefix: str, label: str) -> list[str] | None:
        names = [f"{prefix}[{i}]" for i in range(3)]
        have = [n in index for n in names]
        if any(have) and not all(have):
            missing = [f"{label}[{i}]" for i, h in enumerate(have) if not h]
            raise RecordingError(
                f"{path}: line {header_no}: the {label} columns lack {', '.join(missing)}; decode the log again "
                "with blackbox_decode (all three axes are logged together)"
            )
        return names if all(have) else None

    gyro_cols = group("gyroadc", "gyroADC")
    missing = [c for c, ok in (("time (us)", "time" in index), ("gyroADC[0..2]", gyro_cols is not None)) if not ok]
    if missing:
        raise RecordingError(
            f"{path}: line {header_no}: no {' or '.join(repr(m) for m in missing)} column(s) in the header; "
            "expected the CSV that blackbox_decode writes from a Betaflight/INDIflight log (header 'loopIteration, "
            "time (us), ..., gyroADC[0], gyroADC[1], gyroADC[2], accSmooth[0], ..., eRPM[0], ...'): decode the "
            "flight log with blackbox_decode, and log the gyro (Betaflight's blackbox 'GYRO' field)"
        )
    acc_cols = group("accsmooth", "accSmooth")
    rotor_col, rotor_is_erpm = None, False
    if rotor is not None:
        want = f"erpm[{int(rotor)}]" if not isinstance(rotor, str) else rotor.strip().lower()
        rotor_is_erpm = _ERPM.match(want) is not None
        erpm_cols = [text for name, _, text in header if _ERPM.match(name)]
        if want in index:
            rotor_col = want
        elif isinstance(rotor, str) or erpm_cols:
            have = ", ".join(erpm_cols) or "none"
            raise RecordingError(
                f"{path}: line {header_no}: no column {want!r} for rotor={rotor!r} (eRPM columns: {have}); pass the "
                "motor that drives the flywheel (rotor=k reads eRPM[k]), or rotor=None to read no rotor"
            )
    assert gyro_cols is not None  # refused above
    # units of the columns read (blackbox_decode marks a converted field with its unit)
    time_unit = unit["time"]
    if time_unit not in _TIME_UNITS:
        raise RecordingError(f"{path}: line {header_no}: 'time ({time_unit})' is not us, ms or s")
    g_unit = unit[gyro_cols[0]]
    if g_unit is not None and gyro_scale is not None:
        raise ValueError(
            f"Recording.from_blackbox: the gyroADC columns of {path} are in {g_unit} (their header says so); "
            "gyro_scale applies to raw columns: leave it out"
        )
    g_factor = {None: (1.0 if gyro_scale is None else gyro_scale) * math.pi / 180, "deg/s": math.pi / 180, "rad/s": 1.0}
    if g_unit not in g_factor:
        raise RecordingError(f"{path}: line {header_no}: gyroADC in {g_unit!r}; rbjax reads raw, deg/s or rad/s")
    a_factor = 1.0
    if acc_cols is not None:
        a_unit = unit[acc_cols[0]]
        if a_unit is not None and acc_1g is not None:
            raise ValueError(
                f"Recording.from_blackbox: the accSmooth columns of {path} are in {a_unit} (their header says so); "
                "acc_1g applies to raw columns: leave it out"
            )
        factors = {None: G0 / (2048.0 if acc_1g is None else acc_1g), "g": G0, "m/s/s": 1.0, "m/s2": 1.0}
        if a_unit not in factors:
            raise RecordingError(f"{path}: line {header_no}: accSmooth in {a_unit!r}; rbjax reads raw, g or m/s/s")
        a_factor = factors[a_unit]
    cols = ["time", *gyro_cols, *(acc_cols or []), *([rotor_col] if rotor_col else [])]
    where = [index[c] for c in cols]
    label = {index[c]: header[index[c]][2] for c in cols}
    rows = np.empty((len(lines) - 1, len(cols)))
    for r, (n, line) in enumerate(lines[1:]):
        cells = next(csv.reader([line], skipinitialspace=True))
        if len(cells) <= max(where):
            raise RecordingError(
                f"{path}: line {n}: {len(cells)} cells, the header has {len(header)}; a cut-off line "
                "(the log ended mid-frame?): delete it"
            )
        for j, c in enumerate(where):
            try:
                rows[r, j] = float(cells[c])
            except ValueError:
                raise RecordingError(
                    f"{path}: line {n}: {cells[c].strip()[:30]!r} in column {label[c]!r} is not a number; "
                    "decode the log without --debug (its frame notes break the table) or delete the line"
                ) from None
    if rows.shape[0] < 2:
        raise RecordingError(f"{path}: {rows.shape[0]} sample(s) below the header; record (log) for longer")
    raw_t = rows[:, 0]
    back = np.flatnonzero(np.diff(raw_t) <= 0)
    if back.size:
        i = int(back[0])
        n_this, n_prev = lines[i + 2][0], lines[i + 1][0]
        what = "repeats" if raw_t[i + 1] == raw_t[i] else "goes back"
        raise RecordingError(
            f"{path}: line {n_this}: time {raw_t[i + 1]:.10g} {time_unit or 'us'} {what} after {raw_t[i]:.10g} "
            f"(line {n_prev}): two logs in one file, or the flight controller's 32-bit µs clock wrapped (after "
            "71.6 min); decode each log to its own file (blackbox_decode writes LOG.01.csv, LOG.02.csv, ...; "
            "--index N picks one) or cut the file at that line"
        )
    times = (raw_t - raw_t[0]) * _TIME_UNITS[time_unit]
    gyro = rows[:, 1:4] * g_factor[g_unit] @ R.T
    acc = None if acc_cols is None else rows[:, 4:7] * a_factor @ R.T
    rates = None
    if rotor_col is not None:
        v = rows[:, -1]
        # eRPM/100 -> electrical rpm -> mechanical rpm (poles/2 electrical turns per turn) -> rad/s
        rates = rotor_sign * (v * 100.0 / (motor_poles / 2) * 2 * math.pi / 60 if rotor_is_erpm else v)
    return {"times": times, "gyro": gyro, "accelerations": acc, "rotor_rates": rates}
