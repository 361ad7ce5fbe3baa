"""``KrylovNewton``: the step minimiser of the 3D shell with its linear solves in JAX.

The same Newton as :class:`SparseNewton` (the simplified Newton of :func:`simplified_newton_loop`
with a kept matrix, the same assembly of ∇²Φ_inc from the shell's CSR values, the point blocks,
the diagonal, the gas's rank-one term and the dashpots' columns: :func:`newton_matrix`), but each
solve is block-Jacobi preconditioned conjugate gradients written in JAX (the 3D engine's, lent by
``shell3d.internal``): no ``pure_callback``, so a whole time step runs on the arrays' device. The
dense terms are matvec terms, not Sherman–Morrison/Woodbury. The kept matrix is kept as its
values, and its block-Jacobi preconditioner is rebuilt from them at each solve (3×3 inverses).
The pattern's index arrays (:func:`krylov_layout`: 2 nnz integers) enter the step's program as
constants, read from the system's static pattern.

Newton's step retries a solve that fails (no convergence, non-positive curvature) with the matrix
shifted by 1e-2, 1e-1, 1 times its mean free diagonal, as SparseNewton's factorisation does; a
failed shift gives the scaled-descent fallback. The implicit derivative's solve is never shifted:
its failure raises at run time (``eqx.error_if``).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from .._errors import InvalidInputError
from ..shell3d.internal import krylov_layout, krylov_solve, sparse_operator
from ._minimise import AbstractMinimiser, KeptMatrix, newton_loop, simplified_newton_loop
from ._sparse import newton_matrix, rayleigh_values

#: Newton's step shifts a matrix whose CG fails by these multiples of its mean free diagonal, in turn.
SHIFTS = (0.0, 1e-2, 1e-1, 1.0)


def step_operator(potential, matrix):
    """Newton's matrix parts (:func:`newton_matrix`) as a JAX ``SparseOperator`` on the shell
    pattern's dofs (3V + 3: the vertices' and three held trailing ones), held outside the step's
    free dofs."""
    data, blocks, diag, c2, u, columns, coeffs = matrix
    system = potential.system
    layout = krylov_layout(system.sparsity.pattern)
    n = layout.free.shape[0]
    m = diag.shape[0]
    free = jnp.zeros(n).at[potential.free_dofs].set(1.0)
    nodal = blocks + diag.reshape(-1, 3)[:, :, None] * jnp.eye(3)
    nodal = jnp.concatenate([nodal, jnp.zeros((n // 3 - nodal.shape[0], 3, 3))])
    dense = jnp.concatenate([u[None, :], columns]) if columns.size else u[None, :]
    dense = jnp.pad(dense, ((0, 0), (0, n - m)))
    weights = jnp.concatenate([jnp.reshape(c2, (1,)), coeffs])
    return sparse_operator(layout, data, free=free, blocks=nodal, columns=dense, coeffs=weights)


class KrylovNewton(AbstractMinimiser):
    """Newton's method on a ShellDynamicSystem step with CG solves in JAX (module doc).

    ``step_tolerance`` [m], ``max_steps``, ``max_halvings`` and ``reuse_matrix`` as for
    :class:`SparseNewton`; each linear solve stops at ‖b − A x‖₂ ≤ ``rtol`` ‖b‖₂ [-] (default
    1e-10) or fails after ``krylov_max_steps`` CG iterations.
    """

    step_tolerance: float = eqx.field(static=True, default=1e-10)
    max_steps: int = eqx.field(static=True, default=50)
    max_halvings: int = eqx.field(static=True, default=40)
    reuse_matrix: bool = eqx.field(static=True, default=True)
    rtol: float = eqx.field(static=True, default=1e-10)
    krylov_max_steps: int = eqx.field(static=True, default=20_000)

    def __check_init__(self):
        if not 0.0 < self.rtol < 1.0:
            raise InvalidInputError(f"KrylovNewton rtol: must be in (0, 1), got {self.rtol!r}.")
        if not (isinstance(self.krylov_max_steps, int) and self.krylov_max_steps >= 1):
            raise InvalidInputError(
                f"KrylovNewton krylov_max_steps: must be an integer ≥ 1, got {self.krylov_max_steps!r}."
            )

    def _solve(self, operator, potential, rhs):
        """(x on the free dofs, CG iterations, status) of operator x = rhs (rhs on the free dofs)."""
        n = operator.free.shape[0]
        b = jnp.zeros(n).at[potential.free_dofs].set(rhs)
        x, iterations, status = krylov_solve(operator, b, float(self.rtol), int(self.krylov_max_steps))
        return x[potential.free_dofs], iterations, status

    def krylov_iterations(self, potential, y, rhs):
        """CG iterations [-] of one unshifted solve with Newton's matrix at y [m] (for benchmarks)."""
        operator = step_operator(potential, newton_matrix(potential, y, rayleigh_values(potential), "KrylovNewton"))
        return self._solve(operator, potential, rhs)[1]

    def linear_solve(self, potential, y, rhs):
        matrix = newton_matrix(potential, y, rayleigh_values(potential), "KrylovNewton")
        x, _, status = self._solve(step_operator(potential, matrix), potential, rhs)
        return eqx.error_if(
            x,
            status != 0,
            "KrylovNewton: the implicit derivative's CG solve failed (no convergence within "
            "krylov_max_steps, or an indefinite Hessian). Raise krylov_max_steps, or use SparseNewton.",
        )

    def _direction(self, potential, matrix, g):
        operator = step_operator(potential, matrix)
        scale = operator.mean_free_diagonal()
        shifts = jnp.asarray(SHIFTS)

        def cond(c):
            return (c[2] != 0) & (c[0] < len(SHIFTS))

        def body(c):
            k = c[0]
            p, _, status = self._solve(operator.shifted(shifts[k] * scale), potential, -g)
            return k + 1, p, status

        _, p, status = jax.lax.while_loop(cond, body, (jnp.asarray(0), jnp.zeros_like(g), jnp.asarray(-1)))
        # Every shift failed: fall back to descent scaled by the inertia, as SparseNewton does.
        ok = (status == 0) & jnp.all(jnp.isfinite(p)) & (g @ p < 0.0)
        return jnp.where(ok, p, -g / jnp.max(potential.inertia_weight))

    def initial_memory(self, potential, y0):
        if not self.reuse_matrix:
            return None
        shapes = jax.eval_shape(lambda y: newton_matrix(potential, y, rayleigh_values(potential), "KrylovNewton"), y0)
        return KeptMatrix(jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype), shapes), jnp.asarray(True))

    def minimise(self, potential, y0, memory=None):
        # K(xₙ) of Rayleigh β is the same in every iteration of the step: assembled once, before the loop.
        rayleigh = rayleigh_values(potential)

        def assemble(y):
            return newton_matrix(potential, y, rayleigh, "KrylovNewton")

        if not self.reuse_matrix:
            return newton_loop(self, potential, y0, lambda y, g: self._direction(potential, assemble(y), g))
        memory = self.initial_memory(potential, y0) if memory is None else memory
        return simplified_newton_loop(
            self, potential, y0, assemble, lambda values, g: self._direction(potential, values, g), memory
        )
