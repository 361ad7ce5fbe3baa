"""The Dask worker plugin that points every worker's JAX at one compilation cache and keeps all it compiles there."""

from __future__ import annotations

from distributed.diagnostics.plugin import WorkerPlugin


class CompilationCache(WorkerPlugin):
    """Set each worker's JAX persistent compilation cache to ``directory`` (a path every worker can
    read and write, e.g. on the cluster's shared file system; None: the worker's own, as shelljax
    sets it at import), and keep every program a worker compiles there, however quick to compile:
    a fresh worker otherwise compiles again the programs under 1 s that the serial run compiled
    once, several seconds a worker (docs/cluster.md). A loaded program is the one compiled, so
    results do not change."""

    name = "shelljax-compilation-cache"

    def __init__(self, directory: str | None = None):
        self.directory = directory

    def setup(self, worker):
        import jax

        import shelljax  # noqa: F401 - 64-bit mode, XLA flags and the default cache before JAX computes anything

        if self.directory is not None:
            jax.config.update("jax_compilation_cache_dir", self.directory)
        if jax.config.jax_compilation_cache_dir:  # none when the user turned shelljax's cache off
            jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
