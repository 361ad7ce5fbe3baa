"""What :mod:`shelljax.runner` offers other shelljax packages but not its users (not public API; it
may change without notice): ``stage``, a stage's wall time and what JAX compiled in it."""

from ._compile_log import stage

__all__ = ["stage"]
