"""Test session set-up: float64 by default, strict dtype promotion.

Accuracy tests run in float64 (tolerances near 1e-12 are meaningless in
float32); float32 tests ask for it explicitly with ``dtype=jnp.float32`` data.
Strict promotion turns any silent float32/float64 mixing inside rbjax into an
error, so the library never hard-codes a dtype.
"""

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")


# The default run (`pytest`) is the quick suite (< 10 minutes on 2 cores); `--runslow` adds the
# long-horizon, notebook and heavy-compile cases marked `slow`. The README's test command and
# .ci/run pass it, so CI runs everything.
def pytest_addoption(parser):
    parser.addoption("--runslow", action="store_true", help="also run tests marked slow (CI does)")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--runslow"):
        return
    import pytest

    skip = pytest.mark.skip(reason="slow: run with --runslow (the README's test command and .ci/run do)")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
