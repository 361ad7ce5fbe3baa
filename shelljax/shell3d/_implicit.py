"""Equilibria as differentiable functions of parameters, by implicit differentiation.

At an equilibrium r(x*, θ) = ∇ₓE(x*, θ) = 0 on the free dofs, so dx* = −H⁻¹ ∂r/∂θ dθ with the
(symmetric) Hessian H = ∂r/∂x. The primal solve is a host Newton run (``jax.pure_callback``), the
tangent solve a ``jax.lax.custom_linear_solve`` whose matvec is a JAX Hessian-vector product and
whose solve is the same host sparse factorization (CHOLMOD or SuperLU, + Sherman–Morrison) as in
Newton (:func:`shelljax._solution.implicit_tangent`, shared with the axisymmetric engine). Being
symmetric, the same solve serves the transpose, so both ``jax.jvp``/``jacfwd`` and
``jax.grad``/``jacrev`` work, also under ``jax.jit``. No Newton iteration is unrolled and no dense
Hessian is formed.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from .._solution import implicit_tangent
from ._linear import AbstractLinearSolver, DirectSolver


def implicit_equilibrium(
    minimise_host: Callable,
    residual: Callable,
    hessian_host: Callable,
    free,
    n_dofs: int,
    *,
    linear_solver: AbstractLinearSolver | None = None,
    hessian_device: Callable | None = None,
) -> Callable:
    """Build ``theta -> x*`` (custom JVP) from a host solver and a JAX residual.

    ``minimise_host(theta) -> (n,)`` runs on numpy values of the parameter pytree ``theta``;
    ``residual(x, theta) -> (n,)`` is the JAX energy gradient; ``hessian_host(x, theta)`` returns
    ``(csr_matrix with fixed dofs folded in, rank_one | None)`` for the exact Hessian; ``free`` is
    the (n,) bool mask of free dofs (the fixed ones do not move with θ). ``linear_solver``: the
    tangent solve's (:class:`DirectSolver` by default); a :class:`KrylovSolver` needs
    ``hessian_device(x, theta) -> SparseOperator``, the same Hessian as a JAX operator.
    """
    linear_solver = DirectSolver() if linear_solver is None else linear_solver
    mask = jnp.asarray(np.asarray(free, dtype=np.float64))
    out_shape = jax.ShapeDtypeStruct((n_dofs,), jnp.float64)

    def _host_minimise(theta):
        theta_np = jax.tree_util.tree_map(np.asarray, theta)
        return np.asarray(minimise_host(theta_np), dtype=np.float64)

    @jax.custom_jvp
    def equilibrium(theta):
        return jax.pure_callback(_host_minimise, out_shape, theta)

    @equilibrium.defjvp
    def _equilibrium_jvp(primals, tangents):
        (theta,), (dtheta,) = primals, tangents
        x = equilibrium(theta)
        solve = linear_solver.tangent_solve(hessian_host, hessian_device, x, theta)
        return x, implicit_tangent(residual, x, theta, dtheta, mask, solve)

    return equilibrium
