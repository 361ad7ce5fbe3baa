"""The paper's closed-form estimator (Procedures 1-3), with propagated uncertainties.

* Procedure 1/2, pressure: regress F on w(0) over all samples; the slope s [N/m] gives
  P̂ = k_s P_g = s / (π R) (paper Eq. pressure-estimation), and P_g = P̂ / k_s.
* Procedure 1, calibration: regress P̂ on manometer P_g through the origin over calibration
  sessions; the slope is k_s.
* Procedure 3, modulus: E = √(12(1−ν²)) (1.33 R / (n h))² P_g from the mean wrinkle count n.
* The critical-depth relation E = 2.52 P_g R² / (h w_c) is available but flagged unreliable: the
  paper found the onset of wrinkling ambiguous, and E ∝ 1/w_c turns depth errors into E errors
  of order 100 %.

Uncertainty, two ways that must agree (tests check within 20 %):
* delta method: every output is a power law P_g ∝ s R⁻¹ k_s⁻¹ and E ∝ s R k_s⁻¹ n⁻² h⁻² (R enters
  P_g too, so E ∝ R¹ — the correlation is kept by propagating from the independent inputs);
* bootstrap: F-w samples resampled as cases, wrinkle counts resampled with a ±1 reading error,
  R, h and k_s drawn from normals.
Wrinkle-count variance per trial: sample variance + 1 (a ±1 reading uncertainty per count).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
from scipy import stats

from .._errors import InvalidInputError
from ..paper import PAPER_KS, PAPER_KS_STD
from ..physics import CRITICAL_W, WRINKLE_PREFACTOR
from ..session import Session
from ._result import Estimate

COUNT_READING_STD = 1.0  # [wrinkles] per count
_METHOD = "closed-form (paper Procedures 1-3), delta method"


@dataclasses.dataclass(frozen=True)
class Regression:
    """Ordinary least squares F = slope · w + intercept.

    slope [N/m], intercept [N] (0 when ``through_origin``), their standard errors, the residual
    standard deviation [N], degrees of freedom and the 2x2 covariance of (slope, intercept).
    """

    slope: float
    intercept: float
    slope_std: float
    intercept_std: float
    residual_std: float
    dof: int
    covariance: np.ndarray
    through_origin: bool

    def band(self, depth: np.ndarray, level: float = 0.99) -> tuple[np.ndarray, np.ndarray]:
        """Confidence band [N] of the regression line at ``depth`` [m] (not a prediction band)."""
        design = np.stack([depth, np.ones_like(depth)], axis=-1)
        var = np.einsum("ni,ij,nj->n", design, self.covariance, design)
        half = stats.t.ppf(0.5 + level / 2, self.dof) * np.sqrt(var)
        mean = self.slope * depth + self.intercept
        return mean - half, mean + half


def regress_force_on_depth(depth: np.ndarray, force: np.ndarray, *, through_origin: bool = False) -> Regression:
    """OLS of force [N] on depth [m]; raises InvalidInputError when it is not determined."""
    depth = np.asarray(depth, np.float64)
    force = np.asarray(force, np.float64)
    n_params = 1 if through_origin else 2
    if depth.size <= n_params or np.ptp(depth) == 0:
        raise InvalidInputError(
            f"regression of F on w(0) needs more than {n_params} samples at distinct depths, got "
            f"{depth.size} with depths {np.unique(depth).tolist()} m. Fix: record more force levels"
        )
    design = depth[:, None] if through_origin else np.stack([depth, np.ones_like(depth)], axis=1)
    coef, *_ = np.linalg.lstsq(design, force, rcond=None)
    residual = force - design @ coef
    dof = depth.size - n_params
    sigma2 = float(residual @ residual) / dof
    cov_small = sigma2 * np.linalg.inv(design.T @ design)
    cov = np.zeros((2, 2))
    cov[:n_params, :n_params] = cov_small
    return Regression(
        slope=float(coef[0]),
        intercept=0.0 if through_origin else float(coef[1]),
        slope_std=float(np.sqrt(cov[0, 0])),
        intercept_std=float(np.sqrt(cov[1, 1])),
        residual_std=math.sqrt(sigma2),
        dof=dof,
        covariance=cov,
        through_origin=through_origin,
    )


def pressure_slope(session: Session, *, through_origin: bool = False) -> tuple[Estimate, Regression]:
    """P̂ = k_s P_g = slope / (π R) [Pa] of one session (Procedure 2, steps 1-3)."""
    reg = regress_force_on_depth(session.depth, session.force, through_origin=through_origin)
    if reg.slope <= 0:
        raise InvalidInputError(
            f"{session.source}: force does not increase with depth (fitted slope {reg.slope:.3g} N/m). "
            "Fix: check that force and depth columns are not swapped and depths are magnitudes"
        )
    rel = math.hypot(reg.slope_std / reg.slope, session.radius_std / session.radius)
    value = reg.slope / (math.pi * session.radius)
    return Estimate.lognormal(value, rel, "Pa", _METHOD), reg


@dataclasses.dataclass(frozen=True)
class KsCalibration:
    """k_s from Procedure 1: P̂ = k_s P_g through the origin over calibration sessions.

    ``k_s`` [-]; ``gauge_pressures`` manometer P_g [Pa]; ``pressure_slopes`` P̂ [Pa] with their
    standard deviations ``pressure_slope_stds`` [Pa]; ``objects`` and ``sources`` per point.
    """

    k_s: Estimate
    gauge_pressures: np.ndarray
    pressure_slopes: np.ndarray
    pressure_slope_stds: np.ndarray
    objects: tuple[str, ...]
    sources: tuple[str, ...]


def calibrate_ks(sessions: Sequence[Session], *, through_origin: bool = False) -> KsCalibration:
    """Procedure 1: estimate k_s [-] from sessions that carry a manometer gauge pressure."""
    missing = [str(s.source) for s in sessions if s.manometer_gauge_pressure is None]
    if missing:
        raise InvalidInputError(
            f"{missing[0]}: calibration session has no manometer_gauge_pressure. Fix: add the "
            "manometer reading, or remove the session from [calibration] sessions"
        )
    if len(sessions) < 2:
        raise InvalidInputError(
            f"k_s calibration needs at least 2 sessions at different pressures, got {len(sessions)}. "
            "Fix: add calibration sessions, or set k_s in the config"
        )
    slopes = [pressure_slope(s, through_origin=through_origin)[0] for s in sessions]
    p_true = np.array([s.manometer_gauge_pressure for s in sessions])
    p_hat = np.array([e.value for e in slopes])
    k = float(p_true @ p_hat / (p_true @ p_true))
    residual = p_hat - k * p_true
    k_std = math.sqrt(float(residual @ residual) / (len(sessions) - 1) / float(p_true @ p_true))
    estimate = Estimate.lognormal(k, k_std / k, "1", "closed-form (paper Procedure 1), OLS through origin")
    return KsCalibration(
        k_s=estimate,
        gauge_pressures=p_true,
        pressure_slopes=p_hat,
        pressure_slope_stds=np.array([e.std for e in slopes]),
        objects=tuple(s.object_name for s in sessions),
        sources=tuple(str(s.source) for s in sessions),
    )


def modulus_from_wrinkles(gauge_pressure, radius, thickness, wrinkle_count, poisson_ratio):
    """E [Pa] = √(12(1−ν²)) (1.33 R / (n h))² P_g from P_g [Pa], R [m], h [m], n [-], ν [-]."""
    return (
        math.sqrt(12 * (1 - poisson_ratio**2))
        * (WRINKLE_PREFACTOR * radius / (wrinkle_count * thickness)) ** 2
        * gauge_pressure
    )


def modulus_from_critical_depth(gauge_pressure, radius, thickness, critical_depth):
    """E [Pa] = 2.52 P_g R² / (h w_c) from P_g [Pa], R [m], h [m], onset depth w_c [m] (unreliable)."""
    return CRITICAL_W * gauge_pressure * radius**2 / (thickness * critical_depth)


def _count_stats(counts: np.ndarray) -> tuple[float, float]:
    mean = float(np.mean(counts))
    scatter = float(np.var(counts, ddof=1)) if counts.size > 1 else 0.0
    return mean, math.sqrt((scatter + COUNT_READING_STD**2) / counts.size)


@dataclasses.dataclass(frozen=True)
class ClosedFormResult:
    """Closed-form estimates of one session.

    ``estimates``, by name: ``pressure_slope`` P̂ [Pa], ``gauge_pressure`` P_g [Pa],
    ``young_modulus`` E [Pa] (without wrinkle counts: absent), ``critical_depth_modulus`` E from
    the onset depth [Pa] (without onset depths: absent; flagged unreliable), ``tau`` τ [-] and
    ``wrinkle_count`` mean n [-] (with wrinkle counts), ``k_s`` used [-]. ``regression`` of F on
    w(0), and the ``bootstrap`` estimates of P̂, P_g and E. Each estimate is also an attribute,
    None when absent.
    """

    estimates: dict[str, Estimate]
    regression: Regression
    bootstrap: dict[str, Estimate]

    @property
    def pressure_slope(self) -> Estimate:
        return self.estimates["pressure_slope"]

    @property
    def gauge_pressure(self) -> Estimate:
        return self.estimates["gauge_pressure"]

    @property
    def young_modulus(self) -> Estimate | None:
        return self.estimates.get("young_modulus")

    @property
    def critical_depth_modulus(self) -> Estimate | None:
        return self.estimates.get("critical_depth_modulus")

    @property
    def tau(self) -> Estimate | None:
        return self.estimates.get("tau")

    @property
    def wrinkle_count(self) -> Estimate | None:
        return self.estimates.get("wrinkle_count")

    @property
    def k_s(self) -> Estimate:
        return self.estimates["k_s"]

    def to_dict(self) -> dict:
        """JSON-ready: ``estimates`` by name, the ``bootstrap`` estimates and the ``regression``."""
        reg = self.regression
        return {
            "estimates": {name: est.to_dict() for name, est in self.estimates.items()},
            "bootstrap": {name: est.to_dict() for name, est in self.bootstrap.items()},
            "regression": {
                "slope": {"value": reg.slope, "std": reg.slope_std, "unit": "N/m"},
                "intercept": {"value": reg.intercept, "std": reg.intercept_std, "unit": "N"},
                "residual_std": {"value": reg.residual_std, "unit": "N"},
            },
        }


def paper_k_s() -> Estimate:
    """The paper's calibrated k_s [-] with its assumed standard deviation (``shelljax.paper``)."""
    return Estimate.lognormal(PAPER_KS, PAPER_KS_STD / PAPER_KS, "1", "paper's calibrated value (Section 4.1)")


def estimate_session(
    session: Session,
    *,
    k_s: Estimate | None = None,
    through_origin: bool = False,
    bootstrap_samples: int = 2000,
    seed: int = 0,
) -> ClosedFormResult:
    """Procedures 2 and 3 on one session: P̂, P_g and E with delta-method and bootstrap errors.

    ``k_s`` defaults to :func:`paper_k_s`. ``bootstrap_samples`` = 0 skips the bootstrap.
    """
    if k_s is None:
        k_s = paper_k_s()
    slope_est, reg = pressure_slope(session, through_origin=through_origin)
    rel = {
        "slope": reg.slope_std / reg.slope,
        "radius": session.radius_std / session.radius,
        "thickness": session.thickness_std / session.thickness,
        "k_s": k_s.std / k_s.value,
    }
    p_g = slope_est.value / k_s.value
    gauge = Estimate.lognormal(p_g, math.hypot(rel["slope"], rel["radius"], rel["k_s"]), "Pa", _METHOD)
    estimates = {"pressure_slope": slope_est, "gauge_pressure": gauge}
    if session.wrinkle_counts is not None:
        estimates.update(_wrinkle_estimates(session, p_g, rel))
    if session.onset_depth is not None:
        estimates["critical_depth_modulus"] = _critical_depth_estimate(session, p_g, rel)
    estimates["k_s"] = k_s
    boot = _bootstrap(session, k_s, through_origin, bootstrap_samples, seed) if bootstrap_samples > 0 else {}
    return ClosedFormResult(estimates=estimates, regression=reg, bootstrap=boot)


def _wrinkle_estimates(session: Session, p_g: float, rel: dict[str, float]) -> dict[str, Estimate]:
    """Procedure 3: E [Pa], τ [-] and the mean count n [-] from the wrinkle counts."""
    if np.any(session.wrinkle_counts == 0):
        raise InvalidInputError(
            f"{session.source}: field 'wrinkles.counts': a count of 0 gives no modulus "
            "(n ≈ 1.33 τ^½ needs wrinkles). Fix: indent past the wrinkling onset, or drop [wrinkles]"
        )
    n_mean, n_std = _count_stats(session.wrinkle_counts)
    count_rel = n_std / n_mean
    e_value = modulus_from_wrinkles(p_g, session.radius, session.thickness, n_mean, session.poisson_ratio)
    # E ∝ slope · R · k_s⁻¹ · n⁻² · h⁻²  (P_g ∝ slope/R, times R²)
    e_rel = math.hypot(rel["slope"], rel["radius"], rel["k_s"], 2 * count_rel, 2 * rel["thickness"])
    return {
        "young_modulus": Estimate.lognormal(e_value, e_rel, "Pa", _METHOD),
        # τ = (n / 1.33)² exactly, by the model's own relation.
        "tau": Estimate.lognormal((n_mean / WRINKLE_PREFACTOR) ** 2, 2 * count_rel, "1", _METHOD),
        "wrinkle_count": Estimate(
            n_mean,
            n_std,
            (n_mean - 1.96 * n_std, n_mean + 1.96 * n_std),
            "1",
            "mean of per-trial counts; var = (scatter + 1)/N",
        ),
    }


def _critical_depth_estimate(session: Session, p_g: float, rel: dict[str, float]) -> Estimate:
    """E [Pa] from the mean wrinkling-onset depth, flagged unreliable."""
    w_c = float(np.mean(session.onset_depth))
    w_c_rel = (
        float(np.std(session.onset_depth, ddof=1)) / math.sqrt(session.onset_depth.size)
        if session.onset_depth.size > 1
        else 0.5
    ) / w_c
    # E ∝ P_g R² h⁻¹ w_c⁻¹ ∝ slope R k_s⁻¹ h⁻¹ w_c⁻¹
    c_rel = math.hypot(rel["slope"], rel["radius"], rel["k_s"], rel["thickness"], w_c_rel)
    return Estimate.lognormal(
        modulus_from_critical_depth(p_g, session.radius, session.thickness, w_c),
        c_rel,
        "Pa",
        _METHOD,
        note="unreliable: the wrinkling onset is ambiguous to observe and E ∝ 1/w_c "
        "amplifies its error (paper Section 3.4); use young_modulus from the wrinkle count",
    )


def _positive_normal(rng, mean, std, size):
    # Inputs are positive physical quantities; reflect the rare negative draw instead of dropping it.
    return np.abs(rng.normal(mean, std, size))


def _bootstrap(session, k_s, through_origin, n_samples, seed) -> dict[str, Estimate]:
    rng = np.random.default_rng(seed)
    n = session.depth.size
    idx = rng.integers(0, n, size=(n_samples, n))
    w, f = session.depth[idx], session.force[idx]
    if through_origin:
        slope = np.sum(w * f, axis=1) / np.sum(w * w, axis=1)
    else:
        wc = w - w.mean(axis=1, keepdims=True)
        slope = np.sum(wc * (f - f.mean(axis=1, keepdims=True)), axis=1) / np.sum(wc * wc, axis=1)
    radius = _positive_normal(rng, session.radius, session.radius_std, n_samples)
    ks = _positive_normal(rng, k_s.value, k_s.std, n_samples)
    p_hat = slope / (np.pi * radius)
    draws = {"pressure_slope": (p_hat, "Pa"), "gauge_pressure": (p_hat / ks, "Pa")}
    if session.wrinkle_counts is not None:
        counts = session.wrinkle_counts.astype(np.float64)
        pick = rng.integers(0, counts.size, size=(n_samples, counts.size))
        n_mean = (counts[pick] + rng.normal(0.0, COUNT_READING_STD, pick.shape)).mean(axis=1)
        h = _positive_normal(rng, session.thickness, session.thickness_std, n_samples)
        c = np.sqrt(12 * (1 - session.poisson_ratio**2))
        draws["young_modulus"] = (c * (WRINKLE_PREFACTOR * radius / (n_mean * h)) ** 2 * p_hat / ks, "Pa")
    method = f"closed-form, bootstrap ({n_samples} resamples, seed {seed})"
    out = {}
    for name, (x, unit) in draws.items():
        lo, med, hi = np.percentile(x, [2.5, 50, 97.5])
        out[name] = Estimate(float(med), float(np.std(x, ddof=1)), (float(lo), float(hi)), unit, method)
    return out
