"""Structured Hessian of the meridian problem and its direct solve.

The x–x part of the Hessian is block tridiagonal with 4×4 blocks (two nodes per block: the
bending hinge couples nodes i − 1 and i + 1). On top of it come an arrow (the indenter height
z_c couples to the nodes it touches) and, for a sealed gas, the dense rank-one term
Π''(V) ∇V ∇Vᵀ. The blocks are assembled from element-local second derivatives
(``_hessian``), never materialising a dense matrix; the solve is a block Thomas recursion
(``lax.scan``) followed by Sherman–Morrison (gas) and a Schur complement (indenter). Cost per
Newton step: O(n).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._tracing import tied_to


class StructuredHessian(eqx.Module):
    """H = [[A + σ g gᵀ, b], [bᵀ, c]] with A block tridiagonal.

    ``diag`` and ``upper``: the 4×4 diagonal and upper blocks of A [N/m] as a struct of arrays,
    ``diag[i][j]`` (m,) the entry (i, j) of every diagonal block and ``upper[i][j]`` (m − 1,) of
    every upper block (XLA:CPU fuses arrays of 4×4 blocks badly: docs/axisym.md, *Performance notes*);
    ``arrow`` b (4m,) and ``corner`` c (scalar) [N/m]; ``gas_sigma`` σ = Π''(V) [Pa/m³] and
    ``gas_grad`` g = ∇V (4m,) [m²].
    """

    diag: tuple[tuple[Float[Array, " m"], ...], ...]
    upper: tuple[tuple[Float[Array, " m1"], ...], ...]
    arrow: Float[Array, " nx"]
    corner: Float[Array, ""]
    gas_sigma: Float[Array, ""]
    gas_grad: Float[Array, " nx"]


def _inverse_4x4(m):
    """Inverse of (..., 4, 4) blocks from 2×2 sub-determinants (Laplace expansion).

    Inside the block-Thomas scan a LAPACK LU per block costs more in call overhead than in
    arithmetic.
    """
    a = [[m[..., i, j] for j in range(4)] for i in range(4)]
    s0 = a[0][0] * a[1][1] - a[1][0] * a[0][1]
    s1 = a[0][0] * a[1][2] - a[1][0] * a[0][2]
    s2 = a[0][0] * a[1][3] - a[1][0] * a[0][3]
    s3 = a[0][1] * a[1][2] - a[1][1] * a[0][2]
    s4 = a[0][1] * a[1][3] - a[1][1] * a[0][3]
    s5 = a[0][2] * a[1][3] - a[1][2] * a[0][3]
    c5 = a[2][2] * a[3][3] - a[3][2] * a[2][3]
    c4 = a[2][1] * a[3][3] - a[3][1] * a[2][3]
    c3 = a[2][1] * a[3][2] - a[3][1] * a[2][2]
    c2 = a[2][0] * a[3][3] - a[3][0] * a[2][3]
    c1 = a[2][0] * a[3][2] - a[3][0] * a[2][2]
    c0 = a[2][0] * a[3][1] - a[3][0] * a[2][1]
    det = s0 * c5 - s1 * c4 + s2 * c3 + s3 * c2 - s4 * c1 + s5 * c0
    inv = [
        [
            a[1][1] * c5 - a[1][2] * c4 + a[1][3] * c3,
            -a[0][1] * c5 + a[0][2] * c4 - a[0][3] * c3,
            a[3][1] * s5 - a[3][2] * s4 + a[3][3] * s3,
            -a[2][1] * s5 + a[2][2] * s4 - a[2][3] * s3,
        ],
        [
            -a[1][0] * c5 + a[1][2] * c2 - a[1][3] * c1,
            a[0][0] * c5 - a[0][2] * c2 + a[0][3] * c1,
            -a[3][0] * s5 + a[3][2] * s2 - a[3][3] * s1,
            a[2][0] * s5 - a[2][2] * s2 + a[2][3] * s1,
        ],
        [
            a[1][0] * c4 - a[1][1] * c2 + a[1][3] * c0,
            -a[0][0] * c4 + a[0][1] * c2 - a[0][3] * c0,
            a[3][0] * s4 - a[3][1] * s2 + a[3][3] * s0,
            -a[2][0] * s4 + a[2][1] * s2 - a[2][3] * s0,
        ],
        [
            -a[1][0] * c3 + a[1][1] * c1 - a[1][2] * c0,
            a[0][0] * c3 - a[0][1] * c1 + a[0][2] * c0,
            -a[3][0] * s3 + a[3][1] * s1 - a[3][2] * s0,
            a[2][0] * s3 - a[2][1] * s1 + a[2][2] * s0,
        ],
    ]
    return jnp.stack([jnp.stack(r, -1) for r in inv], -2) / det[..., None, None]


def _matmul(a, b):
    # Tiny blocks: a broadcast multiply–sum fuses into one loop, where XLA's dot on 4×4 operands
    # pays a library call per product inside the scan.
    return jnp.sum(a[..., :, :, None] * b[..., None, :, :], axis=-2)


def _block(entries):
    """A 4×4 (…) array from entry-wise nested lists."""
    return jnp.stack([jnp.stack(row, -1) for row in entries], -2)


def _block_tridiagonal_solve(diag, upper, rhs):
    """Solve A X = rhs for symmetric block-tridiagonal A given entry-wise (``diag[i][j]`` (m,),
    ``upper[i][j]`` (m − 1,)); rhs (m, 4, k).

    The scan works on 4×4 blocks, stacked here once (stacking in every step costs more kernels).
    """
    pad_after = lambda a: jnp.concatenate([a, jnp.zeros(1, a.dtype)])  # noqa: E731
    pad_before = lambda a: jnp.concatenate([jnp.zeros(1, a.dtype), a])  # noqa: E731
    up = _block([[pad_after(upper[i][j]) for j in range(4)] for i in range(4)])
    low = _block([[pad_before(upper[j][i]) for j in range(4)] for i in range(4)])
    diag = _block(diag)

    def forward(carry, blocks):
        c_prev, d_prev = carry
        d_b, l_b, u_b, r_b = blocks
        schur_inverse = _inverse_4x4(d_b - _matmul(l_b, c_prev))
        c_b = _matmul(schur_inverse, u_b)
        d_b_new = _matmul(schur_inverse, r_b - _matmul(l_b, d_prev))
        return (c_b, d_b_new), (c_b, d_b_new)

    init = tied_to(rhs, jnp.zeros((4, 4), rhs.dtype), jnp.zeros_like(rhs[0]))
    _, (cs, ds) = jax.lax.scan(forward, init, (diag, low, up, rhs))

    def backward(x_next, blocks):
        c_b, d_b = blocks
        x_b = d_b - _matmul(c_b, x_next)
        return x_b, x_b

    _, xs = jax.lax.scan(backward, tied_to(rhs, jnp.zeros_like(rhs[0])), (cs, ds), reverse=True)
    return xs


def structured_solve(hess: StructuredHessian, rhs: Float[Array, " ny"]) -> Float[Array, " ny"]:
    """Solve H d = rhs [N] → d [m] (block Thomas + Sherman–Morrison + Schur complement)."""
    n_x = hess.arrow.shape[0]
    r_x, r_z = rhs[:n_x], rhs[n_x]
    cols = jnp.stack([r_x, hess.arrow, hess.gas_grad], axis=-1).reshape(-1, 4, 3)
    sol = _block_tridiagonal_solve(hess.diag, hess.upper, cols).reshape(n_x, 3)
    y_r, y_b, y_g = sol[:, 0], sol[:, 1], sol[:, 2]
    g = hess.gas_grad
    denom = 1.0 + hess.gas_sigma * (g @ y_g)
    y_r = y_r - hess.gas_sigma * y_g * (g @ y_r) / denom
    y_b = y_b - hess.gas_sigma * y_g * (g @ y_b) / denom
    dz = (r_z - hess.arrow @ y_r) / (hess.corner - hess.arrow @ y_b)
    return jnp.concatenate([y_r - y_b * dz, dz[None]])
