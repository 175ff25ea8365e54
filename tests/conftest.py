"""Test session set-up: float64 by default, strict dtype promotion.

Accuracy tests run in float64 (tolerances near 1e-12 are meaningless in
float32); float32 tests ask for it explicitly with ``dtype=jnp.float32`` data.
Strict promotion turns any silent float32/float64 mixing inside rbjax into an
error, so the library never hard-codes a dtype.
"""

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
