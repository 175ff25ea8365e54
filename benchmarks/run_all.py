"""Run every benchmark script in ``benchmarks/`` (``python -m rbjax bench`` calls this).

    python benchmarks/run_all.py            # full runs (many minutes)
    python benchmarks/run_all.py --quick    # each script's --quick mode (< 1 minute each)
    python benchmarks/run_all.py --list     # the scripts it would run

A benchmark is any ``benchmarks/*.py`` not starting with ``_`` (helpers) and not
this file; each must accept ``--quick``. Each runs in its own process (a fresh
JAX, no state shared between benchmarks); the exit status is non-zero if any failed.
"""

from __future__ import annotations

import argparse
import glob
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))


def scripts() -> list[str]:
    return sorted(
        p
        for p in glob.glob(os.path.join(HERE, "*.py"))
        if not os.path.basename(p).startswith("_") and os.path.basename(p) != "run_all.py"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="run each benchmark's --quick mode")
    ap.add_argument("--list", action="store_true", help="list the benchmark scripts and exit")
    args = ap.parse_args(argv)
    if args.list:
        print("\n".join(scripts()))
        return 0
    failed = []
    for path in scripts():
        cmd = [sys.executable, path] + (["--quick"] if args.quick else [])
        print(f"==> {' '.join(cmd)}", flush=True)
        t0 = time.perf_counter()
        rc = subprocess.call(cmd, cwd=os.path.dirname(HERE))
        print(f"<== {os.path.basename(path)}: exit {rc} in {time.perf_counter() - t0:.0f} s", flush=True)
        if rc:
            failed.append(os.path.basename(path))
    if failed:
        print(f"failed: {', '.join(failed)}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
