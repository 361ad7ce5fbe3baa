"""Damped Newton for energy minimisation with sparse Hessians (host-side loop).

The problem is one :class:`AbstractEnergyProblem`: energy, gradient and Hessian of the unknowns x,
the mask of free dofs, and optionally exact Hessian-vector products and a feasibility projection.
Convergence is measured in force units: the largest free component of the energy gradient [N]
(for positions in m and energies in J). A backtracking line search on the energy rejects any
trial point whose energy is not finite, which is how contact barriers stay feasible (the energy
returns +inf for a penetrating configuration). A problem with such barriers can also define
``feasible_trial``, which maps each trial point to a feasible one near it (a projected search
path, as in projected Newton methods for bounds): a step that only a few barrier vertices would
overshoot then moves everything else the whole way instead of being halved as a whole.

Each iteration first tries the exact Hessian (quadratic convergence); if it is not positive
definite (its Cholesky factorization fails) or its step is not a descent direction, it retries
with the per-element PSD-projected Hessian and finally with a diagonal shift. An indefinite
Hessian is never solved by LU here: its Newton step heads for saddles as readily as for minima.
The result is the package's one :class:`shelljax.Solution`; a failure sets its ``result`` code
and, by default (``throw=True``), raises :class:`shelljax.NoConvergenceError` from it carrying the
residual history, so that a result is never returned without meeting the tolerance.

Once a full Newton step has been taken, the next iteration first reuses the last factorization
(a lagged-Hessian or Shamanskii step: one back-substitution instead of an assembly and a
factorization, which dominate the cost on large meshes). The reused factorization is kept while
each such step is a full step that cuts the residual at least ``REUSE_CONTRACTION``-fold;
otherwise the step is still taken if the line search accepts it, and the next iteration
refactorizes. A reused direction is used only if it descends.

Given exact Hessian-vector products (``hessian_operator``), a kept factorization is used instead as
the preconditioner of conjugate gradients on the exact Hessian (an inexact Newton step, solved to
a forcing tolerance of the gradient's norm). It is kept for as long as CG converges within
``CG_MAX_ITERATIONS`` products, also across calls (``factorization=``: a load step starts from the
previous step's last factorization), so the solver refactorizes only where the Hessian has moved.

The linear solves are a ``linear_solver``'s (:class:`DirectSolver`, the host factorizations above,
or :class:`KrylovSolver`, CG in JAX on the device, which assembles and solves afresh at every
iteration: no lagged steps, no kept preconditioner).

The loop runs with NumPy's BLAS limited to one thread: an idle OpenBLAS thread spinning after CG's
dot products steals the core that XLA's products use (docs/shell3d.md, *Solver*).
"""

from __future__ import annotations

import abc
from typing import Any

import equinox as eqx
import numpy as np
from threadpoolctl import threadpool_limits

from .._errors import NoConvergenceError
from .._solution import RESULTS, Solution, raise_if_failed
from ._linear import AbstractLinearSolver, DirectSolver


#: A step with a reused factorization must cut the largest free force by at least this factor
#: (and be a full step) for the factorization to be reused again.
REUSE_CONTRACTION = 4.0
#: Inexact Newton: CG stops once ‖H d + g‖₂ ≤ η ‖g‖₂, with the forcing term η of Eisenstat and
#: Walker (1996, choice 2: η = 0.9 (‖gₖ‖/‖gₖ₋₁‖)²) clipped to [CG_FORCING_MIN, CG_FORCING_MAX]:
#: loose while the nonlinearity dominates the step's error, tight (superlinear) near the solution.
CG_FORCING_MAX = 0.1
CG_FORCING_MIN = 1e-6
#: A kept factorization that needs more products than this is refactorized at the current iterate.
CG_MAX_ITERATIONS = 12
#: From this many products on, CG gives up as soon as its mean contraction per product so far,
#: extrapolated, would not reach the forcing tolerance within CG_MAX_ITERATIONS.
CG_EXTRAPOLATE_AFTER = 4


class AbstractEnergyProblem(eqx.Module):
    """An energy to minimise over the ``free`` dofs of x (host arrays, SI units).

    Subclasses define ``energy``, ``gradient`` and ``hessian``. ``gradient`` returns the
    unmasked gradient with opaque data that ``hessian`` and ``hessian_operator`` may reuse at the
    same x (e.g. a linearization); Newton hands that pair back to them at the iterate it came from.
    Two optional methods are None here and may be defined by a subclass:

    - ``hessian_operator(x, gradient) -> (v ↦ H(x) v)``: exact Hessian-vector products [N], which
      make Newton's steps preconditioned CG solves (module docstring);
    - ``feasible_trial(x, x_trial) -> x_trial' | None``: the line search's trial points become
      ``feasible_trial(x, x + α d)`` and its sufficient-decrease test uses the first-order change
      ∇E·(x_trial' − x) of the projected point (None: no projection, the plain Armijo test).
    """

    free: eqx.AbstractVar[np.ndarray]

    hessian_operator = None
    feasible_trial = None
    #: ``device_operator(x, gradient, project) -> SparseOperator``: Newton's matrix as a JAX
    #: operator, for a :class:`KrylovSolver` (None: host matrices only).
    device_operator = None
    #: Whether ``hessian`` is symmetric: Newton then factorizes it by Cholesky and falls back to the
    #: PSD-projected and shifted Hessians; otherwise (a root problem) by LU, without fallback.
    symmetric = True

    @abc.abstractmethod
    def energy(self, x: np.ndarray) -> float:
        """Energy [J] at x; +inf where x is infeasible."""

    @abc.abstractmethod
    def gradient(self, x: np.ndarray) -> tuple[np.ndarray, Any]:
        """(∇E(x) (n,) [N] with the fixed dofs included, data reusable at x or None)."""

    @abc.abstractmethod
    def hessian(self, x: np.ndarray, gradient: tuple[np.ndarray, Any], project: bool):
        """(csr_matrix with the fixed dofs folded in, rank_one (c, u) for an extra c u uᵀ or None);
        with ``project``, the per-element PSD-projected Hessian."""

    def slope(self, gradient: np.ndarray, direction: np.ndarray) -> float:
        """Directional derivative of the energy along ``direction`` (``gradient``: the masked one)."""
        return float(gradient @ direction)


class AbstractRootProblem(AbstractEnergyProblem):
    """Equations r(x) = 0 over the ``free`` dofs with a sparse, possibly nonsymmetric Jacobian,
    solved by the same Newton: its energy is the merit ½‖r‖², its steps d = −J⁻¹ r (along which the
    merit's slope is −‖r‖²), and it converges on max |r| [the unit of r].

    Subclasses define ``residual(x) -> r (n,)`` and ``jacobian(x) -> csr_matrix`` (fixed dofs
    folded in). Each energy evaluation computes r: the line search's decrease test is on ‖r‖.
    """

    symmetric = False

    @abc.abstractmethod
    def residual(self, x: np.ndarray) -> np.ndarray:
        """r(x) (n,), unmasked."""

    @abc.abstractmethod
    def jacobian(self, x: np.ndarray):
        """∂r/∂x as a csr_matrix with the fixed dofs folded in."""

    def energy(self, x):
        r = np.where(self.free, self.residual(x), 0.0)
        return 0.5 * float(r @ r) if np.all(np.isfinite(r)) else np.inf

    def gradient(self, x):
        return self.residual(x), None

    def hessian(self, x, gradient, project):
        return self.jacobian(x), None

    def slope(self, gradient, direction):
        return -float(gradient @ gradient)


def newton(
    problem: AbstractEnergyProblem,
    x0,
    *,
    atol: float,
    max_steps: int = 60,
    max_halvings: int = 40,
    armijo: float = 1e-4,
    reuse_factorization: bool = True,
    factorization=None,
    name: str = "Newton",
    throw: bool = True,
    linear_solver: AbstractLinearSolver | None = None,
) -> Solution:
    """Minimise ``problem``'s energy from ``x0`` to max |∇E| ≤ ``atol`` [N] over its free dofs.

    ``max_steps``: Newton iterations; ``max_halvings``: line-search halvings per iteration;
    ``reuse_factorization``: try the last factorization before a new one (module docstring);
    ``factorization``: a kept factorization to start with. Returns a :class:`shelljax.Solution`
    (``value`` x [m]; ``history`` [N] from the start's residual on; ``stats``: ``energy`` [J],
    ``factorizations`` (≤ iterations: see factorization reuse), ``products`` (CG's
    Hessian-vector products), ``krylov_iterations`` (a KrylovSolver's CG iterations);
    ``state``: the last factorization, a SparseSolver or None, to precondition a nearby
    minimisation with). ``linear_solver``: :class:`DirectSolver` (default) or
    :class:`KrylovSolver`, which assembles and solves afresh at every iteration (no reuse). With
    ``throw``, a failure raises NoConvergenceError with the history instead.
    """
    linear_solver = DirectSolver() if linear_solver is None else linear_solver
    if not linear_solver.keeps_factorizations:
        reuse_factorization, factorization = False, None
    with threadpool_limits(limits=1, user_api="blas"):
        run = _NewtonRun(problem, atol, max_halvings, armijo, reuse_factorization, factorization, name, linear_solver)
        solution = run.minimise(x0, max_steps)
    return raise_if_failed(solution, name, run.failure) if throw else solution


class _NewtonRun:
    """The state of one Newton minimisation: iterate, residual history, kept factorizations."""

    def __init__(self, problem, atol, max_halvings, armijo, reuse_factorization, factorization, name, linear_solver):
        self.problem, self.atol, self.name = problem, atol, name
        self.max_halvings, self.armijo, self.reuse = max_halvings, armijo, reuse_factorization
        self.free = np.asarray(problem.free, dtype=bool)
        self.linear_solver = linear_solver
        # CG preconditioned by a kept factorization needs a solver that keeps one.
        self.inexact = problem.hessian_operator is not None and linear_solver.keeps_factorizations
        self.factorizations = self.products = self.krylov_iterations = 0
        self.solve_failure = ""  # the last linear solve's failure, for the report
        self.forcing = CG_FORCING_MAX
        # the last factorization, while lagged steps keep converging fast (or CG with it does)
        self.reusable = self.solver = factorization if reuse_factorization else None
        self.failure = ""  # what went wrong, in more words than the result code

    def minimise(self, x0, max_steps: int) -> Solution:
        self.x = np.array(x0, dtype=np.float64)
        self.e = float(self.problem.energy(self.x))
        self.history = []
        if not np.isfinite(self.e):
            self.failure = f"the initial state is infeasible (energy = {self.e})."
            return self._result(0, RESULTS.infeasible_start)
        self._evaluate_gradient()
        self.history = [float(np.max(np.abs(self.g)))]
        for it in range(max_steps):
            if self.history[-1] <= self.atol:
                return self._result(it, RESULTS.successful)
            if not np.isfinite(self.history[-1]):
                break
            step, slope, reused = self._direction(it)
            if step is None:
                return self._result(it, RESULTS.no_descent_direction)
            alpha, x_try, e_try = self._line_search(step, slope)
            if alpha is None:
                if reused:  # a stale factorization is no reason to fail: refactorize and retry
                    self.reusable = None
                    continue
                self.failure = (
                    f"line search failed at iteration {it} (no sufficient decrease after "
                    f"{self.max_halvings} halvings; step norm {np.linalg.norm(step):.3e})."
                )
                return self._result(it, RESULTS.line_search_failed)
            self._accept(x_try, e_try, alpha, reused)
        if self.history[-1] <= self.atol:
            return self._result(max_steps, RESULTS.successful)
        self.failure = (
            f"residual {self.history[-1]:.3e} N above tolerance {self.atol:.3e} N after {max_steps} "
            "iterations. Use smaller continuation steps or allow more iterations (max_steps; "
            "shell3d.Indentation(max_newton_iterations=...))."
        )
        return self._result(max_steps, RESULTS.max_steps_reached)

    def _result(self, iterations: int, result) -> Solution:
        stats = {
            "energy": self.e,
            "factorizations": self.factorizations,
            "products": self.products,
            "krylov_iterations": self.krylov_iterations,
        }
        return Solution(self.x, result, iterations, self.history, stats, self.solver)

    def _evaluate_gradient(self) -> None:
        self.current = self.problem.gradient(self.x)
        self.g = np.where(self.free, self.current[0], 0.0)

    def _direction(self, it: int):
        """(step, slope g·step, whether a kept factorization gave it): a descent direction."""
        if self.reusable is not None:
            d = self._reused_direction()
            if d is not None and np.all(np.isfinite(d)) and self.problem.slope(self.g, d) < 0.0:
                return d, self.problem.slope(self.g, d), True
        for mode in ("exact", "projected", "shifted") if self.problem.symmetric else ("exact",):
            d = self._factorized_direction(mode)
            if d is None:
                continue
            slope = self.problem.slope(self.g, d)
            if np.all(np.isfinite(d)) and slope < 0.0:
                return d, slope, False
        self.failure = (
            f"no descent direction at iteration {it} (Hessian singular or indefinite even after projection and "
            f"shift). {self.solve_failure}"
        ).strip()
        return None, None, False

    def _reused_direction(self):
        """Newton step through the kept factorization: directly, or as CG's preconditioner."""
        free, reusable = self.free, self.reusable
        if not self.inexact:
            return np.where(free, -reusable.apply_inverse(self.g), 0.0)
        product = self.problem.hessian_operator(self.x, self.current)
        d, used = _preconditioned_cg(
            lambda v: np.where(free, product(v), 0.0),
            lambda r: np.where(free, reusable.apply_inverse(r), 0.0),
            self.g,
            self.forcing,
        )
        self.products += used
        if d is None:
            self.reusable = None
        return d

    def _factorized_direction(self, mode: str):
        """Newton step through a fresh factorization of the ``mode`` Hessian, or None if it is
        not positive definite."""
        try:
            self.solver = self.linear_solver.newton_inverse(self.problem, self.x, self.current, mode)
            self.factorizations += 1
            try:
                d = -self.solver.apply_inverse(self.g)
            finally:
                self.krylov_iterations += getattr(self.solver, "iterations", 0)
        except NoConvergenceError as err:
            self.solve_failure = str(err)
            return None
        return np.where(self.free, d, 0.0)

    def _line_search(self, step, slope):
        """(α, x_try, E(x_try)) of the first accepted halving of ``step``; α None if none is."""
        alpha = 1.0
        gnorm = float(np.linalg.norm(self.g))
        for _ in range(self.max_halvings):
            x_try = self.x + alpha * step
            predicted = alpha * slope
            projected = None if self.problem.feasible_trial is None else self.problem.feasible_trial(self.x, x_try)
            if projected is not None:
                x_try = projected
                predicted = min(float(self.g @ (x_try - self.x)), 0.0)
            e_try = float(self.problem.energy(x_try))
            if np.isfinite(e_try):
                if e_try <= self.e + self.armijo * predicted:
                    return alpha, x_try, e_try
                if abs(e_try - self.e) <= 1e-11 * max(abs(self.e), 1e-300):
                    # Energy differences below round-off: accept if the residual decreases.
                    g_try = np.where(self.free, self.problem.gradient(x_try)[0], 0.0)
                    if float(np.linalg.norm(g_try)) < gnorm:
                        return alpha, x_try, e_try
            alpha *= 0.5
        return None, None, None

    def _accept(self, x_try, e_try, alpha: float, reused: bool) -> None:
        """Move to the accepted point; update CG's forcing term and the kept factorization."""
        gnorm = float(np.linalg.norm(self.g))
        self.x, self.e = x_try, e_try
        self._evaluate_gradient()
        self.history.append(float(np.max(np.abs(self.g))))
        # A linear residual of atol/2 in the 2-norm is below atol in every component: never ask more.
        gnew = float(np.linalg.norm(self.g))
        forcing = max(0.9 * (gnew / gnorm) ** 2, 0.5 * self.atol / max(gnew, 1e-300))
        self.forcing = float(np.clip(forcing, CG_FORCING_MIN, CG_FORCING_MAX))
        full_step = alpha == 1.0
        if self.inexact:  # a preconditioner: kept while CG converges with it
            self.reusable = (self.reusable if reused else self.solver) if self.reuse else None
        elif reused:
            keep = full_step and self.history[-1] * REUSE_CONTRACTION <= self.history[-2]
            self.reusable = self.reusable if keep else None
        else:
            self.reusable = self.solver if (self.reuse and full_step) else None


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


__all__ = ["AbstractEnergyProblem", "AbstractRootProblem", "newton"]
