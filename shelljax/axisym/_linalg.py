"""Structured Hessian of the meridian problem and its direct solve.

The x–x part of the Hessian is block tridiagonal with 4×4 blocks (two nodes per block: the
bending hinge couples nodes i − 1 and i + 1). On top of it come an arrow (the indenter height
z_c couples to the nodes it touches) and, for a sealed gas, the dense rank-one term
Π''(V) ∇V ∇Vᵀ. The block part is recovered exactly from 11 Hessian-vector products with
coloured seeds (half bandwidth 5 dofs), never materialising a dense matrix; the solve is a
block Thomas recursion (``lax.scan``) followed by Sherman–Morrison (gas) and a Schur
complement (indenter). Cost per Newton step: O(n) with 12 HVPs.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

_HALF_BAND = 5
_N_COLORS = 2 * _HALF_BAND + 1


class StructuredHessian(eqx.Module):
    """H = [[A + σ g gᵀ, b], [bᵀ, c]] with A block tridiagonal.

    ``diag`` (m, 4, 4) and ``upper`` (m − 1, 4, 4) [N/m] blocks of A; ``arrow`` b (4m,) and
    ``corner`` c (scalar) [N/m]; ``gas_sigma`` σ = Π''(V) [Pa/m³] and ``gas_grad`` g = ∇V (4m,) [m²].
    """

    diag: Float[Array, "m 4 4"]
    upper: Float[Array, "m1 4 4"]
    arrow: Float[Array, " nx"]
    corner: Float[Array, ""]
    gas_sigma: Float[Array, ""]
    gas_grad: Float[Array, " nx"]


def _block_index_maps(n_x: int):
    m = n_x // 4
    p = np.arange(4)
    rows_d = 4 * np.arange(m)[:, None, None] + p[None, :, None]
    cols_d = 4 * np.arange(m)[:, None, None] + p[None, None, :]
    rows_u = 4 * np.arange(m - 1)[:, None, None] + p[None, :, None]
    cols_u = 4 * np.arange(m - 1)[:, None, None] + 4 + p[None, None, :]
    return (rows_d, cols_d), (rows_u, cols_u)


def _gather_band(hv, rows, cols):
    valid = np.abs(rows - cols) <= _HALF_BAND
    safe_cols = np.where(valid, cols, rows)
    vals = hv[safe_cols % _N_COLORS, rows]
    return jnp.where(jnp.asarray(valid), vals, 0.0)


def structured_hessian(band_grad, y, mask, gas_sigma, gas_grad) -> StructuredHessian:
    """Assemble the structured Hessian at y.

    ``band_grad(y)`` is the gradient [N] of an energy whose Hessian is the block-tridiagonal
    part plus the arrow (the gas enters it linearised, Π'(V̄)·V); ``mask`` (bool, len y) marks
    fixed unknowns, whose rows and columns become the identity.
    """
    n_y = y.shape[0]
    n_x = n_y - 1
    seeds = np.zeros((_N_COLORS + 1, n_y))
    for c in range(_N_COLORS):
        seeds[c, c:n_x:_N_COLORS] = 1.0
    seeds[-1, -1] = 1.0
    free = jnp.asarray(~mask, dtype=y.dtype)
    seeds = jnp.asarray(seeds) * free[None, :]
    hv = jax.vmap(lambda v: jax.jvp(band_grad, (y,), (v,))[1])(seeds) * free[None, :]
    (rd, cd), (ru, cu) = _block_index_maps(n_x)
    diag = _gather_band(hv[:-1, :n_x], rd, cd)
    fixed_x = jnp.asarray(mask[:n_x], dtype=y.dtype)
    eye_fix = jnp.asarray(np.eye(4))[None] * fixed_x.reshape(-1, 4)[:, None, :]
    diag = diag + eye_fix
    upper = _gather_band(hv[:-1, :n_x], ru, cu)
    arrow = hv[-1, :n_x]
    corner = jnp.where(mask[-1], 1.0, hv[-1, -1])
    return StructuredHessian(diag, upper, arrow, corner, gas_sigma, gas_grad * free[:n_x])


def _inverse_4x4(m):
    """Inverse of (..., 4, 4) blocks from 2×2 sub-determinants (Laplace expansion).

    Inside the block-Thomas scan a LAPACK LU per block costs more in call overhead than in
    arithmetic: this closed form made the solve 2.2× (one curve) to 3.5× (batch of 64) faster.
    """
    a = [[m[..., i, j] for j in range(4)] for i in range(4)]
    s0 = a[0][0]*a[1][1] - a[1][0]*a[0][1]
    s1 = a[0][0]*a[1][2] - a[1][0]*a[0][2]
    s2 = a[0][0]*a[1][3] - a[1][0]*a[0][3]
    s3 = a[0][1]*a[1][2] - a[1][1]*a[0][2]
    s4 = a[0][1]*a[1][3] - a[1][1]*a[0][3]
    s5 = a[0][2]*a[1][3] - a[1][2]*a[0][3]
    c5 = a[2][2]*a[3][3] - a[3][2]*a[2][3]
    c4 = a[2][1]*a[3][3] - a[3][1]*a[2][3]
    c3 = a[2][1]*a[3][2] - a[3][1]*a[2][2]
    c2 = a[2][0]*a[3][3] - a[3][0]*a[2][3]
    c1 = a[2][0]*a[3][2] - a[3][0]*a[2][2]
    c0 = a[2][0]*a[3][1] - a[3][0]*a[2][1]
    det = s0*c5 - s1*c4 + s2*c3 + s3*c2 - s4*c1 + s5*c0
    inv = [
        [ a[1][1]*c5 - a[1][2]*c4 + a[1][3]*c3, -a[0][1]*c5 + a[0][2]*c4 - a[0][3]*c3,
          a[3][1]*s5 - a[3][2]*s4 + a[3][3]*s3, -a[2][1]*s5 + a[2][2]*s4 - a[2][3]*s3],
        [-a[1][0]*c5 + a[1][2]*c2 - a[1][3]*c1,  a[0][0]*c5 - a[0][2]*c2 + a[0][3]*c1,
         -a[3][0]*s5 + a[3][2]*s2 - a[3][3]*s1,  a[2][0]*s5 - a[2][2]*s2 + a[2][3]*s1],
        [ a[1][0]*c4 - a[1][1]*c2 + a[1][3]*c0, -a[0][0]*c4 + a[0][1]*c2 - a[0][3]*c0,
          a[3][0]*s4 - a[3][1]*s2 + a[3][3]*s0, -a[2][0]*s4 + a[2][1]*s2 - a[2][3]*s0],
        [-a[1][0]*c3 + a[1][1]*c1 - a[1][2]*c0,  a[0][0]*c3 - a[0][1]*c1 + a[0][2]*c0,
         -a[3][0]*s3 + a[3][1]*s1 - a[3][2]*s0,  a[2][0]*s3 - a[2][1]*s1 + a[2][2]*s0],
    ]
    return jnp.stack([jnp.stack(r, -1) for r in inv], -2) / det[..., None, None]


def _block_tridiagonal_solve(diag, upper, rhs):
    """Solve A X = rhs for symmetric block-tridiagonal A; rhs (m, 4, k)."""
    zeros = jnp.zeros((1, 4, 4), diag.dtype)
    up = jnp.concatenate([upper, zeros], axis=0)
    low = jnp.concatenate([zeros, jnp.swapaxes(upper, 1, 2)], axis=0)

    def forward(carry, blocks):
        c_prev, d_prev = carry
        d_b, l_b, u_b, r_b = blocks
        schur_inverse = _inverse_4x4(d_b - l_b @ c_prev)
        c_b = schur_inverse @ u_b
        d_b_new = schur_inverse @ (r_b - l_b @ d_prev)
        return (c_b, d_b_new), (c_b, d_b_new)

    init = (jnp.zeros((4, 4), diag.dtype), jnp.zeros_like(rhs[0]))
    _, (cs, ds) = jax.lax.scan(forward, init, (diag, low, up, rhs))

    def backward(x_next, blocks):
        c_b, d_b = blocks
        x_b = d_b - c_b @ x_next
        return x_b, x_b

    _, xs = jax.lax.scan(backward, jnp.zeros_like(rhs[0]), (cs, ds), reverse=True)
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
