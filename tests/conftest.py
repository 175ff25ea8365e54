"""Test session set-up: float64 by default, strict dtype promotion.

Accuracy tests run in float64 (tolerances near 1e-12 are meaningless in
float32); float32 tests ask for it explicitly with ``dtype=jnp.float32`` data.
Strict promotion turns any silent float32/float64 mixing inside rbjax into an
error, so the library never hard-codes a dtype.
"""

import gc
import importlib.metadata
import os
import shutil
import tempfile

import jax
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")


# The default run (`pytest`) is the quick suite (< 10 minutes on 2 cores); `--runslow` adds the
# long-horizon, notebook and heavy-compile cases marked `slow`, and the combinations of parameters
# the quick suite leaves out (`_combinations_left_out`). The README's test command and .ci/run pass
# it, so CI runs everything.
def pytest_addoption(parser):
    parser.addoption("--runslow", action="store_true", help="also run tests marked slow (CI does)")


# Most of the suite's time is XLA compiling. The xdist workers of one run compile many of the
# same programs (the same step at the same shapes, in different test files), and a worker that
# drops its compiled programs (below) compiles its module's again. JAX's persistent compilation
# cache, in a directory made for this run and shared by its workers, compiles each once: a
# program another worker compiled is read back from disk instead. Every program is kept
# (min compile time 0): most of the suite's programs compile in well under a second, yet they
# are most of its time. The directory goes at the end of the run; nothing outlives it, so a
# run never reads what an earlier rbjax (or jaxlib) wrote. Set RBJAX_TEST_COMPILATION_CACHE=0 to
# run without it.
_CACHE_ENV = "RBJAX_TEST_COMPILATION_CACHE_DIR"


# The suite's programs are small and run for milliseconds; compiling them is most of its time.
# XLA's classic CPU emitters and LLVM without optimisation compile them in less than half the
# CPU time (tests/test_gradients.py: 67 -> 30 CPU-s) and compute the same arithmetic to
# round-off. Set before any backend starts, and inherited by the workers and the processes
# tests start. The benchmarks and users' programs keep XLA's defaults, and so do the tests that
# hold a property of XLA's default pipeline (they run in a process of their own with
# ``default_xla_env()``). RBJAX_TEST_FAST_COMPILE=0 runs the whole suite with the defaults.
# They are CPU flags: where a GPU or TPU plugin is installed the tests run there, and that jaxlib
# (0.11.2 with CUDA 13 on an H200, 2026-12-04) ended every pytest process at start with them set.
_FAST_COMPILE = ("--xla_cpu_use_fusion_emitters=false", "--xla_backend_optimization_level=0")
_FLAGS_BEFORE = "RBJAX_TEST_XLA_FLAGS_BEFORE"


def _accelerator_plugin() -> bool:
    names = {(d.metadata["Name"] or "").lower().replace("_", "-") for d in importlib.metadata.distributions()}
    return any(n.startswith(("jax-cuda", "jax-rocm", "libtpu")) for n in names)


_PLATFORMS = os.environ.get("JAX_PLATFORMS", "")
_CPU_ONLY = _PLATFORMS == "cpu" or (not _PLATFORMS and not _accelerator_plugin())
if os.environ.get("RBJAX_TEST_FAST_COMPILE", "1") != "0" and _FLAGS_BEFORE not in os.environ and _CPU_ONLY:
    os.environ[_FLAGS_BEFORE] = os.environ.get("XLA_FLAGS", "")
    os.environ["XLA_FLAGS"] = " ".join(os.environ[_FLAGS_BEFORE].split() + list(_FAST_COMPILE))


def failure_under_default_xla(module: str, function: str) -> str | None:
    """Call ``function()`` of test module ``module`` in a fresh process with XLA's default flags
    (float64, as here): ``None`` if it returned, else its traceback. For a test of a property of
    XLA's default pipeline, which the suite's fast-compile flags do not share."""
    import subprocess
    import sys

    here = os.path.dirname(os.path.abspath(__file__))
    code = (
        f"import jax; jax.config.update('jax_enable_x64', True); from {module} import {function}; "
        f"{function}(); print('returned')"
    )
    env = dict(default_xla_env(), PYTHONPATH=os.pathsep.join([here, os.path.dirname(here)]))
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    if res.returncode == 0 and res.stdout.strip().endswith("returned"):
        return None
    return f"{module}.{function} under XLA's default flags:\n{res.stderr[-3000:]}"


def default_xla_env() -> dict[str, str]:
    """This process's environment with XLA's flags as they were before the suite's (for a subprocess)."""
    env = dict(os.environ, RBJAX_TEST_FAST_COMPILE="0")  # also where the subprocess imports this file
    if _FLAGS_BEFORE in env:
        env["XLA_FLAGS"] = env.pop(_FLAGS_BEFORE)
    return env


def pytest_configure(config):
    if os.environ.get("RBJAX_TEST_COMPILATION_CACHE", "1") == "0":
        return
    if _CACHE_ENV not in os.environ:  # the controller (or a run without xdist): make the directory
        os.environ[_CACHE_ENV] = tempfile.mkdtemp(prefix="rbjax-test-xla-cache-")
        config._rbjax_cache_owner = True
    # as variables too, so that the workers and the Python processes tests start use it
    settings = {
        "jax_compilation_cache_dir": os.environ[_CACHE_ENV],
        "jax_persistent_cache_min_compile_time_secs": 0.0,
        "jax_persistent_cache_min_entry_size_bytes": 0,
    }
    for name, value in settings.items():
        os.environ[name.upper()] = str(value)
        jax.config.update(name, value)


def pytest_unconfigure(config):
    if getattr(config, "_rbjax_cache_owner", False):
        shutil.rmtree(os.environ.pop(_CACHE_ENV), ignore_errors=True)
        jax.config.update("jax_compilation_cache_dir", None)


def pytest_collection_modifyitems(config, items):
    if config.getoption("--runslow"):
        return
    skip = pytest.mark.skip(reason="slow: run with --runslow (the README's test command and .ci/run do)")
    combination = pytest.mark.skip(
        reason="a combination of parameters whose every value the quick suite runs in other cases: --runslow runs it"
    )
    dropped = _combinations_left_out(items)
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
        elif item in dropped:
            item.add_marker(combination)


def _combinations_left_out(items) -> set:
    """The parametrised cases the quick suite leaves out: it runs every value of every parameter,
    not every combination.

    A test parametrised over one list runs all its cases. One parametrised over several (method x
    dtype x force model x batch shape) runs, of its cases not marked slow, a few that together take
    each value of each parameter at least once (greedy: the case with the most values not yet seen,
    first in collection order on a tie); the other combinations run with ``--runslow``, as CI does.
    """
    groups: dict = {}
    for item in items:
        spec = getattr(item, "callspec", None)
        if spec is not None and "slow" not in item.keywords:
            groups.setdefault((item.path, item.originalname), []).append(item)
    left_out = set()
    for cases in groups.values():
        values = [{(name, _key(v)) for name, v in c.callspec.params.items()} for c in cases]
        unseen, kept = set().union(*values), set()
        while unseen:
            best = max(range(len(cases)), key=lambda i: (len(values[i] & unseen), -i))
            kept.add(best)
            unseen -= values[best]
        left_out.update(c for i, c in enumerate(cases) if i not in kept)
    return left_out


def _key(value):
    """A parameter value as a set element: itself if hashable, else its identity (one list's object)."""
    try:
        hash(value)
    except TypeError:
        return id(value)
    return (type(value).__name__, value)


# Every program XLA:CPU compiles keeps its machine code in memory mappings of its own, and JAX's
# caches keep every program alive. A worker that runs a few hundred tests holds thousands, and
# Linux allows a process 65,530 mappings (vm.max_map_count): at that limit the next compile dies
# inside LLVM (SIGSEGV or SIGABRT, no Python error), and with `--dist loadfile` xdist then waits
# forever for the rest of the dead worker's file. Measured in one xdist worker of the whole suite
# (2026-12-02): 29,000 mappings after 5 minutes, the crash at about 16. So a test that leaves the
# process above a quarter of the limit drops the compiled programs; a module's later tests
# recompile what they share, once.
_MAPPINGS_BEFORE_CLEARING = 16_000


def _mapping_count() -> int:
    try:
        with open("/proc/self/maps", "rb") as f:
            return sum(1 for _ in f)
    except OSError:  # not Linux: no such limit to keep under
        return 0


# Reading /proc/self/maps costs ~10 ms at 8,000 mappings. The heaviest tests add a few thousand
# (the worker above: ~100 a second), so counting after every 8th test still leaves the count far
# below the limit between two looks
_CHECK_EVERY = 8
_tests_run = 0


@pytest.fixture(autouse=True)
def _release_compiled_programs():
    global _tests_run
    yield
    _tests_run += 1
    if _tests_run % _CHECK_EVERY == 0 and _mapping_count() > _MAPPINGS_BEFORE_CLEARING:
        jax.clear_caches()
        gc.collect()
