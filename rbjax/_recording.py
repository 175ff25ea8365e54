"""Reading a recorded motion for ``python -m rbjax fit``: CSV or NPZ, checked line by line.

A recording is a table of samples. Its columns come in groups, each all or
nothing:

    t             sample times (s; see --time-unit)
    qw,qx,qy,qz   orientation, body to world, [w, x, y, z]
    gx,gy,gz      gyro: angular velocity, body (gyro) frame (rad/s)
    tx,ty,tz      known torque about the centre of mass, world frame (N m)
    btx,bty,btz   known torque about the centre of mass, body frame (N m; a reaction wheel)
    ax,ay,az      accelerometer, body frame, in free flight (m/s²)

NPZ files hold the same data as arrays named times (T,), quaternions (T, 4),
gyro, torques, body_torques and accelerations (each (T, 3)).

Every way a CSV can be malformed that we have met (empty, header only, another
delimiter, ragged rows, text in a number column, a half group of columns)
raises :class:`RecordingError` with one line naming the file, the line and the
remedy: ``numpy.genfromtxt`` would instead fill NaNs or raise a message about
its own internals.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

__all__ = ["GROUPS", "RecordingError", "read_recording", "time_unit_hint"]

#: column groups of a CSV recording: name in the result -> columns
GROUPS: dict[str, tuple[str, ...]] = {
    "times": ("t",),
    "quaternions": ("qw", "qx", "qy", "qz"),
    "gyro": ("gx", "gy", "gz"),
    "torques": ("tx", "ty", "tz"),
    "body_torques": ("btx", "bty", "btz"),
    "accelerations": ("ax", "ay", "az"),
}

_OTHER_DELIMITERS = {";": "semicolons", "\t": "tabs", "|": "bars"}
_SECONDS = {"s": 1.0, "ms": 1e-3, "us": 1e-6}


class RecordingError(ValueError):
    """A recording that cannot be read; the message is one line naming the file and the remedy.

    Raised by :meth:`rbjax.Recording.from_file` and :meth:`rbjax.Recording.from_phyphox`
    (and by ``python -m rbjax fit``) for a missing or malformed file: the line
    of a CSV (1-based, header included) and what to change. A ``ValueError``.
    """


def read_recording(path: Path, time_unit: str = "s") -> dict[str, np.ndarray]:
    """Read ``path`` (``.csv`` or ``.npz``) into float64 arrays keyed as :data:`GROUPS`.

    ``times`` is converted to seconds from ``time_unit`` (``"s"``, ``"ms"`` or
    ``"us"``); the other groups are returned as stored. Only the groups present
    are returned; ``times`` is always present.

    Raises:
        RecordingError: a missing file, another suffix, a malformed table or
            array (see the module docstring), or fewer than 2 samples.
    """
    path = Path(path)
    if not path.exists():
        raise RecordingError(f"no such file: {path}")
    if path.suffix == ".npz":
        rec = _read_npz(path)
    elif path.suffix == ".csv":
        rec = _read_csv(path)
    else:
        raise RecordingError(f"{path}: expected a .csv or .npz recording, got '{path.suffix or 'no suffix'}'")
    rec["times"] = rec["times"] * _SECONDS[time_unit]
    return rec


def time_unit_hint(rec: dict[str, np.ndarray]) -> str | None:
    """Why the times (in seconds) look like milliseconds, or ``None`` when they look right.

    A sample interval of a second or more is plausible (a slowly tumbling
    satellite), so the interval alone only earns a note. With a gyro the test is
    sharp: a body turning more than 1 rad between samples is aliased, no fit
    can follow it, and the usual cause is times in milliseconds read as seconds.
    """
    t = rec["times"]
    dt = float(np.median(np.diff(t)))
    if dt < 1.0:
        return None
    if "gyro" in rec:
        turn = float(np.median(np.linalg.norm(rec["gyro"], axis=-1))) * dt
        if turn > 1.0:
            return (
                f"the median sample interval is {dt:g} s and the gyro turns {turn:.3g} rad between samples, "
                "far too much to follow: the times look like milliseconds; pass --time-unit ms "
                "(or --time-unit s to fit them as seconds)"
            )
    return f"note: the median sample interval is {dt:g} s; if the times are in milliseconds, pass --time-unit ms"


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    try:
        z = np.load(path)
    except Exception as e:  # a zip that is not one, a truncated file
        raise RecordingError(f"{path}: not a readable .npz file ({type(e).__name__}: {e})") from e
    with z:
        missing = {"times"} - set(z.files)
        if missing:
            raise RecordingError(f"{path}: missing arrays {sorted(missing)} (found {sorted(z.files)})")
        rec = {k: np.asarray(z[k], np.float64) for k in GROUPS if k in z.files}
    width = {k: len(v) for k, v in GROUPS.items()}
    for k, a in rec.items():
        want = (len(rec["times"]),) if k == "times" else (len(rec["times"]), width[k])
        if a.shape != want:
            raise RecordingError(f"{path}: array '{k}' has shape {a.shape}, expected {want}")
    _check_length(path, len(rec["times"]))
    return rec


def _read_csv(path: Path) -> dict[str, np.ndarray]:
    text = path.read_text(encoding="utf-8-sig")  # a BOM from spreadsheet exports is not part of 't'
    lines = [(n, ln) for n, ln in enumerate(text.splitlines(), 1) if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise RecordingError(f"{path}: the file is empty; expected a header row ({_header_example()}) and samples")
    header_no, header_line = lines[0]
    header = [c.strip().lower() for c in next(csv.reader([header_line]))]
    if len(header) == 1:
        found = [name for d, name in _OTHER_DELIMITERS.items() if d in header_line]
        how = f"it is separated by {found[0]}" if found else "it has a single column"
        raise RecordingError(
            f"{path}: line {header_no}: the header '{header_line.strip()[:60]}' is not comma-separated ({how}); "
            f"rbjax reads comma-separated files with a header such as {_header_example()}"
        )
    dup = sorted({c for c in header if header.count(c) > 1})
    if dup:
        raise RecordingError(f"{path}: line {header_no}: column(s) {dup} appear more than once in the header")
    if "t" not in header:
        raise RecordingError(f"{path}: line {header_no}: no 't' column (sample times) in the header {header}")
    for name, cols in GROUPS.items():
        have = [c for c in cols if c in header]
        if have and len(have) < len(cols):
            missing = [c for c in cols if c not in header]
            raise RecordingError(
                f"{path}: line {header_no}: columns {have} of the {name} group are there but {missing} are missing; "
                f"give all of {list(cols)} or none"
            )
    if len(lines) == 1:
        raise RecordingError(
            f"{path}: only a header, no samples; write the samples below it, one row per time (at least 2 rows)"
        )
    used = [c for cols in GROUPS.values() if cols[0] in header for c in cols]
    index = [header.index(c) for c in used]
    rows = np.empty((len(lines) - 1, len(used)))
    for r, (n, line) in enumerate(lines[1:]):
        fields = next(csv.reader([line]))
        if len(fields) != len(header):
            raise RecordingError(
                f"{path}: line {n} has {len(fields)} fields but the header has {len(header)} "
                "(a ragged row: a missing or extra value, or a comma inside a number)"
            )
        for j, i in enumerate(index):
            try:
                rows[r, j] = float(fields[i])
            except ValueError:
                raise RecordingError(
                    f"{path}: line {n}, column '{header[i]}': {fields[i].strip()[:30]!r} is not a number"
                ) from None
    _check_length(path, len(rows))
    col = {c: rows[:, j] for j, c in enumerate(used)}
    return {
        name: (col["t"] if name == "times" else np.stack([col[c] for c in cols], -1))
        for name, cols in GROUPS.items()
        if cols[0] in col
    }


def _check_length(path: Path, n: int) -> None:
    if n == 0:
        raise RecordingError(f"{path}: no samples (empty arrays); save the recording's data, at least 2 samples")
    if n < 2:
        raise RecordingError(f"{path}: {n} sample(s); a fit needs a recording of many samples")


def _header_example() -> str:
    return "'" + ",".join(c for name in ("times", "quaternions", "gyro") for c in GROUPS[name]) + "'"
