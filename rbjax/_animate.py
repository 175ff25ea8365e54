"""Animation export: a trajectory drawn frame by frame and written as a GIF or an MP4.

Each body is drawn in its own 3D panel, in world coordinates (m), as the solid of uniform density
with its mass and inertia: the box or the ellipsoid with the same principal moments, aligned with
its principal axes. An arrow from the centre of mass shows the world angular momentum ``L``, and a
fading trail follows the tip of the body's longest axis. Rendering is matplotlib's (``Agg``);
the file is written by its Pillow writer (GIF, always available with matplotlib) or by ffmpeg
(MP4, when an ``ffmpeg`` executable is on the path).
"""

from __future__ import annotations

import itertools
import math
import time as _time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ._rotations_np import np_qmat

__all__ = ["animate"]

# faces of the unit cube [-1, 1]^3 by corner index (corner k has coordinates from the bits of k)
_CORNERS = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
_FACES = np.array([[0, 1, 3, 2], [4, 5, 7, 6], [0, 1, 5, 4], [2, 3, 7, 6], [0, 2, 6, 4], [1, 3, 7, 5]])


def ellipsoid_mesh(n_lon: int = 14, n_lat: int = 8) -> np.ndarray:
    """Quads ``(F, 4, 3)`` on the unit sphere (scaled per body into its inertia ellipsoid)."""
    lon = np.linspace(0, 2 * np.pi, n_lon + 1)
    lat = np.linspace(-np.pi / 2, np.pi / 2, n_lat + 1)
    p = lambda a, b: np.stack([np.cos(b) * np.cos(a), np.cos(b) * np.sin(a), np.sin(b)], -1)
    quads = [
        [p(lon[i], lat[j]), p(lon[i + 1], lat[j]), p(lon[i + 1], lat[j + 1]), p(lon[i], lat[j + 1])]
        for i in range(n_lon)
        for j in range(n_lat)
    ]
    return np.array(quads)


def half_extents(moments: np.ndarray, mass: np.ndarray, shape: str) -> np.ndarray:
    """Half side lengths (box) or semi-axes (ellipsoid) ``(N, 3)`` (m) with the given principal moments.

    A box of half sides ``h`` has ``I₁ = m/3 (h₂² + h₃²)``, an ellipsoid of semi-axes ``h`` has
    ``I₁ = m/5 (h₂² + h₃²)``, so ``h₁² = k/(2m) (I₂ + I₃ − I₁)`` with ``k = 3`` or ``5``.
    """
    k = 3.0 if shape == "box" else 5.0
    total = moments.sum(-1, keepdims=True)
    sq = k / (2 * mass[:, None]) * (total - 2 * moments)
    # a triangle-equality body (a rod, a plate) has a zero extent: keep it visible as a thin slab
    return np.sqrt(np.maximum(sq, 1e-4 * sq.max(-1, keepdims=True)))


def frames_of(traj: Any) -> dict[str, Any]:
    """Positions ``(T, N, 3)``, rotations ``(T, N, 3, 3)``, world ``L`` ``(T, N, 3)`` (a gyrostat's total),
    the rotors' world momentum ``h`` ``(T, N, 3)`` (zeros without rotors), mass ``(N,)``, inertia ``(N, 3, 3)``."""
    if not hasattr(traj, "body"):
        raise TypeError(f"rbjax.animate needs a State or MatrixState trajectory (with a body), got {type(traj)}")
    pos = np.asarray(traj.position, np.float64)
    body = traj.body
    mass, inertia = np.asarray(body.mass, np.float64), np.asarray(body.inertia, np.float64)
    times = getattr(traj, "time", None)
    times = None if times is None else np.asarray(times, np.float64)
    first = 1 if pos.ndim == 1 else 0  # a time axis to add (1) or the leading axis (0)
    # a batch at one instant (traj[-1], a fresh State.create batch) or a trajectory? Time tells: a
    # trajectory's increases along its leading axis, the bodies of a batch share one clock. A body
    # shaped like the axes after the first (1 <= ndim = pos.ndim - 2) marks a hand-built trajectory
    # whose time was left at its default 0
    if pos.ndim >= 2 and times is not None and times.shape == pos.shape[:-1] and not 1 <= mass.ndim == pos.ndim - 2:
        t_lead = times.reshape(pos.shape[0], -1)[:, 0]
        if t_lead.size > 1 and np.all(t_lead == t_lead[0]):
            first = 1
    if first:  # one instant: one frame of all its bodies
        pos, times = pos[None], None if times is None else times[None]
    lead = pos.shape[:-1]  # (T, *B)
    T, B = lead[0], lead[1:]
    # the body may or may not carry the time axis: it never changes along it, so frame 0 is the body
    if mass.ndim > len(lead) - 1:
        mass, inertia = mass[0], inertia[0]
    mass = np.broadcast_to(mass, B).reshape(-1)
    inertia = np.broadcast_to(inertia, (*B, 3, 3)).reshape(-1, 3, 3)
    n = mass.shape[0]
    pos = pos.reshape(T, n, 3)
    field = lambda name, core: np.asarray(getattr(traj, name), np.float64).reshape(T, n, *core)
    if hasattr(traj, "orientation"):
        q = field("orientation", (4,))
        R = np_qmat(q / np.linalg.norm(q, axis=-1, keepdims=True))
    else:
        R = field("rotation", (3, 3))
    # a gyrostat's rotors: their momentum in the world frame, R Σ_k h_k a_k (zero without rotors)
    h = np.zeros((T, n, 3))
    rotors = getattr(traj, "rotors", None)
    if rotors is not None:
        axes = np.asarray(rotors.axes, np.float64)
        k = axes.shape[-2]
        if axes.ndim - 2 > len(B):  # the rotors carry the time axis too; they never change along it
            axes = axes[0]
        axes = np.broadcast_to(axes, (*B, k, 3)).reshape(n, k, 3)
        h_k = np.asarray(traj.rotor_momentum, np.float64).reshape(T, n, k)
        h = np.einsum("tnij,tnj->tni", R, np.einsum("tnk,nkj->tnj", h_k, axes))
    if hasattr(traj, "orientation"):
        L = field("angular_momentum", (3,))  # the total, rotors included
    else:  # MatrixState: L = R I_L Rᵀ ω + R Σ_k h_k a_k
        I_w = R @ inertia[None] @ np.swapaxes(R, -1, -2)
        L = np.einsum("tnij,tnj->tni", I_w, field("angular_velocity", (3,))) + h
    # one clock per frame: the batch shares it (its first body's)
    times = times.reshape(T, -1)[:, 0] if times is not None and times.size == pos.shape[0] * n else None
    return {"pos": pos, "R": R, "L": L, "h": h, "mass": mass, "inertia": inertia, "time": times}


def check_numbers(fn: str, **numbers: tuple[Any, str]) -> None:
    """``TypeError``/``ValueError`` in ``fn``'s name unless each ``name=(value, rule)`` holds.

    Rules: ``"int>=0"``, ``"int>=1"``, ``">0"`` (a finite real number), ``">0|None"``,
    ``">=0|None"``, ``"port"`` (an int in 0..65535).
    """
    for name, (value, rule) in numbers.items():
        if value is None and rule.endswith("|None"):
            continue
        whole = rule.startswith("int") or rule == "port"
        kinds = (int, np.integer) if whole else (int, float, np.integer, np.floating)
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, kinds):
            raise TypeError(f"{fn}: {name} must be {'an int' if whole else 'a real number'}, got {value!r}")
        low = {"int>=0": 0, "int>=1": 1, "port": 0}.get(rule)
        if low is not None:
            if value < low or (rule == "port" and value > 65535):
                span = "in 0..65535" if rule == "port" else f">= {low}"
                raise ValueError(f"{fn}: {name} must be {span}, got {value!r}")
        elif not np.isfinite(value) or value < 0 or (rule.startswith(">0") and value == 0):
            raise ValueError(f"{fn}: {name} must be finite and {rule.split('|')[0]}, got {value!r}")


def pick(n: int, bodies: int | Sequence[int] | None) -> np.ndarray:
    if bodies is None:
        bodies = min(n, 9)
    if isinstance(bodies, (int, np.integer)):
        if not 1 <= bodies <= n:
            raise ValueError(f"rbjax.animate: bodies={bodies} must be between 1 and the batch size {n}")
        # evenly spread over the (flattened) batch, deterministic, first and last included
        return np.unique(np.round(np.linspace(0, n - 1, int(bodies))).astype(int))
    idx = np.asarray(bodies, int).reshape(-1)
    if idx.size == 0 or idx.min() < -n or idx.max() >= n:
        raise ValueError(f"rbjax.animate: body indices {idx.tolist()} out of range for a batch of {n}")
    return idx % n


def _clock(k: int, dt: float | None, times: np.ndarray | None) -> str:
    """The clock of saved frame ``k``: ``k dt`` if ``dt`` is given, else the trajectory's time, else the frame."""
    if dt is not None:
        return f"t = {k * dt:.3f} s"
    if times is not None:
        return f"t = {times[k]:.3f} s"
    return f"frame {k}"


def animate(
    traj: Any,
    path: str | Path,
    *,
    bodies: int | Sequence[int] | None = None,
    shape: str = "box",
    dt: float | None = None,
    frames: slice | None = None,
    max_frames: int = 100,
    fps: int = 15,
    trail: int = 30,
    dpi: int = 80,
    panel_size: float = 3.0,
    title: str | None = None,
) -> dict[str, float]:
    """Write an animation of a trajectory: each body as its box or inertia ellipsoid, ``L`` and a trail.

    Args:
        traj: a :class:`State` or :class:`MatrixState` trajectory as :func:`rbjax.simulate` returns
            it: fields ``(T, *B, ...)`` with the leading time axis (positions in m, world frame;
            quaternions body to world). Its ``body`` may be ``(*B)``-shaped, shared, or carry the
            time axis too (frame 0 is used: mass properties do not change). A state without a
            time axis (one body, or a batch at one instant such as ``traj[-1]``) is drawn as one
            frame of all its bodies: a leading axis along which ``time`` does not change is a
            batch axis, not time (unless the body has the shape of the other axes: a hand-built
            trajectory whose time was left at 0).
        path: output file: ``.gif`` (matplotlib's Pillow writer) or ``.mp4`` (needs ``ffmpeg``).
        bodies: which bodies of the flattened batch ``*B`` to draw, one panel each: a list of flat
            indices, or a count ``k`` for ``k`` bodies spread evenly over the batch (default: all,
            up to 9).
        shape: ``"box"``: the uniform cuboid with the body's principal moments, half sides
            ``hᵢ² = 3/(2m) (Iⱼ + Iₖ − Iᵢ)``; ``"ellipsoid"``: the uniform ellipsoid with them,
            ``hᵢ² = 5/(2m) (Iⱼ + Iₖ − Iᵢ)``. Either is drawn along the principal axes, rotated by
            ``R`` and placed at the centre of mass.
        dt: time between saved frames (s), for the clock under the panels; default: the
            trajectory's ``time`` field (the batch's one clock), else frame numbers.
        frames: which saved frames to draw, e.g. ``slice(0, 200)`` for the first 200 (default: all).
        max_frames: at most this many frames are drawn (every ``ceil(T' / max_frames)``-th of the
            ``T'`` selected frames).
        fps: frames per second of the file.
        trail: length, in drawn frames, of the fading trail of the tip of the body's longest
            principal axis (0: none).
        dpi: resolution (dots per inch): each panel is ``panel_size·dpi`` pixels square.
        panel_size: side of each panel (inches).
        title: figure title (default: none; the clock is always shown).

    Each panel is a cube in world coordinates (equal scales, axes labelled x, y, z in m, no tick
    labels) holding the body's path plus 1.4 times its largest half extent. The angular-momentum
    arrow starts at the centre of mass and is drawn over the solid; its length is ``1.3 · max h``
    at the largest ``|L|`` the body reaches, so it shows direction and relative size (its scale,
    kg m²/s per drawn metre, differs between panels). A gyrostat's ``L`` is the total, rotors
    included, and a thinner orange arrow on the same scale draws the rotors' own momentum
    ``R Σ_k h_k a_k`` (world frame), the share of ``L`` that the wheels hold (the scale is then
    set by the larger of ``|L|`` and that).

    Returns:
        ``{"frames": F, "seconds": render time (s), "bytes": file size}``.
    """
    if shape not in ("box", "ellipsoid"):
        raise ValueError(f"rbjax.animate: shape must be 'box' or 'ellipsoid', got {shape!r}")
    check_numbers("rbjax.animate", dt=(dt, ">0|None"), max_frames=(max_frames, "int>=1"), fps=(fps, "int>=1"))
    check_numbers("rbjax.animate", trail=(trail, "int>=0"), dpi=(dpi, "int>=1"), panel_size=(panel_size, ">0"))
    path = Path(path)
    if path.suffix.lower() not in (".gif", ".mp4"):
        raise ValueError(f"rbjax.animate: path must end in .gif or .mp4, got {path.name!r}")
    # a bare Figure, not pyplot: no backend is chosen or switched (a notebook keeps its own), and
    # nothing is left open in pyplot's registry
    import matplotlib
    from matplotlib import animation
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    if path.suffix.lower() == ".mp4" and not animation.writers.is_available("ffmpeg"):
        raise RuntimeError("rbjax.animate: writing .mp4 needs ffmpeg on the path; write a .gif instead")

    t0 = _time.perf_counter()
    data = frames_of(traj)
    idx = pick(data["pos"].shape[1], bodies)
    T = data["pos"].shape[0]
    chosen = np.arange(T)[frames if frames is not None else slice(None)]
    if chosen.size == 0:
        raise ValueError(f"rbjax.animate: frames={frames} selects none of the {T} saved frames")
    frames_idx = chosen[:: max(1, math.ceil(chosen.size / max_frames))]
    pos, R, L, h = (data[k][frames_idx][:, idx] for k in ("pos", "R", "L", "h"))
    mass, inertia = data["mass"][idx], data["inertia"][idx]
    moments, axes = np.linalg.eigh(inertia)
    axes = axes * np.sign(np.linalg.det(axes))[:, None, None]
    half = half_extents(moments, mass, shape)  # (N, 3) along the principal axes
    # body-frame vertices: unit solid scaled by half extents, then principal axes to body frame
    unit = _CORNERS[_FACES] if shape == "box" else ellipsoid_mesh()  # (F, 4, 3)
    verts_body = np.einsum("nij,nfkj->nfki", axes, unit[None] * half[:, None, None, :])  # (N, F, 4, 3)
    longest = np.argmax(half, -1)
    tip_body = axes[np.arange(len(idx)), :, longest] * half[np.arange(len(idx)), longest][:, None]  # (N, 3)
    tips = pos + np.einsum("tnij,nj->tni", R, tip_body)  # (F, N, 3)
    # one scale for L and the rotors' h (a gyrostat's total L may be 0 while its wheels spin)
    Lmax = np.maximum(np.linalg.norm(np.concatenate([L, h]), axis=-1).max(0), 1e-300)
    L_draw = L * (1.3 * half.max(-1) / Lmax)[None, :, None]
    h_draw = h * (1.3 * half.max(-1) / Lmax)[None, :, None]
    rotors = bool(np.any(h))

    n = len(idx)
    cols = math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    fig = Figure(figsize=(panel_size * cols, panel_size * rows), dpi=dpi)
    color = matplotlib.colormaps["tab10"]
    artists = []
    for j in range(n):
        ax = fig.add_subplot(rows, cols, j + 1, projection="3d")
        reach = 1.4 * half[j].max()
        lo, hi = pos[:, j].min(0) - reach, pos[:, j].max(0) + reach
        centre, span = (lo + hi) / 2, (hi - lo).max() / 2
        for set_lim, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
            set_lim(c - span, c + span)
        ax.set_box_aspect((1, 1, 1))
        # equal scales on the three axes, so no tick labels: the panel's span is in the docstring
        for axis, name in zip((ax.xaxis, ax.yaxis, ax.zaxis), "xyz"):
            axis.set_ticklabels([])
            axis.labelpad = -12
            axis.set_label_text(f"{name} (m)", fontsize=6)
        # draw in zorder, not by depth: the L arrow stays on top of the solid it starts inside
        ax.computed_zorder = False
        if n > 1:
            ax.set_title(f"body {int(idx[j])}", fontsize=7, pad=0)
        solid = Poly3DCollection(
            [], facecolor=color(j % 10), edgecolor="k", linewidth=0.3 if shape == "box" else 0.1, alpha=0.75
        )
        solid.set_zorder(1)
        ax.add_collection3d(solid)
        (arrow,) = ax.plot([], [], [], color="crimson", lw=2.0, zorder=3)
        (head,) = ax.plot([], [], [], "o", color="crimson", ms=3, zorder=3)
        (wheel,) = ax.plot([], [], [], color="darkorange", lw=1.5, zorder=4)
        trail_lines = [ax.plot([], [], [], color="0.25", lw=1.0, alpha=a)[0] for a in np.linspace(0.08, 0.9, 6)]
        artists.append((solid, arrow, head, wheel, trail_lines))
    clock = fig.text(0.01, 0.01, "", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.subplots_adjust(left=0, right=1, bottom=0.04, top=0.92 if title else 0.97, wspace=0, hspace=0.05)
    times = data["time"]

    def draw(f: int):
        for j, (solid, arrow, head, wheel, trail_lines) in enumerate(artists):
            v = np.einsum("ij,fkj->fki", R[f, j], verts_body[j]) + pos[f, j]
            solid.set_verts(list(v))
            a, b = pos[f, j], pos[f, j] + L_draw[f, j]
            arrow.set_data_3d(*np.stack([a, b], 1))
            head.set_data_3d(*b[:, None])
            if rotors:
                wheel.set_data_3d(*np.stack([a, a + h_draw[f, j]], 1))
            if trail:
                seg = tips[max(0, f - trail) : f + 1, j]
                # older parts of the trail fainter: consecutive pieces of rising alpha, each
                # overlapping the next by one point so the trail has no gaps
                pieces = np.array_split(np.arange(len(seg)), len(trail_lines))
                for line, p in zip(trail_lines, pieces):
                    piece = seg[p[0] : p[-1] + 2] if len(p) else seg[:0]
                    line.set_data_3d(piece[:, 0], piece[:, 1], piece[:, 2])
        clock.set_text(_clock(int(frames_idx[f]), dt, times))
        return []

    anim = animation.FuncAnimation(fig, draw, frames=len(frames_idx), blit=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = animation.PillowWriter(fps=fps) if path.suffix.lower() == ".gif" else animation.FFMpegWriter(fps=fps)
    anim.save(str(path), writer=writer, dpi=dpi)
    return {"frames": float(len(frames_idx)), "seconds": _time.perf_counter() - t0, "bytes": float(path.stat().st_size)}
