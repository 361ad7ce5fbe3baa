import jax
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")

import shelljax  # noqa: E402,F401  (x64 for every test, whatever it imports first)


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop JAX's compiled programs after each test file.

    XLA:CPU maps every compiled kernel into its own three memory mappings (code, constants, data),
    and Linux allows a process 65 530 (vm.max_map_count). An xdist worker running half the suite
    with an empty compilation cache reached that limit and died inside XLA (SIGSEGV or SIGABRT
    while compiling). Cleared after each file, a worker peaked at 17 200 mappings; what a later
    file needs again comes back from the persistent compilation cache.
    """
    yield
    jax.clear_caches()
