"""Throughput of two checkouts of rbjax side by side: did a change slow the step?

Runs ``rbjax.simulate`` (torque-free boxes, each with its own mass properties,
only the final state saved: ``save_every = steps``) for each method, dtype and N
in a fresh subprocess per measurement, alternating the two checkouts (A B A B
...) so that slow drift of the machine affects both alike, and reports the
best body-steps per second of each and their ratio ``new / base``.

    python benchmarks/ab_throughput.py --base 1f075bb            # base = a git revision
    python benchmarks/ab_throughput.py --quick                   # N = 1e4, euler, JAX path, against HEAD
    python benchmarks/ab_throughput.py --base 1f075bb --path jax # simulate(native=False) on both

The base revision is checked out into a temporary git worktree (removed at the
end); the new side is this checkout. ``--quick`` (what ``python -m rbjax bench
--quick`` runs) is a smoke run: the working tree against ``HEAD`` unless
``--base`` is given, on the JAX path unless ``--path`` is (no kernels to build
for the base), and nothing saved unless ``--out`` is given.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

CHILD = r"""
import json, sys, time
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
import rbjax as rb
method, dtype, n, steps = sys.argv[1], getattr(jnp, sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
native = {"default": None, "jax": False, "native": True}[sys.argv[5]]
rng = np.random.default_rng(0)
q = rng.normal(size=(n, 4)); q /= np.linalg.norm(q, axis=1, keepdims=True)
body = rb.box(jnp.asarray(rng.uniform(0.5, 2, n), dtype), jnp.asarray(rng.uniform(0.1, 1, (n, 3)), dtype))
w = jnp.asarray(rng.normal(size=(n, 3)), dtype)
s = rb.State.create(body, orientation=jnp.asarray(q, dtype), angular_velocity=w)
run = jax.jit(lambda s: rb.simulate(s, None, 1e-3, steps, method, save_every=steps, native=native))
jax.block_until_ready(run(s))
best = float("inf")
for _ in range(5):
    t = time.perf_counter(); jax.block_until_ready(run(s)); best = min(best, time.perf_counter() - t)
print(json.dumps({"rate": n * steps / best}))
"""


def measure(src: str, method: str, dtype: str, n: int, steps: int, path: str) -> float:
    env = dict(os.environ, PYTHONPATH=src, JAX_PLATFORMS="cpu")
    out = subprocess.run(
        [sys.executable, "-c", CHILD, method, dtype, str(n), str(steps), path],
        env=env,
        cwd=src,
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])["rate"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", help="git revision to compare against (--quick: HEAD)")
    ap.add_argument("--methods", default="euler,splitting,rk4")
    ap.add_argument("--dtypes", default="float32,float64")
    ap.add_argument("--sizes", default="10000,100000,1000000")
    ap.add_argument("--repeats", type=int, default=3, help="A/B pairs per configuration")
    ap.add_argument("--steps", type=int, default=None, help="steps per run (default: 2e7 body-steps / N)")
    ap.add_argument(
        "--path",
        choices=["default", "jax", "native"],
        help="simulate's native=None / False / True on both sides (the base's kernels are built for it; "
        "default: default, --quick: jax)",
    )
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", help="JSON to write (default results/ab_throughput.json; --quick: none)")
    args = ap.parse_args(argv)
    if args.quick:
        args.methods, args.dtypes, args.sizes, args.repeats = "euler", "float32", "10000", 1
        args.base, args.path = args.base or "HEAD", args.path or "jax"
    elif args.base is None:
        ap.error("--base is required: the git revision to compare this checkout against (e.g. --base HEAD~1)")
    else:
        args.path, args.out = args.path or "default", args.out or os.path.join(HERE, "results", "ab_throughput.json")
    work = tempfile.mkdtemp(prefix="rbjax_base_")
    add = subprocess.run(
        ["git", "-C", ROOT, "worktree", "add", "--detach", work, args.base], capture_output=True, text=True
    )
    if add.returncode:
        print(f"ab_throughput: cannot check out {args.base!r} (it needs a git checkout of rbjax): {add.stderr.strip()}")
        return 2
    if args.path != "jax":  # the kernels are git-ignored build outputs: the base's own, built from its sources
        build = [sys.executable, "setup.py", "-q", "build_ext", "--inplace"]
        subprocess.run(build, cwd=work, check=True, capture_output=True)
    rows = []
    try:
        for method in args.methods.split(","):
            for dtype in args.dtypes.split(","):
                for n in (int(x) for x in args.sizes.split(",")):
                    steps = args.steps or (max(20, int(2e8 // n // 10)) if not args.quick else 50)
                    base, new = [], []
                    for _ in range(args.repeats):  # A B A B ...
                        base.append(measure(work, method, dtype, n, steps, args.path))
                        new.append(measure(ROOT, method, dtype, n, steps, args.path))
                    row = dict(method=method, dtype=dtype, n=n, steps=steps, base=max(base), new=max(new))
                    row["ratio"] = row["new"] / row["base"]
                    rows.append(row)
                    print(
                        f"{method:>10} {dtype} N={n:>8}: base {row['base']:.3e}  new {row['new']:.3e}  "
                        f"new/base {row['ratio']:.3f}",
                        flush=True,
                    )
    finally:
        subprocess.run(["git", "-C", ROOT, "worktree", "remove", "--force", work], capture_output=True)
    if args.out:
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        with open(args.out, "w") as f:
            json.dump({"base": args.base, "path": args.path, "rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
