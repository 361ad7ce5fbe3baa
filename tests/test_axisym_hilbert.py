"""The Hilbert ordering that lets a batch of curves warm-start from neighbours."""

import itertools

import jax.numpy as jnp
import numpy as np
import pytest

import shelljax  # noqa: F401  (x64)
from shelljax.axisym._hilbert import hilbert_index, hilbert_order


@pytest.mark.parametrize("dims, bits", [(2, 1), (2, 4), (3, 3), (4, 2)])
def test_index_walks_every_cell_once_through_face_neighbours(dims, bits):
    # The two defining properties of a Hilbert curve on a 2**bits grid: the index is a bijection
    # onto 0 … 2**(dims·bits) − 1, and consecutive cells differ by one step along one axis.
    cells = np.array(list(itertools.product(range(2**bits), repeat=dims)))
    index = np.asarray(hilbert_index(jnp.asarray(cells), bits))
    np.testing.assert_array_equal(np.sort(index), np.arange(2 ** (dims * bits)))
    path = cells[np.argsort(index)]
    np.testing.assert_array_equal(np.abs(np.diff(path, axis=0)).sum(axis=1), 1)


def test_order_is_a_permutation_that_keeps_neighbours_close():
    rng = np.random.default_rng(0)
    points = rng.uniform(size=(4000, 3))
    order = np.asarray(hilbert_order(jnp.asarray(points)))
    np.testing.assert_array_equal(np.sort(order), np.arange(len(points)))
    walked = np.linalg.norm(np.diff(points[order], axis=0), axis=1)
    shuffled = np.linalg.norm(np.diff(points, axis=0), axis=1)
    # 4000 points in the unit cube are ≈ 4000^(−1/3) ≈ 0.06 apart; random pairs ≈ 0.66. The
    # median step along the curve was 0.04 (measured); 0.1 leaves room without letting a
    # lexicographic-like order (jumps across the box at every row end) pass.
    assert np.median(walked) < 0.1 < np.median(shuffled)
    assert np.mean(walked) < 0.15 * np.mean(shuffled)


def test_a_constant_last_column_leaves_a_hilbert_path_of_the_others():
    # ν is often held fixed: its face of the 4-D curve must still be walked cell by cell.
    rng = np.random.default_rng(1)
    varying = rng.uniform(size=(3000, 3))
    with_fixed = jnp.column_stack([jnp.asarray(varying), jnp.full(3000, 0.4)])
    order_3d = np.asarray(hilbert_order(jnp.asarray(varying)))
    order_4d = np.asarray(hilbert_order(with_fixed))
    step = lambda order: np.linalg.norm(np.diff(varying[order], axis=0), axis=1)  # noqa: E731
    # as short as the 3-D curve's own steps (median 0.045 each, measured): within 20 %
    assert np.median(step(order_4d)) < 1.2 * np.median(step(order_3d))
    line = jnp.column_stack([jnp.linspace(0.0, 1.0, 50), jnp.full(50, 2.0)])
    assert np.all(np.abs(np.diff(np.asarray(hilbert_order(line)))) == 1)  # a line walked in order
