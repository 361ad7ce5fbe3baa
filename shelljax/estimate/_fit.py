"""Simulation-fitted estimator: Levenberg–Marquardt (optimistix) through a forward model.

Started from the closed-form estimate; error bars from the Gauss–Newton (Laplace) approximation
Cov(u) = (JᵀJ)⁻¹ of the whitened residuals at the optimum (priors included as residuals). Positive
quantities are reported with log-normal 95 % intervals, matching the log parametrisation.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._errors import NoConvergenceError
from .._programs import persistent_jit
from ..session import Session
from ._closed_form import estimate_session
from ._forward import AbstractForwardModel
from ._problem import ALL_NAMES, OFFSET_SCALE, InverseProblem, PaddedProblem, build_problem, padded_problem
from ._result import Estimate

_METHOD = "fit: Levenberg-Marquardt through {model}, Laplace (Gauss-Newton) errors"
_UNITS = {
    "gauge_pressure": "Pa",
    "young_modulus": "Pa",
    "thickness": "m",
    "radius": "m",
    "depth_offset": "m",
    "force_gain": "1",
}


@dataclasses.dataclass(frozen=True)
class FitResult:
    """Result of :func:`fit_session`.

    ``estimates``: every free parameter (gauge_pressure [Pa], young_modulus [Pa], and nuisances:
    thickness [m], radius [m], depth_offset [m], force_gain [-]); ``covariance``: Cov(u) of the
    unknowns in the problem's scaled space; ``chi2`` and ``dof`` of the whitened residuals;
    ``steps``: LM iterations; ``predicted_depth`` [m] at the recorded forces and
    ``predicted_wrinkle_count`` at the optimum; ``problem``: the inverse problem solved;
    ``u``: the optimum in the problem's scaled space; ``source``: the session's file;
    ``converged``: False only when ``fit_session(..., raise_on_failure=False)`` returned the last
    Levenberg–Marquardt iterate.
    """

    estimates: dict[str, Estimate]
    covariance: np.ndarray
    chi2: float
    dof: int
    steps: int
    predicted_depth: np.ndarray
    predicted_wrinkle_count: float
    problem: InverseProblem
    u: np.ndarray
    source: Path
    converged: bool = True

    def to_dict(self) -> dict:
        """JSON-ready: ``estimates`` by name, χ², degrees of freedom, iterations, the predicted
        wrinkle count [-] and the depth noise σ_w [m] of the whitened residuals."""
        return {
            "estimates": {name: est.to_dict() for name, est in self.estimates.items()},
            "chi2": self.chi2,
            "dof": self.dof,
            "iterations": self.steps,
            "predicted_wrinkle_count": self.predicted_wrinkle_count,
            "depth_noise": {"value": self.problem.depth_noise, "unit": "m"},
        }


OPTIMALITY_TOL = 1e-3  # [χ²] an optimum's remaining Gauss–Newton decrease; 1 χ² ≈ a 1σ shift


@jax.jit
def _forward_ok(problem, u):
    return problem.forward_ok(u)


def _with_dense_jacobian(fn):
    """``fn`` (u ↦ (residuals, aux)) whose linearisation is a matrix, computed once by forward mode.

    optimistix applies a linearisation several times (materialised for the damped solve,
    transposed for the gradient, applied for the predicted decrease), and each use of the engine's
    tangent map is another copy of it for XLA to compile; a matrix costs nothing to reuse.
    """

    @jax.custom_jvp
    def dense(u):
        return fn(u)

    def residuals_and_all(v):
        out = fn(v)
        return out[0], out

    @dense.defjvp
    def dense_jvp(primals, tangents):
        (u,), (du,) = primals, tangents
        jac, (r, aux) = jax.jacfwd(residuals_and_all, has_aux=True)(u)
        return (r, aux), (jac @ du, jax.tree_util.tree_map(_zero_tangent, aux))

    return dense


def _zero_tangent(x):
    # the aux is not differentiated; a bool needs JAX's float0 tangent
    x = jnp.asarray(x)
    if jnp.issubdtype(x.dtype, jnp.inexact):
        return jnp.zeros_like(x)
    return np.zeros(x.shape, jax.dtypes.float0)


def _solve(problem: PaddedProblem, u0, rtol, atol, max_steps: int):
    # One compiled program; every forward-model call in it is another engine copy to compile, so
    # the residuals, Jacobian and predictions at the optimum are LM's own, not a fresh pass.
    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    residuals = _with_dense_jacobian(problem.residuals_and_prediction)
    sol = optx.least_squares(lambda u, args: residuals(u), solver, u0, has_aux=True, max_steps=max_steps, throw=False)
    # (sol.aux belongs to the iterate before the last accepted one; the state's to the optimum)
    *prediction, forward_ok = sol.state.aux
    accepted = sol.state.f_info
    return dict(
        u=sol.value,
        ok=sol.result == optx.RESULTS.successful,
        forward_ok=forward_ok,
        steps=sol.stats["num_steps"],
        out_of_steps=sol.result == optx.RESULTS.nonlinear_max_steps_reached,
        residual=accepted.residual,
        jacobian=accepted.jac.as_matrix(),
        prediction=tuple(prediction),
    )


# a fit is compiled more often than it runs long: XLA:CPU's legacy elemental emitters and LLVM at
# -O1 compile it faster, and it runs as fast (docs/fit-and-bayes.md#compilation)
_FIT_COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False, "xla_backend_optimization_level": 1}
_solve_kept = persistent_jit(_solve, cpu_compiler_options=_FIT_COMPILER_OPTIONS)


def solve_least_squares(
    problem, u0, rtol: float = 1e-8, atol: float = 1e-8, max_steps: int = 200, optimality_tol: float = OPTIMALITY_TOL
):
    """Levenberg–Marquardt on ``problem.residuals_and_prediction`` (whitened residuals, aux
    ending in a forward-model-finite flag) from ``u0``.

    Returns (the solve's outputs: u, residual, jacobian, steps, and the aux at the optimum;
    converged; forward model finite; the χ² a Gauss–Newton step would still remove). Converged
    as :func:`fit_session` documents.
    """
    out = _solve_kept(problem, u0, rtol, atol, max_steps=int(max_steps))
    finite = bool(out["forward_ok"])
    jac = np.asarray(out["jacobian"])
    # optimistix also stops "successfully" after a step it rejected (e.g. the engine failed at the
    # trial point): the χ² decrease a Gauss–Newton step still promises, ‖J δ‖² with δ the
    # least-squares solution of J δ = r, tells an optimum from that (lstsq: J may be singular
    # where the forward model failed and every residual is the same constant).
    step = np.linalg.lstsq(jac, np.asarray(out["residual"]), rcond=None)[0]
    promised_decrease = float(np.sum((jac @ step) ** 2))
    converged = (bool(out["ok"]) or bool(out["out_of_steps"])) and finite and promised_decrease < optimality_tol
    return out, converged, finite, promised_decrease


def fit_session(
    session: Session,
    model: AbstractForwardModel,
    *,
    nuisance: tuple[str, ...] = (),
    depth_noise: float | None = None,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    max_steps: int = 200,
    raise_on_failure: bool = True,
) -> FitResult:
    """Fit P_g [Pa] and E [Pa] (and nuisances) of ``session`` through ``model``.

    Converged means: the forward model is finite at the last iterate and a Gauss–Newton step
    there would remove less than ``OPTIMALITY_TOL`` of χ², and Levenberg–Marquardt either met
    its ``rtol``/``atol`` step tolerances or ran out of its ``max_steps`` at such a point (near
    the optimum the engine's round-off can make every trial step a rejected one, so LM's own test
    may never fire).

    ``raise_on_failure=False`` returns the last iterate (``converged = False``) when
    Levenberg–Marquardt stops without meeting its tolerances but the forward model is finite
    there (bayes uses it only to place its surrogate).

    Raises:
        NoConvergenceError: when Levenberg–Marquardt stops without converging (unless
            ``raise_on_failure`` is False), or the forward model fails at the optimum; the
            message says which and where.
    """
    start = estimate_session(session, bootstrap_samples=0)
    start_modulus = start.young_modulus.value if start.young_modulus is not None else 1e6
    problem = build_problem(
        session,
        model,
        start_pressure=start.gauge_pressure.value,
        start_modulus=start_modulus,
        depth_noise=depth_noise,
        nuisance=nuisance,
    )
    # the padded problem: one compiled fit for every session of this model's structure
    padded, columns, rows = padded_problem(problem)
    u0 = jnp.zeros(len(ALL_NAMES))
    out, converged, finite, promised_decrease = solve_least_squares(padded, u0, rtol, atol, max_steps)
    # from a failed start every residual is the same constant, so LM cannot move and ends there
    # unfinite: only then is the start checked (its program is compiled only then)
    if not finite and not bool(_forward_ok(padded, u0)):
        raise NoConvergenceError(
            f"{session.source}: the forward model {type(model).__name__} fails at the closed-form "
            f"start (P_g = {start.gauge_pressure.value:.4g} Pa, E = {start_modulus:.4g} Pa); "
            "check the session's forces and geometry against the model's range"
        )
    u, steps, residual = np.asarray(out["u"])[columns], out["steps"], np.asarray(out["residual"])[rows]
    jac = np.asarray(out["jacobian"])[np.ix_(rows, columns)]
    if not converged and (raise_on_failure or not finite):
        phys = {k: float(v) for k, v in problem.physical(u).items()}
        raise NoConvergenceError(
            f"{session.source}: Levenberg-Marquardt did not converge in {int(steps)} steps "
            f"(last P_g = {phys['gauge_pressure']:.4g} Pa, E = {phys['young_modulus']:.4g} Pa, "
            f"forward model finite: {finite}, χ² a Gauss-Newton step would still remove: "
            f"{promised_decrease:.3g}); try nuisance=() or check the data for outliers"
        )
    covariance = np.linalg.inv(jac.T @ jac)
    chi2 = float(residual @ residual)
    return FitResult(
        estimates=_laplace_estimates(problem, u, covariance),
        covariance=covariance,
        chi2=chi2,
        dof=int(residual.size - problem.ndim),
        steps=int(steps),
        predicted_depth=np.asarray(out["prediction"][0])[: problem.force.shape[0]],
        predicted_wrinkle_count=float(out["prediction"][1]),
        problem=problem,
        u=np.asarray(u),
        source=session.source,
        converged=converged,
    )


def _laplace_estimates(problem: InverseProblem, u, covariance: np.ndarray) -> dict[str, Estimate]:
    """Every free parameter's value and Laplace error at ``u``, in SI."""
    u_std = np.sqrt(np.diag(covariance))
    physical = {k: float(v) for k, v in problem.physical(u).items()}
    method = _METHOD.format(model=type(problem.model).__name__)
    estimates = {}
    for i, name in enumerate(problem.names):
        if name == "depth_offset":
            value, std = physical[name], OFFSET_SCALE * u_std[i]
            estimates[name] = Estimate(value, std, (value - 1.96 * std, value + 1.96 * std), "m", method)
        else:  # log-parametrised: σ(u) is the relative standard deviation
            estimates[name] = Estimate.lognormal(physical[name], float(u_std[i]), _UNITS[name], method)
    return estimates


def relative_error(estimate: Estimate, truth: float) -> float:
    """(estimate − truth) / truth [-]."""
    return estimate.value / truth - 1.0 if truth else math.nan
