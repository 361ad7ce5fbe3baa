"""One candidate's fit and its out-of-sample score.

Fit: Levenberg–Marquardt on the joint problem (``estimate.solve_least_squares``), with the
Laplace (Gauss–Newton) covariance of the free unknowns.

Score: leave-one-trial-out, exact for the model linearised at the optimum (Gauss–Newton). With
whitened residuals r(u) ≈ r + J Δu and J (rows: data, then priors), leaving out trial i (rows
J_i, r_i) moves the optimum by Δ_i = −H₋ᵢ⁻¹ (Jᵀr − J_iᵀr_i), H₋ᵢ = JᵀJ − J_iᵀJ_i, and predicts the
trial's whitened data as normal with mean e_i = r_i + J_i Δ_i and covariance C_i = I + J_i H₋ᵢ⁻¹ J_iᵀ
(noise plus the parameters' uncertainty without that trial). elpd_i = log N(0; e_i, C_i) plus the
whitening's log-Jacobian is the log predictive density of trial i's data from a model that never
saw it. No forward solve beyond the fit: the fit's Jacobian holds everything
(docs/sim-to-real.md compares it with refitting without each trial).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats

from ..estimate import solve_least_squares
from ._model import JointProblem, StudyArrays

FIT_TOLERANCE = 1e-6  # [-] LM's rtol and atol on u: far below any parameter's statistical error
# [χ²] an optimum's remaining Gauss–Newton decrease: 0.5 χ² is 0.25 nats of log-likelihood, 16 times
# below the 4-nat decision margin, and above the engine's floor on joint studies: its depth is kinked
# in the finger's radius where the contact patch is about an element wide
OPTIMALITY_TOLERANCE = 0.5
RESTARTS = 2


@dataclasses.dataclass(frozen=True)
class CandidateFit:
    """A fitted model: ``u`` (all entries), ``data`` (with the ``free`` mask and priors it was
    fitted under), ``jacobian`` of the whitened residuals w.r.t. the free entries, ``residual``
    (whitened, at the optimum), ``covariance`` of the free entries (scaled space), ``chi2``,
    ``steps``, ``converged``, ``message`` (why not), ``prediction`` (depth [m], count [-], shape
    [m], wrinkled) at the optimum."""

    data: StudyArrays
    u: np.ndarray
    jacobian: np.ndarray
    residual: np.ndarray
    covariance: np.ndarray
    chi2: float
    steps: int
    converged: bool
    message: str
    prediction: dict


def fit_candidate(data: StudyArrays, wrinkle_law: str, u_start: np.ndarray, max_steps: int = 100) -> CandidateFit:
    """Fit the free entries of ``data.free`` from ``u_start`` (scaled space)."""
    problem = JointProblem(data, wrinkle_law)
    u = jnp.asarray(u_start)
    for _ in range(RESTARTS + 1):
        # A restart from where LM stopped gets a fresh trust region: one that shrank on the engine's
        # round-off far from the optimum then takes full steps again.
        out, converged, finite, promised = solve_least_squares(
            problem, u, FIT_TOLERANCE, FIT_TOLERANCE, max_steps, OPTIMALITY_TOLERANCE
        )
        if converged or not finite:
            break
        u = out["u"]
    free = np.asarray(data.free)
    jac = np.asarray(out["jacobian"])[:, free]
    message = (
        ""
        if converged
        else (
            f"Levenberg-Marquardt stopped after {int(out['steps'])} steps without converging (forward model finite: "
            f"{finite}, χ² a Gauss-Newton step would still remove: {promised:.3g})"
        )
    )
    covariance = np.full((free.sum(), free.sum()), np.nan)
    if converged:
        try:
            covariance = np.linalg.inv(jac.T @ jac)
        except np.linalg.LinAlgError:
            converged, message = False, "the fitted parameters are not identified by the data (singular Jacobian)"
    residual = np.asarray(out["residual"])
    pred = jax.tree_util.tree_map(np.asarray, out["prediction"][0])
    return CandidateFit(
        data=data,
        u=np.asarray(out["u"]),
        jacobian=jac,
        residual=residual,
        covariance=covariance,
        chi2=float(residual @ residual),
        steps=int(out["steps"]),
        converged=converged,
        message=message,
        prediction=pred,
    )


@dataclasses.dataclass(frozen=True)
class LooScore:
    """Leave-one-trial-out score of one fit: ``elpd`` (units,) [-] per trial, and per data row
    (depth, count, shape, in that order) the held-out ``residual`` (observed − predicted, in the
    row's unit: m or wrinkles), its predictive ``std`` (same unit), the ``whitened`` held-out
    residual (independent standard normals under the model) and the ``pit`` value."""

    elpd: np.ndarray
    residual: np.ndarray
    std: np.ndarray
    whitened: np.ndarray
    pit: np.ndarray

    @property
    def total(self) -> float:
        return float(np.sum(self.elpd))


def _row_layout(data: StudyArrays):
    """(unit of each data row, raw-from-whitened map of the data rows, log-Jacobian per unit)."""
    n_d = data.depth.shape[0]
    units = np.concatenate([np.asarray(data.depth_unit), np.asarray(data.count_unit), np.asarray(data.shape_unit)])
    # raw = M · whitened for the data rows: depth rows W⁻¹ (block-diagonal), counts 1, shape σ
    n = units.size
    raw = np.zeros((n, n))
    raw[:n_d, :n_d] = np.linalg.inv(np.asarray(data.whitening))
    raw[n_d:, n_d:] = np.diag(np.concatenate([np.ones(data.count.shape[0]), np.asarray(data.shape_std)]))
    log_jac = np.asarray(data.depth_unit_constant)
    shape_unit = np.asarray(data.shape_unit)
    log_jac = log_jac - np.bincount(
        shape_unit, weights=np.log(np.asarray(data.shape_std)) + 0.5 * math.log(2 * math.pi), minlength=log_jac.size
    )
    log_jac = log_jac - 0.5 * math.log(2 * math.pi) * np.bincount(np.asarray(data.count_unit), minlength=log_jac.size)
    return units, raw, log_jac


def unit_log_jacobian(data: StudyArrays) -> np.ndarray:
    """Log-Jacobian [-] of each leave-one-out unit's whitening: its whitened log density plus
    this is the log density of its raw data."""
    return _row_layout(data)[2]


def held_out_units(jac: np.ndarray, resid: np.ndarray, units: np.ndarray, n_units: int):
    """For each unit i of the whitened least-squares problem (rows ``units == i``; the rows past
    ``units`` are priors, never left out): (i, its rows, the optimum's move Δ_i, H₋ᵢ⁻¹, the held-out
    whitened residual, and the log-density [-] of its whitened data without the whitening's Jacobian)."""
    hessian, gradient = jac.T @ jac, jac.T @ resid
    for i in range(n_units):
        rows = np.flatnonzero(units == i)
        j_i, r_i = jac[rows], resid[rows]
        h_inv = np.linalg.pinv(hessian - j_i.T @ j_i)
        delta = -h_inv @ (gradient - j_i.T @ r_i)
        chol = np.linalg.cholesky(np.eye(rows.size) + j_i @ h_inv @ j_i.T)
        white = np.linalg.solve(chol, r_i + j_i @ delta)
        yield i, rows, delta, h_inv, white, -0.5 * white @ white - np.sum(np.log(np.diag(chol)))


def loo_score(fit: CandidateFit) -> LooScore:
    """Leave-one-trial-out score of ``fit``, exact for the model linearised at the optimum."""
    data = fit.data
    units, raw, log_jac = _row_layout(data)
    n_data = units.size
    jac, resid = fit.jacobian, fit.residual
    raw_jac = raw @ jac[:n_data]
    raw_resid = raw @ resid[:n_data]  # predicted − observed
    raw_var = np.sum(raw**2, axis=1)  # noise variance of each row (marginal)
    elpd = np.zeros(data.n_units)
    out_resid, out_std, out_white = (np.zeros(n_data) for _ in range(3))
    for i, rows, delta, h_inv, white, log_density in held_out_units(jac, resid, units, data.n_units):
        elpd[i] = log_density + log_jac[i]
        out_white[rows] = -white
        g = raw_jac[rows]
        out_resid[rows] = -(raw_resid[rows] + g @ delta)
        out_std[rows] = np.sqrt(raw_var[rows] + np.einsum("ij,jk,ik->i", g, h_inv, g))
    pit = stats.norm.cdf(out_resid / out_std)
    return LooScore(elpd=elpd, residual=out_resid, std=out_std, whitened=out_white, pit=pit)


def laplace_interval(fit: CandidateFit, index: int) -> tuple[float, float]:
    """(value, std) of u[index] in the scaled space."""
    free_index = int(np.sum(np.asarray(fit.data.free)[:index]))
    return float(fit.u[index]), float(math.sqrt(max(fit.covariance[free_index, free_index], 0.0)))
