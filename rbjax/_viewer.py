"""Interactive 3D viewer: a trajectory in the browser, with a time slider (the ``viewer`` extra).

Built on `viser <https://viser.studio>`_, which serves its own web client (bundled in the Python
wheel) from a local web server: nothing is fetched from the internet, so it works offline. Each body
is drawn as the uniform box (or ellipsoid) with its principal moments, as in
:func:`rbjax.animate`, with an arrow along its world angular momentum ``L`` and the trail of the tip
of its longest axis.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import jax.numpy as jnp
import numpy as np

from ._animate import check_numbers, ellipsoid_mesh, frames_of, half_extents, pick
from ._math import matrix_to_quat_unchecked

__all__ = ["Viewer", "view"]

# a unit cube [-1, 1]^3 as 12 triangles
_CUBE_V = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])
_CUBE_F = np.array(
    [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4]]
    + [[1, 5, 7], [1, 7, 3]]
)
_COLORS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75)]


def _sphere_mesh() -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of the unit sphere, from the quads of :func:`rbjax.animate`'s ellipsoid."""
    quads = ellipsoid_mesh(24, 12)
    verts = quads.reshape(-1, 3)
    faces = np.arange(len(verts)).reshape(-1, 4)
    return verts, np.concatenate([faces[:, [0, 1, 2]], faces[:, [0, 2, 3]]])


@dataclass
class Viewer:
    """A running viewer (returned by :func:`rbjax.view`).

    Attributes:
        server: the ``viser.ViserServer``.
        frame: the time slider's handle; setting ``frame.value = k`` shows saved frame ``k``.
        url: the page to open, ``http://host:port``.
    """

    server: Any
    frame: Any
    url: str
    _stop: threading.Event = field(repr=False)

    def stop(self) -> None:
        """Stop playback and the server."""
        self._stop.set()
        self.server.stop()


def view(
    traj: Any,
    *,
    bodies: int | Sequence[int] | None = None,
    shape: str = "box",
    dt: float | None = None,
    host: str = "127.0.0.1",
    port: int = 8080,
    trail: int = 50,
    fps: float = 20.0,
    spacing: float | None = None,
    play: bool = True,
) -> Any:
    """Show a trajectory in an interactive 3D viewer in the browser, with a time slider.

    Starts a `viser` server on ``http://host:port`` (open it in a browser; it works offline) and
    returns at once: the caller keeps the Python process alive (in a notebook, the kernel does; in
    a script, ``viewer.server.sleep_forever()``) and stops it with ``viewer.stop()``.

    Args:
        traj: a :class:`State` or :class:`MatrixState` trajectory ``(T, *B, ...)``, as
            :func:`rbjax.simulate` returns it (positions in m, world frame; its ``body`` with or
            without the time axis).
        bodies: which bodies of the flattened batch to show: flat indices, or a count ``k`` spread
            evenly over the batch (default: all, up to 9).
        shape: ``"box"`` or ``"ellipsoid"``: the uniform solid with the body's principal moments
            (see :func:`rbjax.animate`).
        dt: time between saved frames (s), shown next to the slider (default: frame numbers).
        host: interface to serve on (``"0.0.0.0"`` to reach it from other machines).
        port: TCP port.
        trail: frames of the trail of each body's longest-axis tip (0: none).
        fps: playback rate, frames per second, when "play" is ticked.
        spacing: distance (m) between bodies laid out on a grid; default: their world positions,
            unless all of them start at one point, in which case a grid ``3 max h`` apart.
        play: start playing at once (the checkbox in the panel toggles it).

    Returns:
        a :class:`Viewer`: its ``url``, ``server`` and ``frame`` slider.
    """
    try:
        import viser
    except ImportError as e:  # pragma: no cover - the optional extra
        raise ImportError("rbjax.view needs viser: pip install 'rbjax[viewer]'") from e
    if shape not in ("box", "ellipsoid"):
        raise ValueError(f"rbjax.view: shape must be 'box' or 'ellipsoid', got {shape!r}")
    # checked here: viser's server thread would die on them with the call left waiting
    check_numbers("rbjax.view", dt=(dt, ">0|None"), port=(port, "port"), trail=(trail, "int>=0"))
    check_numbers("rbjax.view", fps=(fps, ">0"), spacing=(spacing, ">=0|None"))

    data = frames_of(traj)
    idx = pick(data["pos"].shape[1], bodies)
    pos, R, L = (data[k][:, idx] for k in ("pos", "R", "L"))
    mass, inertia = data["mass"][idx], data["inertia"][idx]
    moments, axes = np.linalg.eigh(inertia)
    axes = axes * np.sign(np.linalg.det(axes))[:, None, None]
    half = half_extents(moments, mass, shape)
    n, T = len(idx), pos.shape[0]
    reach = float(half.max())
    if spacing is None and n > 1 and np.ptp(pos[0], axis=0).max() < 1e-9:
        spacing = 3.0 * reach
    if spacing:
        cols = int(np.ceil(np.sqrt(n)))
        grid = np.array([[(j % cols) * spacing, (j // cols) * spacing, 0.0] for j in range(n)])
        pos = pos + (grid - grid.mean(0))[None]
    # (T, N, 4): the drawn solid's principal frame to world; viser takes [w, x, y, z] as rbjax does
    wxyz = np.asarray(matrix_to_quat_unchecked(jnp.asarray(R @ axes[None])), np.float64)
    longest = np.argmax(half, -1)
    tip_body = axes[np.arange(n), :, longest] * half[np.arange(n), longest][:, None]
    tips = pos + np.einsum("tnij,nj->tni", R, tip_body)
    L_draw = L * (2.5 * half.max(-1) / np.maximum(np.linalg.norm(L, axis=-1).max(0), 1e-300))[None, :, None]

    server = viser.ViserServer(host=host, port=port, verbose=False)
    server.scene.set_up_direction("+z")
    centre = pos.reshape(-1, 3).mean(0)
    extent = float(np.ptp(pos.reshape(-1, 3), axis=0).max()) + 2 * reach
    server.initial_camera.position = tuple(centre + extent * np.array([1.2, -1.6, 1.0]))
    server.initial_camera.look_at = tuple(centre)
    floor = (centre[0], centre[1], float(pos[..., 2].min()) - 1.6 * reach)  # a grid under the bodies
    server.scene.add_grid("/grid", width=2 * extent, height=2 * extent, cell_size=extent / 10, position=floor)
    verts, faces = (_CUBE_V, _CUBE_F) if shape == "box" else _sphere_mesh()
    solids, arrows, trails = [], [], []
    for j in range(n):
        solids.append(
            server.scene.add_mesh_simple(
                f"/body{j}", verts, faces, color=_COLORS[j % len(_COLORS)], scale=tuple(half[j]), flat_shading=True
            )
        )
        arrows.append(
            server.scene.add_arrows(
                f"/L{j}",
                np.zeros((1, 2, 3)),
                (220, 20, 60),
                shaft_radius=reach / 40,
                head_radius=reach / 12,
                head_length=reach / 5,
            )
        )
        if trail:
            trails.append(server.scene.add_line_segments(f"/trail{j}", np.zeros((1, 2, 3)), (70, 70, 70)))

    def show(f: int) -> None:
        with server.atomic():
            for j in range(n):
                solids[j].position, solids[j].wxyz = pos[f, j], wxyz[f, j]
                arrows[j].points = np.stack([pos[f, j], pos[f, j] + L_draw[f, j]])[None]
                if trail and f > 0:
                    seg = tips[max(0, f - trail) : f + 1, j]
                    trails[j].points = np.stack([seg[:-1], seg[1:]], 1)

    label = "time (s)" if dt else "frame"
    slider = server.gui.add_slider("frame", min=0, max=T - 1, step=1, initial_value=0)
    clock = server.gui.add_text(label, initial_value="0", disabled=True)
    playing = server.gui.add_checkbox("play", initial_value=play)

    @slider.on_update
    def _(_event: Any) -> None:  # a drag in the browser, or frame.value = k from Python
        f = int(slider.value)
        show(f)
        clock.value = f"{f * dt:.3f}" if dt else str(f)

    show(0)
    stop = threading.Event()

    def loop() -> None:  # playback: advance the slider while "play" is ticked
        while not stop.is_set():
            if playing.value:
                f = (int(slider.value) + 1) % T
                slider.value = f
                show(f)
                clock.value = f"{f * dt:.3f}" if dt else str(f)
            time.sleep(1.0 / fps)

    threading.Thread(target=loop, daemon=True, name="rbjax-viewer-play").start()
    return Viewer(server=server, frame=slider, url=f"http://{host}:{server.get_port()}", _stop=stop)
