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

from ._cli_common import CLIError, Parser
from ._cli_fit import add_fit_parser

__all__ = ["main", "benchmarks_dir"]


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


def build_parser() -> argparse.ArgumentParser:
    """The ``argparse`` parser of ``python -m rbjax`` (subcommands demo, bench, fit)."""
    common = Parser(add_help=False)
    common.add_argument("--debug", action="store_true", help="show the full traceback on errors")
    parser = Parser(
        prog="python -m rbjax",
        parents=[common],
        description="rbjax: batched, differentiable rigid-body dynamics in JAX.",
    )
    sub = parser.add_subparsers(dest="command", metavar="{demo,bench,fit}", parser_class=Parser)
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

    add_fit_parser(sub, common)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m rbjax``; returns the exit status.

    Called with ``argv=None`` (the process's own command line) ``fit`` also turns
    on the persistent compilation cache (:func:`._cli_common.compile_cache_dir`).
    """
    entry = argv is None
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    try:
        rest = [a for a in argv if a != "--debug"]
        if rest[:1] == ["demo"]:
            return _demo(rest[1:])
        args = build_parser().parse_args(argv)
        args.compile_cache = entry  # the process's own command line: programs may be kept on disk
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
