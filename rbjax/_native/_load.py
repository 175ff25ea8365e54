"""Loading the native kernels: the library built at install, its call version, its instruction set.

See :mod:`rbjax._native` for what the kernels compute and when :func:`rbjax.simulate` takes them.
"""

from __future__ import annotations

import ctypes
import dataclasses
import functools
import importlib.util
import os
import warnings
from pathlib import Path

import jax

from .._methods import BUILTIN

__all__ = ["METHODS", "TARGET", "ISA", "ISA_CAPS", "NativeStatus", "native_status"]

# the methods with a kernel and their codes (block.h: Method), as each Method records its own
METHODS = dict(
    sorted(((m.name, m.native_code) for m in BUILTIN.values() if m.native_code is not None), key=lambda p: p[1])
)
TARGET = "rbjax_advance"
ABI = 4  # kernels.cc: rbjax_native_abi, the version of the call's operands and attributes
ISA = ("x86-64 baseline", "AVX2", "AVX-512")
# RBJAX_NATIVE_ISA's values (kernels.cc: isa): the widest instruction set the kernels may use
ISA_CAPS = ("baseline", "avx2", "avx512")


@dataclasses.dataclass(frozen=True)
class NativeStatus:
    """Whether :func:`rbjax.simulate` can use the native kernels here.

    Attributes:
        available: the library was built, loaded and registered with XLA.
        library: its path, or ``None``.
        instruction_set: what its steps run with on this processor
            (``"AVX-512"``, ``"AVX2"``, ``"x86-64 baseline"``), or ``None``.
        reason: why not, when not available.
        methods: the methods it implements.
    """

    available: bool
    library: str | None
    instruction_set: str | None
    reason: str
    methods: tuple[str, ...] = tuple(METHODS)

    def __str__(self) -> str:
        if self.available:
            return (
                f"native kernels: loaded from {self.library} ({self.instruction_set}); simulate uses them for "
                f"{', '.join(self.methods)} on State batches on the CPU, the JAX path otherwise"
            )
        return f"native kernels: not available ({self.reason}); simulate uses the JAX path"


def _library_path() -> Path | None:
    spec = importlib.util.find_spec(__name__.rpartition(".")[0] + "._kernels")
    if spec is not None and spec.origin:
        return Path(spec.origin)
    return None


@functools.cache
def native_status() -> NativeStatus:
    """Whether the native kernels were built at install and loaded, and which path ``simulate`` takes.

    The library ``rbjax/_native/_kernels*.so`` is compiled by the package's build
    from ``kernels.cc`` (a C++ compiler is needed; without one the install still
    succeeds and every run takes the JAX path). Loaded on the first call and
    registered with XLA as the CPU custom call ``"rbjax_advance"``. Returns a
    :class:`NativeStatus`; ``str()`` of it is one line for a log, and its ``methods``
    the methods with a kernel (``"euler"``, ``"rk4"``, ``"splitting"``,
    ``"semi_implicit_euler"``, ``"rk4_body"``).
    """
    path = _library_path()
    if path is None:
        return NativeStatus(False, None, None, "the library was not built at install (no C++ compiler?)")
    try:
        lib = ctypes.CDLL(str(path))
        abi = int(lib.rbjax_native_abi()) if hasattr(lib, "rbjax_native_abi") else 1
        if abi != ABI:
            return NativeStatus(
                False,
                str(path),
                None,
                f"{path.name} was built from another kernels.cc (call version {abi}, this rbjax needs {ABI}): "
                "rebuild it (pip install -e ., or python setup.py build_ext --inplace)",
            )
        jax.ffi.register_ffi_target(TARGET, jax.ffi.pycapsule(lib.RbjaxAdvance), platform="cpu")
        # a call marked num_batch_dims = 1 (only `_call` with sharded=True, whose operands are all
        # (N, c)) is split over the devices of its batch; unmarked calls are not partitioned
        jax.ffi.register_ffi_target_as_batch_partitionable(TARGET)
        isa = ISA[min(int(lib.rbjax_native_isa()), 2)]
        cap = os.environ.get("RBJAX_NATIVE_ISA")
        if cap is not None and cap not in ISA_CAPS:
            warnings.warn(
                f"rbjax: RBJAX_NATIVE_ISA={cap!r} is not one of {', '.join(ISA_CAPS)}: ignored, the kernels run {isa}",
                stacklevel=2,
            )
    except (OSError, AttributeError, ValueError, RuntimeError) as e:
        return NativeStatus(False, str(path), None, f"{path.name} could not be loaded: {e}")
    return NativeStatus(True, str(path), isa, "")
