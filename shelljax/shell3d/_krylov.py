"""Preconditioned conjugate gradients on a sparse Hessian, in JAX (runs on the arrays' device).

The matrix is a :class:`SparsityPattern`'s CSR values (assembled in JAX, as for the host solve)
with the pattern's fixed dofs folded in, plus optional extra 3×3 nodal blocks (the dynamics'
inertia and contact blocks), plus a dense low-rank term Σₖ dₖ uₖ uₖᵀ (a sealed gas's rank-one
Π''(V) ∇V ∇Vᵀ, the dynamics' centre-of-mass dashpots) applied as matvec terms, and restricted to
the free dofs of a mask: A v = M (K v + B v + Σₖ dₖ uₖ (uₖ·v)) for M v = v, and A v = v on the
masked-out dofs (their unit pivots). The sparse product is a ``segment_sum`` over the CSR rows
(faster than ``jax.experimental.sparse``'s BCSR product on the CPU: docs/shell3d.md, *Solver*).

The preconditioner is the inverse of A's 3×3 nodal diagonal blocks (block Jacobi): the shells'
stiffness couples a node's three dofs strongly (membrane stiffness along the surface, little
across it), which point Jacobi ignores (docs/shell3d.md, *Solver*, measures both).

The conjugate-gradient loop is written here, not taken from lineax or ``jax.scipy``: it stops on
the plain relative residual ‖b − A x‖₂ ≤ rtol ‖b‖₂ (lineax's CG tests every component in both the
residual's and the solution's units), counts its iterations (``jax.scipy``'s returns none) and
stops on a direction of non-positive curvature (both would carry on, silently, towards a saddle):
the caller learns why a solve failed (:data:`KRYLOV_STATUS`).
"""

from __future__ import annotations

import dataclasses
import weakref

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ._sparse import SparsityPattern

#: Status codes of :func:`conjugate_gradient`, and what each means.
KRYLOV_STATUS = {
    0: "converged",
    1: "no convergence within max_steps",
    2: "non-positive curvature (the matrix or the preconditioner is not positive definite)",
    3: "non-finite values",
}
#: CG's recursive residual drifts from the true one in floating point: every this many
#: iterations the residual is recomputed from b − A x (as lineax's CG does).
RESIDUAL_REFRESH = 25


class KrylovLayout(eqx.Module):
    """Device index arrays of a pattern for :class:`SparseOperator` (built once per pattern):
    ``rows``/``indices`` (nnz,) the CSR row and column of each entry, ``fixed_entries`` and
    ``fixed_diagonal`` the pattern's folding positions, ``block_positions`` (n/3, 3, 3) the CSR
    position of each entry of each node's diagonal 3×3 block, ``free`` (n,) the pattern's free
    dofs (1.0) and fixed ones (0.0)."""

    rows: Int[Array, " nnz"]
    indices: Int[Array, " nnz"]
    fixed_entries: Int[Array, " a"]
    fixed_diagonal: Int[Array, " b"]
    block_positions: Int[Array, "N 3 3"]
    free: Float[Array, " n"]


_LAYOUTS: "weakref.WeakKeyDictionary[SparsityPattern, KrylovLayout]" = weakref.WeakKeyDictionary()


def krylov_layout(pattern: SparsityPattern) -> KrylovLayout:
    """The :class:`KrylovLayout` of ``pattern`` (kept while the pattern lives)."""
    if pattern in _LAYOUTS:
        return _LAYOUTS[pattern]
    n = pattern.n_dofs
    rows = np.repeat(np.arange(n), np.diff(pattern.indptr))
    keys = rows.astype(np.int64) * n + pattern.indices
    base = 3 * np.arange(n // 3)[:, None, None]
    wanted = (base + np.arange(3)[:, None]) * n + base + np.arange(3)  # (N, 3, 3) row·n + col
    positions = np.searchsorted(keys, wanted)
    if np.any(keys[np.minimum(positions, keys.size - 1)] != wanted):
        raise ValueError("the sparsity pattern lacks a node's diagonal 3×3 block")
    with jax.ensure_compile_time_eval():  # device arrays, also when first asked for inside a trace
        layout = KrylovLayout(
            rows=jnp.asarray(rows, dtype=jnp.int32),
            indices=jnp.asarray(pattern.indices, dtype=jnp.int32),
            fixed_entries=jnp.asarray(pattern.fixed_entries, dtype=jnp.int32),
            fixed_diagonal=jnp.asarray(pattern.fixed_diagonal, dtype=jnp.int32),
            block_positions=jnp.asarray(positions, dtype=jnp.int32),
            free=jnp.asarray(pattern.free, dtype=jnp.float64),
        )
    _LAYOUTS[pattern] = layout
    return layout


class SparseOperator(eqx.Module):
    """A = M (K_fold + blockdiag(blocks) + Uᵀ diag(coeffs) U) M + (I − M) on n dofs (module doc).

    ``values`` (nnz,) [N/m]: CSR values on the layout's pattern, unfolded; ``free`` (n,): the mask
    M (1.0 free, 0.0 held), within the pattern's free dofs; ``blocks`` (n/3, 3, 3) [N/m] or None;
    ``columns`` (k, n) and ``coeffs`` (k,) [N/m per column unit²]: the low-rank term (k may be 0).
    """

    values: Float[Array, " nnz"]
    rows: Int[Array, " nnz"]
    indices: Int[Array, " nnz"]
    block_positions: Int[Array, "N 3 3"]
    free: Float[Array, " n"]
    blocks: Float[Array, "N 3 3"] | None
    columns: Float[Array, "k n"]
    coeffs: Float[Array, " k"]

    def mv(self, v: Float[Array, " n"]) -> Float[Array, " n"]:
        """A v [N] for v [m]."""
        held = v * self.free
        out = jax.ops.segment_sum(
            self.values * held[self.indices], self.rows, num_segments=v.shape[0], indices_are_sorted=True
        )
        if self.blocks is not None:
            out = out + jnp.einsum("nij,nj->ni", self.blocks, held.reshape(-1, 3)).reshape(-1)
        out = out + (self.coeffs * (self.columns @ held)) @ self.columns
        return self.free * out + (1.0 - self.free) * v

    def diagonal_blocks(self) -> Float[Array, "N 3 3"]:
        """A's (n/3, 3, 3) diagonal nodal blocks [N/m]."""
        blocks = self.values[self.block_positions]
        if self.blocks is not None:
            blocks = blocks + self.blocks
        nodal = self.columns.reshape(self.columns.shape[0], self.free.shape[0] // 3, 3)
        blocks = blocks + jnp.einsum("k,kni,knj->nij", self.coeffs, nodal, nodal)
        mask = self.free.reshape(-1, 3)
        eye = jnp.eye(3)
        return mask[:, :, None] * blocks * mask[:, None, :] + eye * (1.0 - mask)[:, None, :]

    def mean_free_diagonal(self) -> Float[Array, ""]:
        """Mean |A_ii| [N/m] over the free dofs (the scale of a diagonal shift)."""
        diag = jnp.diagonal(self.diagonal_blocks(), axis1=1, axis2=2).reshape(-1)
        return jnp.sum(jnp.abs(diag) * self.free) / jnp.maximum(jnp.sum(self.free), 1.0)

    def shifted(self, shift) -> "SparseOperator":
        """A + shift I on the free dofs (shift [N/m])."""
        eye = shift * jnp.broadcast_to(jnp.eye(3), self.block_positions.shape)
        blocks = eye if self.blocks is None else self.blocks + eye
        return dataclasses.replace(self, blocks=blocks)


def sparse_operator(
    layout: KrylovLayout,
    values: Float[Array, " nnz"],
    free: Float[Array, " n"] | None = None,
    blocks: Float[Array, "N 3 3"] | None = None,
    columns: Float[Array, "k n"] | None = None,
    coeffs: Float[Array, " k"] | None = None,
) -> SparseOperator:
    """The :class:`SparseOperator` of CSR ``values`` on ``layout``'s pattern, its fixed dofs
    folded in (zero rows and columns, unit diagonal, as :meth:`SparsityPattern.matrix` does);
    ``free``: the mask M (default: the pattern's free dofs)."""
    values = values.at[layout.fixed_entries].set(0.0).at[layout.fixed_diagonal].set(1.0)
    n = layout.free.shape[0]
    free = layout.free if free is None else free
    if columns is None:
        columns, coeffs = jnp.zeros((0, n)), jnp.zeros((0,))
    return SparseOperator(
        values=values,
        rows=layout.rows,
        indices=layout.indices,
        block_positions=layout.block_positions,
        free=free,
        blocks=blocks,
        columns=columns * free,
        coeffs=coeffs,
    )


def block_jacobi(operator: SparseOperator, nodal: bool = True):
    """v ↦ P⁻¹ v: the inverse of ``operator``'s 3×3 diagonal nodal blocks (``nodal``) or of its
    diagonal (point Jacobi)."""
    blocks = operator.diagonal_blocks()
    if not nodal:
        diag = jnp.diagonal(blocks, axis1=1, axis2=2)
        return lambda v: v / diag.reshape(-1)
    inverse = jnp.linalg.inv(blocks)
    return lambda v: jnp.einsum("nij,nj->ni", inverse, v.reshape(-1, 3)).reshape(-1)


def conjugate_gradient(matvec, precondition, b: Float[Array, " n"], rtol: float, max_steps: int):
    """(x, iterations, status): preconditioned CG on A x = b from x = 0, to ‖b − A x‖₂ ≤ rtol ‖b‖₂.

    ``status`` (:data:`KRYLOV_STATUS`): 0 converged; 1 not within ``max_steps``; 2 a direction of
    non-positive curvature pᵀAp ≤ 0 or a non-positive rᵀP⁻¹r (A or the preconditioner is not
    positive definite); 3 non-finite values. Traceable (a ``lax.while_loop``).
    """
    target = rtol * jnp.linalg.norm(b)
    z = precondition(b)
    rz = b @ z

    def status_of(r, rz, curvature, k):
        size = jnp.linalg.norm(r)
        return jnp.where(
            ~(jnp.isfinite(size) & jnp.isfinite(rz)),
            3,
            jnp.where(
                size <= target, 0, jnp.where((curvature <= 0.0) | (rz <= 0.0), 2, jnp.where(k >= max_steps, 1, -1))
            ),
        )

    def cond(c):
        return c["status"] < 0

    def body(c):
        x, r, p, rz, k = c["x"], c["r"], c["p"], c["rz"], c["k"]
        ap = matvec(p)
        curvature = p @ ap
        alpha = rz / jnp.where(curvature > 0.0, curvature, 1.0)
        x = x + alpha * p
        k = k + 1
        r = jax.lax.cond(k % RESIDUAL_REFRESH == 0, lambda: b - matvec(x), lambda: r - alpha * ap)
        z = precondition(r)
        rz_new = r @ z
        p = z + (rz_new / jnp.where(rz > 0.0, rz, 1.0)) * p
        return dict(x=x, r=r, p=p, rz=rz_new, k=k, status=status_of(r, rz_new, curvature, k))

    init = dict(x=jnp.zeros_like(b), r=b, p=z, rz=rz, k=jnp.asarray(0), status=status_of(b, rz, 1.0, 0))
    out = jax.lax.while_loop(cond, body, init)
    return out["x"], out["k"], out["status"]


@eqx.filter_jit
def krylov_solve(operator: SparseOperator, b: Float[Array, " n"], rtol: float, max_steps: int, nodal: bool = True):
    """(x, iterations, status) of :func:`conjugate_gradient` on ``operator`` x = b with its
    block-Jacobi preconditioner (``nodal``; point Jacobi otherwise)."""
    return conjugate_gradient(operator.mv, block_jacobi(operator, nodal), b, rtol, max_steps)


def failure_message(status: int, iterations: int, rtol: float, n: int) -> str:
    """Why a Krylov solve of ``n`` dofs failed, and what to do."""
    return (
        f"Krylov solve ({n} dofs) failed after {iterations} CG iterations: {KRYLOV_STATUS[int(status)]} "
        f"(rtol {rtol:g}). Raise KrylovSolver(max_steps=...), or use DirectSolver() for an ill-conditioned "
        "or indefinite system."
    )


__all__ = [
    "KRYLOV_STATUS",
    "KrylovLayout",
    "SparseOperator",
    "block_jacobi",
    "conjugate_gradient",
    "failure_message",
    "krylov_layout",
    "krylov_solve",
    "sparse_operator",
]
