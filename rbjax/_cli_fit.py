"""``python -m rbjax fit``: an inertia fitted to a recording file, or to the throws of a phyphox export or blackbox log.

A blackbox log is the CSV that ``blackbox_decode`` writes from a Betaflight/INDIflight
flight controller's log (:meth:`rbjax.Recording.from_blackbox`): a thrown device with a
flywheel. Its throws are found (from ``accSmooth``) and fitted like a phyphox export's, with
the flywheel's momentum (``--rotor-axis``, and ``--rotor-inertia`` for kg m²); a log with
the flywheel's eRPM and no ``--rotor-axis`` is refused (``--no-rotor`` fits without it).

The exit status tells a script whether what it asked for converged (:func:`exit_status`):

- 0: all of it: the recording's fit; of a phyphox export or blackbox log, every throw's own fit and,
  with two or more throws and no ``--separate``, the joint fit.
- 1: nothing usable: the recording's (or the only throw's) fit did not converge; the
  joint fit did not (whatever the throws' own fits did: the joint one is the answer
  asked for); with ``--separate``, no throw's fit converged.
- 2: an error (bad arguments, an unreadable recording, an output path that cannot be written).
- 3: part of it: the joint fit converged but not every throw's own fit did; with
  ``--separate``, some throws' fits converged and some did not (the combination is
  over those that did).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import warnings
from pathlib import Path

from ._cli_common import CLIError, use_compile_cache
from ._cli_plot import plot_throw_fits

__all__ = ["EXIT_STATUS_HELP", "FIT_OPTIONS", "add_fit_parser", "exit_status", "run_fit"]

EXIT_STATUS_HELP = """\
exit status:
  0  everything asked for converged: the recording's fit; of a phyphox export (or a
     blackbox log), every throw's own fit and (two or more throws, without --separate) the joint fit
  1  nothing usable converged: the recording's or the only throw's fit; the joint fit
     (whatever the throws' own fits did); with --separate, no throw's fit
  2  an error: bad arguments, an unreadable recording, an output path that cannot be written
  3  part of it converged: the joint fit but not every throw's own fit; with --separate,
     some throws' fits but not all (the combination is over those that converged)
"""


FIT_OPTIONS = {  # CLI flag destination -> fit_inertia keyword, passed only when given
    "method": "method",
    "segments": "segments",
    "substeps": "substeps",
    "orientation_std": "orientation_std",
    "rate_std": "rate_std",
    "acceleration_std": "acceleration_std",
    "max_steps": "max_steps",
    "loss": "loss",
    "loss_scale": "loss_scale",
    "drag": "drag",
}


def _pm(x: float, s: float) -> str:
    """``x ± s`` with ``s`` to two significant digits and ``x`` to the same decimal place (at least
    four): a σ of 3e-5 printed to four decimals read "± 0.0000", as if the fit had none."""
    if not math.isfinite(s) or s <= 0:
        return f"{x:.4f} ± {s:.2g}"
    decimals = min(max(4, 1 - math.floor(math.log10(s))), 12)
    return f"{x:.{decimals}f} ± {s:.{decimals}f}"


def _pm_list(values, sigmas) -> str:
    return ", ".join(_pm(float(x), float(s)) for x, s in zip(values, sigmas, strict=True))


def _check_outputs(args: argparse.Namespace) -> None:
    """``CLIError`` for an output path (``--out``, ``--plot``, ``--mjcf``, ``--urdf``) that cannot be written, or an
    inertia export without ``--mass``: before the fit, not after it."""
    import os

    exports = [f"--{flag}" for flag in ("mjcf", "urdf") if getattr(args, flag, None) is not None]
    if exports and getattr(args, "mass", None) is None:
        raise CLIError(f"{'/'.join(exports)} needs --mass KG (the body's mass: a rotation fit does not determine it)")
    for flag in ("mass", "scale"):
        value = getattr(args, flag, None)
        if value is not None and not (math.isfinite(value) and value > 0):
            raise CLIError(f"--{flag} must be finite and > 0, got {value}")
    for flag in ("out", "plot", "mjcf", "urdf"):
        value = getattr(args, flag, None)
        if value is None:
            continue
        path = Path(value)
        parent = path.parent if str(path.parent) else Path(".")
        if path.is_dir():
            example = {"mjcf": "inertial.xml", "urdf": "inertial.urdf", "plot": "fit.png"}.get(flag, "fit.json")
            raise CLIError(f"--{flag} {value} is a directory; give a file name, e.g. {path / example}")
        if not parent.is_dir():
            raise CLIError(f"--{flag} {value}: no directory {parent}; create it first (mkdir -p {parent})")
        if not os.access(parent, os.W_OK | os.X_OK) or (path.exists() and not os.access(path, os.W_OK)):
            raise CLIError(f"--{flag} {value}: not writable; choose a path you may write")


def json_text(obj: object) -> str:
    """``obj`` as standard JSON for ``--out``: arrays as lists, every non-finite number as ``null``.

    A fit's report holds ``inf`` (σ on the edge of physical inertias) and NaN (a part not
    fitted, a σ undefined); Python's ``json`` would write them as ``Infinity``/``NaN``, which
    are not JSON, and strict readers (JavaScript's ``JSON.parse``, Go, jq) refuse the file.
    """

    def clean(v: object) -> object:
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}  # pyright: ignore[reportUnknownVariableType]
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]  # pyright: ignore[reportUnknownVariableType]
        if hasattr(v, "__array__") and not isinstance(v, (bool, int, float)):
            import numpy as np

            return clean(np.asarray(v).tolist())
        if isinstance(v, float) and not math.isfinite(v):
            return None
        return v

    return json.dumps(clean(obj), indent=1, allow_nan=False)


def run_fit(args: argparse.Namespace) -> int:
    _check_outputs(args)
    import jax

    jax.config.update("jax_enable_x64", True)
    if getattr(args, "compile_cache", False):
        use_compile_cache()
    from . import fit_inertia
    from ._blackbox import is_blackbox_csv
    from ._recording import RecordingError, read_recording, time_unit_hint

    # before phyphox's test: a log decoded with --unit-frame-time s has a "time (s)" column too
    if is_blackbox_csv(Path(args.recording)):
        return _fit_blackbox(args)
    blackbox_only = [
        flag
        for flag, dest in (
            ("--rotor-axis", "rotor_axis"),
            ("--rotor-inertia", "rotor_inertia"),
            ("--rotor-motor", "rotor_motor"),
            ("--motor-poles", "motor_poles"),
            ("--gyro-scale-log", "gyro_scale_log"),
            ("--acc-1g", "acc_1g"),
            ("--board-axes", "board_axes"),
            ("--no-rotor", "no_rotor"),
        )
        if getattr(args, dest, None) not in (None, False)
    ]
    if blackbox_only:
        raise CLIError(
            f"{', '.join(blackbox_only)} appl(ies) to blackbox logs (blackbox_decode's CSV, with 'time (us)' and "
            f"'gyroADC[0]' columns), not to {args.recording}"
        )
    if _is_phyphox(Path(args.recording)):
        return _fit_throws(args)
    for flag in ("threshold", "margin", "min_duration", "plot"):
        if getattr(args, flag) is not None:
            raise CLIError(f"--{flag.replace('_', '-')} applies to phyphox exports (throws), not to {args.recording}")
    if args.separate:
        raise CLIError(f"--separate applies to phyphox exports (throws), not to {args.recording}")
    try:
        rec = read_recording(Path(args.recording), args.time_unit or "s")
    except RecordingError as e:
        raise CLIError(str(e)) from e
    if "quaternions" not in rec and "gyro" not in rec:
        raise CLIError(f"{args.recording}: the recording has neither quaternions (qw,qx,qy,qz) nor gyro (gx,gy,gz)")
    if args.time_unit is None and (hint := time_unit_hint(rec)) is not None:
        if not hint.startswith("note:"):
            raise CLIError(f"{args.recording}: {hint}")
        print(f"{args.recording}: {hint}", file=sys.stderr)
    _check_scale(args, "torques" in rec or "body_torques" in rec, args.recording)
    if args.gyro_only:
        rec.pop("quaternions", None)
    for flag, key, what in (
        (args.accelerometer, "accelerations", "--accelerometer"),
        (
            args.gyro_bias or args.gyro_rotation or args.gyro_only or args.gyro_scale,
            "gyro",
            "--gyro-bias/--gyro-rotation/--gyro-only/--gyro-scale",
        ),
    ):
        if flag and key not in rec:
            raise CLIError(f"{args.recording}: {what} needs the {key} columns in the recording")
    ignored = [] if args.accelerometer or "accelerations" not in rec else ["ax,ay,az (pass --accelerometer)"]
    if ignored:
        print(f"note: ignoring columns {', '.join(ignored)}", file=sys.stderr)
    kwargs = {kw: getattr(args, dest) for dest, kw in FIT_OPTIONS.items() if getattr(args, dest) is not None}
    kwargs.update({k: True for k in ("gyro_bias", "gyro_rotation", "gyro_scale") if getattr(args, k)})
    if args.accelerometer:
        kwargs["accelerations"] = rec["accelerations"]
    try:
        res = fit_inertia(
            rec["times"],
            rec.get("quaternions"),
            body_rates=rec.get("gyro"),
            torques=rec.get("torques"),
            body_torques=rec.get("body_torques"),
            **kwargs,
        )
    except (ValueError, TypeError) as e:
        raise CLIError(str(e)) from e
    out = _fit_report(res)
    unit = {
        "kg m^2": "kg m²",
        "rotor inertia J": "units of the rotor's inertia J",
    }.get(out["inertia_units"], "normalised to trace 1 (no torques: scale not identifiable)")
    print(f"inertia ({unit}), body frame:")
    for row in out["inertia"]:
        print("  [" + "  ".join(f"{v: .6e}" for v in row) + "]")
    print(
        "principal moments: "
        + ", ".join(f"{m:.6e} ± {s:.1e}" for m, s in zip(out["principal_moments"], out["moment_std"]))
    )
    for key, label, unit in (
        ("gyro_bias", "gyro bias", "rad/s"),
        ("lever_arm", "accelerometer lever arm", "m"),
        ("accelerometer_bias", "accelerometer bias", "m/s²"),
    ):
        if key in out:
            values = zip(out[key], out[key + "_std"], strict=True)
            print(f"{label} ({unit}): " + ", ".join(f"{v: .4e} ± {s:.1e}" for v, s in values))
    if "drag" in out:
        values = zip(out["drag"], out["drag_std"], strict=True)
        print("drag (c1, c2; relative to tr I without torques): " + ", ".join(f"{v: .4e} ± {s:.1e}" for v, s in values))
    if "gyro_scale" in out:
        print(f"gyro scale error s (reading (1 + s) w): {out['gyro_scale']: .4e} ± {out['gyro_scale_std']:.1e}")
    if "gyro_rotation" in out:
        print("gyro to body rotation [w, x, y, z]: " + ", ".join(f"{v: .6f}" for v in out["gyro_rotation"]))
    if out.get("outliers"):
        times = ", ".join(f"{rec['times'][i]:.4g}" for i in out["outliers"][:10])
        more = " ..." if len(out["outliers"]) > 10 else ""
        print(f"down-weighted samples (robust loss): {len(out['outliers'])}, at t = {times}{more} s")
    print(
        f"converged (trust this fit): {out['converged']} after {out['iterations']} iterations"
        f" (solver converged {out['solver_converged']}, on boundary {out['on_boundary']},"
        f" residual ratio {out['residual_ratio']:.3g}, white-noise chi2 p-value {out['consistency_pvalue']:.3g})"
    )
    print(f"diagnosis: {out['diagnosis']}")
    if args.out:
        Path(args.out).write_text(json_text(out))
        print(f"saved: {args.out}")
    _write_inertial(args, res)
    return exit_status([out["converged"]])


def _check_scale(args: argparse.Namespace, scale_fixed: bool, what: str) -> None:
    """``CLIError`` before the fit for an export whose scale will be missing (or given twice)."""
    if getattr(args, "mjcf", None) is None and getattr(args, "urdf", None) is None:
        return
    if not scale_fixed and args.scale is None:
        raise CLIError(
            f"{what}: without torques the fit is normalised to tr I = 1 (only its ratios are known); "
            "--mjcf/--urdf need --scale KG_M2, the body's tr I"
        )
    if scale_fixed and args.scale is not None:
        raise CLIError(f"{what}: the torques fix the inertia in kg m²; leave --scale out")


def _write_inertial(args: argparse.Namespace, res) -> None:
    """``--mjcf`` / ``--urdf``: the fitted inertia as an ``<inertial>`` element, with ``--mass`` (and ``--scale``)."""
    for flag, method in (("mjcf", res.mjcf_inertial), ("urdf", res.urdf_inertial)):
        path = getattr(args, flag, None)
        if path is None:
            continue
        try:
            text = method(args.mass, args.scale)
        except ValueError as e:
            remedy = str(e).replace("pass scale=", "pass --scale KG_M2, ")
            raise CLIError(f"--{flag}: {remedy}") from e
        Path(path).write_text(text + "\n")
        print(f"saved: {path}")


def exit_status(converged, joint: bool | None = None) -> int:
    """The exit status of ``fit`` (:data:`EXIT_STATUS_HELP`): 0 all converged, 1 nothing usable, 3 part.

    ``converged``: per fit of its own (the recording, or each throw; a throw that
    could not be fitted counts as not converged); ``joint``: whether the joint fit
    converged, ``None`` where there is none (one recording, one throw, ``--separate``).
    A script that trusts the status is never told 0 while part of what it asked
    for failed, nor anything but 1 when the answer it asked for did not converge.
    """
    converged = [bool(c) for c in converged]
    if joint is not None:
        if not joint:
            return 1
        return 0 if all(converged) else 3
    if all(converged) and converged:
        return 0
    return 3 if any(converged) else 1


def _is_phyphox(path: Path) -> bool:
    """A phyphox export: a directory, a ``.zip``, or a ``.csv`` whose header names ``Time (s)``."""
    if path.is_dir() or path.suffix.lower() == ".zip":
        return True
    if path.suffix.lower() != ".csv" or not path.is_file():
        return False
    with path.open(encoding="utf-8-sig", errors="replace") as f:
        return "time (s)" in f.readline().lower()


def _refuse_unsupported(args: argparse.Namespace, what: str) -> None:
    """``CLIError`` for the recording-file options that a file of throws (fitted from the gyro) has no use for."""
    unsupported = [
        flag
        for flag, on in (
            ("--time-unit", args.time_unit is not None),
            ("--accelerometer", args.accelerometer),
            ("--gyro-rotation", args.gyro_rotation),
            ("--orientation-std", args.orientation_std is not None),
            ("--acceleration-std", args.acceleration_std is not None),
        )
        if on
    ]
    if unsupported:
        raise CLIError(
            f"{args.recording}: {', '.join(unsupported)} do(es) not apply to {what} "
            "(times in s; each throw is fitted from the gyroscope alone)"
        )


def _fit_throws(args: argparse.Namespace) -> int:
    """``fit`` of a phyphox export: find the throws, fit the gyro of each (one ragged call), report."""
    from . import Recording, RecordingError

    _refuse_unsupported(args, "a phyphox export")
    try:
        rec = Recording.from_phyphox(args.recording)
    except RecordingError as e:
        raise CLIError(str(e)) from e
    if rec.gyro is None:
        raise CLIError(f"{args.recording}: no gyroscope columns; record 'Gyroscope rotation rate' with phyphox")
    _check_scale(args, False, args.recording)
    return _fit_windows(args, rec, {})


def _fit_windows(args: argparse.Namespace, rec, rotor: dict) -> int:
    """Find the throws of ``rec``, fit the gyro (and rotor) of each (one ragged call) and the joint fit, report.

    ``rotor``: fit_inertia's ``rotor_axis``/``rotor_inertia`` for a recording with ``rotor_rates``, else ``{}``.
    """
    import dataclasses

    import numpy as np

    from . import find_throws, fit_inertia
    from .identification._throws import NoFlightWarning

    found = {k: getattr(args, k) for k in ("threshold", "margin", "min_duration") if getattr(args, k) is not None}
    try:
        # find_throws says why it found no flight in a warning; the CLI says it as its error
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            windows = find_throws(rec, **found)
    except ValueError as e:
        raise CLIError(f"{args.recording}: {e}") from e
    if not windows:
        why = next((w.message.reason for w in said if isinstance(w.message, NoFlightWarning)), "")
        raise CLIError(
            f"{args.recording}: no free flight found ({why}); check with rbjax.plot_throws, or lower "
            "--min-duration" + (" / raise --threshold" if rec.accelerations is not None else "")
        )
    throws = [dataclasses.replace(rec.window(t0, t1), accelerations=None) for t0, t1 in windows]
    if (args.mjcf is not None or args.urdf is not None) and args.separate and len(throws) > 1:
        raise CLIError(
            f"{args.recording}: --mjcf/--urdf export one inertia, and --separate fits {len(throws)} throws "
            "one by one; drop --separate for their joint fit"
        )
    kwargs = {kw: getattr(args, dest) for dest, kw in FIT_OPTIONS.items() if getattr(args, dest) is not None}
    kwargs.update({k: True for k in ("gyro_bias", "gyro_scale") if getattr(args, k)})
    kwargs.update(rotor)
    try:
        res = fit_inertia(throws, **kwargs)
    except (ValueError, TypeError) as e:
        raise CLIError(str(e)) from e
    joint = None
    if len(throws) > 1 and not args.separate:
        try:
            joint = fit_inertia(throws, **kwargs, joint=True)
        except (ValueError, TypeError) as e:
            raise CLIError(str(e)) from e
    report = _throws_report(res, windows, [len(r) for r in throws], joint)
    absolute = _absolute_moments(report, res, joint) if rotor else None
    print(
        f"{args.recording}: {len(windows)} throw(s); principal moments as I_k / tr I (ascending), "
        + ("gyro and rotor fits" if rotor else "gyro-only fits")
    )
    for k, row in enumerate(report["throws"]):
        head = f"throw {k + 1}: t = {row['t0']:.3f}-{row['t1']:.3f} s ({row['samples']} samples): "
        if row["failed"]:
            print(head + f"not fitted: {row['error']}")
            continue
        moments, ratios = _pm_list(row["moments"], row["moment_std"]), _pm_list(row["ratios"], row["ratio_std"])
        print(head + f"I/trI = {moments}; I1/I3, I2/I3 = {ratios}")
        if absolute is not None:
            print(
                f"    principal moments ({absolute}): "
                + _pm_list(row["principal_moments"], row["principal_moment_std"])
            )
        print(
            f"    converged (trust) {row['converged']} (white-noise chi2 p-value {row['pvalue']:.3g}, "
            f"gyro rms {row['rate_rms']:.3g} rad/s, {row['iterations']} iterations)"
            + (
                ""
                if "joint_rms" not in row
                else f"; in the joint fit: rms {row['joint_rms']:.3g} x its level, p-value {row['joint_pvalue']:.3g}"
            )
        )
        print(f"    diagnosis: {row['diagnosis']}")
    comb = report["combined"]
    if comb is not None and comb.get("joint"):
        m, rat = _pm_list(comb["moments"], comb["moment_std"]), _pm_list(comb["ratios"], comb["ratio_std"])
        print(f"combined: one inertia fitted to {comb['throws']} throw(s) jointly: I/trI = {m}; I1/I3, I2/I3 = {rat}")
        if absolute is not None:
            print(
                f"    principal moments ({absolute}): "
                + _pm_list(comb["principal_moments"], comb["principal_moment_std"])
            )
        print(
            f"    joint fit converged (trust): {comb['converged']} (white-noise chi2 p-value "
            f"{comb['pvalue']:.3g}, gyro rms "
            f"{comb['rate_rms']:.3g} rad/s); spread of the separate fits: "
            + ", ".join(f"{x:.2g}" for x in comb["moments_spread"])
        )
        print(f"    diagnosis: {comb['diagnosis']}")
    elif comb is None:
        print("combined: no throw converged; nothing to combine (see the diagnostics above)")
    elif comb["throws"] == 1:  # one throw has no spread: its own fit and σ are printed above
        print("combined: one converged throw, its fit above (no spread to take with one)")
    else:
        med = _pm_list(comb["moments"], comb["moments_spread"])
        rat = _pm_list(comb["ratios"], comb["ratios_spread"])
        print(
            f"combined over {comb['throws']} converged throw(s), median ± spread: I/trI = {med}; I1/I3, I2/I3 = {rat}"
        )
    if args.plot:
        plot_throw_fits(args.plot, throws, res, joint)
        print(f"plot: {args.plot}")
    if args.out:
        Path(args.out).write_text(json_text(report))
        print(f"saved: {args.out}")
    if args.mjcf is not None or args.urdf is not None:
        if joint is not None:
            _write_inertial(args, joint)
        else:  # one throw (more with --separate are refused before the fit)
            import jax

            _write_inertial(args, jax.tree.map(lambda a: a[0], res))
    converged = np.asarray(res.converged) & ~np.asarray(res.failed)
    return exit_status(converged.tolist(), None if joint is None else bool(joint.converged))


def _absolute_moments(report: dict, res, joint) -> str:
    """Add each throw's (and the joint fit's) principal moments and inertia in the fit's own units to ``report``
    (a rotor fixes the scale: kg m² with ``--rotor-inertia``, else units of J); return those units in words."""
    import numpy as np

    units = str(res.inertia_units[0] if np.ndim(res.inertia_units) else res.inertia_units)
    report["inertia_units"] = units
    for k, row in enumerate(report["throws"]):
        row.update(
            principal_moments=np.asarray(res.principal_moments)[k].tolist(),
            principal_moment_std=np.asarray(res.moment_std)[k].tolist(),
            inertia=np.asarray(res.inertia)[k].tolist(),
        )
    if joint is not None and report["combined"] is not None:
        report["combined"].update(
            principal_moments=np.asarray(joint.principal_moments).tolist(),
            principal_moment_std=np.asarray(joint.moment_std).tolist(),
            inertia=np.asarray(joint.inertia).tolist(),
        )
    return {"kg m^2": "kg m²", "rotor inertia J": "units of the rotor's inertia J"}.get(units, units)


def _fit_blackbox(args: argparse.Namespace) -> int:
    """``fit`` of a blackbox log (``blackbox_decode``'s CSV): find the throws, fit each with the flywheel, report."""
    from . import Recording, RecordingError

    _refuse_unsupported(args, "a blackbox log")
    motor = 0 if args.rotor_motor is None else args.rotor_motor
    if args.no_rotor and (args.rotor_axis is not None or args.rotor_inertia is not None):
        raise CLIError("--no-rotor fits without the rotor; leave --rotor-axis/--rotor-inertia out")
    if args.rotor_inertia is not None and args.rotor_axis is None:
        raise CLIError("--rotor-inertia needs --rotor-axis AX,AY,AZ (the flywheel's spin axis, body frame)")
    try:
        rec = Recording.from_blackbox(
            args.recording,
            gyro_scale=args.gyro_scale_log,
            acc_1g=args.acc_1g,
            motor_poles=14 if args.motor_poles is None else args.motor_poles,
            axes=args.board_axes,
            rotor=None if args.no_rotor else motor,
        )
    except (RecordingError, ValueError, TypeError) as e:
        raise CLIError(str(e)) from e
    rotor: dict = {}
    if rec.rotor_rates is not None:
        if args.rotor_axis is None:
            raise CLIError(
                f"{args.recording}: the log has the flywheel's rate (eRPM[{motor}]); its momentum changes "
                "the motion, so the fit needs --rotor-axis AX,AY,AZ (its spin axis in the body frame, along its "
                "angular velocity) and --rotor-inertia J (kg m², for an inertia in kg m²); --no-rotor fits "
                "without it (not trusted while the flywheel spins)"
            )
        if args.plot:
            # plot_throw_fits simulates the fitted body without a flywheel: its curves would not be the fit's
            raise CLIError("--plot does not draw fits with a rotor yet; leave it out (the JSON of --out holds the fit)")
        rotor = {"rotor_axis": args.rotor_axis}
        if args.rotor_inertia is not None:
            rotor["rotor_inertia"] = args.rotor_inertia
    elif args.rotor_axis is not None:
        raise CLIError(
            f"{args.recording}: --rotor-axis given, but the log has no eRPM[{motor}] column; log the "
            "motor's RPM (bidirectional DShot, blackbox field 'RPM'), pick the motor with --rotor-motor K, or "
            "leave --rotor-axis out"
        )
    if args.mjcf is not None or args.urdf is not None:
        if rotor and "rotor_inertia" not in rotor:
            raise CLIError(f"{args.recording}: --mjcf/--urdf need the inertia in kg m²: pass --rotor-inertia J (kg m²)")
        if not rotor:
            _check_scale(args, False, args.recording)
    return _fit_windows(args, rec, rotor)


def _normalised(res):
    """``(I/trI, σ, [I1/I3, I2/I3], σ)`` of a result (any leading axes).

    The ratios' σ propagates the moments' σ to first order as if independent,
    ``σ(a/b)² ≈ (a/b)² ((σ_a/a)² + (σ_b/b)²)`` (:class:`FitResult` holds no
    covariance between the moments).
    """
    import numpy as np

    m, s = np.asarray(res.principal_moments), np.asarray(res.moment_std)
    m, s = m / m.sum(-1, keepdims=True), s / m.sum(-1, keepdims=True)
    ratios = m[..., :2] / m[..., 2:]
    ratio_std = ratios * np.sqrt((s[..., :2] / m[..., :2]) ** 2 + (s[..., 2:] / m[..., 2:]) ** 2)
    return m, s, ratios, ratio_std


def _throws_report(res, windows, samples, joint=None) -> dict:
    """Per throw: window, normalised moments ± σ, the ratios ``I1/I3, I2/I3`` ± σ, diagnostics; and the combination.

    The combination is the ``joint`` fit (``fit_inertia(..., joint=True)``) when
    given: one inertia for all throws, with its σ; each throw's row then also
    holds its residual level and p-value in it. Otherwise it is over the converged
    throws: the median, and as spread the sample standard deviation (0 for one
    throw); the joint one keeps that spread of the separate fits too.
    """
    import numpy as np

    m, s, ratios, ratio_std = _normalised(res)
    errors = {int(e.split(":")[0].split()[-1]): e.split(":", 1)[1].strip() for e in res.member_errors}
    rows = []
    for k, (t0, t1) in enumerate(windows):
        rows.append(
            dict(
                t0=t0,
                t1=t1,
                samples=samples[k],
                failed=bool(np.asarray(res.failed)[k]),
                error=errors.get(k, ""),
                moments=m[k].tolist(),
                moment_std=s[k].tolist(),
                ratios=ratios[k].tolist(),
                ratio_std=ratio_std[k].tolist(),
                converged=bool(np.asarray(res.converged)[k]),
                solver_converged=bool(np.asarray(res.solver_converged)[k]),
                model_consistent=bool(np.asarray(res.model_consistent)[k]),
                well_determined=bool(np.asarray(res.well_determined)[k]),
                pvalue=float(np.asarray(res.consistency_pvalue)[k]),
                principal_axes=np.asarray(res.principal_axes)[k].tolist(),
                principal_axes_std=np.asarray(res.principal_axes_std)[k].tolist(),
                inertia_covariance=np.asarray(res.inertia_covariance)[k].tolist(),
                rate_rms=float(np.asarray(res.rate_rms)[k]),
                iterations=int(np.asarray(res.iterations)[k]),
                **_verdict_fields(res, k),
            )
        )
        if np.any(np.isfinite(np.asarray(res.drag)[k])):  # NaN unless drag= was given
            rows[-1].update(drag=np.asarray(res.drag)[k].tolist(), drag_std=np.asarray(res.drag_std)[k].tolist())
        if joint is not None:
            rows[-1].update(joint_rms=joint.member_rms[k], joint_pvalue=joint.member_pvalue[k])
    ok = np.asarray(res.converged) & ~np.asarray(res.failed)
    combined = None

    def spread(x):
        return np.std(x, 0, ddof=1) if len(x) > 1 else np.zeros(x.shape[1:])

    if ok.any():
        combined = dict(
            throws=int(ok.sum()),
            moments=np.median(m[ok], 0).tolist(),
            moments_spread=spread(m[ok]).tolist(),
            ratios=np.median(ratios[ok], 0).tolist(),
            ratios_spread=spread(ratios[ok]).tolist(),
        )
    if joint is not None:
        jm, js, jr, jrs = _normalised(joint)
        combined = dict(
            joint=True,
            throws=len(rows) - len(joint.member_errors),
            moments=jm.tolist(),
            moment_std=js.tolist(),
            ratios=jr.tolist(),
            ratio_std=jrs.tolist(),
            moments_spread=spread(m[ok]).tolist() if ok.any() else [np.nan] * 3,
            converged=bool(joint.converged),
            solver_converged=bool(joint.solver_converged),
            model_consistent=bool(joint.model_consistent),
            well_determined=bool(joint.well_determined),
            pvalue=float(joint.consistency_pvalue),
            rate_rms=float(joint.rate_rms),
            principal_axes=np.asarray(joint.principal_axes).tolist(),
            principal_axes_std=np.asarray(joint.principal_axes_std).tolist(),
            inertia_covariance=np.asarray(joint.inertia_covariance).tolist(),
            **_verdict_fields(joint),
        )
        if np.any(np.isfinite(np.asarray(joint.drag))):
            combined.update(drag=np.asarray(joint.drag).tolist(), drag_std=np.asarray(joint.drag_std).tolist())
    return {"throws": rows, "combined": combined}


def _verdict_fields(res, k: int | None = None) -> dict:
    """The verdict's JSON fields of one fit (``k``: its index in a batch): diagnosis, white σ, misfit structure."""
    import numpy as np

    def one(name):
        v = np.asarray(getattr(res, name))
        return v if k is None else v[k]

    diagnosis = res.diagnosis if k is None else res.diagnosis[k]
    names = ("drag", "bias", "rotor", "scale")
    return dict(
        diagnosis=diagnosis,
        moment_std_white=one("moment_std_white").tolist(),
        misfit_ratio=one("noise_scale").tolist(),
        correlation_length=one("correlation_length").tolist(),
        misfit_structured=bool(one("misfit_structured")),
        cause_share=dict(zip(names, one("cause_share").tolist(), strict=True)),
        causes_allowed_for=[n for n, on in zip(names, one("cause_significant").tolist(), strict=True) if on],
    )


def _fit_report(res) -> dict:
    """The JSON-ready fields of a FitResult (plain floats, lists and bools)."""
    import numpy as np

    from .identification._result import MODEL_PARTS

    # inertia_units: "kg m^2", "rotor inertia J" (a rotor of unknown J) or "trace-normalised"
    out: dict = {
        "scale_fixed": bool(res.scale_fixed),
        "inertia_units": str(res.inertia_units),
        "segments": int(res.segments),
    }
    # principal_axes: columns are the axes (body frame); inertia_covariance: (xx, yy, zz, xy, xz, yz)
    for k in (
        "inertia",
        "principal_moments",
        "moment_std",
        "principal_axes",
        "principal_axes_std",
        "inertia_covariance",
        "initial_angular_velocity",
    ):
        out[k] = np.asarray(getattr(res, k)).tolist()
    for k in ("converged", "solver_converged", "model_consistent", "well_determined", "on_boundary"):
        out[k] = bool(getattr(res, k))
    out["iterations"] = int(res.iterations)
    out.update(_verdict_fields(res))
    out["consistency_pvalue"], out["chi2"], out["dof"] = (
        float(getattr(res, k)) for k in ("consistency_pvalue", "chi2", "dof")
    )
    for k, name in (
        ("orientation_rms", "orientation_rms_rad"),
        ("rate_rms", "rate_rms_rad_s"),
        ("residual_ratio", "residual_ratio"),
    ):
        v = float(getattr(res, k))
        if np.isfinite(v):
            out[name] = v
    # sensor models: only the fitted ones (a field that was not fitted is zeros / NaN)
    for k in ("gyro_bias", "lever_arm", "accelerometer_bias"):
        std = getattr(res, k + "_std")
        if np.all(np.isfinite(np.asarray(std))):
            out[k], out[k + "_std"] = np.asarray(getattr(res, k)).tolist(), np.asarray(std).tolist()
    if np.any(np.isfinite(np.asarray(res.drag))):  # NaN unless drag= was given
        out["drag"], out["drag_std"] = np.asarray(res.drag).tolist(), np.asarray(res.drag_std).tolist()
    if np.isfinite(float(res.gyro_scale_std)):  # NaN unless gyro_scale=True
        out["gyro_scale"], out["gyro_scale_std"] = float(res.gyro_scale), float(res.gyro_scale_std)
    # ΔBIC of each optional part fitted (or score-tested): > 0 the data support it
    out["delta_bic"] = {
        k: float(v) for k, v in zip(MODEL_PARTS, np.asarray(res.delta_bic).tolist(), strict=True) if np.isfinite(v)
    }
    if np.all(np.isfinite(np.asarray(res.gyro_rotation_std))):  # NaN unless gyro_rotation=True
        out["gyro_rotation"] = np.asarray(res.gyro_rotation).tolist()
        out["gyro_rotation_std_rad"] = np.asarray(res.gyro_rotation_std).tolist()
    out["outliers"] = np.flatnonzero(np.asarray(res.outliers)).tolist()
    return out


def _recording_help() -> str:
    from ._recording import __doc__ as doc

    return (doc or "").split("\n\n", 1)[1].split("\nEvery way")[0]


def _fit_default(name: str) -> object:
    """The default of ``fit_inertia``'s keyword ``name``: the help text quotes the code's value."""
    import inspect

    from .identification import fit_inertia

    return inspect.signature(fit_inertia).parameters[name].default


def _throws_default(name: str) -> float:
    """The default of ``find_throws``' keyword ``name``, quoted in the help."""
    import inspect

    from .identification import find_throws

    return inspect.signature(find_throws).parameters[name].default


def _floats(n: int):
    """An argparse type: ``n`` comma-separated numbers, as a list (3 x 3 row by row for 9)."""

    def parse(text: str):
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {n} comma-separated numbers, got {text!r}") from None
        if len(values) != n or not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"expected {n} finite comma-separated numbers, got {text!r}")
        return values if n != 9 else [values[0:3], values[3:6], values[6:9]]

    return parse


def add_fit_parser(sub, common: argparse.ArgumentParser) -> None:
    """Add the ``fit`` subcommand to ``sub`` (the subparsers of ``python -m rbjax``)."""
    fit = sub.add_parser(
        "fit",
        parents=[common],
        help="fit an inertia tensor to recorded motion",
        description="Fit an inertia tensor to recorded motion (exit status: see the end).\n\n" + _recording_help(),
        epilog=EXIT_STATUS_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    fit.add_argument(
        "recording",
        help="a .csv or .npz recording (see above), a phyphox export (a directory or .zip of CSVs, "
        "or one CSV with 'Time (s)' columns) or a blackbox log (blackbox_decode's CSV): its throws are found "
        "and each is fitted from the gyroscope (exit status: see the end)",
    )
    fit.add_argument("--out", default=None, help="write the result as JSON to this path")
    export = fit.add_argument_group("the fitted inertia for a simulator (MuJoCo, URDF)")
    export.add_argument("--mjcf", default=None, metavar="XML", help="write a MuJoCo <inertial> element")
    export.add_argument("--urdf", default=None, metavar="URDF", help="write a URDF <inertial> element")
    export.add_argument("--mass", type=float, default=None, metavar="KG", help="the body's mass (needed by both)")
    export.add_argument(
        "--scale",
        type=float,
        default=None,
        metavar="KG_M2",
        help="tr I of the body, for a fit normalised to tr I = 1 (without torques: every gyro-only fit)",
    )
    fit.add_argument("--time-unit", choices=["s", "ms", "us"], default=None, help="unit of the t column (default s)")
    fit.add_argument(
        "--method",
        default=None,
        help=f"integrator of the model (see rbjax.methods(); default {_fit_default('method')})",
    )
    fit.add_argument(
        "--segments",
        type=int,
        default=None,
        help="multiple-shooting segments (default: per 512 intervals and per 4π turned)",
    )
    fit.add_argument("--substeps", type=int, default=None, help="integrator steps per sample interval")
    fit.add_argument(
        "--max-steps",
        type=int,
        default=None,
        help=f"Levenberg–Marquardt step limit (default {_fit_default('max_steps')})",
    )
    noise = fit.add_argument_group("noise levels (default: estimated from the data)")
    noise.add_argument("--orientation-std", type=float, default=None, metavar="RAD")
    noise.add_argument("--rate-std", type=float, default=None, metavar="RAD_S", help="gyro noise")
    noise.add_argument("--acceleration-std", type=float, default=None, metavar="M_S2", help="accelerometer noise")
    sensors = fit.add_argument_group("sensor models (each opt-in)")
    sensors.add_argument("--gyro-only", action="store_true", help="ignore the quaternion columns: fit body rates alone")
    sensors.add_argument(
        "--drag",
        choices=["linear", "quadratic", "auto"],
        default=None,
        help="fit a body-frame air-drag torque -(c1 + c2|w|) w; auto: none, linear or quadratic, "
        "whichever has the smallest BIC (default: none)",
    )
    sensors.add_argument(
        "--gyro-scale", action="store_true", help="fit a scale error s common to the gyro's axes: (1 + s) w"
    )
    sensors.add_argument("--gyro-bias", action="store_true", help="fit a constant gyro bias (rad/s)")
    sensors.add_argument(
        "--gyro-rotation", action="store_true", help="fit a fixed rotation from the gyro frame to the body frame"
    )
    sensors.add_argument(
        "--accelerometer",
        action="store_true",
        help="use the ax,ay,az columns: fit the lever arm and accelerometer bias",
    )
    throws = fit.add_argument_group("phyphox exports: finding the throws (see rbjax.find_throws)")
    throws.add_argument(
        "--threshold",
        type=float,
        default=None,
        metavar="M_S2",
        help=f"free fall: |a| below this (default {_throws_default('threshold'):.3g})",
    )
    throws.add_argument(
        "--margin",
        type=float,
        default=None,
        metavar="S",
        help=f"trimmed at both ends of a flight (default {_throws_default('margin'):g})",
    )
    throws.add_argument(
        "--min-duration",
        type=float,
        default=None,
        metavar="S",
        help=f"shortest throw kept (default {_throws_default('min_duration'):g})",
    )
    throws.add_argument(
        "--separate",
        action="store_true",
        help="combine the throws as the median of separate fits (default: one joint fit of all throws)",
    )
    throws.add_argument("--plot", default=None, metavar="PNG", help="write measured against fitted rates per throw")
    bb = fit.add_argument_group(
        "blackbox logs: a thrown device's flight controller with a flywheel (blackbox_decode's CSV, header "
        "'time (us)', 'gyroADC[0]', ..., 'accSmooth[0]', ..., 'eRPM[0]'; see rbjax.Recording.from_blackbox); "
        "its throws are found and each is fitted from the gyro with the flywheel's momentum"
    )
    bb.add_argument(
        "--rotor-axis",
        type=_floats(3),
        default=None,
        metavar="AX,AY,AZ",
        help="the flywheel's spin axis, body frame, unit vector along its angular velocity (needed with eRPM)",
    )
    bb.add_argument(
        "--rotor-inertia",
        type=float,
        default=None,
        metavar="J",
        help="the flywheel's axial inertia (kg m²): the inertia comes out in kg m² (without: in units of J)",
    )
    bb.add_argument(
        "--rotor-motor", type=int, default=None, metavar="K", help="the flywheel's motor, eRPM[K] (default 0)"
    )
    bb.add_argument("--motor-poles", type=int, default=None, metavar="N", help="the motor's magnet poles (default 14)")
    bb.add_argument(
        "--gyro-scale-log",
        type=float,
        default=None,
        metavar="DEG_S",
        help="deg/s per count of raw gyroADC columns (default 1; 0.1 with blackbox_high_resolution)",
    )
    bb.add_argument(
        "--acc-1g",
        type=float,
        default=None,
        metavar="COUNTS",
        help="accSmooth counts per g (the log's acc_1G; default 2048)",
    )
    bb.add_argument(
        "--board-axes",
        type=_floats(9),
        default=None,
        metavar="R11,...,R33",
        help="rotation from the board's axes to the body frame, row by row: body = R board (default identity)",
    )
    bb.add_argument(
        "--no-rotor", action="store_true", help="fit a log with eRPM without the flywheel (not trusted while it spins)"
    )
    robust = fit.add_argument_group("robust fitting")
    robust.add_argument("--loss", choices=["squared", "huber", "cauchy"], default=None, help="default squared")
    robust.add_argument("--loss-scale", type=float, default=None, metavar="SIGMAS", help="where the robust loss bends")
    fit.set_defaults(func=run_fit)
