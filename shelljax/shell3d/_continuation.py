"""Continuation over a load parameter with a tqdm progress bar (host-side)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from tqdm.auto import tqdm


def continuation(values: Sequence, solve_step: Callable, *, progress=None, desc: str = "continuation"):
    """Call ``solve_step(value, previous)`` for each load ``value`` in order; return the results.

    ``previous`` is the last result (None first), used as the warm start. ``progress``: True shows
    a bar, False hides it, None (default) shows it only once the run has lasted more than 2 s.
    """
    results, previous = [], None
    start = time.perf_counter()
    bar = None
    try:
        for i, value in enumerate(values):
            if bar is None and (progress or (progress is None and time.perf_counter() - start > 2.0)):
                bar = tqdm(total=len(values), initial=i, desc=desc, leave=False)
            previous = solve_step(value, previous)
            results.append(previous)
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    return results
