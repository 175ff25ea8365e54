"""The bad-input guard: every public name is called with invalid inputs, or excused.

Each *slot* is one argument of one public function or constructor; hypothesis
draws a value from one of the *families* of invalid inputs that apply to it
(wrong types, non-finite values, wrong shapes, non-positive sizes, low-precision
or complex dtypes, and traced bad values under ``jit`` in checked mode) and the
call must either

* raise ``ValueError`` or ``TypeError`` from rbjax's own code (the raising
  frame is in the ``rbjax`` package: rbjax's words, not a message from JAX's or
  NumPy's internals), or, for a traced value, equinox's run-time error carrying
  rbjax's ``(checked=...)`` message; or
* return a result whose every floating leaf is finite (never a silent NaN).

``test_every_public_name_is_covered_or_excused`` enumerates ``rbjax.__all__``
so that a new public name must get a slot here or an entry in ``EXCUSED``
with its reason.
"""

from __future__ import annotations

import dataclasses
import inspect
import re
import traceback
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import rbjax as rb

# these tests run "splitting" under drag on purpose (paths held to each other, inputs refused):
# its first order there is tests/test_force_protocol.py's to check
pytestmark = pytest.mark.filterwarnings("ignore::rbjax.OrderWarning")

RBJAX_DIR = str(Path(rb.__file__).parent)


def _body():
    return rb.box(1.0, [0.1, 0.2, 0.4])


def _state():
    return rb.State.create(_body(), angular_velocity=[0.3, 1.0, 0.3])


def _particles():
    return rb.ParticleState.create(1.0)


# ------------------------------------------------------------------ families of bad values

_NONFINITE = (np.nan, np.inf, -np.inf)


def _shaped(shape: tuple[int, ...]) -> st.SearchStrategy:
    """Float64 arrays of ``shape`` with at least one NaN or inf."""

    def make(args):
        flat, where, bad = args
        a = np.asarray(flat, np.float64).reshape(shape) if shape else np.float64(flat[0])
        if shape:
            a = a.copy()
            a.flat[where % a.size] = bad
            return a
        return np.float64(bad)

    n = int(np.prod(shape)) if shape else 1
    return st.tuples(
        st.lists(st.floats(0.1, 2.0), min_size=n, max_size=n), st.integers(0, 100), st.sampled_from(_NONFINITE)
    ).map(make)


def _wrong_shape(shape: tuple[int, ...]) -> st.SearchStrategy:
    """Float arrays whose trailing dimension differs from ``shape``'s (or with one axis too many)."""
    last = shape[-1] if shape else None
    sizes = st.integers(1, 5).filter(lambda k: k != last)
    return st.one_of(
        sizes.map(lambda k: np.full(shape[:-1] + (k,), 0.5)),
        st.just(np.full((2, 2) + shape if shape else (2, 7), 0.5)) if shape else st.just(np.full((2, 7), 0.5)),
    )


FAMILIES: dict[str, Callable[[tuple[int, ...]], st.SearchStrategy]] = {
    "wrong_type": lambda shape: st.sampled_from([None, "x", object(), {"a": 1}, ["a", "b"]]),
    "non_finite": _shaped,
    "wrong_shape": _wrong_shape,
    "non_positive": lambda shape: st.floats(-10.0, 0.0).map(lambda v: np.full(shape, v)),
    "low_precision": lambda shape: st.sampled_from([jnp.float16, jnp.bfloat16]).map(lambda d: jnp.full(shape, 0.5, d)),
    "complex": lambda shape: st.just(np.full(shape, 0.5 + 0.5j)),
    "bool": lambda shape: st.just(True),
    "bad_int": lambda shape: st.sampled_from([True, -1, 2.5, "3", None]),
}


@dataclasses.dataclass(frozen=True)
class Slot:
    """One argument of one public name: ``call(bad)`` calls it with ``bad`` in that argument."""

    api: str
    arg: str
    call: Callable[[Any], Any]
    families: tuple[str, ...]
    shape: tuple[int, ...] = ()
    traced: bool = False  # the value goes in traced, under jit, with checked=True

    def __str__(self) -> str:
        return f"{self.api}({self.arg})"


REAL = ("wrong_type", "non_finite", "low_precision", "complex")
SIZE = REAL + ("non_positive", "wrong_shape")
VEC = REAL + ("wrong_shape",)
STATEY = ("wrong_type",)
FORCE_OUT = ("wrong_type", "wrong_shape")


def _quantity(name: str) -> Callable[[Any], Any]:
    return lambda v: getattr(rb, name)(v)


def _as_forces(v):
    """A force callable's return value: ``Forces(torque=v)`` for an array of any shape, else ``v`` itself."""
    return rb.Forces(torque=v) if isinstance(v, np.ndarray) else v


def _toss() -> rb.Recording:
    """A held phone (|a| = g), 0.5 s of free flight (|a| = 0), held again; 100 Hz."""
    t = np.arange(150) / 100
    a = np.zeros((150, 3))
    a[:, 2] = np.where((t > 0.5) & (t < 1.0), 0.0, 9.81)
    return rb.Recording(times=t, gyro=np.zeros((150, 3)), accelerations=a)


def _sim(**kw):
    base = dict(state=_state(), forces=None, dt=0.01, steps=3)
    base.update(kw)
    return rb.simulate(base.pop("state"), base.pop("forces"), base.pop("dt"), base.pop("steps"), **base)


SLOTS: list[Slot] = [
    # ---- bodies and shapes
    Slot("Body", "mass", lambda v: rb.Body(v, jnp.eye(3)), REAL + ("non_positive",)),
    Slot("Body", "inertia", lambda v: rb.Body(1.0, v), VEC + ("non_positive",), (3, 3)),
    Slot("box", "mass", lambda v: rb.box(v, [0.1, 0.2, 0.4]), REAL + ("non_positive",)),
    Slot("box", "size", lambda v: rb.box(1.0, v), SIZE, (3,)),
    Slot("sphere", "radius", lambda v: rb.sphere(1.0, v), SIZE[:-1]),
    Slot("cylinder", "radius", lambda v: rb.cylinder(1.0, v, 1.0), SIZE[:-1]),
    Slot("cylinder", "length", lambda v: rb.cylinder(1.0, 0.5, v), SIZE[:-1]),
    Slot("ellipsoid", "semi_axes", lambda v: rb.ellipsoid(1.0, v), SIZE, (3,)),
    Slot("from_particles", "masses", lambda v: rb.from_particles(v, jnp.eye(3)), REAL + ("non_positive",), (3,)),
    # ---- states
    # (wrong types, float16 and mismatched shapes in the .create classmethods: KNOWN_GAPS below)
    Slot("State", "create.position", lambda v: rb.State.create(_body(), position=v), ("non_finite",), (3,)),
    Slot("State", "create.orientation", lambda v: rb.State.create(_body(), orientation=v), ("non_finite",), (4,)),
    Slot(
        "State",
        "create.angular_velocity",
        lambda v: rb.State.create(_body(), angular_velocity=v),
        ("non_finite",),
        (3,),
    ),
    Slot(
        "MatrixState",
        "create.orientation",
        lambda v: rb.MatrixState.create(_body(), orientation=v),
        ("non_finite",),
        (4,),
    ),
    Slot("MatrixState", "create.velocity", lambda v: rb.MatrixState.create(_body(), velocity=v), ("non_finite",), (3,)),
    Slot("ParticleState", "create.mass", lambda v: rb.ParticleState.create(v), REAL + ("non_positive",)),
    Slot("ParticleState", "create.velocity", lambda v: rb.ParticleState.create(1.0, velocity=v), ("non_finite",), (3,)),
    Slot("Forces", "force", lambda v: rb.Forces(force=v), VEC, (3,)),
    Slot("Forces", "rotor_torque", lambda v: rb.Forces(rotor_torque=v), REAL, (2,)),
    Slot("Rotors", "axes", lambda v: rb.Rotors(v, [1e-3]), VEC, (1, 3)),
    Slot("Rotors", "inertia", lambda v: rb.Rotors([[0.0, 0.0, 1.0]], v), REAL + ("non_positive",), (1,)),
    Slot(
        "rotor_rates",
        "rates",
        lambda v: rb.rotor_rates(rb.Rotors([[0.0, 0.0, 1.0]], [1e-3]), v, 0.01),
        REAL + ("wrong_shape",),
        (3, 1),
    ),
    Slot("Checks", "energy_factor", lambda v: rb.Checks(energy_factor=v), ("wrong_type", "non_positive", "non_finite")),
    # ---- simulation
    Slot("simulate", "dt", lambda v: _sim(dt=v), REAL + ("non_positive", "bool")),
    Slot("simulate", "dt(traced)", lambda v: _sim_traced(v), ("non_positive", "non_finite"), traced=True),
    Slot("simulate", "steps", lambda v: _sim(steps=v), ("bad_int",)),
    Slot("simulate", "save_every", lambda v: _sim(steps=4, save_every=v), ("bad_int",)),
    Slot("simulate", "t0", lambda v: _sim(t0=v), REAL),
    Slot("simulate", "state", lambda v: _sim(state=v), STATEY),
    Slot("simulate", "forces", lambda v: _sim(forces=v), ("wrong_type",)),
    Slot(
        "simulate", "forces()", lambda v: _sim(forces=lambda s, t: _as_forces(v)), ("wrong_type", "wrong_shape"), (3,)
    ),
    Slot("simulate", "method", lambda v: _sim(method=v), ("wrong_type",)),
    Slot("simulate", "checked", lambda v: _sim(checked=v), ("wrong_type",)),
    Slot("simulate", "checkpoint", lambda v: _sim(steps=4, checkpoint=v), ("bad_int",)),
    Slot("step", "dt", lambda v: rb.step(_state(), None, v), REAL + ("non_positive", "bool")),
    Slot(
        "step",
        "forces()",
        lambda v: rb.step(_state(), lambda s, t: _as_forces(v), 0.01),
        ("wrong_type", "wrong_shape"),
        (3,),
    ),
    Slot("simulate_chunked", "dt", lambda v: rb.simulate_chunked(_state(), None, v, 4, progress=False), REAL),
    Slot(
        "simulate_chunked", "steps", lambda v: rb.simulate_chunked(_state(), None, 0.1, v, progress=False), ("bad_int",)
    ),
    Slot(
        "simulate_chunked",
        "chunk_steps",
        lambda v: rb.simulate_chunked(_state(), None, 0.1, 4, chunk_steps=v, progress=False),
        ("bad_int",),
    ),
    Slot("simulate_truncated", "dt", lambda v: rb.simulate_truncated(_state(), None, v, 4, truncate_every=2), REAL),
    Slot("shoot", "steps", lambda v: rb.shoot(_state(), None, 0.1, v), ("bad_int",)),
    Slot("torque_free", "t", lambda v: rb.torque_free(_state(), v), ("wrong_type", "non_finite", "complex")),
    # ---- force models
    Slot("Gravity", "g", lambda v: rb.Gravity(v), VEC, (3,)),
    Slot("LinearDrag", "linear", lambda v: rb.LinearDrag(v), REAL),
    Slot("QuadraticDrag", "linear", lambda v: rb.QuadraticDrag(v), REAL),
    Slot("Spring", "stiffness", lambda v: rb.Spring.to_anchor([0], [[0.0, 0, 0]], v), REAL),
    Slot("Thruster", "thrust", lambda v: rb.Thruster([0], [[0.0, 0, 1]], v), REAL),
    Slot("ConstantForce", "force", lambda v: rb.ConstantForce(force=v), VEC, (3,)),
    Slot("TimeSeriesForce", "force", lambda v: rb.TimeSeriesForce([0.0, 1.0], force=v), VEC, (2, 3)),
    # ---- quantities of a state
    *[
        Slot(name, "state", _quantity(name), STATEY)
        for name in (
            "kinetic_energy",
            "linear_momentum",
            "angular_momentum",
            "angular_velocity",
            "body_angular_velocity",
            "orientation",
            "rotation_matrix",
            "world_inertia",
            "to_matrix_state",
            "to_state",
        )
    ],
    # ---- files
    Slot("save", "obj", lambda v: rb.save(_tmp() / "x.npz", v), ("wrong_type",)),
    Slot("load", "path", lambda v: rb.load(_tmp() / "absent.npz" if v is None else _tmp()), ("wrong_type",)),
    Slot("read_metadata", "path", lambda v: rb.read_metadata(_tmp() / "absent.npz"), ("wrong_type",)),
    Slot("ChunkWriter", "resume", lambda v: rb.ChunkWriter(_tmp() / "w", overwrite=True, resume=True), ("bool",)),
    # ---- trajectories and batches
    Slot("concatenate", "items", lambda v: rb.concatenate(v), ("wrong_type",)),
    Slot("concatenate", "items[1]", lambda v: rb.concatenate([_state(), v]), ("wrong_type",)),
    Slot("batch_sharding", "obj", lambda v: rb.batch_sharding(v, jax.make_mesh((1,), ("bodies",))), ("wrong_type",)),
    Slot("symmetric_part", "A", lambda v: rb.symmetric_part(v), ("wrong_shape",), (3, 3)),
    # ---- recordings
    Slot("Recording", "times", lambda v: rb.Recording(times=v), ("wrong_type", "non_finite", "complex"), (4,)),
    Slot(
        "Recording",
        "gyro",
        lambda v: rb.Recording(times=np.arange(4) / 100, gyro=v),
        ("wrong_type", "non_finite", "complex", "wrong_shape"),
        (4, 3),
    ),
    Slot(
        "Recording",
        "rotor_rates",
        lambda v: rb.Recording(times=np.arange(4) / 100, gyro=np.zeros((4, 3)), rotor_rates=v),
        ("wrong_type", "non_finite", "complex", "wrong_shape"),
        (4,),
    ),
    Slot("find_throws", "recording", lambda v: rb.find_throws(v), ("wrong_type",)),
    Slot(
        "find_throws",
        "threshold",
        lambda v: rb.find_throws(_toss(), threshold=v),
        ("wrong_type", "non_finite", "non_positive"),
    ),
    Slot("plot_throws", "recording", lambda v: rb.plot_throws(v, []), ("wrong_type",)),
    # ---- calibration (its numeric arguments need fits: tests/test_calibration.py refuses them)
    Slot(
        "calibrate_device",
        "alone",
        lambda v: rb.calibrate_device(v, v, device_mass=0.1, proof_mass=0.2, proof_inertia=np.eye(3)),
        ("wrong_type",),
    ),
    Slot("object_inertia", "device", lambda v: rb.object_inertia(None, v, object_mass=1.0), ("wrong_type",)),
]

# Names not called above, with the reason.
EXCUSED: dict[str, str] = {
    "RecordingError": "an exception class: raised by the readers, not called with data",
    # jax.numpy-level building blocks used inside traced kernels: they follow jax.numpy's shape and
    # type conventions (its errors are JAX's) and cannot test values, which are traced there
    **{
        n: "array function used inside traced kernels: NaN in gives NaN out by design; its shapes and "
        "dtypes are checked while tracing (HELPERS, test_helpers_*)"
        for n in (
            "cross",
            "matrix_to_quat",
            "orthonormalize",
            "quat_angle",
            "quat_conjugate",
            "quat_exp",
            "quat_log",
            "quat_multiply",
            "quat_normalize",
            "quat_rotate",
            "quat_to_matrix",
            "safe_norm",
            "skew",
            "parallel_axis",
            "rotate_inertia",
            "inertia_from_params",
            "params_from_inertia",
            "second_moment",
        )
    },
    **{
        n: "jax.numpy-level function of states used inside traced kernels: NaN in gives NaN out by design"
        for n in ("derivative", "defects")
    },
    "TRIANGLE_RTOL": "a constant",
    "methods": "no argument but an optional state type; returns the registry",
    "native_status": "takes no argument; reports whether the native kernels loaded",
    "NativeStatus": "the report native_status returns; built by rbjax, not by users",
    "StepSizeWarning": "a warning class: given by simulate and step, not called with data",
    "ForceModel": "abstract base class (its refusals: FORCE_MODEL_CASES['PerBodyForce'], test_force_protocol.py)",
    "PerBodyForce": "abstract base class: FORCE_MODEL_CASES['PerBodyForce'] holds its refusals",
    "Method": "an integrator's record: its fields are checked when it is built (test_method_objects.py)",
    "AbstractMethod": "abstract base: a subclass is checked when defined and built (test_method_protocol.py)",
    "OrderWarning": "a warning class: given by simulate, not called with data",
    "field": "declares a dataclass field when a class is defined; holds no data to check",
    "static_field": "declares a dataclass field when a class is defined; holds no data to check",
    "ForceSum": "built by + from validated models",
    "CustomForce": "wraps a user's callable: its output is checked as a force callable's (slot simulate(forces()))",
    "ExternalForce": "wraps user callables of t; checked like a force callable when simulated",
    "FitResult": "a result container returned by fit_inertia, not built by users",
    "DeviceCalibration": "a result container returned by calibrate_device, not built by users",
    "ObjectInertia": "a result container returned by object_inertia, not built by users",
    "fit_inertia": "validated by tests/test_fit.py (its own argument checks); too slow to compile per example",
    "fit_inertia_linear": "validated by tests/test_fit.py",
    "Scene": "validated by tests/test_scene.py (kind/method checks); each example would compile a kernel",
    "body_kind": "takes a Body, which is validated at construction",
    "register_kernel": "extension hook for kernel authors, checked by tests/test_scene.py",
    "animate": "renders files through matplotlib; its argument checks are in tests/test_animate.py",
    "view": "starts a web server (viser); tested in a browser by tests/test_viewer.py",
    "Viewer": "the server object behind view; tests/test_viewer.py",
}

_TMP: list[Path] = []


def _tmp() -> Path:
    return _TMP[0]


@pytest.fixture(autouse=True, scope="module")
def _tmpdir(tmp_path_factory):
    _TMP[:] = [tmp_path_factory.mktemp("bad")]


_TRACED = eqx.filter_jit(lambda dt: rb.simulate(_state(), None, dt, 3, "euler", checked=True).position)


def _sim_traced(v):
    return _TRACED(jnp.asarray(v, jnp.float64))


def _from_rbjax(e: BaseException) -> bool:
    """Whether the innermost frame that raised ``e`` is rbjax's own code."""
    frames = traceback.extract_tb(e.__traceback__)
    return bool(frames) and frames[-1].filename.startswith(RBJAX_DIR)


def _fault(slot: Slot, value: Any, family: str) -> str | None:
    """What is wrong with how ``slot`` treats the bad ``value``, or None when it is refused in rbjax's
    words (``ValueError``/``TypeError`` raised in rbjax's own code) or gives a finite result."""
    try:
        out = slot.call(value)
        jax.block_until_ready(out)
    except (ValueError, TypeError) as e:
        return None if _from_rbjax(e) else f"{type(e).__name__} from outside rbjax: {e}"
    except Exception as e:  # noqa: BLE001
        if slot.traced and "(checked=...)" in str(e):
            return None  # equinox's run-time error carrying rbjax's message
        return f"{type(e).__name__} (not ValueError/TypeError): {e}"
    # a complex number has no finite real answer: taking its real part drops data without a word
    if family == "complex":
        return "accepted a complex value instead of refusing it"
    for leaf in jax.tree.leaves(out):
        a = np.asarray(leaf)
        if np.issubdtype(a.dtype, np.floating) and not np.isfinite(a).all():
            return "returned non-finite values silently"
    return None


@pytest.mark.parametrize("slot", SLOTS, ids=str)
@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_bad_input_is_refused_in_rbjax_words_or_gives_a_finite_result(slot, data):
    family = data.draw(st.sampled_from(slot.families), label="family")
    value = data.draw(FAMILIES[family](slot.shape), label="value")
    fault = _fault(slot, value, family)
    assert fault is None, f"{slot} with {value!r} ({family}): {fault}"


_FORCE_SLOTS = [
    s for s in SLOTS if isinstance(getattr(rb, s.api, None), type) and issubclass(getattr(rb, s.api), rb.ForceModel)
]


@pytest.mark.parametrize("slot", _FORCE_SLOTS, ids=str)
@settings(max_examples=6, deadline=None)
@given(data=st.data())
def test_bad_input_to_a_users_subclass_of_a_force_law_is_refused_as_by_the_law(slot, data):
    """The slots of the public force laws with the law replaced by a user's subclass of it
    (``rb.<Law>`` patched while the slot is called; see :func:`_subclass_of`)."""
    family = data.draw(st.sampled_from(slot.families), label="family")
    value = data.draw(FAMILIES[family](slot.shape), label="value")
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(rb, slot.api, _subclass_of(getattr(rb, slot.api)))
        fault = _fault(slot, value, family)
    assert fault is None, f"a subclass of {slot} with {value!r} ({family}): {fault}"


def test_every_public_name_is_covered_or_excused():
    covered = {s.api for s in SLOTS}
    public = set(rb.__all__)
    missing = sorted(public - covered - set(EXCUSED))
    assert not missing, f"public names with no bad-input slot and no reason in EXCUSED: {missing}"
    stale = sorted((covered | set(EXCUSED)) - public)
    assert not stale, f"slots or excuses for names that are not public: {stale}"
    assert not covered & set(EXCUSED), "a name is both covered and excused"


# Bad inputs that used to get JAX's message from State.create and friends (they converted with
# jnp.asarray before any check); kept as regression cases.
FIXED_GAPS = {
    "State.create(position='x')": lambda: rb.State.create(_body(), position="x"),
    "State.create(angular_velocity=float16)": lambda: rb.State.create(
        _body(), angular_velocity=jnp.ones(3, jnp.float16)
    ),
    "State.create(body batch (3,), position (4, 3))": lambda: rb.State.create(
        rb.box(jnp.ones(3), jnp.ones((3, 3))), position=jnp.zeros((4, 3))
    ),
    "MatrixState.create(velocity=object())": lambda: rb.MatrixState.create(_body(), velocity=object()),
    "ParticleState.create(velocity (2,))": lambda: rb.ParticleState.create(1.0, velocity=np.ones(2)),
}


@pytest.mark.parametrize("name", list(FIXED_GAPS))
def test_state_create_refuses_in_rbjax_words(name):
    with pytest.raises((ValueError, TypeError)) as info:
        FIXED_GAPS[name]()
    assert _from_rbjax(info.value), info.value


def test_text_in_a_list_is_refused_before_jax_reads_it():
    # jnp.asarray takes a string such as 'a' or 'f' for a dtype name (NumPy warns that 'a' is
    # deprecated) before it fails: rbjax refuses the list first, in its own words and quietly
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for make in (
            lambda: rb.box(1.0, ["a", "b", "f"]),
            lambda: rb.LinearDrag([["a"], ["d"]]),
            lambda: rb.State.create(_body(), position=("x", 1.0, 2.0)),
            lambda: rb.from_particles(["a", "b"], np.zeros((2, 3))),  # through array_arg
            lambda: rb.quat_normalize(["a", "b", "f", "d"]),
        ):
            with pytest.raises(TypeError, match="holding text") as info:
                make()
            assert _from_rbjax(info.value), info.value


# ------------------------------------------------------------------ silent wrong answers off the tested path


def test_cli_fit_help_quotes_the_defaults_fit_inertia_uses():
    """Every ``(default X)`` in ``fit``'s help for an option passed to fit_inertia is fit_inertia's default."""
    import argparse
    import inspect
    import re

    from rbjax import _cli, _cli_fit

    parser = _cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    fit = sub.choices["fit"]
    defaults = inspect.signature(rb.fit_inertia).parameters
    checked = 0
    for action in fit._actions:
        kw = _cli_fit.FIT_OPTIONS.get(action.dest)
        said = re.search(r"default ([^()\s]+)\)", action.help or "")
        if kw is None or said is None:
            continue
        assert said.group(1) == str(defaults[kw].default), (action.dest, action.help, defaults[kw].default)
        checked += 1
    assert checked >= 2  # --method and --max-steps at least


def _empty(kind: str):
    """An empty batch (N = 0) of ``kind``."""
    if kind == "ParticleState":
        return rb.ParticleState.create(jnp.ones(0))
    body = rb.box(jnp.ones(0), jnp.ones((0, 3)))
    return getattr(rb, kind).create(body)


@pytest.mark.parametrize("kind", ["State", "MatrixState", "ParticleState"])
@pytest.mark.parametrize("method", ["euler", "rk4", "splitting"])
def test_an_empty_batch_simulates_to_empty_results(kind, method):
    """N = 0 has no clock to read (the time was read from body 0): it simulates to empty frames."""
    state = _empty(kind)
    traj = rb.simulate(state, rb.Gravity() + rb.LinearDrag(0.1), 0.01, 4, method, save_every=2)
    assert traj.position.shape == (3, 0, 3)
    assert traj.time.shape == (3, 0)
    assert rb.step(state, None, 0.01, method).position.shape == (0, 3)
    chunked = rb.simulate_chunked(state, None, 0.01, 4, method, chunk_steps=2, progress=False)
    assert chunked.position.shape == (5, 0, 3)


_BAD_TIMES = {
    "two times, one body": [0.0, 1.0],
    "(2, 3) times": np.zeros((2, 3)),
    "a string": "x",
    "NaN": np.nan,
    "inf in a list": [np.inf],
}
_TIME_TAKERS = {
    "State.create": lambda t: rb.State.create(_body(), time=t),
    "MatrixState.create": lambda t: rb.MatrixState.create(_body(), time=t),
    "ParticleState.create": lambda t: rb.ParticleState.create(1.0, time=t),
    "State": lambda t: rb.State(_body(), [0.0, 0, 0], [0.0, 0, 0], [1.0, 0, 0, 0], [0.0, 0, 0], time=t),
    "MatrixState": lambda t: rb.MatrixState(_body(), [0.0, 0, 0], [0.0, 0, 0], np.eye(3), [0.0, 0, 0], time=t),
    "ParticleState": lambda t: rb.ParticleState([0.0, 0, 0], [0.0, 0, 0], 1.0, time=t),
}


@pytest.mark.parametrize("bad", list(_BAD_TIMES))
@pytest.mark.parametrize("taker", list(_TIME_TAKERS))
def test_a_time_that_does_not_fit_the_batch_is_refused_naming_time(taker, bad):
    with pytest.raises((ValueError, TypeError)) as info:
        _TIME_TAKERS[taker](_BAD_TIMES[bad])
    assert _from_rbjax(info.value), info.value
    assert "time" in str(info.value) and taker.split(".")[0] in str(info.value)


# ---- math helpers: every public function taking (..., 3), (..., 4), (..., 3, 3) or (..., 6) arrays

_CORE = re.compile(r"""["'](?:\.\.\.|\*B) ?(3 3|3|4|6)["']""")
_EXTRA_ARGS = {  # required arguments without a core shape
    "parallel_axis": {"mass": 1.0},
    "angular_momentum": {"state": rb.State.create(rb.box(1.0, [0.1, 0.2, 0.4]), velocity=[1.0, 0.0, 0.0])},
    "box": {"mass": 1.0},
    "ellipsoid": {"mass": 1.0},
}


def _core_args() -> dict[str, dict[str, tuple[int, ...]]]:
    """``{helper: {argument: core shape}}`` of every public function, read from its annotations."""
    out = {}
    for name in rb.__all__:
        fn = getattr(rb, name)
        if not inspect.isfunction(fn):
            continue
        args = {}
        for p in inspect.signature(fn).parameters.values():
            m = _CORE.search(str(p.annotation))
            if m:
                args[p.name] = tuple(int(c) for c in m.group(1).split())
        if args:
            out[name] = args
    return out


HELPERS = _core_args()


def _good(core: tuple[int, ...], dtype=np.float64) -> np.ndarray:
    """A valid argument of ``core`` shape for every helper: a vector, a unit quaternion, the identity."""
    return {
        (3,): np.array([1, 2, 3]),
        (4,): np.array([1, 0, 0, 0]),
        (3, 3): np.eye(3, dtype=int),
        (6,): np.array([0, 1, 0, 1, 0, 1]),
    }[core].astype(dtype)


def _helper_call(name: str, **override):
    kwargs = {a: _good(c) for a, c in HELPERS[name].items()} | _EXTRA_ARGS.get(name, {}) | override
    return getattr(rb, name)(**kwargs)


def test_the_helper_list_is_complete():
    """The introspected list holds the known validation helpers (so the regex still reads the annotations)."""
    for name in ("quat_multiply", "quat_exp", "skew", "quat_to_matrix", "orthonormalize", "cross", "quat_rotate"):
        assert name in HELPERS, name
    assert HELPERS["quat_rotate"] == {"q": (4,), "v": (3,)}


@pytest.mark.parametrize("slot", [f"{n}.{a}" for n, args in HELPERS.items() for a in args])
@settings(max_examples=8, deadline=None)
@given(data=st.data())
def test_helpers_refuse_a_wrong_last_axis_naming_the_argument(slot, data):
    """A 3-vector for a quaternion, a fifth component, ``[1, 2]`` for ``skew``: ``ValueError`` naming it."""
    name, arg = slot.split(".")
    core = HELPERS[name][arg]
    batch = data.draw(st.sampled_from([(), (2,)]), label="batch")
    axis = data.draw(st.integers(0, len(core) - 1), label="axis")
    size = data.draw(st.integers(1, 7).filter(lambda k: k != core[axis]), label="size")
    shape = batch + core[:axis] + (size,) + core[axis + 1 :]
    with pytest.raises(ValueError) as info:
        jax.block_until_ready(_helper_call(name, **{arg: np.full(shape, 0.5)}))
    assert _from_rbjax(info.value), info.value
    assert f"{name}: {arg} " in str(info.value), info.value


@pytest.mark.parametrize("name", list(HELPERS))
def test_helpers_compute_integer_inputs_in_floats(name):
    """Integers are cast to the default float dtype (as the constructors do): same values as float input."""
    as_int = {a: _good(c, np.int32) for a, c in HELPERS[name].items()}
    got = jax.tree.leaves(_helper_call(name, **as_int))
    want = jax.tree.leaves(_helper_call(name))
    assert got and len(got) == len(want)
    for g, w in zip(got, want):
        assert jnp.issubdtype(g.dtype, jnp.floating)
        np.testing.assert_allclose(g, w, rtol=1e-12)


@pytest.mark.parametrize("name", list(HELPERS))
def test_helpers_refuse_bool_and_complex_arguments_in_rbjax_words(name):
    for bad in (np.full(_good(next(iter(HELPERS[name].values()))).shape, 0.5 + 0.5j), True):
        arg = next(iter(HELPERS[name]))
        with pytest.raises(TypeError) as info:
            _helper_call(name, **{arg: bad})
        assert _from_rbjax(info.value) and re.search(rf"{name}: {arg}\b", str(info.value)), info.value


@settings(max_examples=30, deadline=None)
@given(
    rotvec=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
    scale=st.floats(0.05, 20.0),
    noise=st.lists(st.floats(-1e-3, 1e-3), min_size=9, max_size=9),
)
def test_orthonormalize_returns_the_rotation_of_any_positive_multiple(rotvec, scale, noise):
    """``orthonormalize(c (Q + E))`` is ``Q`` (to ``O(E)``) with ``det = +1`` for every ``c > 0``; 2 R gave -R."""
    Q = np.asarray(rb.quat_to_matrix(rb.quat_exp(np.asarray(rotvec))))
    R = scale * (Q + np.reshape(noise, (3, 3)))
    out = np.asarray(rb.orthonormalize(R))
    assert abs(np.linalg.det(out) - 1) < 1e-9
    np.testing.assert_allclose(out.T @ out, np.eye(3), atol=1e-9)
    np.testing.assert_allclose(out, Q, atol=1e-2)
    np.testing.assert_allclose(np.asarray(rb.orthonormalize(scale * Q)), Q, atol=1e-12)


def test_orthonormalize_refuses_what_it_cannot_do():
    Q = np.asarray(rb.quat_to_matrix(rb.quat_normalize(np.array([1.0, 0.2, 0.3, 0.4]))))
    with pytest.raises(ValueError, match=r"orthonormalize: R must have det R > 0"):
        rb.orthonormalize(-Q)  # a reflection
    with pytest.raises(ValueError, match=r"orthonormalize: R is too far .* more iterations"):
        rb.orthonormalize(Q @ np.diag([1.3, 1.0, 0.8]))  # 2 iterations do not get there
    far = np.asarray(rb.orthonormalize(Q @ np.diag([1.3, 1.0, 0.8]), iterations=8))
    assert abs(np.linalg.det(far) - 1) < 1e-12
    assert np.isnan(np.asarray(jax.jit(rb.orthonormalize)(-Q))).all()  # traced: NaN, not a wrong rotation


# ---- force models: every public ForceModel class refuses what it cannot mean, naming the argument


def _three():
    """Three rigid bodies in a row (a 1-D batch of N = 3)."""
    return rb.State.create(rb.box(jnp.ones(3), jnp.ones((3, 3))), position=np.eye(3), angular_velocity=np.ones(3))


_Z = [[0.0, 0.0, 1.0]]

# model class -> {case: (what the message names, build at construction, or None if refused when simulated)}
FORCE_MODEL_CASES: dict[str, dict[str, tuple[str, Callable[[], Any]]]] = {
    "Gravity": {
        "scalar g": ("g", lambda: rb.Gravity(9.81)),
        "2-vector g": ("g", lambda: rb.Gravity([0.0, -9.81])),
        "4-vector g": ("g", lambda: rb.Gravity([0.0, 0.0, -9.81, 0.0])),
        "g per body, wrong batch": ("g", lambda: _sim3(rb.Gravity(np.zeros((2, 3))))),
    },
    "LinearDrag": {
        "negative linear": ("linear", lambda: rb.LinearDrag(-0.1)),
        "negative angular": ("angular", lambda: rb.LinearDrag(0.1, angular=[-0.2])),
        "linear per body, wrong batch": ("linear", lambda: _sim3(rb.LinearDrag(np.ones(2)))),
    },
    "QuadraticDrag": {
        "negative linear": ("linear", lambda: rb.QuadraticDrag(-0.1)),
        "negative angular": ("angular", lambda: rb.QuadraticDrag(0.1, angular=-1.0)),
        "angular per body, wrong batch": ("angular", lambda: _sim3(rb.QuadraticDrag(0.1, angular=np.ones(4)))),
    },
    "Spring": {
        "negative stiffness": ("stiffness", lambda: rb.Spring.between([0], [1], -1.0)),
        "negative damping": ("damping", lambda: rb.Spring.to_anchor([0], [0.0, 0, 0], 1.0, damping=-0.5)),
        "negative rest length": ("rest_length", lambda: rb.Spring.between([0], [1], 1.0, rest_length=-1.0)),
        "negative body index": ("body_index", lambda: rb.Spring.between([-1], [1], 1.0)),
        "float body index": ("body_index", lambda: rb.Spring.to_anchor([0.0], [0.0, 0, 0], 1.0)),
        "2-D body indices": ("body_index", lambda: rb.Spring.to_anchor([[0]], [0.0, 0, 0], 1.0)),
        "body past the batch": ("body_index", lambda: _sim3(rb.Spring.to_anchor([3], [0.0, 0, 0], 1.0))),
        "index_b past the batch": ("index_b", lambda: _sim3(rb.Spring.between([0], [7], 1.0))),
        "index_b past the batch, step": ("index_b", lambda: rb.step(_three(), rb.Spring.between([0], [7], 1.0), 0.01)),
        "index_b past the batch, Scene": (
            "index_b",
            lambda: rb.Scene.build(_three(), rb.Spring.between([0], [7], 1.0)),
        ),
        "stiffness per spring, wrong count": ("stiffness", lambda: rb.Spring.between([0, 1], [1, 2], [1.0, 2, 3])),
        "2-vector anchor": ("anchor", lambda: rb.Spring.to_anchor([0], [[0.0, 0]], 1.0)),
        "body and other of different lengths": ("other_index", lambda: rb.Spring.between([0, 1], [2], 1.0)),
    },
    "Thruster": {
        "body past the batch": ("body_index", lambda: _sim3(rb.Thruster(jnp.array([5]), _Z, 1.0))),
        "body past the batch, step": ("body_index", lambda: rb.step(_three(), rb.Thruster([3], _Z, 1.0), 0.01)),
        "negative body index": ("body_index", lambda: rb.Thruster([-1], _Z, 1.0)),
        "float body index": ("body_index", lambda: rb.Thruster([1.0], _Z, 1.0)),
        "non-unit direction": ("direction", lambda: rb.Thruster([0], [[0.0, 0, 2]], 1.0)),
        "4-vector direction": ("direction", lambda: rb.Thruster([0], [[0.0, 0, 1, 0]], 1.0)),
        "thrust per thruster, wrong count": ("thrust", lambda: rb.Thruster([0, 1], _Z, [1.0, 2, 3])),
    },
    "ConstantForce": {
        "2-vector force": ("force", lambda: rb.ConstantForce([0.0, 1.0])),
        "4-vector torque": ("torque", lambda: rb.ConstantForce(torque=[0.0, 0, 1, 0])),
        "force per body, wrong batch": ("force", lambda: _sim3(rb.ConstantForce(np.ones((2, 3))))),
    },
    "TimeSeriesForce": {
        "decreasing times": ("times", lambda: rb.TimeSeriesForce([1.0, 0.0], force=np.ones((2, 3)))),
        "2-D times": ("times", lambda: rb.TimeSeriesForce(np.zeros((2, 2)), force=np.ones((2, 3)))),
        "(K, 2) force": ("force", lambda: rb.TimeSeriesForce([0.0, 1.0], force=np.ones((2, 2)))),
        "force per body, wrong batch": (
            "force",
            lambda: _sim3(rb.TimeSeriesForce([0.0, 1.0], force=np.ones((2, 2, 3)))),
        ),
    },
    "ExternalForce": {
        "force not callable": ("force", lambda: rb.ExternalForce(force=np.ones(3))),
        "force(t) of the wrong shape": ("force", lambda: _sim3(rb.ExternalForce(force=lambda t: jnp.ones(2)))),
        "torque(t) a string": ("torque", lambda: _sim3(rb.ExternalForce(torque=lambda t: "x"))),
    },
    "CustomForce": {
        "fn not callable": ("fn", lambda: rb.CustomForce(3.0)),
        "fn returning a wrong shape": ("force", lambda: _sim3(rb.CustomForce(lambda s, t: rb.Forces(np.ones((2, 3)))))),
    },
    "PerBodyForce": {
        "a law without on_body": ("on_body", lambda: type("NoLaw", (rb.PerBodyForce,), {})()),
        "a text field jit cannot trace": ("forces: _TextField.mode", lambda: _sim3(_TextField())),
    },
    "ForceSum": {
        "a term that is not a model": ("terms", lambda: rb.ForceSum((rb.Gravity(), 3.0))),
        "a bad term inside a sum": ("Thruster: body_index", lambda: _sim3(rb.Gravity() + rb.Thruster([4], _Z, 1.0))),
    },
}


def _sim3(model):
    return rb.simulate(_three(), model, 0.01, 2, "euler")


class _TextField(rb.PerBodyForce):
    """A per-body law with a text option that was not declared static."""

    mode: str = "push"

    def on_body(self, state, t):
        return rb.Forces(force=jnp.ones(3, state.dtype))


def _subclass_of(cls: type) -> type:
    """A user's subclass of ``cls`` whose ``__post_init__`` does nothing: the law's checks must still run."""
    return type(f"My{cls.__name__}", (cls,), {"__post_init__": lambda self: None, "__module__": __name__})


def test_every_public_force_model_has_bad_input_cases():
    models = sorted(
        n for n in rb.__all__ if isinstance(getattr(rb, n), type) and issubclass(getattr(rb, n), rb.ForceModel)
    )
    models.remove("ForceModel")  # the abstract base
    assert sorted(FORCE_MODEL_CASES) == models


@pytest.mark.parametrize(
    "case", [f"{m}: {c}" for m, cases in FORCE_MODEL_CASES.items() for c in cases], ids=lambda c: c
)
def test_force_models_refuse_what_they_cannot_mean_naming_the_argument(case):
    model, name = case.split(": ", 1)
    arg, build = FORCE_MODEL_CASES[model][name]
    with pytest.raises((ValueError, TypeError)) as info:
        jax.block_until_ready(build())
    msg = str(info.value)
    assert _from_rbjax(info.value), f"{case}: raw error {type(info.value).__name__}: {msg}"
    assert arg in msg, f"{case}: the message does not name {arg!r}: {msg}"
    assert model in msg or "force callable" in msg or ": " in arg, f"{case}: the message does not name {model}: {msg}"


@pytest.mark.parametrize(
    "case", [f"{m}: {c}" for m, cases in FORCE_MODEL_CASES.items() for c in cases], ids=lambda c: c
)
def test_subclasses_of_force_models_refuse_the_same_inputs(case, monkeypatch):
    """Every case above with the model replaced by a user's subclass of it (``rb.<Model>`` patched)."""
    model, name = case.split(": ", 1)
    arg, build = FORCE_MODEL_CASES[model][name]
    monkeypatch.setattr(rb, model, _subclass_of(getattr(rb, model)))
    with pytest.raises((ValueError, TypeError)) as info:
        jax.block_until_ready(build())
    msg = str(info.value)
    assert _from_rbjax(info.value), f"{case}: raw error {type(info.value).__name__}: {msg}"
    assert arg in msg, f"{case}: the message does not name {arg!r}: {msg}"


@settings(max_examples=15, deadline=None)
@given(
    pairs=st.lists(st.tuples(st.integers(0, 3), st.integers(0, 3)), min_size=1, max_size=4),
    k=st.floats(0.0, 50.0),
    c=st.floats(0.0, 5.0),
)
def test_springs_between_bodies_in_the_batch_conserve_momentum(pairs, k, c):
    """Σ F = 0 and Σ (τ + x × F) = 0 over the batch for any valid index pairs (equal and opposite forces)."""
    n = 4
    rng = np.random.default_rng(len(pairs))
    q = rng.normal(size=(n, 4))
    s = rb.State.create(
        rb.box(jnp.ones(n), jnp.ones((n, 3))),
        position=rng.normal(size=(n, 3)),
        velocity=rng.normal(size=(n, 3)),
        orientation=q / np.linalg.norm(q, axis=-1, keepdims=True),
        angular_velocity=rng.normal(size=(n, 3)),
    )
    a, b = (np.array(x) for x in zip(*pairs))
    points = dict(point_a=rng.normal(size=(len(a), 3)), point_b=rng.normal(size=(len(a), 3)))
    # the spring force is central (along d): linear and angular momentum are conserved
    out = rb.Spring.between(a, b, k, rest_length=0.3, **points)(s, 0.0)
    F, tau = np.asarray(out.force), np.asarray(out.torque)
    np.testing.assert_allclose(F.sum(0), 0.0, atol=1e-10 * (1 + np.abs(F).max()))
    L_rate = tau + np.cross(np.asarray(s.position), F)
    np.testing.assert_allclose(L_rate.sum(0), 0.0, atol=1e-10 * (1 + np.abs(L_rate).max()))
    # the vector dashpot is equal and opposite but not central: linear momentum only
    F = np.asarray(rb.Spring.between(a, b, k, rest_length=0.3, damping=c, **points)(s, 0.0).force)
    np.testing.assert_allclose(F.sum(0), 0.0, atol=1e-10 * (1 + np.abs(F).max()))
    # and one index past the batch is refused, not dropped (the reaction would vanish)
    with pytest.raises(ValueError, match="outside the batch of 4 bodies"):
        rb.simulate(s, rb.Spring.between(a, b + n, k), 0.01, 1, "euler")


# ---- one dtype per state: result_type of the typed float inputs (NumPy/JAX arrays and the body);
# Python numbers and lists take it (weakly typed); none typed: the default float (float64 here, x64)

_KINDS = {
    "list": lambda v: np.asarray(v).tolist(),
    "np32": lambda v: np.asarray(v, np.float32),
    "np64": lambda v: np.asarray(v, np.float64),
    "jnp32": lambda v: jnp.asarray(v, jnp.float32),
    "jnp64": lambda v: jnp.asarray(v, jnp.float64),
}
_TYPED = {"list": None, "np32": np.float32, "np64": np.float64, "jnp32": np.float32, "jnp64": np.float64}


def _made(cls: str, body_dtype, kinds: dict[str, str]):
    """``cls`` built from arguments of the given kinds, and the dtype the rule says it must have."""
    values = {
        "position": [0.1, 0.2, 0.3],
        "velocity": [1.0, 0.0, 0.0],
        "angular_velocity": [0.0, 0.5, 0.0],
        "orientation": [1.0, 0.0, 0.0, 0.0],
        "angular_momentum": [0.0, 0.1, 0.0],
        "rotation": np.eye(3),
        "mass": 2.0,
    }
    args = {k: _KINDS[kind](values[k]) for k, kind in kinds.items()}
    typed = [_TYPED[kind] for kind in kinds.values() if _TYPED[kind] is not None]
    if cls == "ParticleState":
        return rb.ParticleState.create(args.pop("mass", 2.0), **args), np.result_type(*typed or [np.float64])
    body = rb.box(jnp.asarray(1.0, body_dtype), jnp.asarray([0.1, 0.2, 0.4], body_dtype))
    want = np.result_type(body_dtype, *typed)
    if cls == "State.direct":
        full = {
            k: args.get(k, np.asarray(values[k]).tolist())
            for k in ("position", "velocity", "orientation", "angular_momentum")
        }
        return rb.State(body, **full), want
    if cls == "MatrixState.direct":
        full = {
            k: args.get(k, np.asarray(values[k]).tolist())
            for k in ("position", "velocity", "rotation", "angular_velocity")
        }
        return rb.MatrixState(body, **full), want
    return getattr(rb, cls.split(".")[0]).create(body, **args), want


_ARGS_OF = {
    "State.create": ("position", "velocity", "orientation", "angular_velocity"),
    "MatrixState.create": ("position", "velocity", "orientation", "angular_velocity"),
    "ParticleState": ("mass", "position", "velocity"),
    "State.direct": ("position", "velocity", "orientation", "angular_momentum"),
    "MatrixState.direct": ("position", "velocity", "rotation", "angular_velocity"),
}


@pytest.mark.parametrize("cls", list(_ARGS_OF))
@settings(max_examples=20, deadline=None)
@given(data=st.data())
def test_a_state_has_one_dtype_the_result_type_of_its_typed_inputs(cls, data):
    """No mix of float32 and float64 leaves (a float32 body in a float64 state is cast with it)."""
    assert jax.config.jax_enable_x64  # the mixes exist only under x64 (conftest)
    body_dtype = data.draw(st.sampled_from([np.float32, np.float64]), label="body")
    names = _ARGS_OF[cls]
    kinds = {
        n: k
        for n, k in zip(
            names, data.draw(st.lists(st.sampled_from([None, *_KINDS]), min_size=len(names), max_size=len(names)))
        )
        if k is not None and not (n == "mass" and k == "list")
    }
    state, want = _made(cls, body_dtype, kinds)
    dtypes = {np.dtype(leaf.dtype) for leaf in jax.tree.leaves(state)}
    assert dtypes == {np.dtype(want)}, (cls, body_dtype, kinds, dtypes)
    assert state.dtype == want


# ---- animate: a batch at one instant, the clock of a batch, labels, the L arrow on top


@pytest.fixture(scope="module")
def _batch_traj():
    body = rb.box(jnp.array([1.0, 2.0, 1.5]), jnp.array([[0.1, 0.2, 0.4], [0.3, 0.2, 0.1], [0.2, 0.2, 0.3]]))
    state = rb.State.create(body, position=np.eye(3), angular_velocity=np.ones((3, 3)), time=0.5)
    return rb.simulate(state, None, 0.01, 8, "rk4", save_every=4)  # 3 frames of 3 bodies, t = 0.5, 0.54, 0.58


def test_animate_draws_a_batch_at_one_instant_as_one_frame_of_all_bodies(_batch_traj):
    pytest.importorskip("matplotlib")
    from rbjax._animate import frames_of

    for instant in (_batch_traj[-1], jax.tree.map(lambda a: a[-1], _batch_traj), _batch_traj[0]):
        data = frames_of(instant)
        assert data["pos"].shape == (1, 3, 3), data["pos"].shape  # was (3, 1, 3): three frames of one body
        np.testing.assert_allclose(data["pos"][0], np.asarray(instant.position))
    fresh = rb.State.create(rb.box(1.0, [0.1, 0.2, 0.4]), position=np.eye(3))  # a shared body
    assert frames_of(fresh)["pos"].shape == (1, 3, 3)
    one = rb.State.create(rb.box(1.0, [0.1, 0.2, 0.4]))
    assert frames_of(one)["pos"].shape == (1, 1, 3)
    assert frames_of(_batch_traj)["pos"].shape == (3, 3, 3)  # a trajectory stays one


def test_animate_clock_of_a_batch_uses_the_trajectory_time(_batch_traj):
    pytest.importorskip("matplotlib")
    from rbjax._animate import _clock, frames_of

    times = frames_of(_batch_traj)["time"]
    np.testing.assert_allclose(times, [0.5, 0.54, 0.58])
    assert _clock(2, None, times) == "t = 0.580 s"  # was "frame 2"
    assert _clock(2, 0.1, times) == "t = 0.200 s"


def test_animate_labels_its_axes_and_draws_the_arrow_over_the_body(_batch_traj, tmp_path, monkeypatch):
    pytest.importorskip("matplotlib")
    from matplotlib import animation

    figs = []

    def save(self, *args, **kwargs):  # keeps the figure instead of rendering it
        figs.append(self._fig)
        self._draw_was_started = True  # or matplotlib warns, when it is collected, that it never drew

    monkeypatch.setattr(animation.FuncAnimation, "save", save)
    (tmp_path / "a.gif").write_bytes(b"")
    rb.animate(_batch_traj, tmp_path / "a.gif", dpi=20, panel_size=1.0)
    axes = figs[0].axes
    assert len(axes) == 3
    for ax in axes:
        assert (ax.get_xlabel(), ax.get_ylabel(), ax.get_zlabel()) == ("x (m)", "y (m)", "z (m)")
        assert ax.computed_zorder is False  # zorder decides, not depth sorting
        solid = ax.collections[0]
        arrow = ax.lines[0]
        assert arrow.get_zorder() > solid.get_zorder()


# ---- one default method across the house ("euler" is 3.09 rad off on the README's body)


def test_every_public_method_default_is_the_house_default():
    """Every public function or constructor with a ``method`` parameter defaults to ``"splitting"``
    (``fit_inertia`` excepted: rbjax/identification keeps ``"rk4"``)."""
    from rbjax._methods import DEFAULT_METHOD

    assert DEFAULT_METHOD == "splitting"
    seen = []
    for name in rb.__all__:
        obj = getattr(rb, name)
        for fn in (obj, getattr(obj, "build", None)) if isinstance(obj, type) else (obj,):
            if not callable(fn) or name == "fit_inertia":
                continue
            try:
                params = inspect.signature(fn).parameters
            except (TypeError, ValueError):
                continue
            # (None: a record of the method used, e.g. ChunkWriter's metadata, not an integrator default)
            if "method" in params and params["method"].default not in (inspect.Parameter.empty, None):
                assert params["method"].default == DEFAULT_METHOD, (name, params["method"].default)
                seen.append(name)
    assert {"simulate", "step", "simulate_chunked", "Scene", "shoot", "simulate_truncated"} <= set(seen), seen


def test_the_default_method_keeps_the_readme_body_on_the_exact_solution():
    """The README's body over 5 s at dt = 1e-3 (measured 2026-12-02: splitting 2.1e-6 rad, euler 3.09 rad)."""
    body = rb.box(mass=1.0, size=[0.1, 0.2, 0.4])
    state = rb.State.create(body, angular_velocity=[0.01, 5.0, 0.01])
    exact = rb.torque_free(state, 1e-3 * np.arange(0, 5001, 50))
    traj = rb.simulate(state, None, 1e-3, 5000, save_every=50)  # the default method
    assert float(rb.quat_angle(traj.orientation, exact.orientation).max()) < 1e-5
    energy = np.asarray(rb.kinetic_energy(traj))
    assert np.abs(energy / energy[0] - 1).max() < 1e-6
    euler = rb.simulate(state, None, 1e-3, 5000, "euler", save_every=50)
    assert float(rb.quat_angle(euler.orientation[-1], exact.orientation[-1])) > 1.0  # why it is not the default


@pytest.mark.parametrize("kind", ["State", "ParticleState"])
def test_angular_momentum_about_one_point_per_body(kind):
    """``about`` of shape (N, 3) pairs point i with body i (it met every body: an (N, N, 3) result)."""
    rng = np.random.default_rng(7)
    x, v, a = (rng.normal(size=(3, 3)) for _ in range(3))
    if kind == "State":
        s = rb.State.create(
            rb.box(jnp.ones(3), jnp.ones((3, 3))), position=x, velocity=v, angular_velocity=rng.normal(size=(3, 3))
        )
    else:
        s = rb.ParticleState.create(jnp.ones(3), position=x, velocity=v)
    got = np.asarray(rb.angular_momentum(s, about=a))
    assert got.shape == (3, 3)
    for i in range(3):
        np.testing.assert_allclose(got[i], np.asarray(rb.angular_momentum(s[i], about=a[i])), rtol=1e-13)
    with pytest.raises(ValueError, match=r"angular_momentum: about of shape \(2, 3\)"):
        rb.angular_momentum(s, about=a[:2])
    with pytest.raises(ValueError, match=r"Forces.at_point: the batch shapes"):
        rb.Forces.at_point(np.ones(3), np.ones((2, 3)), s)
    np.testing.assert_allclose(
        rb.Forces.at_point(np.eye(3), a, s).torque, np.cross(a - x, np.eye(3)), rtol=1e-13, atol=1e-15
    )


def test_checked_mode_tests_traced_force_model_indices_and_signs():
    """Under a caller's jit the values cannot be read before tracing: checked mode tests them at run time."""
    s3 = _three()
    run = eqx.filter_jit(
        lambda idx, k, checked: (
            rb.simulate(
                s3, rb.Gravity() + rb.Spring.between(jnp.array([0]), idx, k), 0.01, 2, "euler", checked=checked
            ).position
        )
    )
    assert run(jnp.array([2]), jnp.asarray(1.0), True).shape == (3, 3, 3)
    with pytest.raises(Exception, match=r"simulate\(checked=...\): Spring: other_index \(index_b of Spring.between\)"):
        run(jnp.array([7]), jnp.asarray(1.0), True)
    with pytest.raises(Exception, match=r"simulate\(checked=...\): Spring: stiffness must be >= 0"):
        run(jnp.array([2]), jnp.asarray(-1.0), True)
    thrust = eqx.filter_jit(
        lambda idx: rb.simulate(s3, rb.Thruster(idx, _Z, 1.0), 0.01, 2, "euler", checked=True).position
    )
    with pytest.raises(Exception, match=r"simulate\(checked=...\): Thruster: body_index holds an index outside"):
        thrust(jnp.array([-1]))


@pytest.mark.parametrize(
    ("masses", "points", "arg"),
    [([1.0, 1, 1], np.ones((3, 2)), "points"), ([1.0, 1], np.eye(3), "masses"), (1.0, np.ones(3), "masses")],
)
def test_from_particles_names_its_own_arguments(masses, points, arg):
    """Points (P, 2) were reported as ``skew: a``; P masses for another number of points as JAX's ``mul``."""
    with pytest.raises(ValueError) as info:
        rb.from_particles(masses, points)
    assert _from_rbjax(info.value) and f"from_particles: {arg}" in str(info.value), info.value
