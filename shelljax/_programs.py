"""Traced programs kept across processes, as serialized StableHLO (``jax.export``).

JAX's persistent compilation cache keeps what XLA compiled, but every new process still traces
its programs again, and tracing the fit (Levenberg–Marquardt through the engine's equilibria) is
most of a warm fit's first call. :func:`persistent_jit` keeps the traced and lowered program
itself, keyed by everything that shapes it:

* the package's sources (a SHA-256 of every ``shelljax/**/*.py``): any code change is a new key,
  so a kept program never outlives the code that traced it;
* the versions of jax and jaxlib (an exported program may call jaxlib's LAPACK kernels, whose
  interface is stable only within a version);
* the arguments' tree structure, including every static field of an ``eqx.Module``, and each
  array leaf's shape and dtype; the values of the static arguments; the platform of the device
  the calling stage runs on (``shelljax.Placement``), which need not be JAX's default backend.

A program is looked for in memory, then in ``programs/`` under JAX's persistent-cache directory
(see :mod:`shelljax`; off with ``SHELLJAX_NO_COMPILATION_CACHE=1``), then among the programs the
package ships (``shelljax/data/programs/``, written by ``tools/ship_programs.py`` for the
default experiment's fit and posterior), and is traced and stored only when none has it. The program that
runs is the exported one in every case, so a run does not depend on where it came from.

Programs that cannot be exported (host callbacks, such as the 3D shell's sparse factorisation)
fall back to ``jax.jit``: an error of the function itself is then raised by that trace.
"""

from __future__ import annotations

import functools
import hashlib
import os
import sys
import tempfile
import threading
import warnings
from collections.abc import Callable
from pathlib import Path

import jax
import jaxlib
import numpy as np

from ._placement import export_platform

# every source of the package shapes the key, and the shipped programs
# are the package's data (pyproject's package-data)
PACKAGE_DIR = Path(__file__).resolve().parent
SHIPPED_DIR = PACKAGE_DIR / "data" / "programs"
SUFFIX = ".jaxexport"
# jaxlib's CPU linear-algebra kernels the fit calls (QR for Levenberg–Marquardt's damped step);
# jax.export refuses those not on its stable list, which the key's jaxlib version makes safe here
_LAPACK_KERNELS = tuple(
    f"lapack_{name}_ffi" for name in ("dormqr", "dorgqr", "dgeqrf", "dgetrf", "dpotrf", "dtrsm", "dsyevd", "dgesdd")
)
_LOADED: dict[str, Callable] = {}


@functools.cache
def source_fingerprint() -> str:
    """SHA-256 (hex) of every ``.py`` file of the package, by relative path and content."""
    digest = hashlib.sha256()
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        digest.update(path.relative_to(PACKAGE_DIR).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def user_program_dir() -> Path | None:
    """``programs/`` in JAX's persistent compilation-cache directory, or None when that cache is off."""
    cache = jax.config.jax_compilation_cache_dir
    return None if not cache else Path(cache) / "programs"


def _leaf_signature(leaf) -> str:
    # a Python scalar traces as a weakly typed array: a different program from a strong one
    weak = isinstance(leaf, (bool, int, float, complex))
    return f"{np.shape(leaf)}:{jax.numpy.result_type(leaf)}:{'weak' if weak else 'strong'}"


def program_key(name: str, args: tuple, static: dict) -> str:
    """The key of the program ``name`` traced for ``args`` (a pytree) and ``static`` (hashable values)."""
    leaves, treedef = jax.tree_util.tree_flatten(args)
    with np.printoptions(threshold=sys.maxsize):  # a static array's repr in full, never "..."
        structure = str(treedef)
    versions = [source_fingerprint(), jax.__version__, jaxlib.__version__, export_platform()]
    parts = [
        name,
        *versions,
        structure,
        *map(_leaf_signature, leaves),
        *(f"{k}={v!r}" for k, v in sorted(static.items())),
    ]
    return f"{name}-{hashlib.sha256(chr(0).join(parts).encode()).hexdigest()[:32]}"


def _read(key: str) -> jax.export.Exported | None:
    user = user_program_dir()
    for directory in ([user] if user else []) + [SHIPPED_DIR]:
        path = directory / (key + SUFFIX)
        if path.is_file():
            try:
                return jax.export.deserialize(bytearray(path.read_bytes()))
            except Exception as error:  # a truncated or foreign file: trace again, and say so
                warnings.warn(f"{path}: not a readable exported program ({error}); tracing it again", stacklevel=3)
    return None


def _write(key: str, exported: jax.export.Exported) -> None:
    directory = user_program_dir()
    if directory is None:
        return
    try:
        directory.mkdir(parents=True, exist_ok=True)
        # written whole, then renamed: a process reading it never sees half a file
        with tempfile.NamedTemporaryFile(dir=directory, suffix=".part", delete=False) as handle:
            handle.write(exported.serialize())
        os.replace(handle.name, directory / (key + SUFFIX))
    except OSError as error:  # a read-only cache costs the next process a trace, not this run
        warnings.warn(
            f"{directory}: cannot keep the traced program {key} ({error}); the next process traces it again",
            stacklevel=3,
        )


def persistent_jit(fn: Callable, *, cpu_compiler_options: dict | None = None) -> Callable:
    """``jax.jit(fn)`` whose traced program is kept across processes.

    Positional arguments are pytrees of arrays (an ``eqx.Module``'s static fields are part of the
    key); keyword arguments are static, part of the key, and must have a faithful ``repr``.
    ``cpu_compiler_options``: XLA options for compiling it on the CPU (part of the persistent
    compilation cache's key, not of this one's).
    """

    @functools.wraps(fn)
    def call(*args, **static):
        key = program_key(fn.__qualname__, args, static)
        leaves = jax.tree_util.tree_leaves(args)
        program = _LOADED.get(key)
        if program is None:
            # one thread traces and compiles a program; another that asks for it meanwhile waits
            # for that, instead of compiling it a second time (map_batch's threads, a compile ahead)
            with _lock(key):
                program = _LOADED.get(key)
                if program is None:
                    # the device is asked only now: importing shelljax does not start JAX; a
                    # stage's program is exported for its device (shelljax.Placement), not the default
                    on_cpu = export_platform() == "cpu"
                    options = _known_options(cpu_compiler_options or {}) if on_cpu else {}
                    program = _load_or_export(fn, key, args, static, options)
                    program.lower(*leaves).compile()  # kept by jit for the calls to come
                    _LOADED[key] = program
        return program(*leaves)

    return call


_LOCKS: dict[str, threading.Lock] = {}
_LOCKS_LOCK = threading.Lock()


def _lock(key: str) -> threading.Lock:
    with _LOCKS_LOCK:
        return _LOCKS.setdefault(key, threading.Lock())


def _known_options(options: dict) -> dict:
    """``options`` less those the installed XLA does not know (flags come and go between jaxlib
    releases; an unknown one fails every compile that names it)."""
    return {name: value for name, value in options.items() if _option_known(name, value)}


@functools.cache
def _option_known(name: str, value) -> bool:
    try:
        jax.jit(lambda x: x, compiler_options={name: value}).lower(0.0).compile()
    except Exception:  # XLA's error for an unknown flag has no type of its own
        return False
    return True


def _load_or_export(fn: Callable, key: str, args: tuple, static: dict, options: dict) -> Callable:
    leaves, treedef = jax.tree_util.tree_flatten(args)
    exported = _read(key)
    if exported is None:

        def flat(*flat_leaves):
            return fn(*jax.tree_util.tree_unflatten(treedef, flat_leaves), **static)

        try:
            unchecked = [jax.export.DisabledSafetyCheck.custom_call(kernel) for kernel in _LAPACK_KERNELS]
            exported = jax.export.export(jax.jit(flat), platforms=[export_platform()], disabled_checks=unchecked)(
                *leaves
            )
        except Exception:  # not exportable: the plain trace raises the function's own errors
            return jax.jit(flat, compiler_options=options)
        _write(key, exported)

    @functools.wraps(fn)  # the compile log and JAX's own messages name the program after fn
    def run(*flat_leaves):
        return exported.call(*flat_leaves)

    return jax.jit(run, compiler_options=options)
