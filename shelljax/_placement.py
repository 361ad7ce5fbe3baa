"""Where each stage of a command runs: the host CPU or the accelerator (docs/gpu.md).

A :class:`Placement` is built from a device request, ``auto``, ``cpu`` or ``gpu`` (strings only at
the edge: ``--device``, ``[compute] device``), and answers, for a stage of a given
:class:`StageKind`, which JAX device runs it:

- ``LATENCY`` (one session's fit, a Newton solve, an emcee step, the closed form, one object's
  diagnosis): the host CPU under ``auto``, since a GPU's kernel launches and transfers cost more
  than such a small program gains;
- ``BATCHED`` (surrogate building, catalogues, batched axisymmetric curves, studies): the
  accelerator when JAX sees one;
- ``SPARSE`` (the 3D engine, the implicit dynamics): the accelerator when JAX sees one and the
  problem has at least ``sparse_min_dofs`` unknowns, else the CPU.

``cpu`` puts every stage on the CPU; ``gpu`` every stage on the GPU, and refuses, naming the
devices JAX sees and the ``[gpu]`` extra, when there is none. :meth:`Placement.stage` runs a block
under ``jax.default_device`` of its stage's device; :func:`to_device` and :func:`to_host` move a
stage's inputs in and its results out (NumPy), so data crosses devices only at stage boundaries.

``jax_platforms`` is process-wide and read when JAX first initialises its backends, which
importing shelljax does not do: :func:`use_cpu_only` (what ``--device cpu`` calls before any
computation) keeps a JAX built with CUDA from starting it; called later it changes nothing.
"""

from __future__ import annotations

import contextlib
import dataclasses
import enum
from collections.abc import Callable, Iterator
from typing import Any

import jax
import numpy as np

from ._errors import InvalidInputError

DEVICE_REQUESTS = ("auto", "cpu", "gpu")
#: unknowns [count] from which a sparse stage goes to the accelerator under ``auto``: below it a
#: host factorisation takes milliseconds, less than a GPU's launches and transfers (docs/gpu.md)
SPARSE_MIN_DOFS = 30_000
_ACCELERATOR_PLATFORMS = ("gpu", "cuda", "rocm")


class StageKind(enum.Enum):
    """What bounds a stage's time, which decides where it runs (module docstring)."""

    LATENCY = "latency"
    BATCHED = "batched"
    SPARSE = "sparse"


def device_label(device: jax.Device) -> str:
    """``"cpu:0"``, ``"gpu:0"``: the platform and id of a JAX device, as results.json records it."""
    platform = "gpu" if device.platform in _ACCELERATOR_PLATFORMS else device.platform
    return f"{platform}:{device.id}"


def is_accelerator(device: jax.Device) -> bool:
    """Whether ``device`` is a GPU (the sparse stages then take the device-side Krylov solve)."""
    return device.platform in _ACCELERATOR_PLATFORMS


def _accelerators() -> list[jax.Device]:
    try:
        return [d for d in jax.devices() if is_accelerator(d)]
    except RuntimeError:  # a platform JAX was told to use failed to start: there is no accelerator
        return []


def _seen() -> str:
    try:
        devices = jax.devices()
    except RuntimeError as err:
        return f"none ({err})"
    return ", ".join(f"{device_label(d)} ({d.device_kind})" for d in devices)


def current_device() -> jax.Device:
    """The device this thread's computations go to: the enclosing ``jax.default_device`` (a
    :meth:`Placement.stage`), else JAX's default device."""
    chosen = jax.config.jax_default_device
    if chosen is None:
        return jax.devices()[0]
    return jax.devices(chosen)[0] if isinstance(chosen, str) else chosen


def export_platform() -> str:
    """``jax.export``'s name of the current device's platform (``cpu``, ``cuda``, ``rocm``, ``tpu``):
    a program traced for a stage is exported for the device the stage runs on, which need not be
    JAX's default backend (``jax.export.default_export_platform``)."""
    platform = current_device().platform
    if platform not in _ACCELERATOR_PLATFORMS:
        return platform
    default = jax.export.default_export_platform()
    return default if default in ("cuda", "rocm") else "cuda"


def on_current_device(fn: Callable) -> Callable:
    """``fn`` wrapped to run under this thread's current device, for another thread to call:
    ``jax.default_device`` is thread-local, and a stage's helper threads (batches over host
    threads, programs compiled ahead) must compute where the stage does."""
    device = current_device()

    def placed(*args, **kwargs):
        with jax.default_device(device):
            return fn(*args, **kwargs)

    return placed


def use_cpu_only() -> None:
    """Make JAX start only its CPU backend (``jax_platforms = "cpu"``), so a JAX built with CUDA
    does not initialise the GPU; effective only before JAX's first computation in the process."""
    jax.config.update("jax_platforms", "cpu")


@dataclasses.dataclass(frozen=True)
class Placement:
    """Where each :class:`StageKind` runs, from a device ``request`` (``auto``, ``cpu``, ``gpu``).

    ``sparse_min_dofs``: the size [unknowns] from which a sparse stage is placed on the
    accelerator under ``auto``. Building one with ``gpu`` when JAX sees no GPU raises
    :class:`~shelljax.InvalidInputError`.
    """

    request: str = "auto"
    sparse_min_dofs: int = SPARSE_MIN_DOFS

    def __post_init__(self):
        if self.request not in DEVICE_REQUESTS:
            raise InvalidInputError(
                f"device = {self.request!r} is not a device request. Fix: one of {', '.join(DEVICE_REQUESTS)}"
            )
        if self.request == "gpu" and not _accelerators():
            raise InvalidInputError(
                f"device = 'gpu' was asked for, but JAX sees no GPU (devices: {_seen()}). Fix: install the "
                'CUDA wheels with pip install ".[gpu]" on a machine with an NVIDIA GPU, or use --device auto/cpu'
            )

    @property
    def accelerator(self) -> jax.Device | None:
        """The accelerator stages may use (None under ``cpu`` or without one)."""
        if self.request == "cpu":
            return None
        found = _accelerators()
        return found[0] if found else None

    @property
    def host(self) -> jax.Device:
        """The host CPU device."""
        return jax.devices("cpu")[0]

    def device_for(self, kind: StageKind, n_dofs: int | None = None) -> jax.Device:
        """The device of a stage of ``kind`` (``n_dofs``: a sparse stage's unknowns [count])."""
        accelerator = self.accelerator
        if accelerator is None:
            return self.host
        if self.request == "gpu" or kind is StageKind.BATCHED:
            return accelerator
        if kind is StageKind.SPARSE and n_dofs is not None and n_dofs >= self.sparse_min_dofs:
            return accelerator
        return self.host

    def sparse_on_accelerator(self, n_dofs: int) -> bool:
        """Whether a sparse problem of ``n_dofs`` unknowns runs on the accelerator, i.e. whether its caller
        should pick the device-side linear solve rather than the host factorisation."""
        accelerator = self.accelerator
        return accelerator is not None and self.device_for(StageKind.SPARSE, n_dofs) == accelerator

    @contextlib.contextmanager
    def stage(self, kind: StageKind, n_dofs: int | None = None) -> Iterator[jax.Device]:
        """Run the ``with`` block under ``jax.default_device`` of the stage's device (yielded):
        arrays it creates, and uncommitted inputs it computes on, live there."""
        device = self.device_for(kind, n_dofs)
        with jax.default_device(device):
            yield device

    def describe(self) -> dict:
        """The request and what it resolved to, per stage kind, as results.json records them."""
        resolved = {kind.value: device_label(self.device_for(kind)) for kind in (StageKind.LATENCY, StageKind.BATCHED)}
        resolved["sparse_small"] = device_label(self.device_for(StageKind.SPARSE, 0))
        resolved["sparse_large"] = device_label(self.device_for(StageKind.SPARSE, self.sparse_min_dofs))
        return {
            "request": self.request,
            "resolved": resolved,
            "sparse_min_dofs": self.sparse_min_dofs,
            "devices_seen": _seen(),
        }


def requested_placement(request: str) -> Placement:
    """The :class:`Placement` of a request made at the edge (``--device``, ``[compute] device``, a
    work item on a worker): ``cpu`` first calls :func:`use_cpu_only`, so that a process which has
    not computed yet never starts CUDA."""
    if request == "cpu":
        use_cpu_only()
    return Placement(request)


def to_device(tree: Any, device: jax.Device) -> Any:
    """A stage's inputs, their JAX arrays put on ``device`` (the stage's entry); NumPy arrays and
    other leaves stay as they are (host data a stage reads on the host, e.g. a sparsity pattern)."""
    return jax.tree.map(lambda leaf: jax.device_put(leaf, device) if isinstance(leaf, jax.Array) else leaf, tree)


def to_host(tree: Any) -> Any:
    """A stage's results, its arrays brought back to the host as NumPy arrays (the stage's exit)."""
    return jax.tree.map(lambda leaf: np.asarray(leaf) if isinstance(leaf, jax.Array) else leaf, tree)
