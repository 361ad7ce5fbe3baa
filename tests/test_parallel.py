"""Batches split over host threads (shelljax._parallel)."""

import jax
import jax.numpy as jnp
import numpy as np

from shelljax._parallel import map_batch


def test_threaded_batch_equals_the_whole_batch_and_drops_its_padding():
    calls = []

    @jax.jit
    def rows(x):
        return {"sum": jnp.sum(x, axis=1), "square": x**2}

    def fn(x):
        calls.append(x.shape)
        return rows(x)

    batch = np.arange(15.0).reshape(5, 3)
    got = map_batch(fn, batch, workers=2)
    want = rows(batch)
    # 5 rows over 2 threads: two slices of 3 rows (the last padded with a copy of row 4)
    assert sorted(calls) == [(3, 3), (3, 3)]
    np.testing.assert_array_equal(got["sum"], want["sum"])
    np.testing.assert_array_equal(got["square"], want["square"])
    calls.clear()
    map_batch(fn, batch, workers=1)
    assert calls == [(5, 3)]
