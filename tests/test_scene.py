"""Scene specialisations against the general path, mixed batches, compiled cost, sharding."""

import os
import subprocess
import sys
import textwrap

import jax
import jax.extend
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb

# these tests run "splitting" under drag on purpose (paths held to each other, inputs refused):
# its first order there is tests/test_force_protocol.py's to check
pytestmark = pytest.mark.filterwarnings("ignore::rbjax.OrderWarning")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RNG = np.random.default_rng(7)
N = 6
QUATS = RNG.normal(size=(N, 4))
QUATS /= np.linalg.norm(QUATS, axis=-1, keepdims=True)
OMEGA = RNG.normal(size=(N, 3)) * 2
VEL = RNG.normal(size=(N, 3))
TORQUE = RNG.normal(size=(N, 3)) * 0.3


def _max_rel(a, b):
    """Largest difference over every changing leaf, relative to that leaf's largest entry."""
    errs = jax.tree.map(lambda x, y: float(jnp.max(jnp.abs(x - y)) / jnp.max(jnp.abs(y))), a, b)
    return max(jax.tree.leaves(errs))


def _bodies(kind):
    m = jnp.asarray(RNG.uniform(0.5, 2.0, N))
    if kind == "isotropic":
        return rb.sphere(m, jnp.asarray(RNG.uniform(0.2, 1.0, N)))
    if kind == "axisymmetric":
        return rb.cylinder(m, jnp.asarray(RNG.uniform(0.2, 1.0, N)), jnp.asarray(RNG.uniform(0.2, 2.0, N)))
    return rb.box(m, jnp.asarray(RNG.uniform(0.2, 2.0, (N, 3))))


def _state(body, form):
    s = rb.State.create(body, orientation=QUATS, angular_velocity=OMEGA, velocity=VEL)
    return s if form == "quaternion" else rb.to_matrix_state(s)


FORCES = rb.Gravity() + rb.LinearDrag(0.2, angular=0.1) + rb.ConstantForce(torque=TORQUE)


def test_body_kind_detection():
    assert rb.body_kind(rb.sphere(jnp.ones(3), 0.5)) == "isotropic"
    assert rb.body_kind(rb.box(2.0, jnp.array([0.3, 0.3, 0.3]))) == "isotropic"  # a cube
    assert rb.body_kind(rb.cylinder(1.0, 0.2, 1.0)) == "axisymmetric"
    assert rb.body_kind(rb.box(1.0, jnp.array([1.0, 2.0, 3.0]))) == "general"
    mixed = rb.Body(jnp.ones(2), jnp.stack([jnp.eye(3), jnp.diag(jnp.array([1.0, 1.0, 2.0]))]))
    assert rb.body_kind(mixed) == "axisymmetric"  # the most special kind covering both
    tilted = rb.rotate_inertia(rb.cylinder(1.0, 0.2, 1.0).inertia, rb.quat_to_matrix(jnp.asarray(QUATS[0])))
    assert rb.body_kind(rb.Body(1.0, tilted)) == "general"  # symmetry axis not body z


# Tolerances of specialised vs general kernels, relative to each field's largest entry, over 100
# steps of dt = 0.01 with |ω| dt ≈ 0.03:
# * quaternion form: the kinds evaluate ω = R(q̂) I⁻¹ R(q̂)ᵀ L by different closed forms of the
#   same algebra: round-off only, 1e-13.
# * matrix form, Euler: the closed forms assume RᵀR = 1; the general path's R is orthogonal to
#   the residual of its Newton–Schulz projection (~1e-13 per step here): 1e-10.
# * matrix form, RK4: stage matrices R + h/2 k are off SO(3) by O(dt²), where R I Rᵀ and the
#   closed forms differ at O(dt²) per stage: both are RK4 (order 4) but differ at the size of the
#   truncation error, 5e-7 here: 2e-6.
TOL = {
    ("quaternion", "euler"): 1e-13,
    ("quaternion", "rk4"): 1e-13,
    ("matrix", "euler"): 1e-10,
    ("matrix", "rk4"): 2e-6,
}


@pytest.mark.parametrize("method", ["euler", "rk4"])
@pytest.mark.parametrize("form", ["quaternion", "matrix"])
@pytest.mark.parametrize("kind", ["isotropic", "axisymmetric"])
def test_specialised_kernels_match_general_path(kind, form, method):
    s = _state(_bodies(kind), form)
    scene = rb.Scene.build(s, FORCES, method)
    assert (scene.kind, scene.torque_free) == (kind, False)
    got = scene.simulate(s, 0.01, 100, save_every=20)
    want = rb.Scene.build(s, FORCES, method, kind="general").simulate(s, 0.01, 100, save_every=20)
    assert _max_rel(got, want) < TOL[form, method]
    # ... and the motion is not trivial: the bodies turned by far more than the tolerance
    assert float(jnp.max(jnp.abs(rb.orientation(got)[-1] - rb.orientation(got)[0]))) > 0.1


@pytest.mark.parametrize("kind", ["isotropic", "axisymmetric"])
def test_splitting_scene_kernels_match_general_splitting(kind):
    """The splitting kernels of spheres and cylinders (no principal frame) against ``rb.simulate``.

    Same map by another algebra: the general path turns about principal axes found by ``eigh``
    (arbitrary within the equal-moment plane), the kernel about body z and world L. Under torques,
    drag and gravity over 100 steps of dt = 0.01, the two agree to 1e-12 relative (round-off of the
    frame products, ~1e-15 per step; the oblate cylinders' two half turns against one full turn
    differ by ~1e-13 rad at these angles, see ``_cayley``).
    """
    s = _state(_bodies(kind), "quaternion")
    scene = rb.Scene.build(s, FORCES, "splitting")
    assert scene.kind == kind
    got = scene.simulate(s, 0.01, 100, save_every=20)
    assert _max_rel(got, rb.simulate(s, FORCES, 0.01, 100, "splitting", save_every=20)) < 1e-12
    assert float(jnp.max(jnp.abs(got.orientation[-1] - got.orientation[0]))) > 0.1  # not trivial


@pytest.mark.parametrize("form", ["quaternion", "matrix"])
def test_general_scene_kernel_matches_registered_methods(form):
    # The scene's general kernels against rbjax.simulate's "euler" and "rk4" on boxes. Euler and
    # matrix-form RK4: identical formulas, round-off (1e-13). Quaternion RK4: the scene evaluates
    # ω at a stage from q̂ = q/‖q‖, the registered method from the unnormalised stage q
    # (‖q‖ - 1 = O(dt²)); both are order 4 and differ by ~2e-7 here: tolerance 1e-6.
    s = _state(_bodies("general"), form)
    for method, tol in (("euler", 1e-13), ("rk4", 1e-6 if form == "quaternion" else 1e-13)):
        got = rb.Scene.build(s, FORCES, method).simulate(s, 0.01, 100, save_every=20)
        assert _max_rel(got, rb.simulate(s, FORCES, 0.01, 100, method, save_every=20)) < tol


@pytest.mark.parametrize("kind", ["isotropic", "axisymmetric"])
def test_torque_free_scene_matches_general_path(kind):
    # Torque-free: L is never updated; the registered method adds exact zeros. Round-off only
    # against the scene's general kernel (1e-13 relative over 100 RK4 steps).
    s = _state(_bodies(kind), "quaternion")
    forces = rb.Gravity() + rb.LinearDrag(0.3)
    scene = rb.Scene.build(s, forces, "rk4")
    assert scene.torque_free
    got = scene.simulate(s, 0.01, 100, save_every=50)
    want = rb.Scene.build(s, forces, "rk4", kind="general").simulate(s, 0.01, 100, save_every=50)
    assert _max_rel(got, want) < 1e-13
    np.testing.assert_array_equal(got.angular_momentum[-1], s.angular_momentum)  # exactly constant


def test_particles_match_general_path_and_sphere_translation():
    # Particles skip rotation; their translation under gravity and drag is a sphere's (the
    # equations decouple), so the two scenes' positions agree to round-off (1e-14 relative).
    body = _bodies("isotropic")
    p = rb.ParticleState.create(body.mass, position=np.zeros((N, 3)), velocity=VEL)
    forces = rb.Gravity() + rb.LinearDrag(0.2)
    scene = rb.Scene.build(p, forces, "rk4")
    assert scene.kind == "particles"
    got = scene.simulate(p, 0.01, 100, save_every=50)
    assert _max_rel(got, rb.simulate(p, forces, 0.01, 100, "rk4", save_every=50)) < 1e-14
    s = _state(body, "quaternion")
    sphere = rb.Scene.build(s, forces, "rk4").simulate(s, 0.01, 100, save_every=50)
    assert _max_rel(got.position, sphere.position) < 1e-14


def test_mixed_batch_equals_per_body_runs():
    # Boxes, a sphere, a cylinder and a body made of point masses in one general batch, against
    # each body run alone (one compiled program for the four). Round-off: 1e-13 relative.
    masses, points = (
        jnp.array([1.0, 2.0, 0.5, 1.5]),
        jnp.array([[0.3, 0.0, 0.1], [-0.2, 0.4, 0.0], [0.0, -0.3, 0.5], [0.1, 0.1, -0.4]]),
    )
    cloud, _ = rb.from_particles(masses, points)
    parts = [rb.box(1.0, jnp.array([1.0, 2.0, 0.5])), rb.sphere(2.0, 0.4), rb.cylinder(1.5, 0.3, 1.2), cloud]
    body = rb.Body(jnp.stack([b.mass for b in parts]), jnp.stack([b.inertia for b in parts]))
    n = len(parts)
    s = rb.State.create(body, orientation=QUATS[:n], angular_velocity=OMEGA[:n], velocity=VEL[:n])
    forces = rb.Gravity() + rb.LinearDrag(0.2, angular=0.1)
    scene = rb.Scene.build(s, forces, "rk4")
    assert scene.kind == "general"
    got = scene.simulate(s, 0.01, 100, save_every=50)
    for i, b in enumerate(parts):
        one = rb.State.create(
            rb.Body(b.mass[None], b.inertia[None]),
            orientation=QUATS[i : i + 1],
            angular_velocity=OMEGA[i : i + 1],
            velocity=VEL[i : i + 1],
        )
        alone = rb.Scene.build(one, forces, "rk4", kind="general")
        ref = alone.simulate(one, 0.01, 100, save_every=50)
        # got[:, i : i + 1]: every frame of body i, its body and time included
        assert _max_rel(got[:, i : i + 1], ref) < 1e-13, i


def _count_eqns(jaxpr):
    n = 0
    for eqn in jaxpr.eqns:
        n += 1
        for sub in jax.extend.core.jaxprs_in_params(eqn.params):
            n += _count_eqns(sub)
    return n


def test_compiled_step_contains_only_what_the_scene_uses():
    # Cost by construction: the traced step of a simpler scene has strictly fewer operations.
    def cost(state, forces, kind=None):
        scene = rb.Scene.build(state, forces, "rk4", kind=kind)
        return _count_eqns(jax.make_jaxpr(lambda s: scene.step(s, 0.01))(state).jaxpr)

    s = _state(_bodies("isotropic"), "quaternion")
    p = rb.ParticleState.create(s.body.mass, velocity=VEL)
    g = rb.Gravity()
    torqued = g + rb.ConstantForce(torque=TORQUE)
    general, axisym, iso = (cost(s, torqued, k) for k in ("general", "axisymmetric", "isotropic"))
    assert iso < axisym < general
    assert cost(s, g) < iso  # torque-free sphere: L constant, no torque accumulated
    assert cost(p, g) < cost(s, g)  # particles: no rotation at all
    assert cost(s, g) == cost(s, g + rb.ForceSum(()))  # an empty term costs nothing


def test_scene_guards_its_specialisation():
    s = _state(_bodies("isotropic"), "quaternion")
    scene = rb.Scene.build(s, rb.Gravity(), "euler")
    boxes = _state(_bodies("general"), "quaternion")
    with pytest.raises(ValueError, match="specialised for 'isotropic'"):
        scene.simulate(boxes, 0.01, 10)
    with pytest.raises(ValueError, match="more special"):
        rb.Scene.build(boxes, rb.Gravity(), kind="isotropic")
    with pytest.raises(ValueError, match="unknown method"):
        rb.Scene.build(s, rb.Gravity(), "leapfrog-typo")
    with pytest.raises(TypeError, match="ForceModel"):
        rb.Scene.build(s, rb.Forces(force=jnp.zeros(3)))


def test_float32_scene_tracks_float64():
    # float32 users: an isotropic RK4 scene with torques, 100 steps. Round-off ~1e-7 per step,
    # accumulating to ~1e-6 relative; tolerance 1e-5. Strict dtype promotion (conftest) also
    # proves no float64 constant leaks into the float32 step.
    s64 = _state(_bodies("isotropic"), "quaternion")
    s32 = jax.tree.map(lambda a: a.astype(jnp.float32), s64)
    forces = FORCES
    t64 = rb.Scene.build(s64, forces, "rk4").simulate(s64, 0.01, 100, save_every=100)
    t32 = rb.Scene.build(s32, forces, "rk4").simulate(s32, 0.01, 100, save_every=100)
    assert t32.position.dtype == jnp.float32
    assert _max_rel(jax.tree.map(lambda a: a.astype(jnp.float64), t32), t64) < 1e-5


SHARDING_CHECK = textwrap.dedent(
    """
    import jax, jax.numpy as jnp, numpy as np
    jax.config.update("jax_enable_x64", True)
    import rbjax as rb
    from jax.sharding import NamedSharding, PartitionSpec as P
    assert len(jax.devices()) == 8
    n = 64
    rng = np.random.default_rng(0)
    s = rb.State.create(rb.box(rng.uniform(1, 2, n), rng.uniform(0.5, 1.5, (n, 3))),
                        velocity=rng.normal(size=(n, 3)), angular_velocity=rng.normal(size=(n, 3)))
    spring = rb.Spring.between(np.arange(0, n, 2), np.arange(1, n, 2), 3.0, point_a=np.full((n // 2, 3), 0.1))
    forces = rb.Gravity() + rb.LinearDrag(0.1, angular=0.05) + spring
    worst = 0.0
    explicit = jax.make_mesh((8,), ("bodies",))  # jax's default: explicit axis types
    auto = jax.sharding.Mesh(np.array(jax.devices()), ("bodies",))  # GSPMD propagation
    scene = rb.Scene.build(s, forces, "euler")
    runs = [(explicit, lambda st: scene.simulate(st, 0.01, 20, save_every=5)),
            (auto, lambda st: rb.simulate(st, rb.Gravity(), 0.01, 20, "euler", save_every=5))]
    for mesh, run in runs:
        traj, ref = run(jax.device_put(s, rb.batch_sharding(s, mesh))), run(s)
        for path, leaf in jax.tree_util.tree_leaves_with_path(traj):
            assert len(leaf.sharding.device_set) == 8, leaf.sharding
            assert leaf.shape[:2] == (5, n)  # 5 saved frames lead, then the bodies
            if mesh is auto and jax.tree_util.keystr(path) == ".time":
                continue  # GSPMD replicates the times it builds from scalars (a known limit)
            assert leaf.sharding.spec[1] == "bodies", (leaf.shape, leaf.sharding)
        err = jax.tree.map(lambda a, b: float(jnp.max(jnp.abs(a - b)) / jnp.max(jnp.abs(b))), traj, ref)
        worst = max(worst, max(jax.tree.leaves(err)))
    # the README's normal case: one body shared by the batch (replicated, not split)
    shared = rb.State.create(rb.box(1.0, [0.1, 0.2, 0.4]), angular_velocity=rng.normal(size=(n, 3)))
    traj = rb.simulate(jax.device_put(shared, rb.batch_sharding(shared, auto)), None, 0.01, 20, "rk4", save_every=5)
    assert traj.position.sharding.spec[1] == "bodies" and traj.body.mass.shape == (5, 1)
    ref = rb.simulate(shared, None, 0.01, 20, "rk4", save_every=5)
    worst = max(worst, float(jnp.max(jnp.abs(traj.orientation - ref.orientation))))
    print("WORST", worst)
    """
)


@pytest.mark.slow  # a fresh process with 8 host devices
def test_sharded_simulate_keeps_sharding_and_results():
    # 8 host devices need XLA_FLAGS before JAX starts, hence a fresh process. Every output leaf
    # must stay split over the 8 devices on its body axis (axis 1, behind time) for both mesh
    # axis types (explicit: a Scene with springs that
    # gather and scatter by body index; auto: rbjax.simulate), and equal the unsharded run to
    # round-off (the partitioned program may fuse differently): 1e-13 relative.
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=8".strip()
    env = dict(os.environ, XLA_FLAGS=flags, PYTHONPATH=ROOT, JAX_PLATFORMS="cpu")
    out = subprocess.run([sys.executable, "-c", SHARDING_CHECK], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    worst = float(out.stdout.split("WORST")[-1])
    assert worst < 1e-13
