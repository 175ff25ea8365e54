"""Native CPU kernels behind :func:`rbjax.simulate`, through XLA's FFI.

``kernels.cc`` (built at install, see README.md beside this file) advances a
batch of :class:`rbjax.State` bodies by all the steps between two saved frames
in one call: the methods of ``METHODS`` (``"euler"``, ``"rk4"``, ``"splitting"``,
``"semi_implicit_euler"``, ``"rk4_body"``), float32 and float64, with the force
laws that are per body evaluated inside the kernel (none, constant
:class:`rbjax.Forces`, and sums of :class:`rbjax.Gravity`,
:class:`rbjax.LinearDrag`, :class:`rbjax.QuadraticDrag`,
:class:`rbjax.ConstantForce` and :class:`rbjax.Thruster`, whose body-frame sums
per body the kernel turns by the attitude at each evaluation). A time series
of :class:`rbjax.Forces` (``(steps, *B, 3)``, world frame, N and N·m) goes in by
the frame's slice, ``(save_every, n, 3)``, one row per step, held over the
step's stages. With ``native=True``, ``"euler"`` and ``"semi_implicit_euler"``
(``AT_STEP_START``: forces once per step, at its start) also take any other
force model or callable ``(state, t) -> Forces``: XLA evaluates it at each
step's start and the kernel takes the result, one call per step. A batch
sharded over devices (1-D, no series) is split: the call is
batch-partitionable, each device runs the kernel on its bodies. Anything else
runs the JAX implementation, which stays the reference: the kernel mirrors it
to round-off (tests/test_native.py) and supplies nothing but values.
Derivatives come from the JAX step through a ``custom_jvp``, so ``grad`` and
``jvp`` see exactly the JAX path.

:func:`native_status` says whether the kernels were built and loaded, and why
not; ``simulate(..., native=...)`` forces either path.

Three parts: loading (:mod:`._load`: the library, its call version and
instruction set), planning (:mod:`._plan`: whether a run takes the kernels,
:func:`native_plan` and ``simulate``'s :func:`native_path`, and why not) and
calling (:mod:`._call`: operands, the FFI call, its JVP, and
:func:`frames_advance`, the steps between two saved frames of ``simulate``'s scan).
"""

from __future__ import annotations

from ._call import advance, frames_advance
from ._load import ISA, ISA_CAPS, METHODS, NativeStatus, native_status
from ._plan import (
    AT_STEP_START,
    NATIVE_LAWS,
    native_path,
    native_plan,
    native_terms,
    say_once_unavailable,
    sharded,
)

__all__ = [
    "ISA",
    "ISA_CAPS",
    "METHODS",
    "NativeStatus",
    "native_status",
    "AT_STEP_START",
    "NATIVE_LAWS",
    "native_plan",
    "native_path",
    "native_terms",
    "sharded",
    "say_once_unavailable",
    "advance",
    "frames_advance",
]
