"""The 3D engine's linear solvers, as objects: where Newton's steps and the implicit tangents solve.

:class:`DirectSolver` (the default) factorizes on the host (CHOLMOD, SuperLU: :mod:`._sparse`);
:class:`KrylovSolver` runs preconditioned conjugate gradients in JAX (:mod:`._krylov`), on the
device the arrays live on (the default JAX device), with no host callback.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp

from .._errors import InvalidInputError, NoConvergenceError
from ._krylov import SparseOperator, failure_message, krylov_solve
from ._sparse import SparseSolver

#: Newton's last resort shifts the matrix by this multiple of its mean diagonal.
NEWTON_SHIFT = 1e-3


class AbstractLinearSolver(eqx.Module):
    """How the 3D engine solves with its sparse Hessian: Newton's steps and implicit tangents."""

    #: Whether a solve is a back-substitution through a kept factorization: Newton then reuses
    #: it (lagged steps, CG's preconditioner) instead of assembling afresh.
    keeps_factorizations = True

    @abc.abstractmethod
    def newton_inverse(self, problem, x: np.ndarray, current, mode: str):
        """An object whose ``apply_inverse(rhs)`` solves with Newton's ``mode`` matrix ("exact",
        "projected" or "shifted") of ``problem`` at x (``current``: its gradient pair there);
        raises :class:`NoConvergenceError` where that matrix is not positive definite."""

    @abc.abstractmethod
    def tangent_solve(self, hessian_host, hessian_device, x, theta):
        """b ↦ H(x, θ)⁻¹ b (traceable), H the exact symmetric Hessian with the fixed dofs folded
        in: ``hessian_host(x, θ) -> (csr_matrix, rank_one | None)`` for a host solve,
        ``hessian_device(x, θ) -> SparseOperator`` for a JAX one."""


class DirectSolver(AbstractLinearSolver):
    """Host sparse direct solves: CHOLMOD Cholesky on a METIS ordering, SuperLU for indefinite
    matrices, the sealed gas's rank-one term by Sherman–Morrison (:class:`SparseSolver`); the
    implicit tangents through ``jax.pure_callback``. The default on every device."""

    def newton_inverse(self, problem, x, current, mode):
        mat, rank_one = problem.hessian(x, current, mode != "exact")
        if mode == "shifted":
            diag = np.abs(mat.diagonal())
            mat = mat + NEWTON_SHIFT * np.mean(diag) * sp.identity(mat.shape[0], format="csr")
        symmetric = problem.symmetric
        return SparseSolver(mat, rank_one, symmetric=symmetric, definite=symmetric)

    def tangent_solve(self, hessian_host, hessian_device, x, theta):
        out_shape = jax.ShapeDtypeStruct(x.shape, jnp.float64)

        def host(x_, theta_, b_):
            theta_np = jax.tree_util.tree_map(np.asarray, theta_)
            mat, rank_one = hessian_host(np.asarray(x_), theta_np)
            return SparseSolver(mat, rank_one, symmetric=True).apply_inverse(np.asarray(b_))

        return lambda b: jax.pure_callback(host, out_shape, x, theta, b)


class KrylovSolver(AbstractLinearSolver):
    """Block-Jacobi preconditioned conjugate gradients in JAX, on the arrays' device.

    Each solve stops at ‖b − A x‖₂ ≤ ``rtol`` ‖b‖₂ [-] (default 1e-10: Newton's steps and the
    implicit gradients are exact to that relative residual) or fails after ``max_steps``
    iterations, or on a direction of non-positive curvature (an indefinite matrix). Newton then
    falls back to the PSD-projected Hessian (its eigenvalue clamp on the host, the CG in JAX) and
    to a diagonal shift, as with :class:`DirectSolver`; a failed tangent solve raises at run time.
    Newton assembles a fresh matrix at every iteration (a kept matrix would cost a whole CG solve
    per use too). SPD systems only: the rest-shape solve (nonsymmetric) stays on the host.
    """

    rtol: float = eqx.field(static=True, default=1e-10)
    max_steps: int = eqx.field(static=True, default=20_000)

    keeps_factorizations = False

    def __check_init__(self):
        if not (isinstance(self.rtol, (int, float)) and 0.0 < self.rtol < 1.0):
            raise InvalidInputError(f"KrylovSolver rtol: must be in (0, 1), got {self.rtol!r}.")
        if not (isinstance(self.max_steps, (int, np.integer)) and self.max_steps >= 1):
            raise InvalidInputError(f"KrylovSolver max_steps: must be an integer ≥ 1, got {self.max_steps!r}.")

    def solve(self, operator: SparseOperator, b):
        """(x, CG iterations, status) of operator x = b (JAX arrays; status 0: converged)."""
        return krylov_solve(operator, b, float(self.rtol), int(self.max_steps))

    def newton_inverse(self, problem, x, current, mode):
        if getattr(problem, "device_operator", None) is None:
            raise InvalidInputError(
                f"KrylovSolver: {type(problem).__name__} has no device_operator (a JAX Hessian). "
                "Use DirectSolver() for it."
            )
        operator = problem.device_operator(x, current, mode != "exact")
        if mode == "shifted":
            operator = operator.shifted(NEWTON_SHIFT * operator.mean_free_diagonal())
        return KrylovInverse(self, operator)

    def tangent_solve(self, hessian_host, hessian_device, x, theta):
        def solve(b):
            operator = hessian_device(x, theta)
            out, _, status = self.solve(operator, b)
            return eqx.error_if(
                out,
                status != 0,
                "KrylovSolver: the implicit tangent's CG solve failed (no convergence "
                "within max_steps, or an indefinite Hessian). Raise max_steps, or use DirectSolver().",
            )

        return solve


class KrylovInverse:
    """Newton's solves with one :class:`SparseOperator` (host arrays in and out, CG in JAX);
    ``iterations``: CG iterations so far. A failed solve raises :class:`NoConvergenceError`."""

    def __init__(self, solver: KrylovSolver, operator: SparseOperator):
        self.solver, self.operator, self.iterations = solver, operator, 0

    def apply_inverse(self, rhs) -> np.ndarray:
        x, iterations, status = self.solver.solve(self.operator, jnp.asarray(rhs, dtype=jnp.float64))
        self.iterations += int(iterations)
        if int(status) != 0:
            raise NoConvergenceError(failure_message(int(status), int(iterations), self.solver.rtol, np.size(rhs)))
        return np.asarray(x)


__all__ = ["AbstractLinearSolver", "DirectSolver", "KrylovInverse", "KrylovSolver"]
