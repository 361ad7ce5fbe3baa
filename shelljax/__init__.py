"""shelljax: pressure and Young's modulus of inflated objects from finger indentation.

Importing shelljax turns on JAX's 64-bit mode (``jax_enable_x64``) for the whole process: shells
mix E ≈ 1e6 Pa with h ≈ 1e-3 m, and Newton solves on them fail in float32. If you import jax
yourself, import shelljax first or set ``JAX_ENABLE_X64=1``.

It also turns on JAX's persistent compilation cache (unless you configured one yourself), in
``$SHELLJAX_CACHE_DIR`` or ``~/.cache/shelljax/jax``: the shell solvers take tens of seconds to
compile, and the cache makes the second run of a script start in seconds. Set
``SHELLJAX_NO_COMPILATION_CACHE=1`` to leave JAX's cache settings alone.

On the CPU it adds ``--xla_cpu_multi_thread_eigen=false`` to ``XLA_FLAGS`` (unless that flag is
already set): with jaxlib 0.10.2, XLA:CPU's multi-threaded Eigen pool intermittently wedges on
large vmapped programs (every worker idle, the caller blocked forever in ``BlockUntilReady``;
seen here on the 3D shell's Hessian assembly at 20k faces; the same symptom and workaround are in
PyAutoLabs/PyAutoFit#1530). The flag only takes effect if shelljax is imported before JAX runs its
first computation.
"""

import os as _os

if "xla_cpu_multi_thread_eigen" not in _os.environ.get("XLA_FLAGS", ""):
    _os.environ["XLA_FLAGS"] = (_os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false").strip()

import jax as _jax  # noqa: E402

_jax.config.update("jax_enable_x64", True)
if not _os.environ.get("SHELLJAX_NO_COMPILATION_CACHE") and _jax.config.jax_compilation_cache_dir is None:
    _jax.config.update(
        "jax_compilation_cache_dir",
        _os.environ.get("SHELLJAX_CACHE_DIR", _os.path.join(_os.path.expanduser("~"), ".cache", "shelljax", "jax")),
    )
    _jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)

from ._errors import DeviceError, InvalidInputError, NoConvergenceError, ShelljaxError
from ._placement import Placement, StageKind
from ._solution import RESULTS, Solution
from .physics import ShellProperties

__version__ = "0.1.0"
