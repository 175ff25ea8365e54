"""rbjax.animate: a GIF whose frames show the rotating body move and the body at rest stay still."""

from __future__ import annotations

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb

PIL = pytest.importorskip("PIL.Image")
pytest.importorskip("matplotlib")


@pytest.fixture(scope="module")
def traj():
    # body 0 spins about a tilted axis; body 1 is at rest (the same frame every time)
    body = rb.box(jnp.array([1.0, 2.0]), jnp.array([[0.1, 0.2, 0.4], [0.3, 0.2, 0.1]]))
    state = rb.State.create(body, angular_velocity=jnp.array([[1.0, 4.0, 0.5], [0.0, 0.0, 0.0]]))
    return rb.simulate(state, None, dt=0.01, steps=80, method="rk4", save_every=10)  # 9 frames


def _frames(path):
    im = PIL.open(path)
    out = []
    for k in range(im.n_frames):
        im.seek(k)
        out.append(np.asarray(im.convert("RGB"), dtype=np.int16))
    return out


def test_gif_frames_size_and_motion(traj, tmp_path):
    path = tmp_path / "a.gif"
    info = rb.animate(traj, path, dpi=40, panel_size=2.0, dt=0.1, trail=4)
    frames = _frames(path)
    assert len(frames) == 9 == info["frames"]
    assert frames[0].shape == (80, 160, 3)  # 2 panels of 2 in x 40 dpi, side by side
    assert info["bytes"] == path.stat().st_size > 0
    spinning = [np.abs(f[:, :80] - frames[0][:, :80]).mean() for f in frames[1:]]
    resting = [np.abs(f[:, 80:] - frames[0][:, 80:]).mean() for f in frames[1:]]
    # measured: 4.8..9.5 against 0.08..0.11 (the GIF's per-frame palette dithers the still panel)
    assert min(spinning) > 2.0, spinning  # the rotating box moves in every frame
    assert max(resting) < 0.3, resting  # the body at rest does not


def test_body_with_a_time_axis_and_matrix_state_draw_the_same(traj, tmp_path):
    # simulate's trajectories carry the body per frame; a hand-built one may not
    timed = type(traj)(
        jax.tree.map(lambda a: a[0], traj.body),
        traj.position,
        traj.velocity,
        traj.orientation,
        traj.angular_momentum,
    )
    kw = dict(dpi=30, panel_size=2.0, max_frames=3, bodies=[0], dt=0.1)  # one clock (timed has time 0)
    rb.animate(traj, tmp_path / "a.gif", **kw)
    rb.animate(timed, tmp_path / "b.gif", **kw)
    rb.animate(rb.to_matrix_state(traj), tmp_path / "c.gif", **kw)
    a, b, c = (_frames(tmp_path / f"{x}.gif") for x in "abc")
    assert len(a) == 3 and a[0].shape == (60, 60, 3)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert max(np.abs(x - y).mean() for x, y in zip(a, c)) < 0.5  # same motion, round-off in R


def test_ellipsoid_and_bad_arguments(traj, tmp_path):
    info = rb.animate(traj, tmp_path / "e.gif", shape="ellipsoid", bodies=1, dpi=30, max_frames=2)
    assert info["frames"] == 2
    with pytest.raises(ValueError, match="shape must be"):
        rb.animate(traj, tmp_path / "x.gif", shape="cone")
    with pytest.raises(ValueError, match=r"\.gif or \.mp4"):
        rb.animate(traj, tmp_path / "x.png")
    with pytest.raises(ValueError, match="out of range"):
        rb.animate(traj, tmp_path / "x.gif", bodies=[5])


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(max_frames=0), ValueError, r"max_frames must be >= 1, got 0"),  # was ZeroDivisionError
        (dict(fps=0), ValueError, r"fps must be >= 1"),
        (dict(trail=-1), ValueError, r"trail must be >= 0"),
        (dict(panel_size=float("nan")), ValueError, r"panel_size must be finite and >0"),
        (dict(dt=0.0), ValueError, r"dt must be finite and >0"),
        (dict(dpi=80.5), TypeError, r"dpi must be an int"),
    ],
)
def test_animate_names_a_bad_number(traj, tmp_path, kwargs, error, match):
    with pytest.raises(error, match=r"rbjax\.animate: " + match):
        rb.animate(traj, tmp_path / "x.gif", **kwargs)
    assert not (tmp_path / "x.gif").exists()


def test_view_refuses_a_bad_port_before_starting_a_server(traj):
    # viser's server thread died on port=-1 with the call left waiting for it
    pytest.importorskip("viser")
    with pytest.raises(ValueError, match=r"rbjax\.view: port must be in 0\.\.65535, got -1"):
        rb.view(traj, port=-1)
    with pytest.raises(ValueError, match=r"rbjax\.view: fps must be finite and >0"):
        rb.view(traj, fps=0.0)


@pytest.mark.slow
def test_demo_writes_the_gif_next_to_the_png(tmp_path, capsys):
    from rbjax._cli import main

    png = tmp_path / "demo.png"
    assert main(["demo", "--bodies", "20", "--seconds", "3", "--out", str(png)]) == 0
    out = capsys.readouterr().out
    gif = PIL.open(tmp_path / "demo.gif")
    assert png.exists() and "animation" in out and gif.n_frames >= 50 and gif.size == (320, 320), out
    # the T-handle flips (its intermediate-axis rate changes sign) about every 0.75 s: 13 in the
    # demo's 10 s, so at least 2 in 3 s; 0 meant the flips were counted against the wrong axes
    flips = int(re.search(r"T-handle\s+(\d+) flips", out).group(1))
    assert flips >= 2, out


def test_a_gyrostat_draws_its_total_L_and_the_rotors_momentum(tmp_path):
    # a wheel spun up from rest by its motor inside a body at rest: the body counter-rotates, the
    # total L stays 0 (no external torque) while the rotor's momentum grows. Before, MatrixState's L
    # arrow drew R I ω alone, the body's share, which is not conserved, and no arrow showed the wheel
    from rbjax._animate import frames_of

    rotors = rb.Rotors([[0.0, 0.0, 1.0]], [1e-3])
    for cls in (rb.State, rb.MatrixState):
        state = cls.create(rb.box(1.0, [0.1, 0.2, 0.3]), angular_velocity=[0.0, 0.0, 0.0], rotors=rotors)
        traj = rb.simulate(state, rb.Forces(rotor_torque=jnp.array([0.01])), 0.01, 50, "rk4", save_every=10)
        data = frames_of(traj)
        # |R h a| = |h|: the wheel's momentum, J Ω = 0.01 N m · t, drawn whole
        np.testing.assert_allclose(np.linalg.norm(data["h"][:, 0], axis=-1), np.abs(traj.rotor_momentum[:, 0]))
        assert np.abs(traj.rotor_momentum[-1, 0]) > 4e-3
        # total L conserved at 0, to round-off of the 5e-3 kg m²/s exchanged
        np.testing.assert_allclose(data["L"], 0.0, atol=1e-15)
        rb.animate(traj, tmp_path / f"{cls.__name__}.gif", max_frames=3, trail=0)
        last = _frames(tmp_path / f"{cls.__name__}.gif")[-1]
        # the rotor arrow's dark orange (255, 140, 0), which nothing else in the panel uses
        orange = np.all(np.abs(last - np.array([255, 140, 0])) < 40, axis=-1)
        assert orange.sum() > 10, orange.sum()
