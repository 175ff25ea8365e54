"""Builds rbjax's native CPU kernels (rbjax/_native/kernels.cc) with the package.

Everything else about the package is in pyproject.toml. The kernels are a plain
shared library that rbjax loads with ctypes and registers with XLA's FFI; the
extension is optional: where no C++ compiler (or no jaxlib with the FFI headers)
is found, the build still succeeds and rbjax runs its JAX implementation
(``rbjax.native_status()`` says which). Portable flags only: the x86-64 baseline,
with AVX2 and AVX-512 variants chosen at run time inside the library.
"""

import os
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext


def _ffi_include() -> list[str]:
    """jaxlib's FFI headers (what ``jax.ffi.include_dir()`` returns), or none: build without the kernels."""
    try:
        import jaxlib  # noqa: PLC0415  (a build requirement; jax itself is not installed while building)
    except ImportError:
        return []
    include = Path(jaxlib.__file__).parent / "include"
    return [str(include)] if (include / "xla" / "ffi" / "api" / "ffi.h").is_file() else []


class OptionalBuildExt(build_ext):
    """build_ext that reports a failed kernel build and carries on: rbjax then runs on JAX alone."""

    def run(self):
        try:
            super().run()
        except Exception as e:  # noqa: BLE001  (compiler missing or failing: the extension is optional)
            print(f"rbjax: native kernels not built ({e}); rbjax will use its JAX path", file=sys.stderr)

    def build_extension(self, ext):
        self.compiler.compile = _compile_in_parallel(self.compiler)
        try:
            super().build_extension(ext)
        except Exception as e:  # noqa: BLE001
            print(f"rbjax: native kernels not built ({e}); rbjax will use its JAX path", file=sys.stderr)


def _compile_in_parallel(compiler):
    """``compiler.compile`` with one compiler process per source at a time, up to the CPU count.

    The kernels are four sources (the FFI handler and the steps once per instruction set); one
    after another they take most of the install's time. Built on the private helpers
    distutils' own ``CCompiler.compile`` loops over (as numpy.distutils did); where they are
    missing, the sources compile one after another as before.
    """
    serial = compiler.compile
    if not all(hasattr(compiler, f) for f in ("_setup_compile", "_get_cc_args", "_compile")):
        return serial

    def compile(
        sources,
        output_dir=None,
        macros=None,
        include_dirs=None,
        debug=0,
        extra_preargs=None,
        extra_postargs=None,
        depends=None,
    ):
        macros, objects, extra, pp_opts, build = compiler._setup_compile(
            output_dir, macros, include_dirs, sources, depends, extra_postargs
        )
        cc_args = compiler._get_cc_args(pp_opts, debug, extra_preargs)
        todo = [obj for obj in objects if obj in build]  # (up-to-date objects are left out of build)

        def one(obj):
            src, ext = build[obj]
            compiler._compile(obj, src, ext, cc_args, extra, pp_opts)

        with ThreadPoolExecutor(max(1, min(len(todo), os.cpu_count() or 1))) as pool:
            list(pool.map(one, todo))
        return objects

    return compile


# the FFI handler, then the steps once per instruction set (block.h: why they are sources of their own)
_SOURCES = ("kernels", "steps_baseline", "steps_avx2", "steps_avx512")
include = _ffi_include()
extensions = []
if include:
    extensions.append(
        Extension(
            "rbjax._native._kernels",
            sources=[f"rbjax/_native/{name}.cc" for name in _SOURCES],
            depends=["rbjax/_native/steps.h", "rbjax/_native/block.h"],
            include_dirs=include,
            language="c++",
            # -fno-math-errno: sqrt must not set errno, or the loops over bodies do not vectorise;
            # -ffp-contract=fast: fused multiply-adds where the target has them, as XLA:CPU uses them;
            # -g0 undoes the -g of Python's own CFLAGS: debug information is a quarter of the compile
            # (steps_avx2.cc: 15.3 -> 11.6 CPU-s) and three quarters of the library's size, and GCC
            # emits the same machine code with or without it
            extra_compile_args=[
                "-std=c++17",
                "-O3",
                "-g0",
                "-fno-math-errno",
                "-ffp-contract=fast",
                "-fvisibility=hidden",
                "-Wno-return-type",
            ],
            # linked by the C compiler: name the C++ runtime (operator new, std::function) explicitly
            extra_link_args=["-lstdc++"],
            optional=True,
        )
    )

setup(ext_modules=extensions, cmdclass={"build_ext": OptionalBuildExt})
