import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")

import shelljax  # noqa: E402,F401  (x64 for every test, whatever it imports first)
