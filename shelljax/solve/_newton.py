"""Damped Newton for energy minimisation with sparse Hessians (host-side loop).

Convergence is measured in force units: the largest free component of the energy gradient [N]
(for positions in m and energies in J). A backtracking line search on the energy rejects any
trial point whose energy is not finite, which is how contact barriers stay feasible (the energy
callback returns +inf for a penetrating configuration).

Each iteration first tries the exact Hessian (quadratic convergence); if its factorization fails
or its step is not a descent direction, it retries with the per-element PSD-projected Hessian and
finally with a diagonal shift. A failure raises :class:`shelljax.NoConvergenceError` carrying the
residual history; a result is never returned without meeting the tolerance.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from .._errors import NoConvergenceError
from ._sparse import SparseSolver


@dataclasses.dataclass(frozen=True)
class NewtonResult:
    """Converged state ``x`` with its residual history [N] (max |free gradient| per iterate)."""

    x: np.ndarray
    iterations: int
    history: list
    energy: float


def newton(
    energy: Callable,
    gradient: Callable,
    hessian: Callable,
    x0,
    free,
    *,
    atol: float,
    max_iter: int = 60,
    max_halvings: int = 40,
    armijo: float = 1e-4,
    name: str = "Newton",
) -> NewtonResult:
    """Minimise ``energy`` from ``x0`` to max |∇E| ≤ ``atol`` [N] over the ``free`` dofs.

    ``energy(x) -> float`` [J] (+inf where infeasible); ``gradient(x) -> (n,)`` [N];
    ``hessian(x, project: bool) -> (csr_matrix, rank_one | None)`` with the fixed dofs folded in
    and ``rank_one = (c, u)`` for an extra c u uᵀ. Raises NoConvergenceError with the history.
    """
    free = np.asarray(free, dtype=bool)
    x = np.array(x0, dtype=np.float64)
    e = float(energy(x))
    if not np.isfinite(e):
        raise NoConvergenceError(f"{name}: the initial state is infeasible (energy = {e}).")
    g = np.where(free, gradient(x), 0.0)
    history = [float(np.max(np.abs(g)))]
    for it in range(max_iter):
        if history[-1] <= atol:
            return NewtonResult(x=x, iterations=it, history=history, energy=e)
        if not np.isfinite(history[-1]):
            break
        step = None
        for mode in ("exact", "projected", "shifted"):
            try:
                mat, rank_one = hessian(x, mode != "exact")
                if mode == "shifted":
                    diag = np.abs(mat.diagonal())
                    mat = mat + 1e-3 * np.mean(diag) * _identity_like(mat)
                d = -SparseSolver(mat, rank_one).solve(g)
            except NoConvergenceError:
                continue
            d = np.where(free, d, 0.0)
            slope = float(g @ d)
            if np.all(np.isfinite(d)) and slope < 0.0:
                step = d
                break
        if step is None:
            raise NoConvergenceError(
                f"{name}: no descent direction at iteration {it} (Hessian singular or indefinite "
                "even after projection and shift).",
                history,
            )
        alpha, accepted = 1.0, False
        gnorm = float(np.linalg.norm(g))
        for _ in range(max_halvings):
            x_try = x + alpha * step
            e_try = float(energy(x_try))
            if np.isfinite(e_try):
                if e_try <= e + armijo * alpha * slope:
                    accepted = True
                elif abs(e_try - e) <= 1e-11 * max(abs(e), 1e-300):
                    # Energy differences below round-off: accept if the residual decreases.
                    g_try = np.where(free, gradient(x_try), 0.0)
                    accepted = float(np.linalg.norm(g_try)) < gnorm
                if accepted:
                    break
            alpha *= 0.5
        if not accepted:
            raise NoConvergenceError(
                f"{name}: line search failed at iteration {it} (no sufficient decrease after "
                f"{max_halvings} halvings; step norm {np.linalg.norm(step):.3e}).",
                history,
            )
        x, e = x_try, e_try
        g = np.where(free, gradient(x), 0.0)
        history.append(float(np.max(np.abs(g))))
    if history[-1] <= atol:
        return NewtonResult(x=x, iterations=max_iter, history=history, energy=e)
    raise NoConvergenceError(
        f"{name}: residual {history[-1]:.3e} N above tolerance {atol:.3e} N after {max_iter} "
        "iterations. Use smaller continuation steps or a larger max_iter.",
        history,
    )


def _identity_like(mat):
    import scipy.sparse as sp

    return sp.identity(mat.shape[0], format="csr")
