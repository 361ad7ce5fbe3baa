"""Damped Newton for energy minimisation with sparse Hessians (host-side loop).

Convergence is measured in force units: the largest free component of the energy gradient [N]
(for positions in m and energies in J). A backtracking line search on the energy rejects any
trial point whose energy is not finite, which is how contact barriers stay feasible (the energy
callback returns +inf for a penetrating configuration). A caller with such barriers can also pass
``project``, which maps each trial point to a feasible one near it (a projected search path, as
in projected Newton methods for bounds): a step that only a few barrier vertices would overshoot
then moves everything else the whole way instead of being halved as a whole.

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

Given exact Hessian-vector products (``hessian_operator``), a kept factorization is used instead as
the preconditioner of conjugate gradients on the exact Hessian (an inexact Newton step, solved to
a forcing tolerance of the gradient's norm). It is kept for as long as CG converges within
``CG_MAX_ITERATIONS`` products, also across calls (``factorization=``: a load step starts from the
previous step's last factorization). On a 20k-face shell a product and a solve cost ≈ 13 ms each
against ≈ 550 ms for an assembly and a factorization, and the Hessian of the last load step's
equilibrium preconditions the next one well: the solver refactorizes where the Hessian has moved
(new contacts, buckling), not on every load step.

The loop runs with the BLAS of NumPy limited to one thread (threadpoolctl). Its dot products on
CG's vectors woke OpenBLAS's second thread, which then spins for a while after each call, on the
core that XLA's products and gradients use: on the 20k-face curve the same iterations took 21.9 s
with the default two threads and 13.5 s with one (2-core VM, docs/shell3d.md).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
from threadpoolctl import threadpool_limits

from .._errors import NoConvergenceError
from ._sparse import SparseSolver


#: A step with a reused factorization must cut the largest free force by at least this factor
#: (and be a full step) for the factorization to be reused again.
REUSE_CONTRACTION = 4.0
#: Inexact Newton: CG stops once ‖H d + g‖₂ ≤ η ‖g‖₂, with the forcing term η of Eisenstat and
#: Walker (1996, choice 2: η = 0.9 (‖gₖ‖/‖gₖ₋₁‖)²) clipped to [CG_FORCING_MIN, CG_FORCING_MAX]:
#: loose while the nonlinearity dominates the step's error, tight (superlinear) near the solution.
CG_FORCING_MAX = 0.1
CG_FORCING_MIN = 1e-6
#: A kept factorization that needs more products than this is refactorized at the current iterate
#: (a product and a solve cost ≈ 1/17 of an assembly and a factorization at 20k faces).
CG_MAX_ITERATIONS = 12
#: From this many products on, CG gives up as soon as its mean contraction per product so far,
#: extrapolated, would not reach the forcing tolerance within CG_MAX_ITERATIONS: a poor
#: preconditioner is then replaced after 4 products instead of 12 (20k-face curve: 353 → 248
#: products for 5 → 7 factorizations; giving up from 3 or 5 products on cost as much, docs/shell3d.md).
CG_EXTRAPOLATE_AFTER = 4


@dataclasses.dataclass(frozen=True)
class NewtonResult:
    """Converged state ``x`` with its residual history [N] (max |free gradient| per iterate) and
    the number of Hessian ``factorizations`` it took (≤ iterations: see factorization reuse), the
    Hessian-vector ``products`` of its CG solves, and the ``last_factorization`` (a SparseSolver or
    None) to precondition a nearby solve with."""

    x: np.ndarray
    iterations: int
    history: list
    energy: float
    factorizations: int = 0
    products: int = 0
    last_factorization: object = dataclasses.field(default=None, repr=False)


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
    hessian_operator: Callable | None = None,
    factorization=None,
    project: Callable | None = None,
    name: str = "Newton",
) -> NewtonResult:
    """Minimise ``energy`` from ``x0`` to max |∇E| ≤ ``atol`` [N] over the ``free`` dofs.

    ``energy(x) -> float`` [J] (+inf where infeasible); ``gradient(x) -> (n,)`` [N];
    ``hessian(x, project: bool) -> (csr_matrix, rank_one | None)`` with the fixed dofs folded in
    and ``rank_one = (c, u)`` for an extra c u uᵀ. ``reuse_factorization``: try the last
    factorization before a new one (module docstring). ``project(x, x_trial) -> x_trial'``: the
    line search's trial points become ``project(x, x + α d)`` and its sufficient-decrease test
    uses the first-order change ∇E·(x_trial' − x) of the projected point. Raises
    NoConvergenceError with the history.
    """
    with threadpool_limits(limits=1, user_api="blas"):
        return _newton(energy, gradient, hessian, x0, free, atol=atol, max_iter=max_iter, max_halvings=max_halvings,
                       armijo=armijo, reuse_factorization=reuse_factorization, hessian_operator=hessian_operator,
                       factorization=factorization, project=project, name=name)  # fmt: skip


def _newton(energy, gradient, hessian, x0, free, *, atol, max_iter, max_halvings, armijo, reuse_factorization,
            hessian_operator, factorization, project, name) -> NewtonResult:
    free = np.asarray(free, dtype=bool)
    x = np.array(x0, dtype=np.float64)
    e = float(energy(x))
    if not np.isfinite(e):
        raise NoConvergenceError(f"{name}: the initial state is infeasible (energy = {e}).")
    g = np.where(free, gradient(x), 0.0)
    history = [float(np.max(np.abs(g)))]
    factorizations = products = 0
    forcing = CG_FORCING_MAX
    # the last factorization, while lagged steps keep converging fast (or CG with it does)
    reusable = solver = factorization if reuse_factorization else None

    def result(iterations):
        return NewtonResult(x=x, iterations=iterations, history=history, energy=e, factorizations=factorizations,
                            products=products, last_factorization=solver)  # fmt: skip

    for it in range(max_iter):
        if history[-1] <= atol:
            return result(it)
        if not np.isfinite(history[-1]):
            break
        step, reused = None, False
        if reusable is not None:
            if hessian_operator is None:
                d = np.where(free, -reusable.solve(g), 0.0)
            else:
                product = hessian_operator(x)
                d, used = _preconditioned_cg(lambda v: np.where(free, product(v), 0.0),
                                             lambda r: np.where(free, reusable.solve(r), 0.0), g, forcing)  # fmt: skip
                products += used
                if d is None:
                    reusable = None
            if d is not None and np.all(np.isfinite(d)) and float(g @ d) < 0.0:
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
            predicted = alpha * slope
            if project is not None:
                x_try = project(x, x_try)
                predicted = min(float(g @ (x_try - x)), 0.0)
            e_try = float(energy(x_try))
            if np.isfinite(e_try):
                if e_try <= e + armijo * predicted:
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
        # Never solve for more than the stopping test needs: a linear residual of atol/2 in the
        # 2-norm is below atol in every component (measured: the last step of a load step
        # otherwise asked for 1e-3 … 1e-4 and exhausted CG on 6e-5 N against an atol of 5e-6 N).
        gnew = float(np.linalg.norm(g))
        forcing = max(0.9 * (gnew / gnorm) ** 2, 0.5 * atol / max(gnew, 1e-300))
        forcing = float(np.clip(forcing, CG_FORCING_MIN, CG_FORCING_MAX))
        full_step = alpha == 1.0
        if hessian_operator is not None:  # a preconditioner: kept while CG converges with it
            reusable = (reusable if reused else solver) if reuse_factorization else None
        elif reused:
            keep = full_step and history[-1] * REUSE_CONTRACTION <= history[-2]
            reusable = reusable if keep else None
        else:
            reusable = solver if (reuse_factorization and full_step) else None
    if history[-1] <= atol:
        return result(max_iter)
    raise NoConvergenceError(
        f"{name}: residual {history[-1]:.3e} N above tolerance {atol:.3e} N after {max_iter} "
        "iterations. Use smaller continuation steps or allow more iterations (max_iter; "
        "shell3d.Indentation(max_newton_iterations=...)).",
        history,
    )


def _preconditioned_cg(product, precondition, g, forcing):
    """(d, products): CG on H d = −g preconditioned by ``precondition`` (≈ H⁻¹), to
    ``forcing`` ‖g‖₂; d is None where it did not converge in ``CG_MAX_ITERATIONS`` products, is
    not on course to (``CG_EXTRAPOLATE_AFTER``), or met a direction of non-positive curvature
    (then a factorization at x decides the step)."""
    residual = -g
    z = precondition(residual)
    direction = z
    rz = float(residual @ z)
    d = np.zeros_like(g)
    start = float(np.linalg.norm(g))
    target = forcing * start
    for k in range(1, CG_MAX_ITERATIONS + 1):
        hp = product(direction)
        curvature = float(direction @ hp)
        if not (curvature > 0.0 and rz > 0.0):
            return None, k
        a = rz / curvature
        d = d + a * direction
        residual = residual - a * hp
        remaining = float(np.linalg.norm(residual))
        if remaining <= target:
            return d, k
        if k >= CG_EXTRAPOLATE_AFTER and not _on_course(start, remaining, target, k):
            return None, k
        z = precondition(residual)
        rz, rz_old = float(residual @ z), rz
        direction = z + (rz / rz_old) * direction
    return None, CG_MAX_ITERATIONS


def _on_course(start: float, remaining: float, target: float, used: int) -> bool:
    """Whether CG, having contracted its residual from ``start`` to ``remaining`` in ``used``
    products, reaches ``target`` within ``CG_MAX_ITERATIONS`` products at the same mean rate."""
    rate = (remaining / start) ** (1.0 / used)
    return rate < 1.0 and used + np.log(target / remaining) / np.log(rate) <= CG_MAX_ITERATIONS


def _identity_like(mat):
    import scipy.sparse as sp

    return sp.identity(mat.shape[0], format="csr")
