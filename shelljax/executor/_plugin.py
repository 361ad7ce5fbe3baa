"""The Dask worker plugin that points every worker's JAX at one shared compilation cache."""

from __future__ import annotations

from distributed.diagnostics.plugin import WorkerPlugin


class CompilationCache(WorkerPlugin):
    """Set JAX's persistent compilation cache of each worker to ``directory`` (a path every worker
    can read and write, e.g. on the cluster's shared file system), so a program compiled by one
    worker is loaded, not compiled, by the others."""

    name = "shelljax-compilation-cache"

    def __init__(self, directory: str):
        self.directory = directory

    def setup(self, worker):
        import jax

        import shelljax  # noqa: F401 - 64-bit mode and XLA flags before JAX computes anything

        jax.config.update("jax_compilation_cache_dir", self.directory)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
