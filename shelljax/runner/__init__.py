"""Run an experiment config into a fresh run directory: results.json + figures.

``_run`` holds the run; ``_compile_log`` (what JAX compiled in each stage) and
``_memory_mappings`` (keeping a long run under Linux's mapping limit) serve it alone.
"""

from ._run import run_experiment, summary_table

__all__ = ["run_experiment", "summary_table"]
