"""Throughput and scale: body-steps per second from 1 to 1e6 bodies, peers side by side, roofline.

For each N (bodies), dtype and method in ``rbjax.methods(rbjax.State)`` (found at
run time): body-steps per second of a compiled ``rbjax.simulate`` (lax.scan,
only the final state saved; torque-free free bodies, each with its own mass
properties), first-call compile time, and the executable's peak memory (XLA's
``memory_analysis``: arguments + outputs + temporaries). Beside it, where
installed:

* ``numpy``: the same explicit-Euler step in NumPy on structure-of-arrays data
  ((3, N) arrays, vector ops);
* ``numba-limit``: the hand-written limit, the same Euler as one fused,
  multi-threaded Numba loop (``benchmarks/_numba_limit.py``, the ``bench``
  extra), checked against rbjax's step to round-off, with ``rbjax-forces-jax``
  and ``rbjax-forces-native``: rbjax's euler on that loop's data (zero force
  and torque arrays read every step) through the JAX steps and the native
  kernel, for N ≥ 1e4;
* ``rbjax-native``: each method with a native kernel (``rbjax.native_status()``)
  through it, beside the JAX path (``rbjax``, ``native=False``), and both with
  gravity and quadratic drag (``+forces``) for N ≥ 1e4;
* ``mujoco``: MuJoCo's C engine (``mj_step``) on ONE model of N free bodies
  (freejoint, box geoms, contact and constraint disabled, gravity off, the same
  dt), with its ``Euler`` (semi-implicit) and ``RK4`` integrators; float64 (MuJoCo's
  only precision);
* ``mjx``: MuJoCo XLA on this CPU, ``vmap`` of ``mjx.step`` over N worlds of one
  free body each. Not one model of N bodies: MJX's mass-matrix path is dense in
  the degrees of freedom (nv = 6N), so that scales as N² and runs out of memory
  by N ~ 1e4; batching worlds is how MJX is meant to be used.

The roofline: the machine's memory bandwidth is measured (a large JAX triad
``c = a + s b`` and a NumPy copy), as is its attainable FLOP rate (a fused
chain of multiply-adds on cache-resident data). For each method the time per
body-step is compared with ``max(bytes / bandwidth, flops / flop rate)``, where
bytes = state read and written (13 values each) + the inverse inertia read
(9 values), and flops come from XLA's cost analysis of one step.

    python benchmarks/throughput.py            # full: N up to 1e6 (minutes)
    python benchmarks/throughput.py --quick    # < 1 minute, checks it runs
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)  # allow float64 rows; float32 rows ask for it

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _numba_limit  # noqa: E402
from _common import best_time, compile_timed, machine, peak_rss_mb, write_json  # noqa: E402

import rbjax as rb  # noqa: E402

DT = 1e-3
STATE_VALUES, PARAM_VALUES = 13, 9  # (x, v, q, L) read and written; I_L⁻¹ read
NATIVE = rb.native_status().methods if rb.native_status().available else ()
SCENE_FORCES = rb.Gravity() + rb.QuadraticDrag(0.05, 0.01)  # the forces every real scene has


def make_state(n: int, dtype) -> rb.State:
    rng = np.random.default_rng(0)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    body = rb.box(rng.uniform(0.5, 2, n).astype(dtype), rng.uniform(0.1, 1, (n, 3)).astype(dtype))
    return rb.State.create(
        body,
        orientation=q.astype(dtype),
        angular_velocity=rng.normal(size=(n, 3)).astype(dtype),
        velocity=rng.normal(size=(n, 3)).astype(dtype),
    )


# ----------------------------------------------------------------------------- rbjax


def time_rbjax(state, method: str, steps: int, dt: float = DT, native: bool | None = False, forces=None) -> dict:
    f = jax.jit(lambda s: rb.simulate(s, forces, dt, steps, method, save_every=steps, native=native))
    compiled, t_compile = compile_timed(f, state)
    jax.block_until_ready(compiled(state))
    t = best_time(compiled, state)
    mem = compiled.memory_analysis()
    peak = None
    if mem is not None:
        peak = (
            mem.argument_size_in_bytes + mem.output_size_in_bytes + mem.temp_size_in_bytes - mem.alias_size_in_bytes
        ) / 2**20
    return dict(seconds=t, compile_s=t_compile, peak_mb=peak)


def step_cost(method: str, dtype, n: int = 1024) -> dict:
    """XLA's flop and byte counts of one step, per body."""
    s = make_state(n, dtype)
    ca = jax.jit(lambda s: rb.step(s, None, DT, method)).lower(s).compile().cost_analysis()
    ca = ca[0] if isinstance(ca, list) else ca
    return dict(
        flops=ca.get("flops", 0.0) / n,
        transcendentals=ca.get("transcendentals", 0.0) / n,
        xla_bytes=ca.get("bytes accessed", 0.0) / n,
    )


# ----------------------------------------------------------------------------- NumPy


def numpy_euler_soa(x, v, q, L, Iinv, dt, steps):
    """The same explicit Euler (L-form, torque-free) in NumPy, components along axis 0."""

    def rot(qw, qv, a):
        t = 2 * np.cross(qv, a, axis=0)
        return a + qw * t + np.cross(qv, t, axis=0)

    for _ in range(steps):
        qw, qv = q[0], q[1:]
        lb = rot(qw, -qv, L)
        wb = np.einsum("ijn,jn->in", Iinv, lb)
        w = rot(qw, qv, wb)
        dq = np.empty_like(q)
        dq[0] = -np.sum(w * qv, axis=0)
        dq[1:] = qw * w + np.cross(w, qv, axis=0)
        x = x + v * dt
        q = q + 0.5 * dt * dq
        q = q / np.sqrt(np.sum(q * q, axis=0))
    return x, v, q, L


def jax_euler_soa(x, v, q, L, Iinv, dt, steps):
    """``numpy_euler_soa`` in jax.numpy: a hand-written SoA kernel, the layout's ceiling for XLA."""

    def rot(qw, qv, a):
        t = 2 * jnp.cross(qv, a, axis=0)
        return a + qw * t + jnp.cross(qv, t, axis=0)

    def one(_, c):
        x, q = c
        qw, qv = q[0], q[1:]
        wb = jnp.einsum("ijn,jn->in", Iinv, rot(qw, -qv, L))
        w = rot(qw, qv, wb)
        dq = jnp.concatenate([-jnp.sum(w * qv, axis=0, keepdims=True), qw * w + jnp.cross(w, qv, axis=0)])
        q = q + 0.5 * dt * dq
        return x + v * dt, q * jax.lax.rsqrt(jnp.sum(q * q, axis=0))

    return jax.lax.fori_loop(0, steps, one, (x, q))


def time_jax_soa(state, steps, dt=DT):
    arrs = [
        jnp.asarray(np.asarray(a).T.copy())
        for a in (state.position, state.velocity, state.orientation, state.angular_momentum)
    ]
    Iinv = jnp.asarray(np.moveaxis(np.asarray(state.body.inverse_inertia), 0, -1).copy())
    f = jax.jit(lambda x, v, q, L, Iinv: jax_euler_soa(x, v, q, L, Iinv, x.dtype.type(dt), steps))
    compiled, _ = compile_timed(f, *arrs, Iinv)
    jax.block_until_ready(compiled(*arrs, Iinv))
    return best_time(compiled, *arrs, Iinv)


def time_numpy(state, steps, dt=DT):
    arrs = [np.asarray(a).T.copy() for a in (state.position, state.velocity, state.orientation, state.angular_momentum)]
    Iinv = np.moveaxis(np.asarray(state.body.inverse_inertia), 0, -1).copy()
    return best_time(lambda: numpy_euler_soa(*arrs, Iinv, arrs[0].dtype.type(dt), steps), repeats=2)


# ----------------------------------------------------------------------------- MuJoCo / MJX


def mujoco_xml(n: int, integrator: str) -> str:
    bodies = "".join(
        f'<body pos="{i % 100} {i // 100 % 100} {i // 10000}"><freejoint/>'
        f'<geom type="box" size=".1 .2 .3" mass="1"/></body>'
        for i in range(n)
    )
    return (
        f'<mujoco><option timestep="{DT}" integrator="{integrator}" gravity="0 0 0">'
        '<flag contact="disable" constraint="disable"/></option>'
        # the default arena runs out by N ~ 1e4 free bodies; ~10 kB per body is ample
        f'<size memory="{max(16, n // 100)}M"/>'
        f"<worldbody>{bodies}</worldbody></mujoco>"
    )


def time_mujoco(n: int, integrator: str, steps: int) -> dict:
    import mujoco

    t0 = time.perf_counter()
    m = mujoco.MjModel.from_xml_string(mujoco_xml(n, integrator))
    t_build = time.perf_counter() - t0
    d = mujoco.MjData(m)
    d.qvel[:] = np.random.default_rng(0).normal(size=m.nv)
    mujoco.mj_step(m, d, nstep=2)
    t = best_time(lambda: mujoco.mj_step(m, d, nstep=steps), repeats=3)
    return dict(seconds=t, compile_s=t_build)


def time_mjx(n: int, steps: int) -> dict:
    import mujoco
    from mujoco import mjx

    m = mujoco.MjModel.from_xml_string(mujoco_xml(1, "Euler"))
    d = mujoco.MjData(m)
    mx = mjx.put_model(m)
    dx = mjx.put_data(m, d)
    qvel = jnp.asarray(np.random.default_rng(0).normal(size=(n, m.nv)), dx.qvel.dtype)
    batch = jax.vmap(lambda v: dx.replace(qvel=v))(qvel)

    @jax.jit
    def run(mx, batch):
        return jax.lax.fori_loop(0, steps, lambda _, b: jax.vmap(mjx.step, in_axes=(None, 0))(mx, b), batch)

    compiled, t_compile = compile_timed(run, mx, batch)
    jax.block_until_ready(compiled(mx, batch))
    return dict(seconds=best_time(compiled, mx, batch, repeats=2), compile_s=t_compile, dtype=str(dx.qvel.dtype))


# ----------------------------------------------------------------------------- roofline


def measure_machine(quick: bool) -> dict:
    """Memory bandwidth (bytes/s) from large copies and the attainable elementwise FLOP rate."""
    n = (8 if quick else 32) * 2**20  # float32 elements per array: 32 MiB (quick) / 128 MiB
    a = jnp.ones(n, jnp.float32)
    b = jnp.full(n, 2.0, jnp.float32)
    # ten triads in one call: the loop carry's buffer is reused, so the figure is not the page-fault cost of
    # a fresh 128 MiB output per call
    reps = 10
    triad = jax.jit(lambda a, b: jax.lax.fori_loop(0, reps, lambda _, c: c * 0.5 + b, a))
    jax.block_until_ready(triad(a, b))
    bw_jax = reps * 3 * 4 * n / best_time(triad, a, b, repeats=3)
    x = np.ones(n, np.float32)
    y = np.empty_like(x)
    bw_np = 2 * 4 * n / best_time(lambda: np.copyto(y, x), repeats=5)
    del a, b

    # 64 dependent FMAs per element, fused into one loop by XLA, over a cache-resident array on a CPU;
    # a GPU needs millions of elements to fill its cores, or the figure is one launch's latency
    m, chain = (2**16 if jax.default_backend() == "cpu" else 2**26), 64
    z = jnp.linspace(0.0, 1.0, m, dtype=jnp.float32)

    def fmas(z):
        for _ in range(chain):
            z = z * 0.999 + 0.001
        return z

    f = jax.jit(fmas)
    jax.block_until_ready(f(z))
    flops = 2 * chain * m / best_time(f, z, repeats=10)
    return dict(
        bandwidth_Bps=max(bw_jax, bw_np),
        bandwidth_jax_triad_Bps=bw_jax,
        bandwidth_numpy_copy_Bps=bw_np,
        flops_per_s=flops,
        array_mib=4 * n / 2**20,
    )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="small sizes, < 1 minute")
    p.add_argument(
        "--methods", default="all", help="comma-separated rbjax methods (default: all registered; --quick: euler,rk4)"
    )
    p.add_argument("--no-peers", action="store_true", help="skip MuJoCo and MJX")
    p.add_argument("--dtypes", default=None, help="comma-separated, e.g. float32 (default: float32,float64)")
    p.add_argument("--json", default=None, help="output (default results/throughput[_quick].json)")
    p.add_argument("--sizes", default=None, help="comma-separated N, e.g. 10000,100000 (default: 1 ... 1e6)")
    args = p.parse_args(argv)
    if args.json is None:
        name = "throughput_quick.json" if args.quick else "throughput.json"
        args.json = os.path.join(ROOT, "benchmarks", "results", name)
    sizes = [100, 10_000] if args.quick else [1, 10, 100, 1_000, 10_000, 100_000, 1_000_000]
    if args.sizes:
        sizes = [int(float(n)) for n in args.sizes.split(",")]
    # --quick checks that the benchmark runs: two methods, not every method's compile time
    methods = (["euler", "rk4"] if args.quick else list(rb.methods(rb.State))) if args.methods == "all" else None
    methods = methods or args.methods.split(",")
    dtypes = [np.float32] if args.quick else [np.float32, np.float64]
    if args.dtypes:
        dtypes = [np.dtype(d).type for d in args.dtypes.split(",")]
    budget = 1e6 if args.quick else 2e7  # body-steps per timed run
    peers = {}
    if not args.no_peers:
        for mod in ("mujoco", "mujoco.mjx"):
            try:
                __import__(mod)
                peers[mod] = True
            except Exception as e:  # noqa: BLE001  (an optional peer may fail to import in many ways)
                print(f"{mod} unavailable ({type(e).__name__}: {e}); pip install -e '.[bench]'")
    if not _numba_limit.available():
        print("numba unavailable: no hand-written limit column; pip install -e '.[bench]'")
    mj_sizes = [n for n in sizes if n <= (100 if args.quick else 10_000)]
    # MJX on CPU runs 1e5-1e6 body-steps/s: N = 1e4 took minutes to time and its rate had flattened by 1e3
    mjx_sizes = [] if args.quick else [n for n in sizes if n <= 1_000]

    hw = measure_machine(args.quick)
    print(
        f"memory bandwidth {hw['bandwidth_Bps'] / 1e9:.1f} GB/s "
        f"(jax triad {hw['bandwidth_jax_triad_Bps'] / 1e9:.1f}, "
        f"numpy copy {hw['bandwidth_numpy_copy_Bps'] / 1e9:.1f}); "
        f"attainable {hw['flops_per_s'] / 1e9:.1f} GFLOP/s",
        flush=True,
    )
    costs = {(m, np.dtype(d).name): step_cost(m, d) for m in methods for d in dtypes}

    rows = []

    def checkpoint():
        # the rows so far, after every size: a run cut short (a device lease, a time limit) keeps them
        if args.json:
            write_json(args.json, dict(machine=machine(), hardware=hw, quick=args.quick, rows=rows, partial=True))

    for dtype in dtypes:
        dname = np.dtype(dtype).name
        for n in sizes:
            # at least 100 steps per call (as the goals are measured): below that, at N = 1e6 the call's
            # fixed work (the trajectory's two frames, a body per frame: ~0.12 s) outweighs the steps
            steps = int(max(4 if args.quick else 100, min(2000, budget // n)))
            state = make_state(n, dtype)
            # NumPy's rate per step is flat in the step count: ~2e6 body-steps time it (a 1e6 batch's 100
            # steps would take 15 s of a run whose point is rbjax)
            np_steps = max(2, min(steps, 50 if n < 1000 else int(2e6 // n)))
            t_np = time_numpy(state, np_steps) * steps / np_steps
            rows.append(
                dict(
                    engine="numpy",
                    method="euler",
                    dtype=dname,
                    bodies=n,
                    steps=steps,
                    body_steps_per_s=n * steps / t_np,
                )
            )
            if n >= 1000:
                t_js = time_jax_soa(state, steps)
                rows.append(
                    dict(
                        engine="jax-soa",
                        method="euler",
                        dtype=dname,
                        bodies=n,
                        steps=steps,
                        body_steps_per_s=n * steps / t_js,
                    )
                )
                print(
                    f"jax SoA euler (hand-written, (3, N) layout) {dname} N={n:>8}: "
                    f"{n * steps / t_js:.3e} body-steps/s",
                    flush=True,
                )
            if n >= 10_000 and _numba_limit.available():
                rows += _numba_limit.limit_rows(state, steps, DT, best_time)
            native_methods = [m for m in methods if m in NATIVE]
            for method in native_methods if n >= 1000 else []:
                for forces, label in ((None, ""), (SCENE_FORCES, "+forces")):
                    for engine, native in (("rbjax-native", True), ("rbjax", False)):
                        if label or native:  # the plain JAX rows come below
                            r = time_rbjax(state, method, steps, native=native, forces=forces)
                            rows.append(
                                dict(
                                    engine=engine + label,
                                    method=method,
                                    dtype=dname,
                                    bodies=n,
                                    steps=steps,
                                    body_steps_per_s=n * steps / r["seconds"],
                                    compile_s=r["compile_s"],
                                )
                            )
                            print(
                                f"{engine + label:>20} {method:>6} {dname} N={n:>8}: "
                                f"{n * steps / r['seconds']:.3e} body-steps/s, compile {r['compile_s']:.2f} s",
                                flush=True,
                            )
            for method in methods:
                r = time_rbjax(state, method, steps)
                itemsize = np.dtype(dtype).itemsize
                bytes_bs = (2 * STATE_VALUES + PARAM_VALUES) * itemsize
                c = costs[(method, dname)]
                t_bs = r["seconds"] / (n * steps)
                bound = max(bytes_bs / hw["bandwidth_Bps"], c["flops"] / hw["flops_per_s"])
                rows.append(
                    dict(
                        engine="rbjax",
                        method=method,
                        dtype=dname,
                        bodies=n,
                        steps=steps,
                        body_steps_per_s=n * steps / r["seconds"],
                        compile_s=r["compile_s"],
                        peak_mb=r["peak_mb"],
                        bytes_per_body_step=bytes_bs,
                        **c,
                        achieved_Bps=bytes_bs / t_bs,
                        roofline_s=bound,
                        roofline_fraction=bound / t_bs,
                    )
                )
                print(
                    f"rbjax {method:>20} {dname} N={n:>8}: {n * steps / r['seconds']:.3e} body-steps/s "
                    f"(numpy euler {n * steps / t_np:.2e}), compile {r['compile_s']:.2f} s, "
                    f"roofline {bound / t_bs:.0%}",
                    flush=True,
                )
            checkpoint()
    if "mujoco" in peers:
        for integ in ("Euler", "RK4"):
            for n in mj_sizes:
                steps = int(max(2, min(500, budget / 20 // n)))
                try:
                    r = time_mujoco(n, integ, steps)
                except Exception as e:  # noqa: BLE001  (a peer failing must not lose the rbjax rows)
                    print(f"mujoco {integ} N={n}: failed ({e})", flush=True)
                    continue
                rows.append(
                    dict(
                        engine="mujoco",
                        method=integ,
                        dtype="float64",
                        bodies=n,
                        steps=steps,
                        body_steps_per_s=n * steps / r["seconds"],
                        compile_s=r["compile_s"],
                    )
                )
                print(f"mujoco {integ:>5} N={n:>8}: {n * steps / r['seconds']:.3e} body-steps/s", flush=True)
    if "mujoco.mjx" in peers:
        for n in mjx_sizes:
            steps = int(max(2, min(100, 2e4 // n)))
            try:
                r = time_mjx(n, steps)
            except Exception as e:  # noqa: BLE001
                print(f"mjx N={n}: failed ({e})", flush=True)
                continue
            rows.append(
                dict(
                    engine="mjx",
                    method="Euler",
                    dtype=r["dtype"],
                    bodies=n,
                    steps=steps,
                    body_steps_per_s=n * steps / r["seconds"],
                    compile_s=r["compile_s"],
                )
            )
            print(
                f"mjx   Euler N={n:>8}: {n * steps / r['seconds']:.3e} body-steps/s, compile {r['compile_s']:.1f} s",
                flush=True,
            )

    goals = evaluate_goals(rows, hw, methods)
    md = table(rows, hw, goals)
    print(md)
    if args.json:
        write_json(
            args.json,
            dict(
                machine=machine(),
                hardware=hw,
                quick=args.quick,
                rows=rows,
                goals=goals,
                peak_rss_mb=peak_rss_mb(),
            ),
        )
        with open(args.json[: -len(".json")] + ".md", "w") as f:
            f.write(md)
        print(f"wrote {args.json} and .md")
    return 0


def _rate(rows, **kw):
    hits = [r["body_steps_per_s"] for r in rows if all(r.get(k) == v for k, v in kw.items())]
    return max(hits) if hits else None


def evaluate_goals(rows, hw, methods) -> dict:
    """The targets, at N = 1e5 float32 (or the largest N measured)."""
    ns = sorted({r["bodies"] for r in rows if r["engine"] == "rbjax"})
    n = 100_000 if 100_000 in ns else ns[-1]
    eu = _rate(rows, engine="rbjax", method="euler", dtype="float32", bodies=n)
    npy = _rate(rows, engine="numpy", dtype="float32", bodies=n)
    mj = [r for r in rows if r["engine"] == "mujoco" and r["method"] == "Euler"]
    mj_n = max((r["bodies"] for r in mj), default=None)
    mj_rate = _rate(rows, engine="mujoco", method="Euler", bodies=mj_n) if mj_n else None
    # euler's goals need its row: a run of other methods (--methods) leaves them None
    row = next(
        (
            r
            for r in rows
            if r["engine"] == "rbjax" and r["method"] == "euler" and r["dtype"] == "float32" and r["bodies"] == n
        ),
        None,
    )
    bw_frac = row["achieved_Bps"] / hw["bandwidth_Bps"] if row else None
    per_method = {}
    for m in methods:
        r = next(
            (
                r
                for r in rows
                if r["engine"] == "rbjax" and r["method"] == m and r["dtype"] == "float32" and r["bodies"] == n
            ),
            None,
        )
        if r:
            per_method[m] = dict(roofline_fraction=r["roofline_fraction"], met=r["roofline_fraction"] >= 0.5)
    # the target: euler at least 0.9x the hand-written loop at every N and dtype measured
    vs_limit = {}
    for r in rows:
        if r["engine"] == "numba-limit":
            for path in ("native", "jax"):
                ours = _rate(rows, engine=f"rbjax-forces-{path}", dtype=r["dtype"], bodies=r["bodies"])
                if ours:
                    ratio = ours / r["body_steps_per_s"]
                    vs_limit[f"{path} {r['dtype']} N={r['bodies']}"] = dict(ratio=ratio, target=0.9, met=ratio >= 0.9)
    # an eager call (every check on each call) against the same call under jit, N >= 1e4
    eager_vs_jit = {}
    for r in rows:
        if r["engine"] == "rbjax-forces-eager" and r["bodies"] >= 10_000:
            compiled = _rate(rows, engine="rbjax-forces-native", dtype=r["dtype"], bodies=r["bodies"])
            compiled = compiled or _rate(rows, engine="rbjax-forces-jax", dtype=r["dtype"], bodies=r["bodies"])
            if compiled:
                slowdown = compiled / r["body_steps_per_s"]
                eager_vs_jit[f"{r['dtype']} N={r['bodies']}"] = dict(
                    slowdown=slowdown, target=1.25, met=slowdown <= 1.25
                )
    # native rk4 against native euler, and the forces' cost on each path (N = n, float32)
    native_goals = {}
    eu_nat = _rate(rows, engine="rbjax-native", method="euler", dtype="float32", bodies=n)
    for m in NATIVE:
        nat = _rate(rows, engine="rbjax-native", method=m, dtype="float32", bodies=n)
        nat_f = _rate(rows, engine="rbjax-native+forces", method=m, dtype="float32", bodies=n)
        jx = _rate(rows, engine="rbjax", method=m, dtype="float32", bodies=n)
        jx_f = _rate(rows, engine="rbjax+forces", method=m, dtype="float32", bodies=n)
        if nat and eu_nat and jx and jx_f and nat_f:
            native_goals[m] = dict(
                native_vs_jax=nat / jx,
                vs_native_euler=dict(ratio=nat / eu_nat, target=0.5, met=nat / eu_nat >= 0.5),
                native_forces_cost=dict(ratio=nat / nat_f, target=1.5, met=nat / nat_f <= 1.5),
                jax_with_forces=dict(ratio=jx_f / jx, target=0.5, met=jx_f / jx >= 0.5),
            )
    return dict(
        bodies=n,
        euler_vs_limit=vs_limit,
        eager_vs_jit=eager_vs_jit,
        euler_vs_numpy=dict(
            ratio=eu / npy if eu and npy else None, target=3.0, met=eu / npy >= 3.0 if eu and npy else None
        ),
        euler_vs_mujoco=dict(
            ratio=eu / mj_rate if mj_rate and eu else None,
            mujoco_bodies=mj_n,
            target=100.0,
            met=(eu / mj_rate >= 100.0) if mj_rate and eu else None,
        ),
        euler_bandwidth_fraction=dict(fraction=bw_frac, target=0.5, met=bw_frac >= 0.5 if bw_frac else None),
        methods_within_2x_of_roofline=per_method,
        native=native_goals,
    )


def table(rows, hw, goals) -> str:
    out = [
        f"Memory bandwidth {hw['bandwidth_Bps'] / 1e9:.1f} GB/s, "
        f"attainable {hw['flops_per_s'] / 1e9:.1f} GFLOP/s "
        f"(float32 FMA chain). Machine: {machine()['cpu']}, {os.cpu_count()} cores.\n",
        "The hand-written limit: explicit Euler as one fused multi-threaded Numba loop (benchmarks/"
        "_numba_limit.py), reading zero force and torque arrays each step; `vs limit` is rbjax's euler on "
        "that same data over the loop's rate.\n",
        "| method | dtype | N | body-steps/s (JAX) | native | native / JAX | vs NumPy | hand-written limit "
        "| JAX vs limit | native vs limit | compile (s) | peak MiB | flops/step | roofline |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        if r["engine"] != "rbjax":
            continue
        key = dict(dtype=r["dtype"], bodies=r["bodies"])
        npy = _rate(rows, engine="numpy", **key)
        lim = _rate(rows, engine="numba-limit", **key)
        nat = _rate(rows, engine="rbjax-native", method=r["method"], **key)
        vs = [_rate(rows, engine=f"rbjax-forces-{p}", **key) for p in ("jax", "native")]
        lim_cols = " | ".join(f"{v / lim:.2f}x" if lim and v and r["method"] == "euler" else "-" for v in vs)
        out.append(
            f"| {r['method']} | {r['dtype']} | {r['bodies']:,} | {r['body_steps_per_s']:.2e} | "
            + (f"{nat:.2e} | {nat / r['body_steps_per_s']:.1f}x" if nat else "- | -")
            + f" | {r['body_steps_per_s'] / npy:.1f}x | {f'{lim:.2e}' if lim else '-'} | {lim_cols} | "
            f"{r['compile_s']:.2f} | {r['peak_mb'] or 0:.1f} | {r['flops']:.0f} | {r['roofline_fraction']:.0%} |"
        )
    out += [
        "",
        "| peer | integrator | dtype | N | body-steps/s | rbjax, same N (dtype if run) | ratio |",
        "|---|---|---|---:|---:|---:|---:|",
    ]
    for r in rows:
        if r["engine"].startswith("rbjax") or r["engine"] == "numba-limit":
            continue
        m = "rk4" if r["method"] == "RK4" else "euler"
        dt = "float32" if r["engine"] == "mjx" and "32" in r["dtype"] else r["dtype"]
        ours = _rate(rows, engine="rbjax", method=m, dtype=dt, bodies=r["bodies"])
        if ours is None:  # that dtype was not run (--dtypes): compare with what was
            ours = _rate(rows, engine="rbjax", method=m, bodies=r["bodies"])
        out.append(
            f"| {r['engine']} | {r['method']} | {r['dtype']} | {r['bodies']:,} | "
            f"{r['body_steps_per_s']:.2e} | "
            f"{ours or float('nan'):.2e} | {ours / r['body_steps_per_s'] if ours else float('nan'):.1f}x |"
        )
    g = goals
    verdict = {True: "met", False: "NOT met", None: "not measured (no euler row)"}
    nan = float("nan")
    out += [
        "",
        f"Goals at N = {g['bodies']:,}, float32:",
        f"- euler vs NumPy: {g['euler_vs_numpy']['ratio'] or nan:.1f}x (target 3x): "
        f"{verdict[g['euler_vs_numpy']['met']]}",
        f"- euler vs MuJoCo Euler per body-step (MuJoCo at N = {g['euler_vs_mujoco']['mujoco_bodies']}): "
        f"{g['euler_vs_mujoco']['ratio'] or nan:.0f}x (target 100x): "
        f"{ {True: 'met', False: 'NOT met', None: 'not measured'}[g['euler_vs_mujoco']['met']] }",
        f"- euler memory-bandwidth fraction: {g['euler_bandwidth_fraction']['fraction'] or nan:.0%} (target 50%): "
        f"{verdict[g['euler_bandwidth_fraction']['met']]}",
    ]
    for k, v in g["euler_vs_limit"].items():
        out.append(
            f"- euler vs the hand-written limit, {k}: {v['ratio']:.2f}x (target ≥ 0.9x): "
            + ("met" if v["met"] else "NOT met")
        )
    for k, v in g["eager_vs_jit"].items():
        out.append(
            f"- euler eager against the same call under jit, {k}: {v['slowdown']:.2f}x the time (target ≤ 1.25x): "
            + ("met" if v["met"] else "NOT met")
        )
    for m, v in g["native"].items():
        out.append(
            f"- {m} native: {v['native_vs_jax']:.1f}x its JAX path; {v['vs_native_euler']['ratio']:.2f}x native "
            f"euler (target ≥ 0.5x): {'met' if v['vs_native_euler']['met'] else 'NOT met'}; with gravity + "
            f"quadratic drag {1 / v['native_forces_cost']['ratio']:.2f}x its force-free rate (target ≥ 0.67x): "
            f"{'met' if v['native_forces_cost']['met'] else 'NOT met'}; the JAX path with them "
            f"{v['jax_with_forces']['ratio']:.2f}x its own (target ≥ 0.5x): "
            f"{'met' if v['jax_with_forces']['met'] else 'NOT met'}"
        )
    for m, v in g["methods_within_2x_of_roofline"].items():
        out.append(
            f"- {m}: {v['roofline_fraction']:.0%} of its roofline bound (target ≥ 50%): "
            f"{'met' if v['met'] else 'NOT met'}"
        )
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    sys.exit(main())
