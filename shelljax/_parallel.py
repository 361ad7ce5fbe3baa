"""Batches split over host threads, so that every CPU core works.

XLA on CPU runs a computation made of small operations (a vmapped Newton loop on ~200 unknowns)
on one core, and two computations dispatched one after the other run one after the other.
Dispatched from separate threads they run at once (docs/axisym.md, *Benchmark*). On a GPU the
batch is left whole. Public as ``shelljax.axisym.cpu_workers`` and ``shelljax.axisym.map_batch``.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

import jax
import jax.numpy as jnp


def cpu_workers() -> int:
    """Threads worth using for a batch: the usable CPU cores on the CPU backend, else 1."""
    if jax.default_backend() != "cpu":
        return 1
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def map_batch(fn: Callable, batch, workers: int | None = None):
    """``fn(batch)`` computed as ``workers`` equal slices of the leading axis, one per thread.

    ``fn`` must treat the rows of ``batch`` (an array, leading axis = batch) independently and
    return a pytree of arrays with the same leading axis. The batch is padded with copies of
    its last row to a multiple of ``workers`` so that every slice has one shape (one
    compilation), and the padding is dropped from the result.
    """
    batch = jnp.asarray(batch)
    size = batch.shape[0]
    workers = min(cpu_workers() if workers is None else int(workers), size)
    if workers <= 1:
        return fn(batch)
    per = -(-size // workers)
    pad = per * workers - size
    padded = jnp.concatenate([batch, jnp.repeat(batch[-1:], pad, axis=0)])
    slices = [padded[i * per : (i + 1) * per] for i in range(workers)]
    with ThreadPoolExecutor(workers) as pool:
        parts = list(pool.map(lambda s: jax.block_until_ready(fn(s)), slices))
    return jax.tree_util.tree_map(lambda *xs: jnp.concatenate(xs)[:size], *parts)


__all__ = ["cpu_workers", "map_batch"]
