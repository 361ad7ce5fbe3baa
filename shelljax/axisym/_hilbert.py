"""Hilbert-curve ordering of parameter sets, so that consecutive sets are neighbours.

A batch of forward solves walked in this order can start each solve from its predecessor's
equilibrium (``shelljax.axisym``, docs/axisym.md). The Hilbert curve visits the cells of a grid one face-neighbour
after another, so, unlike a lexicographic or Z-order sort, it never jumps across the box. Written in
jax.numpy (traceable: usable inside ``jit``) after J. Skilling, "Programming the Hilbert
curve", AIP Conf. Proc. 707, 381 (2004).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float, Int

BITS = 10  # grid cells per axis: 2**BITS (a 4-axis index fits in 40 bits of an int64)


def hilbert_index(cells: Int[Array, "b d"], bits: int = BITS) -> Int[Array, " b"]:
    """Distance along the d-dimensional Hilbert curve [-] of integer grid cells in [0, 2**bits)."""
    axes = [cells[:, i].astype(jnp.int64) for i in range(cells.shape[1])]
    n = len(axes)
    # Skilling's AxestoTranspose: undo the excess work of the inverse, then Gray-encode.
    q = 1 << (bits - 1)
    while q > 1:
        low = q - 1
        for i in range(n):
            has_bit = (axes[i] & q) != 0
            swap = (axes[0] ^ axes[i]) & low
            first = jnp.where(has_bit, axes[0] ^ low, axes[0] ^ swap)
            axes[i] = jnp.where(has_bit, axes[i], axes[i] ^ swap) if i else first
            axes[0] = first
        q >>= 1
    for i in range(1, n):
        axes[i] = axes[i] ^ axes[i - 1]
    flip = jnp.zeros_like(axes[0])
    q = 1 << (bits - 1)
    while q > 1:
        flip = jnp.where((axes[-1] & q) != 0, flip ^ (q - 1), flip)
        q >>= 1
    axes = [a ^ flip for a in axes]
    # The transposed form holds the index's bits interleaved across the axes, high bits first.
    index = jnp.zeros_like(axes[0])
    for bit in range(bits - 1, -1, -1):
        for a in axes:
            index = (index << 1) | ((a >> bit) & 1)
    return index


def hilbert_order(points: Float[Array, "b d"], bits: int = BITS) -> Int[Array, " b"]:
    """Permutation (b,) that walks ``points`` along a Hilbert curve through their bounding box.

    Each column is scaled to the box's extent on its own axis, so pass coordinates in which equal
    steps matter equally (logarithms of positive scales). A constant column maps to the last
    cell of its axis: in that face the curve, restricted, is still a Hilbert curve of the other
    axes when the column is the last one (through other faces it jumps now and then), so put
    the column most often held fixed last.
    """
    low = jnp.min(points, axis=0)
    span = jnp.max(points, axis=0) - low
    scaled = jnp.where(span > 0, (points - low) / jnp.where(span > 0, span, 1.0), 1.0)
    cells = jnp.clip(jnp.floor(scaled * (1 << bits)), 0, (1 << bits) - 1).astype(jnp.int64)
    return jnp.argsort(hilbert_index(cells, bits), stable=True)


__all__ = ["hilbert_index", "hilbert_order"]
