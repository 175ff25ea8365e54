"""Command line: ``python -m rbjax {demo,bench,fit}``.

Errors print one line, ``rbjax: error: ...``, on stderr and exit with status 2;
``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

__all__ = ["main", "benchmarks_dir"]


class CLIError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        # argparse prints a usage block; one line with a pointer to --help reads better
        raise CLIError(f"{message} (see '{self.prog} --help')")


def benchmarks_dir() -> Path:
    """The ``benchmarks/`` folder: ``$RBJAX_BENCHMARKS`` if set, else the one next to the ``rbjax`` package.

    In a source checkout (or an editable install) that is the repository's folder; an installed
    wheel has none, since the benchmarks are scripts with their own heavy dependencies (the
    ``bench`` extra), shipped in the source repository and the sdist, not in the wheel.
    """
    env = os.environ.get("RBJAX_BENCHMARKS")
    return Path(env).expanduser().resolve() if env else Path(__file__).resolve().parent.parent / "benchmarks"


def _scripts() -> list[Path]:
    d = benchmarks_dir()
    if not d.is_dir():
        raise CLIError(
            f"no benchmarks folder at {d}. The benchmarks live in benchmarks/ of the rbjax source repository "
            "(and of its sdist, rbjax-VERSION.tar.gz), not in the installed wheel: run 'python -m rbjax bench' "
            "from a checkout, or point RBJAX_BENCHMARKS at that folder (their dependencies: pip install 'rbjax[bench]')"
        )
    return sorted(p for p in d.glob("*.py") if not p.name.startswith("_"))


def _demo(argv: list[str]) -> int:
    from . import _demo

    return int(_demo.main(argv) or 0)


def _bench(args: argparse.Namespace) -> int:
    scripts = _scripts()
    if args.list:
        for p in scripts:
            print(p.stem)
        return 0
    if args.names:
        by_name = {p.stem: p for p in scripts}
        unknown = [n for n in args.names if n.removesuffix(".py") not in by_name]
        if unknown:
            raise CLIError(f"unknown benchmark(s) {unknown}; available: {sorted(by_name)}")
        scripts = [by_name[n.removesuffix(".py")] for n in args.names]
    if not scripts:
        raise CLIError(f"no benchmark scripts in {benchmarks_dir()}")
    failed = []
    for p in scripts:
        cmd = [sys.executable, str(p)] + (["--quick"] if args.quick else [])
        print(f"== {p.stem}: {' '.join(cmd[1:])}", flush=True)
        if subprocess.run(cmd, check=False).returncode != 0:
            failed.append(p.stem)
    if failed:
        raise CLIError(f"benchmark(s) failed: {failed}")
    return 0


def _read_recording(path: Path) -> dict:
    """times (T,), quaternions (T, 4) [w, x, y, z], optional gyro (T, 3) and torques (T, 3).

    NPZ: arrays named ``times``, ``quaternions`` and optionally ``gyro``, ``torques``.
    CSV (header row): ``t, qw, qx, qy, qz`` and optionally ``gx, gy, gz`` (body rad/s)
    and ``tx, ty, tz`` (world N m).
    """
    import numpy as np

    if not path.exists():
        raise CLIError(f"no such file: {path}")
    if path.suffix == ".npz":
        with np.load(path) as z:
            missing = {"times", "quaternions"} - set(z.files)
            if missing:
                raise CLIError(f"{path}: missing arrays {sorted(missing)} (found {z.files})")
            return {
                k: np.asarray(z[k], np.float64) for k in ("times", "quaternions", "gyro", "torques") if k in z.files
            }
    if path.suffix == ".csv":
        data = np.genfromtxt(path, delimiter=",", names=True)
        cols = [c.strip().lower() for c in (data.dtype.names or ())]
        need = ["t", "qw", "qx", "qy", "qz"]
        if any(c not in cols for c in need):
            raise CLIError(f"{path}: CSV needs columns {need} (found {cols})")
        raw = data.dtype.names or ()
        col = lambda names: np.stack([np.asarray(data[raw[cols.index(n)]], np.float64) for n in names], -1)  # noqa: E731
        rec = {"times": col(["t"])[:, 0], "quaternions": col(["qw", "qx", "qy", "qz"])}
        if all(c in cols for c in ("gx", "gy", "gz")):
            rec["gyro"] = col(["gx", "gy", "gz"])
        if all(c in cols for c in ("tx", "ty", "tz")):
            rec["torques"] = col(["tx", "ty", "tz"])
        return rec
    raise CLIError(f"{path}: expected a .csv or .npz recording")


def _fit(args: argparse.Namespace) -> int:
    import json

    import jax
    import numpy as np

    jax.config.update("jax_enable_x64", True)
    from . import fit_inertia

    rec = _read_recording(Path(args.recording))
    try:
        res = fit_inertia(rec["times"], rec["quaternions"], body_rates=rec.get("gyro"), torques=rec.get("torques"))
    except ValueError as e:
        raise CLIError(str(e)) from e
    I = np.asarray(res.inertia)
    out = {
        "inertia": I.tolist(),
        "principal_moments": np.asarray(res.principal_moments).tolist(),
        "moment_std": np.asarray(res.moment_std).tolist(),
        "principal_axes": np.asarray(res.principal_axes).tolist(),
        "scale_fixed": bool(res.scale_fixed),
        "converged": bool(res.converged),
        "iterations": int(res.iterations),
        "orientation_rms_rad": float(res.orientation_rms),
    }
    unit = "kg m²" if out["scale_fixed"] else "normalised to trace 1 (no torques: scale not identifiable)"
    print(f"inertia ({unit}), body frame:")
    for row in I:
        print("  [" + "  ".join(f"{v: .6e}" for v in row) + "]")
    print(
        "principal moments: "
        + ", ".join(f"{m:.6e} ± {s:.1e}" for m, s in zip(out["principal_moments"], out["moment_std"]))
    )
    print(
        f"converged: {out['converged']} after {out['iterations']} iterations; "
        f"orientation rms {out['orientation_rms_rad']:.2e} rad"
    )
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=1))
        print(f"saved: {args.out}")
    return 0 if out["converged"] else 1


def build_parser() -> argparse.ArgumentParser:
    """The ``argparse`` parser of ``python -m rbjax`` (subcommands demo, bench, fit)."""
    common = _Parser(add_help=False)
    common.add_argument("--debug", action="store_true", help="show the full traceback on errors")
    parser = _Parser(
        prog="python -m rbjax",
        parents=[common],
        description="rbjax: batched, differentiable rigid-body dynamics in JAX.",
    )
    sub = parser.add_subparsers(dest="command", metavar="{demo,bench,fit}", parser_class=_Parser)
    sub.required = True

    # listed for --help only: main() hands everything after 'demo' to the demo's own parser
    # (argparse.REMAINDER would not pass on leading options such as --bodies)
    sub.add_parser("demo", help="run the README demo: tumbling boxes and a T-handle ('demo --help')")

    bench = sub.add_parser(
        "bench",
        parents=[common],
        help="run the benchmarks in benchmarks/",
        description=f"Run benchmark scripts from {benchmarks_dir()}.",
    )
    bench.add_argument("names", nargs="*", help="benchmark names (file stems); default: all")
    bench.add_argument("--quick", action="store_true", help="small sizes, for a smoke run")
    bench.add_argument("--list", action="store_true", help="list the benchmarks and exit")
    bench.set_defaults(func=_bench)

    fit = sub.add_parser(
        "fit",
        parents=[common],
        help="fit an inertia tensor to recorded motion",
        description="Fit an inertia tensor to recorded motion. " + (_read_recording.__doc__ or ""),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    fit.add_argument("recording", help="a .csv or .npz recording (see above)")
    fit.add_argument("--out", default=None, help="write the result as JSON to this path")
    fit.set_defaults(func=_fit)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m rbjax``; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    try:
        rest = [a for a in argv if a != "--debug"]
        if rest[:1] == ["demo"]:
            return _demo(rest[1:])
        args = build_parser().parse_args(argv)
        return args.func(args)
    except KeyboardInterrupt:
        print("rbjax: interrupted", file=sys.stderr)
        return 130
    except Exception as e:
        if debug:
            raise
        text = " ".join(str(e).split()) or type(e).__name__
        kind = "" if isinstance(e, CLIError) else f"{type(e).__name__}: "
        print(f"rbjax: error: {kind}{text}", file=sys.stderr)
        return 2
