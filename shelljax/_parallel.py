"""Batches split over host threads, so that every CPU core works.

XLA on CPU runs a computation made of small operations (a vmapped Newton loop on ~200 unknowns)
on one core, and two computations dispatched one after the other run one after the other.
Dispatched from separate threads they run at once (docs/axisym.md, *Benchmark*), each on the
caller's device. On a GPU the batch is left whole. Public as ``shelljax.axisym.cpu_workers`` and ``shelljax.axisym.map_batch``.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

import jax
import numpy as np

from ._placement import current_device, on_current_device


def cpu_workers() -> int:
    """Threads worth using for a batch: the usable CPU cores when it computes on the CPU (the
    current device: ``shelljax.Placement``'s stage), else 1."""
    if current_device().platform != "cpu":
        return 1
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def map_batch(fn: Callable, batch, workers: int | None = None, rows_per_call: int | None = None):
    """``fn(batch)`` computed slice by slice of the leading axis, the slices spread over ``workers`` threads.

    ``fn`` must treat the rows of ``batch`` (an array, leading axis = batch) independently and
    return a pytree of arrays with the same leading axis. The slices have ``rows_per_call`` rows
    (default: one slice per worker), the batch padded with copies of its last row to a multiple
    of that, so every call has one shape (one compilation, whatever the batch's size); the
    padding is dropped from the result. Slices and result are host (NumPy) arrays: slicing on
    the host compiles nothing.
    """
    batch = np.asarray(batch)
    size = batch.shape[0]
    workers = max(min(cpu_workers() if workers is None else int(workers), size), 1)
    per = -(-size // workers) if rows_per_call is None else int(rows_per_call)
    calls = -(-size // per)
    padded = np.concatenate([batch, np.repeat(batch[-1:], calls * per - size, axis=0)])
    slices = [padded[i * per : (i + 1) * per] for i in range(calls)]
    if len(slices) == 1:
        parts = [fn(slices[0])]
    else:
        with ThreadPoolExecutor(min(workers, calls)) as pool:
            # each thread computes on the caller's device (jax.default_device is thread-local)
            parts = list(pool.map(on_current_device(lambda s: jax.block_until_ready(fn(s))), slices))
    return jax.tree_util.tree_map(lambda *xs: np.concatenate([np.asarray(x) for x in xs])[:size], *parts)


__all__ = ["cpu_workers", "map_batch"]
