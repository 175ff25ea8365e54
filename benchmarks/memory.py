"""Peak memory of ``Scene.simulate`` against the number of bodies N and ``save_every``.

Each configuration runs in a fresh process (``ru_maxrss`` is a per-process
peak) with float32 spheres under gravity, and reports

* ``state_MB``: the initial state (bodies included) as built on the host;
* ``traj_MB``: the returned trajectory (``steps // save_every + 1`` frames);
* ``xla_args_MB / xla_out_MB / xla_temp_MB``: the compiled program's
  ``memory_analysis()`` (arguments, outputs, scratch);
* ``peak_rss_MB``: the process's peak resident memory, end to end;
  ``state_peak_MB`` / ``scene_peak_MB``: the peak above the runtime's own
  memory (``base_rss_MB``, after importing JAX) once the state is built and
  once ``Scene.build`` has run;
* ``peak_over_data``: ``(peak - base) / (state + trajectory)``, the
  measure (target ≤ 2): the trajectory as returned, bodies and time per frame included.

    python benchmarks/memory.py [--quick] [--full]     # --full adds N = 1e7

``--quick`` (< 30 s) uses N up to 1e5; the default goes to 1e6; ``--full``
runs the 1e7-body case (200 Euler steps, save_every = 100).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))


def _rss_MB() -> tuple[float, float]:
    """(current, peak so far) resident memory of this process, MB."""
    with open("/proc/self/statm") as f:
        current = int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6
    return current, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3


def one(n: int, steps: int, save_every: int, method: str) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    import rbjax as rb
    from rbjax import _simulate

    jnp.zeros(1).block_until_ready()  # the runtime's own memory, before any data
    base_MB, _ = _rss_MB()
    rng = np.random.default_rng(0)
    m = jnp.full((n,), 1.0, jnp.float32)
    v = jnp.asarray(rng.normal(size=(n, 3)).astype(np.float32))
    state = rb.State.create(rb.sphere(m, jnp.float32(0.3)), velocity=v, angular_velocity=v)
    del m, v
    after_state = _rss_MB()
    scene = rb.Scene.build(state, rb.Gravity(), method)
    after_scene = _rss_MB()
    nbytes = lambda tree: sum(a.nbytes for a in jax.tree.leaves(tree))
    # the compiled program's own accounting (private entry point: a failure is a bug in this script)
    c = (
        _simulate._simulate.lower(
            state,
            scene.forces,
            jnp.asarray(1e-3),
            jnp.asarray(0.0),
            jnp.asarray(0),
            steps=steps,
            method=scene.kernel,
            save_every=save_every,
            series=False,
            force_fn=None,
            checks=None,
            checkpoint=None,
            native=False,
        )
        .compile()
        .memory_analysis()
    )
    analysis = dict(
        xla_args_MB=c.argument_size_in_bytes / 1e6,
        xla_out_MB=c.output_size_in_bytes / 1e6,
        xla_temp_MB=c.temp_size_in_bytes / 1e6,
    )
    t = time.perf_counter()
    traj = jax.block_until_ready(scene.simulate(state, 1e-3, steps, save_every=save_every))
    sec = time.perf_counter() - t
    ok = bool(jnp.all(jnp.isfinite(traj.position[-1])))
    state_MB, traj_MB = nbytes(state) / 1e6, nbytes(traj) / 1e6
    peak = _rss_MB()[1]
    return dict(
        n=n,
        steps=steps,
        save_every=save_every,
        method=method,
        frames=int(traj.position.shape[0]),
        state_MB=state_MB,
        traj_MB=traj_MB,
        **analysis,
        seconds=sec,
        finite=ok,
        base_rss_MB=base_MB,
        state_rss_MB=after_state[0] - base_MB,
        state_peak_MB=after_state[1] - base_MB,
        scene_peak_MB=after_scene[1] - base_MB,
        peak_rss_MB=peak,
        # the target: at most 2 (state + bodies + saved frames) above the runtime's own memory
        peak_over_data=(peak - base_MB) / (state_MB + traj_MB),
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--full", action="store_true", help="also N = 1e7 (minutes, ~several GB)")
    ap.add_argument("--one", nargs=4, metavar=("N", "STEPS", "SAVE_EVERY", "METHOD"), help=argparse.SUPPRESS)
    ap.add_argument("--out", default=os.path.join(HERE, "results", "memory.json"))
    args = ap.parse_args()
    if args.one:
        n, steps, every, method = args.one
        print("RESULT " + json.dumps(one(int(n), int(steps), int(every), method)))
        return
    if args.quick:
        configs = [(10_000, 20, 20), (100_000, 20, 20), (100_000, 20, 1)]
    else:
        configs = [
            (10_000, 100, 100),
            (100_000, 100, 100),
            (1_000_000, 100, 100),
            (1_000_000, 100, 10),
            (1_000_000, 100, 1),
        ]
    if args.full:
        configs.append((10_000_000, 200, 100))
    rows = []
    cols = [
        "n",
        "steps",
        "save_every",
        "frames",
        "state_MB",
        "traj_MB",
        "xla_args_MB",
        "xla_out_MB",
        "xla_temp_MB",
        "state_peak_MB",
        "scene_peak_MB",
        "peak_rss_MB",
        "peak_over_data",
        "seconds",
    ]
    print(" ".join(f"{c:>11s}" for c in cols))
    env = dict(os.environ, PYTHONPATH=os.path.dirname(HERE) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    for n, steps, every in configs:
        out = subprocess.run(
            [sys.executable, __file__, "--one", str(n), str(steps), str(every), "euler"],
            env=env,
            capture_output=True,
            text=True,
        )
        line = [x for x in out.stdout.splitlines() if x.startswith("RESULT ")]
        if not line:
            print(f"N={n} failed:\n{out.stderr[-2000:]}")
            continue
        r = json.loads(line[0][7:])
        rows.append(r)
        print(
            " ".join(
                f"{r.get(c, float('nan')):11.1f}" if isinstance(r.get(c), float) else f"{r.get(c, '-'):>11}"
                for c in cols
            )
        )
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(rows, f, indent=1)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
