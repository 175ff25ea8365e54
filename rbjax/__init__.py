"""rbjax: batched, differentiable rigid-body dynamics in JAX.

Conventions: SI units; world-frame vectors unless named ``body_*``; quaternions
``[w, x, y, z]`` mapping body to world; batch dimensions lead.
"""

# The imports are grouped by topic, as a table of contents for a reader, not sorted by module.
# ruff: noqa: I001

from __future__ import annotations

# the integrators: importing this package registers every method (the first import, as before)
from . import _methods

# state and bodies
from ._state import Forces, MatrixState, ParticleState, State
from ._rotors import Rotors
from ._rotor_rates import rotor_rates
from ._body import (
    TRIANGLE_RTOL,
    Body,
    box,
    cylinder,
    ellipsoid,
    from_particles,
    parallel_axis,
    rotate_inertia,
    sphere,
    symmetric_part,
)
from ._inertia_param import inertia_from_params, params_from_inertia, second_moment

# simulating
from ._simulate import simulate, step
from ._dynamics import derivative
from ._validate import StepSizeWarning
from ._methods import AbstractMethod, Method, OrderWarning
from ._torque_free import torque_free  # the exact torque-free solution, ground truth for the integrators

# quantities of a state or a trajectory
from ._quantities import (
    angular_momentum,
    angular_velocity,
    body_angular_velocity,
    kinetic_energy,
    linear_momentum,
    orientation,
    rotation_matrix,
    to_matrix_state,
    to_state,
    world_inertia,
)

# forces and scenes
from ._force_model import ForceModel, ForceSum, PerBodyForce
from ._pytree import field, static_field
from ._forces import ConstantForce, CustomForce, ExternalForce, Gravity, LinearDrag, QuadraticDrag, TimeSeriesForce
from ._attached import Spring, Thruster
from ._scene import Scene, body_kind, register_kernel

# trajectories and batches
from ._trajectory import concatenate
from ._sharding import batch_sharding

# gradients: multiple shooting and truncated gradients
from ._shooting import defects, shoot, simulate_truncated

# fitting inertia
from ._recording import RecordingError
from .identification import FitResult, Recording, find_throws, fit_inertia, fit_inertia_linear, plot_throws
from ._calibration import DeviceCalibration, ObjectInertia, calibrate_device, object_inertia

# long runs: saving and loading, chunked runs, checked mode, the native kernels
from ._io import load, read_metadata, save
from ._chunked import simulate_chunked
from ._chunk_dir import ChunkWriter
from ._checked import Checks
from ._native import NativeStatus, native_status

# seeing the motion (animate needs matplotlib, the demo extra)
from ._animate import animate
from ._viewer import Viewer, view

# quaternions, rotations and small vector helpers
from ._math import (
    cross,
    matrix_to_quat,
    orthonormalize,
    quat_angle,
    quat_conjugate,
    quat_exp,
    quat_log,
    quat_multiply,
    quat_normalize,
    quat_rotate,
    quat_to_matrix,
    safe_norm,
    skew,
)

from ._version import __version__ as __version__


def methods(state_type: type | None = None) -> dict[str, _methods.Method]:
    """rbjax's integrators by name (optionally those supporting ``state_type``): what a ``method=`` string names.

    A method of one's own is a subclass of :class:`AbstractMethod`, passed as an
    instance (``method=Midpoint()``); it is not listed here. Each :class:`Method`
    records its order, what it conserves, its cost per step relative to ``"euler"``
    and, for the explicit methods, its measured
    stability limit ``stable_dt_omega`` (``{state type: dt·|ω|}`` beyond which
    it diverges; e.g. ``rb.methods()["rk4"].stable_dt_omega``).
    """
    return _methods.available(state_type)


__all__ = [
    # state and bodies
    "Forces",
    "MatrixState",
    "ParticleState",
    "State",
    "Rotors",
    "rotor_rates",
    "TRIANGLE_RTOL",
    "Body",
    "box",
    "cylinder",
    "ellipsoid",
    "from_particles",
    "parallel_axis",
    "rotate_inertia",
    "sphere",
    "symmetric_part",
    "inertia_from_params",
    "params_from_inertia",
    "second_moment",
    # simulating
    "simulate",
    "step",
    "methods",
    "derivative",
    "StepSizeWarning",
    "OrderWarning",
    "AbstractMethod",
    "Method",
    "torque_free",
    # quantities of a state or a trajectory
    "angular_momentum",
    "angular_velocity",
    "body_angular_velocity",
    "kinetic_energy",
    "linear_momentum",
    "orientation",
    "rotation_matrix",
    "to_matrix_state",
    "to_state",
    "world_inertia",
    # forces and scenes
    "ForceModel",
    "ForceSum",
    "PerBodyForce",
    "field",
    "static_field",
    "ConstantForce",
    "CustomForce",
    "ExternalForce",
    "Gravity",
    "LinearDrag",
    "QuadraticDrag",
    "TimeSeriesForce",
    "Spring",
    "Thruster",
    "Scene",
    "body_kind",
    "register_kernel",
    # trajectories and batches
    "concatenate",
    "batch_sharding",
    # gradients
    "defects",
    "shoot",
    "simulate_truncated",
    # fitting inertia
    "RecordingError",
    "FitResult",
    "Recording",
    "find_throws",
    "fit_inertia",
    "fit_inertia_linear",
    "plot_throws",
    "DeviceCalibration",
    "ObjectInertia",
    "calibrate_device",
    "object_inertia",
    # long runs
    "load",
    "read_metadata",
    "save",
    "simulate_chunked",
    "ChunkWriter",
    "Checks",
    "NativeStatus",
    "native_status",
    # seeing the motion
    "animate",
    "Viewer",
    "view",
    # quaternions, rotations and vector helpers
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
]
