"""What :mod:`shelljax.shell3d` offers other shelljax packages but not its users (not public API; it
may change without notice): ``membrane_strain``, the small-strain membrane strain of an inflated
scan that the realtime runtime shrinks it by; the JAX Krylov solve (``krylov_layout``,
``sparse_operator``, ``krylov_solve``, ``failure_message``) that the dynamics' ``KrylovNewton``
shares with :class:`shelljax.shell3d.KrylovSolver`."""

from ._krylov import failure_message, krylov_layout, krylov_solve, sparse_operator
from ._rest import membrane_strain

__all__ = ["failure_message", "krylov_layout", "krylov_solve", "membrane_strain", "sparse_operator"]
