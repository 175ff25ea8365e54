"""The force laws the native kernels compute themselves, and the kernel parameters of each."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from .._attached import Thruster
from .._forces import ConstantForce, Gravity, LinearDrag, QuadraticDrag
from .._state import Forces

__all__ = ["LAWS", "NATIVE_TYPES", "thrust_sums"]

# How each law the kernel computes itself adds to its parameters (see _parameters): ``add(key,
# array, components)`` with the law's arrays, ``n`` bodies, the state's dtype.
_Add = Callable[[str, Any, int], None]


def _constant(f: Any, add: _Add, n: int, dtype: Any) -> None:
    add("F", f.force, 3)
    add("tau", f.torque, 3)


def _gravity(f: Gravity, add: _Add, n: int, dtype: Any) -> None:
    add("g", f.g, 3)


def _linear_drag(f: LinearDrag, add: _Add, n: int, dtype: Any) -> None:
    add("b", f.linear, 1)
    add("br", f.angular, 1)


def _quadratic_drag(f: QuadraticDrag, add: _Add, n: int, dtype: Any) -> None:
    add("c", f.linear, 1)
    add("cr", f.angular, 1)


def _thruster(f: Thruster, add: _Add, n: int, dtype: Any) -> None:
    add("thrust", thrust_sums(f, n, dtype), 6)


# The laws the kernel computes itself, listed once, by exact type, each with the parameters it
# adds to: a subclass may compute anything, so it is evaluated by XLA like any other model (the
# JAX path, or at each step's start with AT_STEP_START), never with its parent's formula.
LAWS: dict[type, Callable[[Any, _Add, int, Any], None]] = {
    Forces: _constant,
    ConstantForce: _constant,
    Gravity: _gravity,
    LinearDrag: _linear_drag,
    QuadraticDrag: _quadratic_drag,
    Thruster: _thruster,
}
NATIVE_TYPES = tuple(LAWS)


def thrust_sums(thruster: Thruster, n: int, dtype: Any) -> jax.Array:
    """``(n, 6)``: per body the body-frame sums ``f_b = Σ T_s d_s`` and ``τ_b = Σ p_s × T_s d_s``
    over its thrusters (``body_index[s]`` = the body; ``Thruster`` needs a 1-D batch of ``n`` bodies)."""
    s = thruster.body_index.shape[0]
    d = jnp.broadcast_to(jnp.asarray(thruster.direction, dtype), (s, 3))
    f = jnp.broadcast_to(jnp.asarray(thruster.thrust, dtype), (s,))[:, None] * d
    fb = jnp.zeros((n, 3), dtype).at[thruster.body_index].add(f)
    if thruster.point is None:
        return jnp.concatenate([fb, jnp.zeros((n, 3), dtype)], axis=1)
    p = jnp.broadcast_to(jnp.asarray(thruster.point, dtype), (s, 3))
    return jnp.concatenate([fb, jnp.zeros((n, 3), dtype).at[thruster.body_index].add(jnp.cross(p, f))], axis=1)
