"""rbjax: batched, differentiable rigid-body dynamics in JAX.

Conventions: SI units; world-frame vectors unless named ``body_*``; quaternions
``[w, x, y, z]`` mapping body to world; batch dimensions lead.
"""

from __future__ import annotations

from . import _methods
from ._body import (
    TRIANGLE_RTOL as TRIANGLE_RTOL,
    Body as Body,
    box as box,
    cylinder as cylinder,
    ellipsoid as ellipsoid,
    from_particles as from_particles,
    parallel_axis as parallel_axis,
    rotate_inertia as rotate_inertia,
    sphere as sphere,
)
from ._dynamics import derivative as derivative
from ._math import (
    cross as cross,
    matrix_to_quat as matrix_to_quat,
    orthonormalize as orthonormalize,
    quat_angle as quat_angle,
    quat_conjugate as quat_conjugate,
    quat_exp as quat_exp,
    quat_log as quat_log,
    quat_multiply as quat_multiply,
    quat_normalize as quat_normalize,
    quat_rotate as quat_rotate,
    quat_to_matrix as quat_to_matrix,
    safe_norm as safe_norm,
    skew as skew,
)
from ._quantities import (
    angular_momentum as angular_momentum,
    angular_velocity as angular_velocity,
    body_angular_velocity as body_angular_velocity,
    kinetic_energy as kinetic_energy,
    linear_momentum as linear_momentum,
    orientation as orientation,
    rotation_matrix as rotation_matrix,
    to_matrix_state as to_matrix_state,
    to_state as to_state,
    world_inertia as world_inertia,
)
from ._simulate import simulate as simulate, step as step

# --- differentiable trajectories and inertia fitting ---
from ._fit import FitResult as FitResult, fit_inertia as fit_inertia, fit_inertia_linear as fit_inertia_linear
from ._inertia_param import (
    inertia_from_params as inertia_from_params,
    params_from_inertia as params_from_inertia,
    second_moment as second_moment,
)
from ._state import (
    Forces as Forces,
    MatrixState as MatrixState,
    ParticleState as ParticleState,
    State as State,
)

__version__ = "0.1.0"


def methods(state_type: type | None = None) -> dict[str, _methods.Method]:
    """Registered integrators by name (optionally those supporting ``state_type``).

    Each :class:`Method` records its order, what it conserves and its cost per
    step relative to ``"euler"``.
    """
    return _methods.available(state_type)
