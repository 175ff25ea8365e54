"""rbjax: batched, differentiable rigid-body dynamics in JAX.

Conventions: SI units; world-frame vectors unless named ``body_*``; quaternions
``[w, x, y, z]`` mapping body to world; batch dimensions lead.
"""

from __future__ import annotations

from . import _methods
from ._body import (
    TRIANGLE_RTOL as TRIANGLE_RTOL,
)
from ._body import (
    Body as Body,
)
from ._body import (
    box as box,
)
from ._body import (
    cylinder as cylinder,
)
from ._body import (
    ellipsoid as ellipsoid,
)
from ._body import (
    from_particles as from_particles,
)
from ._body import (
    parallel_axis as parallel_axis,
)
from ._body import (
    rotate_inertia as rotate_inertia,
)
from ._body import (
    sphere as sphere,
)
from ._dynamics import derivative as derivative
from ._inertia_param import (
    inertia_from_params as inertia_from_params,
)
from ._inertia_param import (
    params_from_inertia as params_from_inertia,
)
from ._inertia_param import (
    second_moment as second_moment,
)
from ._recording import RecordingError as RecordingError

# --- differentiable trajectories and inertia fitting ---
from .identification import FitResult as FitResult
from .identification import Recording as Recording
from .identification import find_throws as find_throws
from .identification import fit_inertia as fit_inertia
from .identification import fit_inertia_linear as fit_inertia_linear
from .identification import plot_throws as plot_throws

# isort: split
# --- multiple shooting and truncated gradients ---
from ._shooting import defects as defects
from ._shooting import shoot as shoot
from ._shooting import simulate_truncated as simulate_truncated

# --- end multiple shooting ---
# isort: split
from ._math import (
    cross as cross,
)
from ._math import (
    matrix_to_quat as matrix_to_quat,
)
from ._math import (
    orthonormalize as orthonormalize,
)
from ._math import (
    quat_angle as quat_angle,
)
from ._math import (
    quat_conjugate as quat_conjugate,
)
from ._math import (
    quat_exp as quat_exp,
)
from ._math import (
    quat_log as quat_log,
)
from ._math import (
    quat_multiply as quat_multiply,
)
from ._math import (
    quat_normalize as quat_normalize,
)
from ._math import (
    quat_rotate as quat_rotate,
)
from ._math import (
    quat_to_matrix as quat_to_matrix,
)
from ._math import (
    safe_norm as safe_norm,
)
from ._math import (
    skew as skew,
)
from ._quantities import (
    angular_momentum as angular_momentum,
)
from ._quantities import (
    angular_velocity as angular_velocity,
)
from ._quantities import (
    body_angular_velocity as body_angular_velocity,
)
from ._quantities import (
    kinetic_energy as kinetic_energy,
)
from ._quantities import (
    linear_momentum as linear_momentum,
)
from ._quantities import (
    orientation as orientation,
)
from ._quantities import (
    rotation_matrix as rotation_matrix,
)
from ._quantities import (
    to_matrix_state as to_matrix_state,
)
from ._quantities import (
    to_state as to_state,
)
from ._quantities import (
    world_inertia as world_inertia,
)
from ._simulate import simulate as simulate
from ._simulate import step as step
from ._state import (
    Forces as Forces,
)
from ._state import (
    MatrixState as MatrixState,
)
from ._state import (
    ParticleState as ParticleState,
)
from ._state import (
    State as State,
)
from ._validate import StepSizeWarning as StepSizeWarning

# isort: split
# --- trajectories and batches: frames, slices, bodies, concatenation, sharding ---
from ._body import symmetric_part as symmetric_part
from ._sharding import batch_sharding as batch_sharding
from ._trajectory import concatenate as concatenate

# isort: split
# --- tools: saving/loading, chunked long runs, checked mode ---
from ._checked import Checks as Checks
from ._chunk_dir import ChunkWriter as ChunkWriter
from ._chunked import simulate_chunked as simulate_chunked
from ._io import load as load
from ._io import read_metadata as read_metadata
from ._io import save as save
from ._native import NativeStatus as NativeStatus
from ._native import native_status as native_status

# --- end tools ---
# exact torque-free solution (ground truth for integrator tests and benchmarks)
from ._torque_free import torque_free as torque_free

# --- scenes and force models ---
# isort: split
from ._attached import Spring as Spring
from ._attached import Thruster as Thruster
from ._force_model import ForceModel as ForceModel
from ._force_model import ForceSum as ForceSum
from ._forces import ConstantForce as ConstantForce
from ._forces import CustomForce as CustomForce
from ._forces import ExternalForce as ExternalForce
from ._forces import Gravity as Gravity
from ._forces import LinearDrag as LinearDrag
from ._forces import QuadraticDrag as QuadraticDrag
from ._forces import TimeSeriesForce as TimeSeriesForce
from ._scene import Scene as Scene
from ._scene import body_kind as body_kind
from ._scene import register_kernel as register_kernel

# --- end scenes ---
# isort: split
# --- seeing the motion: animation export (needs matplotlib, the demo extra) ---
from ._animate import animate as animate
from ._viewer import Viewer as Viewer
from ._viewer import view as view

# --- end animation ---
# isort: split
from ._version import __version__ as __version__


def methods(state_type: type | None = None) -> dict[str, _methods.Method]:
    """Registered integrators by name (optionally those supporting ``state_type``).

    Each :class:`Method` records its order, what it conserves, its cost per
    step relative to ``"euler"`` and, for the explicit methods, its measured
    stability limit ``stable_dt_omega`` (``{state type: dt·|ω|}`` beyond which
    it diverges; e.g. ``rb.methods()["rk4"].stable_dt_omega``).
    """
    return _methods.available(state_type)


# Every public name imported above (computed, so each area's export block needs no second edit).
__all__ = sorted(
    name
    for name, value in list(globals().items())
    if not name.startswith("_") and name != "annotations" and not isinstance(value, type(_methods))
)
