"""shelljax: pressure and Young's modulus of inflated objects from finger indentation.

Importing shelljax turns on JAX's 64-bit mode (``jax_enable_x64``) for the whole process: shells
mix E ≈ 1e6 Pa with h ≈ 1e-3 m, and Newton solves on them fail in float32. If you import jax
yourself, import shelljax first or set ``JAX_ENABLE_X64=1``.
"""

import jax as _jax

_jax.config.update("jax_enable_x64", True)

from ._errors import DeviceError, InvalidInputError, NoConvergenceError, ShelljaxError

__version__ = "0.1.0"
