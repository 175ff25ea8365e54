"""The demo of the README's first command: 10,000 tumbling boxes and a Dzhanibekov T-handle.

``python -m rbjax demo`` simulates an embedded default scene (seeded, no input
files): 10,000 boxes of random sizes, masses, orientations and spins, plus a
T-handle spun near its intermediate principal axis. It prints the throughput
and the worst relative drift of energy and of ``|L|`` over the batch, and writes
a PNG of the T-handle's body-frame angular velocity, whose sign flips are the
Dzhanibekov (tennis-racket) effect, and next to it a GIF of the T-handle flipping
(:func:`rbjax.animate`).
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from ._body import box, from_particles
from ._quantities import angular_momentum, body_angular_velocity, kinetic_energy
from ._simulate import simulate
from ._state import State

# default method: the best structure-preserving method registered (see rbjax.methods())
_PREFERRED = ("splitting", "implicit_midpoint", "rk4", "euler")


def t_handle():
    """A T-handle from point masses: a 10 cm handle with a 6 cm crossbar at one end.

    Its principal moments are distinct, so a spin about the intermediate axis is
    unstable and flips periodically.
    """
    handle = [(0.0, 0.0, z) for z in np.linspace(0.0, 0.10, 11)]
    bar = [(x, 0.0, 0.10) for x in np.linspace(-0.03, 0.03, 7)]
    pts = np.array(handle + bar)
    return from_particles(np.full(len(pts), 0.01), pts)[0]


def default_scene(n_boxes: int = 10_000, seed: int = 0, dtype=jnp.float32) -> State:
    """``n_boxes`` random boxes followed by the T-handle (last body)."""
    rng = np.random.default_rng(seed)
    sizes = rng.uniform(0.05, 1.0, size=(n_boxes, 3))
    masses = rng.uniform(0.5, 5.0, size=n_boxes)
    q = rng.normal(size=(n_boxes, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w = rng.normal(scale=2.0, size=(n_boxes, 3))
    boxes = box(masses, sizes)
    th = t_handle()
    moments, axes = (np.asarray(a) for a in th.principal())
    # spin about the intermediate axis, with a 1e-3 perturbation on the others
    w_th = axes @ np.array([1e-3, 20.0, 1e-3])
    mass = np.concatenate([np.asarray(boxes.mass), [float(th.mass)]]).astype(dtype)
    inertia = np.concatenate([np.asarray(boxes.inertia), np.asarray(th.inertia)[None]]).astype(dtype)
    from ._body import Body

    body = Body(mass, inertia)
    q_all = np.concatenate([q, [[1.0, 0, 0, 0]]]).astype(dtype)
    w_all = np.concatenate([w, w_th[None]]).astype(dtype)
    del moments
    return State.create(body, orientation=q_all, angular_velocity=w_all)


def _pick_method(name: str | None) -> str:
    from . import methods

    avail = methods(State)
    if name:
        return name
    return next(m for m in _PREFERRED if m in avail)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m rbjax demo", description=(__doc__ or "rbjax demo").splitlines()[0])
    p.add_argument("--bodies", type=int, default=10_000, help="number of random boxes (default 10000)")
    p.add_argument("--seconds", type=float, default=10.0, help="simulated time in s (default 10)")
    p.add_argument("--dt", type=float, default=2e-3, help="time step in s (default 2e-3)")
    p.add_argument("--method", default=None, help="integrator (default: best available; see rbjax.methods())")
    p.add_argument("--x64", action="store_true", help="run in float64 (default float32)")
    p.add_argument("--out", default="rbjax_demo.png", help="PNG of the T-handle's body rates")
    p.add_argument("--no-gif", action="store_true", help="skip the GIF of the T-handle (written next to the PNG)")
    args = p.parse_args(argv)
    if args.x64:
        jax.config.update("jax_enable_x64", True)
    dtype = jnp.float64 if args.x64 else jnp.float32
    method = _pick_method(args.method)
    steps = int(round(args.seconds / args.dt))
    save_every = max(1, steps // 100)
    steps -= steps % save_every
    state = default_scene(args.bodies, dtype=dtype)
    n = state.batch_shape[0]

    run = lambda s: simulate(s, None, args.dt, steps, method, save_every=save_every)
    t0 = time.perf_counter()
    compiled = jax.jit(run).lower(state).compile()
    t_compile = time.perf_counter() - t0
    t0 = time.perf_counter()
    traj = jax.block_until_ready(compiled(state))
    wall = time.perf_counter() - t0

    E = np.asarray(kinetic_energy(traj), dtype=np.float64)
    Lnorm = np.linalg.norm(np.asarray(angular_momentum(traj), dtype=np.float64), axis=-1)
    e_drift = np.max(np.abs(E - E[0]) / E[0])
    l_drift = np.max(np.abs(Lnorm - Lnorm[0]) / Lnorm[0])

    # the T-handle alone at full time resolution for the plot
    th = jax.tree.map(lambda a: a[-1], state)
    th_traj = simulate(th, None, args.dt, steps, method, save_every=max(1, steps // 4000))
    wb = np.asarray(body_angular_velocity(th_traj))
    t = np.arange(wb.shape[0]) * args.dt * max(1, steps // 4000)
    moments, axes = (np.asarray(a) for a in th.body.principal())  # the body, not its per-frame copies
    wp = wb @ axes  # components along the principal axes
    flips = int(np.sum(np.diff(np.sign(wp[:, 1])) != 0))

    print(f"rbjax demo: {n} bodies ({n - 1} boxes + T-handle), method {method!r}, {np.dtype(dtype).name}")
    print(f"  steps          {steps} x dt {args.dt:g} s = {steps * args.dt:g} s simulated")
    print(f"  compile        {t_compile:.2f} s")
    print(f"  wall time      {wall:.2f} s")
    print(f"  throughput     {n * steps / wall:.3e} body-steps/s")
    print(f"  max rel drift  energy {e_drift:.2e}   |L| {l_drift:.2e}   (worst body, {E.shape[0]} saved frames)")
    print(f"  T-handle       {flips} flips of the intermediate-axis rate in {steps * args.dt:g} s")
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # pragma: no cover
        print("  (matplotlib not installed: no plot; pip install 'rbjax[demo]')")
        return 0
    fig, ax = plt.subplots(figsize=(9, 3.6))
    for k, label in enumerate(["ω₁ (smallest I)", "ω₂ (intermediate I)", "ω₃ (largest I)"]):
        ax.plot(t, wp[:, k], label=label, lw=1.2)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("body-frame angular velocity (rad/s)")
    ax.set_title(f"Dzhanibekov effect: T-handle spun about its intermediate axis ({method})")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"  plot           {args.out}")
    if not args.no_gif:
        from pathlib import Path

        from ._animate import animate

        gif = Path(args.out).with_suffix(".gif")
        # the first 2.5 s hold three flips; 100 frames (0.4 rad of spin apart) render in a few seconds
        dt_saved = float(t[1] - t[0]) if len(t) > 1 else args.dt
        info = animate(
            th_traj,
            gif,
            dt=dt_saved,
            frames=slice(0, int(round(2.5 / dt_saved)) + 1),
            max_frames=100,
            panel_size=4.0,
            fps=15,
            trail=25,
            title="T-handle spun about its intermediate axis",
        )
        kb, sec = info["bytes"] / 1e3, info["seconds"]
        print(f"  animation      {gif} ({info['frames']:.0f} frames, {kb:.0f} kB, rendered in {sec:.1f} s)")
    return 0
