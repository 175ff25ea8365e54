"""Work-precision: error at the final time against wall time, rbjax's methods beside diffrax.

Four problems, each with an exact solution (``rbjax.torque_free`` where the
library has it) or a scipy DOP853 reference at rtol = atol = 1e-13 in float64:

1. ``t_handle``   Dzhanibekov T-handle near the separatrix: ``I = diag(1, 2, 2.8)``,
   ``ω0 = (1e-3, 2, 1e-3)`` (body = world at t = 0), T = 10 s (through the first flip).
2. ``tumble``     a generic asymmetric tumble whose principal axes are not the body
   axes (full, non-diagonal ``I_L``), T = 10 s.
3. ``thruster``   a fast spin (30 rad/s) with a body-fixed thruster: a 2 N force at a
   body point along a body-fixed direction, a callable ``(state, t) -> Forces``
   (orientation-dependent force and torque), T = 2 s.
4. ``driven``     a body under smooth time-varying world torques ``τ(t)``, T = 5 s.

For every method in ``rbjax.methods(rbjax.State)`` (found at run time, so new
methods appear automatically), float32 and float64, and a sweep of ``dt = T/n``
with ``n = 2^k`` (``k = 4..18``; order ≥ 6: ``n = 2^(k/2)``, 8 to 2048, since
their error falls 64-256x per doubling and reaches round-off within a few):

* the error at T: orientation angle ``rb.quat_angle(q, q_ref)`` (rad), relative
  angular-velocity error ``‖ω - ω_ref‖ / ‖ω_ref‖``, relative rotational-energy
  error ``|E - E_ref| / E_ref`` (``E = ½ ω·L``);
* the work: wall time per body-step, timed on a batch of 1e4 copies of the
  problem (batch throughput; ``rbjax.step`` in a ``fori_loop``, best of 3), times
  ``n`` steps = wall time per body to reach T. Compile time is reported apart.
  The error at each dt comes from one body (copies are identical). A method with a
  native kernel (``rbjax.native_status()``) gets a second curve, ``"<method> native"``:
  the same errors (the kernel agrees with the JAX step to round-off), the time of
  ``rbjax.simulate(..., native=True)`` on the same batch (``--no-native``: none).

The peer is diffrax (Tsit5, Dopri8 with a PID controller) on the same ODE
(``rbjax.derivative`` on the flattened ``(x, v, q, L)`` state, the same force
callable), over a sweep of ``rtol = atol``. The batch of 1e4 bodies is ONE ODE of
shape ``(N, 13)``: every body takes the same adaptive steps, as rbjax's batch
does with its fixed step, and no body pays ``vmap``'s masked while-loop
(under ``vmap`` each batched ``while_loop`` iteration runs every body's step and
selects). With identical copies the RMS error norm, hence the step sequence, is
one body's, so this is diffrax's most favourable batched configuration. Its
cost per step (rejected steps included) is measured on that batch ODE at a mid
tolerance; error and step count per tolerance come from one body.

Outputs in ``benchmarks/results/``: ``work_precision.png`` (log-log, one column
per problem; rows: orientation, ω, energy), ``work_precision.md`` (fastest method
per error level, orientation error) and ``work_precision.json``.

    python benchmarks/work_precision.py            # full (minutes)
    python benchmarks/work_precision.py --quick    # tiny sizes, < 1 minute
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import os
import sys
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import best_time, compile_timed, machine, write_json  # noqa: E402

import rbjax as rb  # noqa: E402
from tests.reference import reference_rotation  # noqa: E402

LEVELS = [10.0**-k for k in range(3, 11)]  # error levels of the summary table


# ----------------------------------------------------------------------------- problems


@dataclasses.dataclass(frozen=True)
class Problem:
    name: str
    title: str
    inertia: np.ndarray  # (3, 3) body frame
    q0: np.ndarray  # (4,)
    omega0: np.ndarray  # (3,) world
    T: float
    force: Callable | None  # (state, t) -> Forces, or None (torque-free)
    torque_np: Callable | None  # the same torque for the NumPy reference: (t, q, ω_world) -> τ_world
    mass: float = 1.0

    def state(self, dtype, n: int | None = None) -> rb.State:
        """The initial state in ``dtype``; ``n`` copies (own body parameters each) if given."""
        body = rb.Body(jnp.asarray(self.mass), jnp.asarray(self.inertia))
        s = rb.State.create(body, orientation=self.q0, angular_velocity=self.omega0)
        s = jax.tree.map(lambda a: a.astype(dtype), s)
        if n is not None:
            s = jax.tree.map(lambda a: jnp.tile(a[None], (n,) + (1,) * a.ndim), s)
        return s


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _qrot_np(q, v):
    w, u = q[0], q[1:]
    t = 2 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


# thruster: a force of THRUST N at body point R_B along body direction F_B
THRUST, R_B, F_B = 2.0, np.array([0.2, 0.1, 0.3]), _unit([0.0, 0.6, 0.8])


def thruster_force(state: rb.State, t) -> rb.Forces:
    dt = state.dtype
    f_w = rb.quat_rotate(state.orientation, jnp.asarray(THRUST * F_B, dt))
    p_w = state.position + rb.quat_rotate(state.orientation, jnp.asarray(R_B, dt))
    return rb.Forces.at_point(f_w, p_w, state)


def thruster_torque_np(t, q, w):
    return _qrot_np(q, np.cross(R_B, THRUST * F_B))  # body-fixed torque r × f, rotated to world


def driven_torque(t, xp=jnp):
    return xp.stack([0.5 * xp.sin(3 * t), 0.3 * xp.cos(2 * t), 0.2 * xp.sin(5 * t + 1)])


def driven_force(state: rb.State, t) -> rb.Forces:
    return rb.Forces(torque=driven_torque(t).astype(state.dtype))


def problems() -> dict[str, Problem]:
    rng = np.random.default_rng(42)
    q_gen = _unit(rng.normal(size=4))
    a = _unit([1.0, 2.0, 0.5]) * 0.7  # principal frame rotated 0.7 rad about a tilted axis
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]]) / 0.7
    R_p = np.eye(3) + np.sin(0.7) * K + (1 - np.cos(0.7)) * K @ K
    ps = [
        Problem(
            "t_handle",
            "T-handle (separatrix)",
            np.diag([1.0, 2.0, 2.8]),
            np.array([1.0, 0, 0, 0]),
            np.array([1e-3, 2.0, 1e-3]),
            10.0,
            None,
            None,
        ),
        Problem(
            "tumble",
            "generic tumble",
            R_p @ np.diag([1.0, 2.3, 3.1]) @ R_p.T,
            q_gen,
            np.array([1.2, -0.7, 0.9]),
            10.0,
            None,
            None,
        ),
        Problem(
            "thruster",
            "fast spin + thruster",
            np.diag([2.0, 2.5, 1.0]),
            np.array([1.0, 0, 0, 0]),
            np.array([0.1, 0.05, 30.0]),
            2.0,
            thruster_force,
            thruster_torque_np,
        ),
        Problem(
            "driven",
            "time-varying torque",
            np.diag([1.0, 1.7, 2.4]),
            _unit([0.9, 0.1, -0.3, 0.2]),
            np.array([0.3, 1.0, -0.5]),
            5.0,
            driven_force,
            lambda t, q, w: driven_torque(t, np),
        ),
    ]
    return {p.name: p for p in ps}


def reference(p: Problem) -> dict:
    """Float64 orientation, world ω and rotational energy at ``p.T``."""
    if p.force is None and hasattr(rb, "torque_free"):
        s = rb.torque_free(p.state(jnp.float64), jnp.asarray(p.T))
        q, w, source = np.asarray(s.orientation), np.asarray(rb.angular_velocity(s)), "rb.torque_free (exact)"
    else:
        qs, ws = reference_rotation(p.inertia, p.q0, p.omega0, np.array([0.0, p.T]), p.torque_np)
        q, w, source = qs[-1], ws[-1], "scipy DOP853, rtol = atol = 1e-13"
    R = np.asarray(rb.quat_to_matrix(jnp.asarray(q)))
    E = 0.5 * w @ (R @ p.inertia @ R.T @ w)
    return dict(q=q, w=w, E=E, source=source)


def errors(q, w, ref) -> dict:
    """Orientation angle (rad), relative ω error, relative rotational-energy error, computed in float64."""
    q = np.asarray(q, np.float64)
    w = np.asarray(w, np.float64)
    R = np.asarray(rb.quat_to_matrix(jnp.asarray(q / np.linalg.norm(q))))
    return dict(
        err_angle=float(rb.quat_angle(jnp.asarray(q), jnp.asarray(ref["q"]))),
        err_omega=float(np.linalg.norm(w - ref["w"]) / np.linalg.norm(ref["w"])),
        err_energy=float(abs(0.5 * w @ (R @ ref["I"] @ R.T @ w) - ref["E"]) / ref["E"]),
    )


def _finite(d: dict) -> dict:
    return {k: (v if np.isfinite(v) else None) if isinstance(v, float) else v for k, v in d.items()}


# ----------------------------------------------------------------------------- rbjax


@functools.partial(jax.jit, static_argnames=("method", "force"))
def run_fixed(state, dt, n, *, method, force):
    """``n`` (traced: one compile for every dt) steps of ``dt`` from ``t = 0``."""
    return jax.lax.fori_loop(0, n, lambda k, s: rb.step(s, force, dt, method, t=k * dt), state)


def step_counts(order: int, quick: bool) -> list[int]:
    """Step counts ``n`` of the dt sweep (``dt = T / n``) for a method of ``order``.

    Powers of 2 from 16 to 2^18; from order 6 on, half powers from 8 to 2048: the
    error of an order-8 method falls 256-fold per doubling, and reaches float64
    round-off by n ~ 100 on these problems (finer points for the Pareto front,
    none wasted below round-off).
    """
    if quick:
        return [2**k for k in (4, 6, 8, 10)]
    if order >= 6:
        return [round(2 ** (k / 2)) for k in range(6, 23)]
    return [2**k for k in range(4, 19)]


def rbjax_curves(
    p: Problem, ref: dict, dtype, n_batch: int, methods, quick: bool, log, native: bool = True
) -> list[dict]:
    """Errors from one body (full) or the batch's first body (quick: one compile); cost from the batch.

    With ``native``, a method with a native kernel gets a second curve, ``"<method> native"``.
    """
    rows = []
    sN = p.state(dtype, n_batch)
    s1 = sN if quick else p.state(dtype)
    for method in methods:
        ns = step_counts(rb.methods()[method].order, quick)
        run = functools.partial(run_fixed, method=method, force=p.force)
        steps_t = max(4, int(2e6 / n_batch / max(1.0, rb.methods()[method].cost)))
        dt_t = jnp.asarray(p.T / ns[len(ns) // 2], dtype)
        compiled, t_compile = compile_timed(jax.jit(run), sN, dt_t, steps_t)
        jax.block_until_ready(compiled(sN, dt_t, steps_t))
        t_bs = best_time(compiled, sN, dt_t, steps_t) / (n_batch * steps_t)
        # the native kernel, where simulate has one: the same steps to round-off (tests/test_native.py),
        # so the same errors at a cost of its own; timed on the same batch through simulate
        t_native = None
        if native and method in rb.native_status().methods:
            sim = functools.partial(rb.simulate, method=method, save_every=steps_t, native=True)
            try:
                jax.block_until_ready(sim(sN, p.force, dt_t, steps_t))
                t_native = best_time(sim, sN, p.force, dt_t, steps_t) / (n_batch * steps_t)
            except ValueError as e:  # forces the kernel does not evaluate (a callable): no native curve
                log(f"  rbjax {method:>20} no native curve: {str(e).split(';')[0]}")
        variants = [(method, t_bs)] + ([(f"{method} native", t_native)] if t_native else [])
        for n in ns:
            dt = p.T / n
            out = (compiled if quick else run)(s1, jnp.asarray(dt, dtype), n)
            q, w = out.orientation.reshape(-1, 4)[0], rb.angular_velocity(out).reshape(-1, 3)[0]
            e = errors(q, w, ref)
            for name, t in variants:
                rows.append(
                    _finite(
                        dict(
                            solver="rbjax",
                            method=name,
                            dtype=np.dtype(dtype).name,
                            dt=dt,
                            steps=n,
                            time_per_body_step_s=t,
                            time_per_body_s=t * n,
                            compile_s=t_compile,
                            **e,
                        )
                    )
                )
        log(
            f"  rbjax {method:>20} {np.dtype(dtype).name}: {t_bs * 1e9:7.1f} ns/body-step"
            + (f" (native {t_native * 1e9:.1f}, {t_bs / t_native:.2f}x faster)" if t_native else "")
            + f", compile {t_compile:.2f} s, "
            f"best angle error {min(r['err_angle'] or np.inf for r in rows[-len(ns) :]):.2e}"
        )
    return rows


# ----------------------------------------------------------------------------- diffrax


def _flat(s):
    return jnp.concatenate([s.position, s.velocity, s.orientation, s.angular_momentum], axis=-1)


def _state(y, body):
    return rb.State(body, y[..., 0:3], y[..., 3:6], y[..., 6:10], y[..., 10:13])


@functools.partial(jax.jit, static_argnames=("solver", "force", "max_steps"))
def diffrax_solve(y0, body, t1, rtol, atol, *, solver, force, max_steps):
    import diffrax

    def vf(t, y, body):
        s = _state(y, body)
        return _flat(rb.derivative(s, rb.Forces() if force is None else force(s, t)))

    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(vf),
        getattr(diffrax, solver)(),
        jnp.zeros((), y0.dtype),
        t1,
        None,
        y0,
        args=body,
        saveat=diffrax.SaveAt(t1=True),
        stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol),
        max_steps=max_steps,
        throw=False,
    )
    return sol.ys[-1], sol.stats["num_steps"], sol.result == diffrax.RESULTS.successful


def diffrax_curves(
    p: Problem, ref: dict, dtype, n_batch: int, solvers, tols, max_steps: int, quick: bool, log
) -> list[dict]:
    """Per tolerance: error and step count from one body, time = cost per step on the batch x steps.

    With identical copies the batch ODE takes exactly one body's steps (same RMS
    error norm), so the step count from one body is the batch's. The cost per
    step is measured once per solver on the full batch at a mid tolerance
    (wall time / steps taken, rejected steps included), as rbjax's is; this keeps
    the sweep affordable down to tight tolerances.
    """
    rows = []
    sN = p.state(dtype, n_batch)
    s1 = sN if quick else p.state(dtype, 1)  # quick: one compile, errors from the batch's first body
    t1 = jnp.asarray(p.T, dtype)
    for solver in solvers:
        fn = jax.jit(functools.partial(diffrax_solve, solver=solver, force=p.force, max_steps=max_steps))
        tol_t = jnp.asarray(tols[len(tols) // 2], dtype)
        compiled, t_compile = compile_timed(fn, _flat(sN), sN.body, t1, tol_t, tol_t)
        _, nst, ok = jax.block_until_ready(compiled(_flat(sN), sN.body, t1, tol_t, tol_t))
        t_step = best_time(compiled, _flat(sN), sN.body, t1, tol_t, tol_t, repeats=3, budget_s=3.0) / (
            n_batch * max(int(nst), 1)
        )
        one = compiled if quick else fn.lower(_flat(s1), s1.body, t1, tol_t, tol_t).compile()
        for tol in tols:
            tt = jnp.asarray(tol, dtype)
            y, nsteps, ok = jax.block_until_ready(one(_flat(s1), s1.body, t1, tt, tt))
            if not bool(ok):
                log(f"  diffrax {solver} {np.dtype(dtype).name} tol {tol:.0e}: failed (max_steps or dt underflow)")
                continue
            y0n = np.array(y[0], np.float64)
            y0n[6:10] /= np.linalg.norm(y0n[6:10])  # diffrax does not renormalise q; measure its direction
            s0 = _state(jnp.asarray(y0n), p.state(jnp.float64).body)
            e = errors(s0.orientation, rb.angular_velocity(s0), ref)
            rows.append(
                _finite(
                    dict(
                        solver="diffrax",
                        method=solver,
                        dtype=np.dtype(dtype).name,
                        tol=tol,
                        steps=int(nsteps),
                        time_per_body_step_s=t_step,
                        time_per_body_s=t_step * int(nsteps),
                        compile_s=t_compile,
                        **e,
                    )
                )
            )
        best = min([r["err_angle"] or np.inf for r in rows if r["method"] == solver] + [np.inf])
        log(
            f"  diffrax {solver:>18} {np.dtype(dtype).name}: {t_step * 1e9:7.1f} ns/body-step, compile "
            f"{t_compile:.2f} s, best angle error {best:.2e}"
        )
    return rows


# ----------------------------------------------------------------------------- summary


def pareto_time(rows: list[dict], level: float, key: str = "err_angle") -> float | None:
    """Least time per body reaching error <= level, log-log interpolated along the Pareto front."""
    pts = sorted((r["time_per_body_s"], r[key]) for r in rows if r[key] is not None and r[key] > 0)
    front, best = [], np.inf
    for t, e in pts:
        if e < best:
            front.append((t, e))
            best = e
    if not front or front[-1][1] > level:
        return None
    if front[0][1] <= level:
        return front[0][0]
    for (t0, e0), (t1, e1) in zip(front, front[1:], strict=False):
        if e1 <= level < e0:
            w = np.log(level / e0) / np.log(e1 / e0)
            return float(np.exp(np.log(t0) + w * np.log(t1 / t0)))
    return None


def summary(results: dict, probs: dict[str, Problem]) -> tuple[str, dict]:
    lines, verdicts = [], {}
    for name, rows in results.items():
        lines += [
            f"\n### {probs[name].title} (`{name}`), orientation error at T = {probs[name].T:g} s\n",
            "| error ≤ | fastest rbjax | µs/body | fastest diffrax | µs/body | diffrax / rbjax |",
            "|---:|---|---:|---|---:|---:|",
        ]
        verdicts[name] = {}
        for level in LEVELS:
            best = {}
            for solver in ("rbjax", "diffrax"):
                cands = {}
                for m, d in {(r["method"], r["dtype"]) for r in rows if r["solver"] == solver}:
                    t = pareto_time(
                        [r for r in rows if r["solver"] == solver and r["method"] == m and r["dtype"] == d],
                        level,
                    )
                    if t is not None:
                        cands[f"{m} {d}"] = t
                best[solver] = min(cands.items(), key=lambda kv: kv[1]) if cands else None
            r, d = best["rbjax"], best["diffrax"]
            cell = lambda b: (f"{b[0]}", f"{b[1] * 1e6:.3g}") if b else ("unreached", "–")
            ratio = f"{d[1] / r[1]:.2f}x" if r and d else "–"
            verdicts[name][f"{level:.0e}"] = r is not None and (d is None or r[1] < d[1])
            lines.append(f"| 1e{int(np.log10(level))} | {' | '.join(cell(r))} | {' | '.join(cell(d))} | {ratio} |")
    return "\n".join(lines) + "\n", verdicts


def plot(results: dict, probs: dict[str, Problem], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = [
        ("err_angle", "orientation error (rad)"),
        ("err_omega", "relative ω error"),
        ("err_energy", "relative energy error"),
    ]
    fig, axes = plt.subplots(len(keys), len(results), figsize=(4.2 * len(results), 3.4 * len(keys)), squeeze=False)
    # one colour per method (tab20 has enough for every rbjax method and both diffrax solvers);
    # the line style says the dtype, the marker the library
    cycle = plt.get_cmap("tab20").colors
    colors: dict[str, object] = {}
    for j, (name, rows) in enumerate(results.items()):
        curves = sorted({(r["solver"], r["method"], r["dtype"]) for r in rows})
        for i, (key, label) in enumerate(keys):
            ax = axes[i, j]
            for solver, m, d in curves:
                pts = sorted(
                    (r["time_per_body_s"], r[key])
                    for r in rows
                    if (r["solver"], r["method"], r["dtype"]) == (solver, m, d) and r[key] is not None and r[key] > 0
                )
                if not pts:
                    continue
                c = colors.setdefault(f"{solver} {m}", cycle[(2 * len(colors)) % 20 + (len(colors) >= 10)])
                ax.loglog(
                    *zip(*pts, strict=True),
                    ls="-" if d == "float64" else "--",
                    marker="o" if solver == "rbjax" else "s",
                    ms=3,
                    lw=1.2,
                    color=c,
                )
            ax.set_xlabel("wall time per body to T (s), batch of copies")
            ax.set_ylabel(label)
            ax.grid(True, which="major", alpha=0.3)
            if i == 0:
                ax.set_title(probs[name].title)
    from matplotlib.lines import Line2D

    handles = [
        Line2D([], [], color=c, marker="o" if k.startswith("rbjax") else "s", ms=4, label=k.removeprefix("rbjax "))
        for k, c in colors.items()
    ]
    handles += [Line2D([], [], color="k", ls="-", label="float64"), Line2D([], [], color="k", ls="--", label="float32")]
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 8), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def default_methods(quick: bool) -> list[str]:
    """Every registered method; ``--quick`` (which checks that the benchmark runs) only two,
    which cover its code paths without every method's compile time (rk8 alone takes ~10 s)."""
    return ["euler", "rk4"] if quick else list(rb.methods(rb.State))


def checkpoint(stem: str, results: dict) -> None:
    """The curves so far (``partial: true``), so that a run cut short (a device lease, a time
    limit) keeps them; the finished run overwrites the file with its summary."""
    write_json(stem + ".json", dict(machine=machine(), partial=True, results=results))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny sizes, < 1 minute (checks it runs)")
    ap.add_argument(
        "--problems",
        default="all",
        help="comma-separated subset of " + ",".join(problems()) + " (--quick: thruster)",
    )
    ap.add_argument("--out", default=os.path.join(ROOT, "benchmarks", "results"), help="output folder")
    ap.add_argument("--no-diffrax", action="store_true", help="skip the diffrax peer")
    ap.add_argument("--no-native", action="store_true", help="only rbjax's JAX path (no native-kernel curves)")
    ap.add_argument(
        "--methods",
        default="all",
        help="comma-separated rbjax methods (default: every registered one; --quick: euler,rk4)",
    )
    ap.add_argument("--dtypes", default="float32,float64", help="comma-separated subset of float32,float64")
    args = ap.parse_args(argv)

    probs = problems()
    if args.problems == "all" and args.quick:
        args.problems = "thruster"  # the richest code path: an orientation-dependent force callable
    if args.problems != "all":
        probs = {k: probs[k] for k in args.problems.split(",")}
    if args.quick:
        n_batch = 64
        solvers, tols, max_steps = ["Tsit5"], {jnp.float64: [1e-4, 1e-7]}, 100_000
    else:
        n_batch = 10_000
        solvers, max_steps = ["Tsit5", "Dopri8"], 1_000_000
        tols = {
            jnp.float32: [10.0 ** (-k / 2) for k in range(4, 13)],  # 1e-2 .. 1e-6: float32's floor is ~1e-7
            jnp.float64: [10.0 ** (-k / 2) for k in range(4, 27)],
        }  # 1e-2 .. 1e-13
    dtypes = [{"float32": jnp.float32, "float64": jnp.float64}[d] for d in args.dtypes.split(",")]
    methods = default_methods(args.quick) if args.methods == "all" else args.methods.split(",")
    unknown = set(methods) - set(rb.methods(rb.State))
    if unknown:
        ap.error(f"unknown methods {sorted(unknown)}; available: {sorted(rb.methods(rb.State))}")
    try:
        import diffrax  # noqa: F401
    except ImportError:
        args.no_diffrax = True
        print("diffrax not installed: peer skipped (pip install -e '.[bench]')")

    os.makedirs(args.out, exist_ok=True)
    stem = os.path.join(args.out, "work_precision" + ("_quick" if args.quick else ""))
    t_start = time.perf_counter()
    results, refs = {}, {}
    for name, p in probs.items():
        ref = reference(p)
        ref["I"] = p.inertia
        refs[name] = ref["source"]
        print(f"{p.title} (T = {p.T} s; reference: {ref['source']})", flush=True)
        log = lambda s: print(s, flush=True)
        rows = []
        results[name] = rows
        for dtype in dtypes:
            rows += rbjax_curves(p, ref, dtype, n_batch, methods, args.quick, log, native=not args.no_native)
            checkpoint(stem, results)
            if not args.no_diffrax and dtype in tols:
                rows += diffrax_curves(p, ref, dtype, n_batch, solvers, tols[dtype], max_steps, args.quick, log)
                checkpoint(stem, results)

    table, verdicts = summary(results, probs)
    header = (
        f"Work-precision, batch of {n_batch:,} identical bodies; time = wall time per body to the final "
        f"time (rbjax: measured time per body-step x steps). Machine: {machine()['cpu']}, "
        f"{os.cpu_count()} cores.\n"
    )
    with open(stem + ".md", "w") as f:
        f.write(header + table)
    plot(results, probs, stem + ".png")
    write_json(
        stem + ".json",
        dict(
            machine=machine(),
            quick=args.quick,
            batch=n_batch,
            levels=LEVELS,
            references=refs,
            problems={k: dict(title=p.title, T=p.T) for k, p in probs.items()},
            rbjax_faster_than_diffrax=verdicts,
            results=results,
            diffrax_batching="one ODE of shape (N, 13) (see module docstring)",
        ),
    )
    print(header + table)
    print(f"wrote {stem}.{{md,png,json}} in {time.perf_counter() - t_start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
