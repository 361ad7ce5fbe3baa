"""Damped Newton for energy minimisation with sparse Hessians (host-side loop).

Convergence is measured in force units: the largest free component of the energy gradient [N]
(for positions in m and energies in J). A backtracking line search on the energy rejects any
trial point whose energy is not finite, which is how contact barriers stay feasible (the energy
callback returns +inf for a penetrating configuration).

Each iteration first tries the exact Hessian (quadratic convergence); if it is not positive
definite (its Cholesky factorization fails) or its step is not a descent direction, it retries
with the per-element PSD-projected Hessian and finally with a diagonal shift. An indefinite
Hessian is never solved by LU here: its Newton step heads for saddles as readily as for minima,
and at 80k faces the LU factors alone need GiBs. A failure raises
:class:`shelljax.NoConvergenceError` carrying the residual history; a result is never returned
without meeting the tolerance.

Once a full Newton step has been taken, the next iteration first reuses the last factorization
(a lagged-Hessian or Shamanskii step: one solve instead of an assembly and a factorization, which
dominate the cost on large meshes). The reused factorization is kept while each such step is a
full step that cuts the residual at least ``REUSE_CONTRACTION``-fold; otherwise the step is still
taken if the line search accepts it, and the next iteration refactorizes. A reused direction is
used only if it descends, and the stopping test (max |free force| ≤ atol) is unchanged.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from .._errors import NoConvergenceError
from ._sparse import SparseSolver


#: A step with a reused factorization must cut the largest free force by at least this factor
#: (and be a full step) for the factorization to be reused again.
REUSE_CONTRACTION = 4.0


@dataclasses.dataclass(frozen=True)
class NewtonResult:
    """Converged state ``x`` with its residual history [N] (max |free gradient| per iterate) and
    the number of Hessian ``factorizations`` it took (≤ iterations: see factorization reuse)."""

    x: np.ndarray
    iterations: int
    history: list
    energy: float
    factorizations: int = 0


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
    reuse_factorization: bool = True,
    name: str = "Newton",
) -> NewtonResult:
    """Minimise ``energy`` from ``x0`` to max |∇E| ≤ ``atol`` [N] over the ``free`` dofs.

    ``energy(x) -> float`` [J] (+inf where infeasible); ``gradient(x) -> (n,)`` [N];
    ``hessian(x, project: bool) -> (csr_matrix, rank_one | None)`` with the fixed dofs folded in
    and ``rank_one = (c, u)`` for an extra c u uᵀ. ``reuse_factorization``: try the last
    factorization before a new one (module docstring). Raises NoConvergenceError with the history.
    """
    free = np.asarray(free, dtype=bool)
    x = np.array(x0, dtype=np.float64)
    e = float(energy(x))
    if not np.isfinite(e):
        raise NoConvergenceError(f"{name}: the initial state is infeasible (energy = {e}).")
    g = np.where(free, gradient(x), 0.0)
    history = [float(np.max(np.abs(g)))]
    factorizations = 0
    reusable = None  # the last factorization, while lagged steps keep converging fast
    for it in range(max_iter):
        if history[-1] <= atol:
            return NewtonResult(x=x, iterations=it, history=history, energy=e, factorizations=factorizations)
        if not np.isfinite(history[-1]):
            break
        step, reused = None, False
        if reusable is not None:
            d = np.where(free, -reusable.solve(g), 0.0)
            if np.all(np.isfinite(d)) and float(g @ d) < 0.0:
                step, slope, reused = d, float(g @ d), True
        if step is None:
            for mode in ("exact", "projected", "shifted"):
                try:
                    mat, rank_one = hessian(x, mode != "exact")
                    if mode == "shifted":
                        diag = np.abs(mat.diagonal())
                        mat = mat + 1e-3 * np.mean(diag) * _identity_like(mat)
                    solver = SparseSolver(mat, rank_one, symmetric=True, definite=True)
                    factorizations += 1
                    d = -solver.solve(g)
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
            if reused:  # a stale factorization is no reason to fail: refactorize and retry
                reusable = None
                continue
            raise NoConvergenceError(
                f"{name}: line search failed at iteration {it} (no sufficient decrease after "
                f"{max_halvings} halvings; step norm {np.linalg.norm(step):.3e}).",
                history,
            )
        x, e = x_try, e_try
        g = np.where(free, gradient(x), 0.0)
        history.append(float(np.max(np.abs(g))))
        full_step = alpha == 1.0
        if reused:
            keep = full_step and history[-1] * REUSE_CONTRACTION <= history[-2]
            reusable = reusable if keep else None
        else:
            reusable = solver if (reuse_factorization and full_step) else None
    if history[-1] <= atol:
        return NewtonResult(x=x, iterations=max_iter, history=history, energy=e, factorizations=factorizations)
    raise NoConvergenceError(
        f"{name}: residual {history[-1]:.3e} N above tolerance {atol:.3e} N after {max_iter} "
        "iterations. Use smaller continuation steps or allow more iterations (max_iter; "
        "shell3d.Indentation(max_newton_iterations=...)).",
        history,
    )


def _identity_like(mat):
    import scipy.sparse as sp

    return sp.identity(mat.shape[0], format="csr")
