"""Estimates through a calibrated rig: P_g and E of an object nobody calibrated.

The session (or the sessions of one object) is the diagnosis's joint problem with the rig's
depth-noise model, its reference force and, for each rig model, that model's terms freed under the
rig's correlated normal posterior as their prior — so the rig's parameter uncertainty propagates
into P_g and E. The estimate is the rig models' mixture, weighted as in the rig: its 95 % interval
spans what the calibration could not exclude.

* ``fit``: each model's Levenberg–Marquardt optimum with its Laplace (Gauss–Newton) covariance; the
  mixture of the models' log-normal posteriors.
* ``bayes``: each model's posterior by importance sampling from a Student-t (ν = 5) around its
  Laplace approximation, Pareto-smoothed (PSIS; Vehtari et al. 2024) with its k̂ reported (k̂ > 0.7:
  unreliable), every draw one exact engine solve; the draws of all models pooled by their weights.

The models' weights are the rig's (pseudo-BMA+ on the calibration) times each model's Laplace
evidence for the new session (Bayes' rule on the model index): new data that tell the models apart
sharpen the mixture, data that cannot leave it as the calibration left it.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Sequence
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy import optimize, stats

from .._errors import InvalidInputError, NoConvergenceError
from ..diagnose import GLOBAL_PARAMETERS, MeasurementPrior, build_study, study_arrays
from ..diagnose.internal import (
    LINEAR_SCALE,
    engine_inputs,
    laplace_interval,
    log_prior,
    physical,
    predict,
    solve_curves,
    unit_log_likelihood,
    widened_grid,
)
from ..physics import gas_law
from ..estimate import Estimate
from ..session import Session, load_session
from ._calibrate import Rig, RigWarning, fit_model

ESTIMATE_GRID_SPAN = (0.7, 1.4)  # the engine's grid covers the true forces of every rig model, with room
IMPORTANCE_DRAWS = 512  # exact engine solves in ``bayes``, shared among the rig models by weight
MIN_DRAWS = 64  # ... and never fewer than this for one model
PROPOSAL_DOF = 5.0  # Student-t proposal: heavier tails than the Laplace normal
PARETO_K_LIMIT = 0.7  # PSIS k̂ above which importance weights are unreliable
Z95 = 1.959963984540054


# the measurement that settles a term the calibration could not
SEPARATING_MEASUREMENT = {
    "pad_linear": "a rigid-surface press (the pad alone)",
    "pad_hertz": "a rigid-surface press (the pad alone)",
    "pad_power": "a rigid-surface press (the pad alone)",
    "depth_offset": "a rigid-surface press (the depth gauge's zero)",
    "finger_radius": "a second finger size, or a sphere of known radius",
    "sensor_gain": "the force sensor checked against weights (shelljax sensor-calibrate)",
    "sensor_power": "the force sensor checked against weights across 5-20 N (shelljax sensor-calibrate)",
}


@dataclasses.dataclass(frozen=True)
class RigEstimate:
    """Result of :func:`estimate_with_rig`: ``estimates`` (gauge_pressure [Pa] of each session —
    "gauge_pressure" for one session, "gauge_pressure[i]" for several — and young_modulus [Pa]),
    ``models`` (per rig model: terms, weight, its own estimates, status), ``not_identified`` rig
    terms, ``method`` ("fit" or "bayes"), the ``rig`` used and the ``sources``."""

    estimates: dict[str, Estimate]
    models: tuple[dict, ...]
    not_identified: tuple[str, ...]
    method: str
    rig: Rig
    sources: tuple[str, ...]

    def separating(self) -> list[dict]:
        """For each term not identified: the measurement that would settle it, and the factor by
        which E's 95 % interval would shrink were the weightiest model the only one left."""
        own = next((m for m in self.models if m["status"] == "ok"), None)
        e = self.estimates["young_modulus"]
        shrink = None
        if own is not None:
            width = math.log(e.ci95[1] / e.ci95[0])
            shrink = width / (2 * Z95 * own["estimates"]["young_modulus"]["relative_std"])
        return [
            {"term": t, "measurement": SEPARATING_MEASUREMENT[t], "young_modulus_interval_shrink": shrink}
            for t in self.not_identified
        ]

    def to_dict(self) -> dict:
        """JSON-ready: estimates by name, each rig model's share, and the rig's provenance."""
        return {
            "estimates": {k: v.to_dict() for k, v in self.estimates.items()},
            "rig_models": list(self.models),
            "not_identified": list(self.not_identified),
            "separating": self.separating(),
            "rig": {
                "gas": self.rig.gas,
                "wrinkle_law": self.rig.wrinkle_law,
                "version": self.rig.version,
                "calibration": [c["sha256"] for c in self.rig.calibration],
            },
        }


def check_compatible(rig: Rig, *, gas: str | None, wrinkle_law: str | None, where: str = "the estimate") -> None:
    """Refuse a rig made with other forward-model options than ``where`` asks for."""
    for name, asked, made in (("gas", gas, rig.gas), ("wrinkle_law", wrinkle_law, rig.wrinkle_law)):
        if asked is not None and asked != made:
            raise InvalidInputError(
                f"the rig was calibrated with {name} = {made!r} but {where} asks for {name} = {asked!r}; a rig's "
                f"parameters hold only for the forward model they were learned with. Fix: use {name} = {made!r}, or "
                f"calibrate a rig with `shelljax rig calibrate ... --{name.replace('_', '-')} {asked}`"
            )


def rig_measurement(rig: Rig) -> MeasurementPrior:
    """The rig's weightiest model as a diagnosis baseline (``shelljax.diagnose.diagnose(measurement=...)``)."""
    model = rig.models[0]
    return MeasurementPrior(
        name="+".join(model.terms) or "ideal rig",
        parameters=model.parameters,
        mean=model.mean,
        covariance=model.covariance,
        fixes=model.fixes,
        force_ref=rig.force_ref,
        noise=rig.noise,
    )


def _true_forces(rig: Rig, force: np.ndarray) -> np.ndarray:
    """The true forces [N] the rig's models map ``force`` to, at their means ± 3σ."""
    out = [force]
    for m in rig.models:
        for k in (-3.0, 0.0, 3.0):
            u = dict(zip(m.parameters, m.mean + k * np.sqrt(np.diag(m.covariance)) if m.parameters else []))
            gain = math.exp(u.get("force_gain", 0.0))
            exponent = 1.0 + LINEAR_SCALE["force_exponent"] * u.get("force_exponent", 0.0)
            out.append(gain * rig.force_ref * (force / rig.force_ref) ** exponent)
    return np.concatenate(out)


def _prepare(sessions, rig: Rig):
    sessions = [s if isinstance(s, Session) else load_session(s) for s in sessions]
    if not sessions:
        raise InvalidInputError("no session given. Fix: pass the session TOML file(s) of one object")
    for s in sessions:
        if rig.name is not None and s.rig_name is not None and s.rig_name != rig.name:
            raise InvalidInputError(
                f"{s.source}: field 'rig': recorded with rig {s.rig_name!r}, but the rig file is of "
                f"{rig.name!r}. Fix: estimate through the rig file calibrated for {s.rig_name!r}"
            )
        if s.wrinkle_counts is None:
            raise InvalidInputError(
                f"{s.source}: field 'wrinkles.counts': missing; E needs the wrinkle counts. "
                "Fix: add one count per trial"
            )
    study = build_study(sessions, rig.noise, min_trials=1, command="estimate --rig")
    base = study_arrays(study, gas=gas_law(rig.gas), indenter_radius=rig.indenter_radius, force_ref=rig.force_ref)
    return sessions, study, widened_grid(base, _true_forces(rig, study.force), ESTIMATE_GRID_SPAN)


def _start(base, study, model) -> np.ndarray:
    u = np.zeros(base.free.shape[0])
    for name, value in zip(model.parameters, model.mean):
        u[study.n_sessions + GLOBAL_PARAMETERS.index(name)] = value
    return u


def _quantities(study) -> list[tuple[str, int]]:
    names = [
        ("gauge_pressure" if study.n_sessions == 1 else f"gauge_pressure[{i}]", i) for i in range(study.n_sessions)
    ]
    return names + [("young_modulus", study.n_sessions + GLOBAL_PARAMETERS.index("young_modulus"))]


def _log_reference(data, index: int, n_sessions: int) -> float:
    """log of the physical value at u = 0 of entry ``index`` (P_g or E: log-parametrised)."""
    if index < n_sessions:
        return float(np.log(np.asarray(data.start_pressure)[index]))
    return float(np.log(np.asarray(data.start_modulus)))


def normal_mixture(means, stds, weights) -> tuple[float, float, float, float]:
    """(median, 2.5 % and 97.5 % quantiles, standard deviation) of a mixture of normals."""
    means, weights = np.asarray(means, float), np.asarray(weights, float) / np.sum(weights)
    stds = np.maximum(np.asarray(stds, float), 1e-12)
    lo, hi = float(np.min(means - 10 * stds)), float(np.max(means + 10 * stds))

    def quantile(q):
        return optimize.brentq(
            lambda x: float(np.sum(weights * stats.norm.cdf(x, means, stds))) - q, lo, hi, xtol=1e-10
        )

    std = math.sqrt(max(float(np.sum(weights * (stds**2 + means**2))) - float(np.sum(weights * means)) ** 2, 0.0))
    return quantile(0.5), quantile(0.025), quantile(0.975), std


def _weighted_quantile(values, weights, q):
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(np.interp(q * cum[-1], cum, values[order]))


def _estimate_from_log(center, lo, hi, log_std, method) -> Estimate:
    """A pressure or modulus [Pa] from its log-space median, 95 % bounds and std."""
    value = math.exp(center)
    return Estimate(value, value * log_std, (math.exp(lo), math.exp(hi)), "Pa", method)


def _fit_rig_model(base, study, rig: Rig, model, quantities, method: str, draws: int, seed: int, source):
    """(the report's record, the mixture's entry or None where the fit failed) of the session(s)
    under one rig model: its fit, its Laplace estimates [Pa] and evidence and, for "bayes", its
    importance draws."""
    record = {"terms": list(model.terms), "weight": model.weight}
    fit = fit_model(
        base,
        study,
        model.terms,
        rig.wrinkle_law,
        _start(base, study, model),
        rig_prior=(model.parameters, model.mean, model.covariance) if model.parameters else None,
    )
    if not fit.converged:
        # stacklevel 3: the warning points at the caller of estimate_with_rig, not at this helper
        warnings.warn(
            f"{source}: the fit under rig model {'+'.join(model.terms) or 'ideal'} failed "
            f"({fit.message}); the other models carry its weight",
            RigWarning,
            stacklevel=3,
        )
        return {**record, "status": "failed", "message": fit.message}, None
    laplace = {}
    for name, index in quantities:
        u, std = laplace_interval(fit, index)
        laplace[name] = (u + _log_reference(fit.data, index, study.n_sessions), std)
    record["estimates"] = {n: {"value": math.exp(m), "relative_std": s, "unit": "Pa"} for n, (m, s) in laplace.items()}
    record["chi2"] = fit.chi2
    record["log_evidence"] = _log_evidence(fit, model)
    entry = {"weight": model.weight, "laplace": laplace, "fit": fit, "log_evidence": record["log_evidence"]}
    if method == "bayes":
        n_draws = max(MIN_DRAWS, int(round(draws * model.weight)))
        entry["draws"], entry["draw_weights"], k_hat = _importance(fit, rig, quantities, study, n_draws, seed)
        record["pareto_k"] = k_hat
        if k_hat > PARETO_K_LIMIT:
            warnings.warn(
                f"{source}: PSIS k̂ = {k_hat:.2f} > {PARETO_K_LIMIT} under rig model "
                f"{'+'.join(model.terms) or 'ideal'}: its posterior draws are unreliable",
                RigWarning,
                stacklevel=3,
            )
    record["status"] = "ok"
    return record, entry


def _mixture_estimate(name: str, mixture: list[dict], weights: np.ndarray, method: str, label: str) -> Estimate:
    """The quantity ``name`` [Pa] over the rig models' mixture: their Laplace normals ("fit") or their
    pooled importance draws ("bayes"), weighted by ``weights``."""
    if method == "fit":
        center, lo, hi, log_std = normal_mixture(
            [e["laplace"][name][0] for e in mixture], [e["laplace"][name][1] for e in mixture], weights
        )
    else:
        values = np.concatenate([e["draws"][name] for e in mixture])
        w = np.concatenate([wm * e["draw_weights"] for wm, e in zip(weights, mixture)])
        center, lo, hi = (_weighted_quantile(values, w, q) for q in (0.5, 0.025, 0.975))
        mean = float(np.sum(w * values) / np.sum(w))
        log_std = math.sqrt(float(np.sum(w * (values - mean) ** 2) / np.sum(w)))
    return _estimate_from_log(center, lo, hi, log_std, label)


def estimate_with_rig(
    sessions: Session | str | Path | Sequence[Session | str | Path],
    rig: Rig,
    *,
    method: str = "fit",
    gas: str | None = None,
    wrinkle_law: str | None = None,
    draws: int = IMPORTANCE_DRAWS,
    seed: int = 0,
) -> RigEstimate:
    """P_g [Pa] and E [Pa] of the session(s) of one object through ``rig`` (module docstring).

    ``gas``/``wrinkle_law``: the forward-model options the caller asks for (None: the rig's);
    a rig made with other options is refused. ``draws``: engine solves per model for "bayes".

    Raises:
        InvalidInputError: an unknown method, incompatible options, sessions of several objects.
        NoConvergenceError: no rig model's fit converged.
    """
    if method not in ("fit", "bayes"):
        raise InvalidInputError(f"method {method!r} cannot use a rig. Fix: use 'fit' or 'bayes'")
    check_compatible(rig, gas=gas, wrinkle_law=wrinkle_law)
    if isinstance(sessions, (Session, str, Path)):
        sessions = [sessions]
    sessions, study, base = _prepare(sessions, rig)
    quantities = _quantities(study)
    per_model, mixture = [], []
    for model in rig.models:
        record, entry = _fit_rig_model(base, study, rig, model, quantities, method, draws, seed, sessions[0].source)
        per_model.append(record)
        if entry is not None:
            mixture.append(entry)
    if not mixture:
        raise NoConvergenceError(
            f"{sessions[0].source}: no rig model's fit converged ({'; '.join(r.get('message', '') for r in per_model)})"
        )
    weights = updated_weights([e["weight"] for e in mixture], [e["log_evidence"] for e in mixture])
    for record, weight in zip([r for r in per_model if r["status"] == "ok"], weights):
        record["updated_weight"] = float(weight)
    label = f"{method} through a rig of {len(rig.models)} model(s)"
    estimates = {name: _mixture_estimate(name, mixture, weights, method, label) for name, _ in quantities}
    return RigEstimate(
        estimates=estimates,
        models=tuple(per_model),
        not_identified=rig.not_identified,
        method=method,
        rig=rig,
        sources=tuple(str(s.source) for s in sessions),
    )


def _log_evidence(fit, model) -> float:
    """Laplace log evidence [nats] of the estimated session(s) under a rig model, up to a constant
    shared by every model: −χ²/2 + ½ log det Σ_posterior − ½ log det Σ_rig (P_g and E flat in log)."""
    posterior = np.linalg.slogdet(fit.covariance)[1]
    prior = np.linalg.slogdet(model.covariance)[1] if model.parameters else 0.0
    return float(-0.5 * fit.chi2 + 0.5 * posterior - 0.5 * prior)


def updated_weights(calibration_weights, log_evidence) -> np.ndarray:
    """The rig models' weights [-] after the estimated session: the calibration's times each model's
    evidence for the new data (Bayes' rule on the model index), normalised."""
    log_w = np.log(np.asarray(calibration_weights, float)) + np.asarray(log_evidence, float)
    w = np.exp(log_w - log_w.max())
    return w / w.sum()


@eqx.filter_jit
def _log_posterior_batch(data, u_batch, wrinkle_law: str):
    """Log posterior [-] of each row of ``u_batch``: one batched engine solve for every draw."""
    phys = jax.vmap(lambda u: physical(u, data))(u_batch)
    shell, physics = jax.vmap(lambda p: engine_inputs(p, data))(phys)
    n_draws, n_sessions = shell.gauge_pressure.shape[:2]
    flat = lambda v: v.reshape((n_draws * n_sessions,) + v.shape[2:])  # noqa: E731
    curves = solve_curves(
        jax.tree_util.tree_map(flat, shell), jax.tree_util.tree_map(flat, physics), data
    )  # draws are scattered: walking curve to curve saves nothing
    curves = jax.tree_util.tree_map(lambda v: v.reshape((n_draws, n_sessions) + v.shape[1:]), curves)

    def one(u, c):
        pred, ok = predict(u, data, c, wrinkle_law)
        lp = jnp.sum(unit_log_likelihood(pred, data)) + log_prior(u, data)
        return jnp.where(ok & jnp.isfinite(lp), lp, -jnp.inf)

    return jax.vmap(one)(u_batch, curves)


def psis(log_weights: np.ndarray) -> tuple[np.ndarray, float]:
    """Pareto-smoothed importance weights (normalised) and k̂ of raw log weights (Vehtari et al. 2024)."""
    log_weights = np.asarray(log_weights, float)
    finite = np.isfinite(log_weights)
    lw = np.where(finite, log_weights - np.max(log_weights[finite]), -np.inf)
    n = int(finite.sum())
    tail = int(min(0.2 * n, 3 * math.sqrt(n)))
    k_hat = math.inf
    if tail >= 5:
        order = np.argsort(lw)
        cutoff = lw[order[-tail - 1]]
        exceed = np.exp(lw[order[-tail:]]) - math.exp(cutoff)
        k_hat, _, scale = stats.genpareto.fit(exceed, floc=0.0)
        smoothed = math.exp(cutoff) + stats.genpareto.ppf((np.arange(1, tail + 1) - 0.5) / tail, k_hat, scale=scale)
        lw[order[-tail:]] = np.log(np.minimum(smoothed, 1.0))
    w = np.exp(lw)
    return w / w.sum(), float(k_hat)


def _importance(fit, rig: Rig, quantities, study, draws: int, seed: int):
    """(log-value draws by quantity, their PSIS weights, k̂) of one model's posterior."""
    rng = np.random.default_rng(seed)
    free = np.flatnonzero(np.asarray(fit.data.free))
    chol = np.linalg.cholesky(fit.covariance)
    z = rng.standard_normal((draws, free.size)) / np.sqrt(rng.chisquare(PROPOSAL_DOF, (draws, 1)) / PROPOSAL_DOF)
    u = np.tile(fit.u, (draws, 1))
    u[:, free] += z @ chol.T
    log_q = stats.multivariate_t(loc=fit.u[free], shape=fit.covariance, df=PROPOSAL_DOF).logpdf(u[:, free])
    log_p = np.asarray(_log_posterior_batch(fit.data, jnp.asarray(u), rig.wrinkle_law))
    weights, k_hat = psis(log_p - log_q)
    values = {name: u[:, index] + _log_reference(fit.data, index, study.n_sessions) for name, index in quantities}
    return values, weights, k_hat
