"""The diagnosis: WHERE the baseline misfits, WHICH candidate effect explains it, HOW FAR the gap shrinks.

Decision rule (documented in docs/sim-to-real.md):

* a candidate beats the baseline when its leave-one-trial-out expected log predictive density
  exceeds the baseline's by Δ ≥ ``WIN_NATS`` = 4 nats *and* by ``WIN_SE`` = 2 standard errors of
  the difference. 4 nats bounds false alarms: a candidate whose extra parameter is truly absent
  gains in-sample χ²₁/2 and loses ≈ 1 nat out of sample, so it reaches Δ ≥ 4 only when χ²₁ ≥ 10
  (p = 0.0016; ≈ 1.4 % for the best of 9 candidates). 2 SE guards against a gain carried by one
  or two trials. A 4-SE margin would miss real effects: the SE comes from 9–16 trials whose gains
  differ by pressure (an effect grows with the force or the pressure), so it is large even when
  every trial gains (docs/sim-to-real.md);
* the winner is then expanded by the forward search the rig uses (``_search``): every pair of it
  with another candidate is fitted, and the best pair that beats the winner by the same margin
  becomes the model, expanded to triples in turn (``MAX_EFFECTS``);
* the verdict is the chosen model (one effect, or a combination ``a+b``), or ``none``; it becomes
  ``unexplained`` when the chosen model (or the baseline) still misfits: its held-out whitened
  residuals fail a χ² test at p < ``MISFIT_P``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from scipy import stats

from .._errors import InvalidInputError, NoConvergenceError
from ..estimate import DEFAULT_OPTIONS
from .._options import WRINKLE_LAWS
from ..physics import gas_law
from ..session import Session, load_session
from ._effects import (
    EFFECTS,
    FREE_THICKNESS_STD,
    GLOBAL_PARAMETERS,
    UNITS,
    check_effect_names,
    combination_name,
    effect_parameters,
    effects_of,
    free_mask,
)
from ._loo import CandidateFit, LooScore, fit_candidate, laplace_interval, loo_score
from ._measurement import MeasurementPrior, measured_baseline
from ._model import StudyArrays, physical, study_arrays
from ._robust import expansion_widening, not_excluded, robust_range, separating
from ._search import Margin, forward_search, pseudo_bma_plus
from ._study import SHAPE_OBSERVABLES, Study, build_study, object_unknowns

WIN_SE = 2.0
WIN_NATS = 4.0
MISFIT_P = 1e-3
MAX_EFFECTS = 3  # the search stops at triples: a fourth effect at once is beyond what 2-4 pressures separate
BASELINES = {"estimator": "isothermal", "paper": "prescribed"}  # name → gas law
OBSERVABLES = ("depth", "wrinkle_count") + SHAPE_OBSERVABLES


@dataclasses.dataclass(frozen=True)
class Diagnosis:
    """Result of :func:`diagnose`: ``report`` is the JSON contract (docs/sim-to-real.md);
    ``study``, ``fits`` and ``scores`` (by effect name, "baseline" included), and the held-out residuals
    of every data point under the baseline and the chosen model (``points_before``/``points_after``:
    observable, session, force level, observed, held-out residual and std, z, whitened, pit)."""

    report: dict
    study: Study
    fits: dict[str, CandidateFit]
    scores: dict[str, LooScore]
    points_before: dict
    points_after: dict

    @property
    def verdict(self) -> str:
        return self.report["verdict"]


def _physical_value(name: str, u: float, data) -> float:
    """Physical value of a global parameter at scaled value ``u`` (its reference from ``data``)."""
    s = int(data.radius.shape[0])
    vec = np.asarray(data.u_base).copy()
    vec[s + GLOBAL_PARAMETERS.index(name)] = u
    data_free = eqx.tree_at(lambda d: d.free, data, jnp.ones_like(data.free))
    value = np.asarray(physical(jnp.asarray(vec), data_free)[name])
    return float(np.mean(value)) if value.ndim else float(value)


def _parameter_report(fit: CandidateFit, names: Sequence[str]) -> dict:
    out = {}
    s = int(fit.data.radius.shape[0])
    for name in names:
        index = s + GLOBAL_PARAMETERS.index(name)
        u, std = laplace_interval(fit, index)
        lo, hi = (_physical_value(name, u + k * 1.959963984540054 * std, fit.data) for k in (-1, 1))
        value = _physical_value(name, u, fit.data)
        out[name] = {"value": value, "ci95": [min(lo, hi), max(lo, hi)], "unit": UNITS[name]}
    return out


def _session_estimates(fit: CandidateFit) -> dict:
    """P_g [Pa] per session and E [Pa], with 95 % intervals (log-normal, Laplace)."""
    s = int(fit.data.radius.shape[0])
    phys = {k: np.asarray(v) for k, v in physical(jnp.asarray(fit.u), fit.data).items()}
    out = {"gauge_pressure": [], "young_modulus": None}
    for i in range(s):
        _, std = laplace_interval(fit, i)
        value = float(phys["gauge_pressure"][i])
        out["gauge_pressure"].append(
            {"value": value, "ci95": [value * math.exp(-1.96 * std), value * math.exp(1.96 * std)], "unit": "Pa"}
        )
    _, std = laplace_interval(fit, s + GLOBAL_PARAMETERS.index("young_modulus"))
    value = float(phys["young_modulus"])
    out["young_modulus"] = {
        "value": value,
        "ci95": [value * math.exp(-1.96 * std), value * math.exp(1.96 * std)],
        "unit": "Pa",
    }
    return out


def _points(study: Study, score: LooScore, regime: np.ndarray) -> dict:
    """Per data row (depth, count, shape): observable, session, force level, regime, observed,
    held-out residual (observed − predicted) and its std, z = residual/std, whitened residual
    (independent N(0, 1) under the model) and LOO-PIT."""
    observed = np.concatenate([study.depth, study.count, study.shape_value])
    rows = {
        "observable": np.array(
            ["depth"] * study.depth.size
            + ["wrinkle_count"] * study.count.size
            + [SHAPE_OBSERVABLES[k] for k in study.shape_kind]
        ),
        "session": np.concatenate([study.depth_session, study.count_session, study.shape_session]),
        "level": np.concatenate([study.level, np.full(study.count.size, np.nan), study.shape_force]),
        "regime": np.concatenate(
            [
                np.where(regime, "after_onset", "before_onset"),
                np.full(study.count.size, "top_force"),
                np.full(study.shape_value.size, "shape"),
            ]
        ),
        "force": np.concatenate([study.force, np.full(study.count.size, np.nan), study.shape_force]),
        "observed": observed,
        "residual": score.residual,
        "std": score.std,
        "z": score.residual / score.std,
        "whitened": score.whitened,
        "pit": score.pit,
    }
    return rows


def _group(points: dict, mask: np.ndarray, unit: str | None = None) -> dict:
    z, w, pit = points["z"][mask], points["whitened"][mask], points["pit"][mask]
    chi2 = float(np.sum(w**2))
    # standardized by the whole noise model: the whitened residuals (a trial's depths share its
    # zero error, so dividing each by its marginal std would count that error once per sample)
    out = {
        "n": int(mask.sum()),
        "rms_standardized": float(np.sqrt(np.mean(w**2))),
        "rms_marginal_z": float(np.sqrt(np.mean(z**2))),
        "mean_marginal_z": float(np.mean(z)),
        "chi2": chi2,
        "p_value": float(stats.chi2.sf(chi2, mask.sum())),
        "loo_pit_ks_p_value": float(stats.kstest(pit, "uniform").pvalue) if mask.sum() >= 3 else None,
    }
    if unit is not None:
        resid = points["residual"][mask]
        rel = resid / np.where(points["observed"][mask] != 0, points["observed"][mask], np.nan)
        out.update(
            rms=float(np.sqrt(np.mean(resid**2))), unit=unit, rms_percent=float(100 * np.sqrt(np.nanmean(rel**2)))
        )
    out["misfit"] = out["p_value"] < MISFIT_P
    return out


def _structure(study: Study, points: dict) -> dict:
    """Depth residual [m] regressed on Legendre polynomials of force: offset, slope, curvature."""
    sel = points["observable"] == "depth"
    f = study.force
    xi = (2 * f - f.min() - f.max()) / max(f.max() - f.min(), 1e-12)
    design = np.stack([np.ones_like(xi), xi, 0.5 * (3 * xi**2 - 1)], axis=1)
    resid = points["residual"][sel]
    std = points["std"][sel]

    def fit(mask):
        a = design[mask] / std[mask, None]
        coef, *_ = np.linalg.lstsq(a, resid[mask] / std[mask], rcond=None)
        cov = np.linalg.pinv(a.T @ a)
        se = np.sqrt(np.diag(cov))
        return {
            name: {"value": float(c), "std": float(e), "z": float(c / e) if e > 0 else 0.0, "unit": "m"}
            for name, c, e in zip(("offset", "slope", "curvature"), coef, se)
        }

    out = {
        "basis": "Legendre polynomials of the force scaled to [-1, 1] over the study's forces",
        "pooled": fit(np.ones(f.size, bool)),
    }
    out["by_session"] = [fit(study.depth_session == s) for s in range(study.n_sessions)]
    return out


def _where(study: Study, points: dict) -> dict:
    units = {"depth": "m", "wrinkle_count": "1", **{k: "m" for k in SHAPE_OBSERVABLES}}
    by_obs = {
        name: _group(points, points["observable"] == name, units[name])
        for name in OBSERVABLES
        if np.any(points["observable"] == name)
    }
    by_regime = {
        name: _group(points, points["regime"] == name)
        for name in ("before_onset", "after_onset")
        if np.any(points["regime"] == name)
    }
    depth = points["observable"] == "depth"
    by_level = [
        {"force": float(lv), "unit": "N", **_group(points, depth & np.isclose(points["level"], lv))}
        for lv in np.unique(study.level)
    ]
    by_session = [
        {"session": str(s.source), **_group(points, points["session"] == i)} for i, s in enumerate(study.sessions)
    ]
    groups = (
        [f"observable:{k}" for k, v in by_obs.items() if v["misfit"]]
        + [f"regime:{k}" for k, v in by_regime.items() if v["misfit"]]
        + [f"force:{v['force']:.3g} N" for v in by_level if v["misfit"]]
        + [f"session:{v['session']}" for v in by_session if v["misfit"]]
    )
    return {
        "by_observable": by_obs,
        "by_regime": by_regime,
        "by_force_level": by_level,
        "by_session": by_session,
        "structure_along_force": _structure(study, points),
        "misfit_groups": groups,
        "misfit_threshold_p": MISFIT_P,
    }


def _gap(points: dict) -> dict:
    """Held-out gap: RMS of the standardized (whitened) held-out residuals, √(χ²/n), overall and per
    observable, with the RMS residual per observable in its unit and in % of the measured value."""
    units = {"depth": "m", "wrinkle_count": "1", **{k: "m" for k in SHAPE_OBSERVABLES}}
    out = {"rms_standardized": float(np.sqrt(np.mean(points["whitened"] ** 2))), "by_observable": {}}
    for name in OBSERVABLES:
        sel = points["observable"] == name
        if sel.any():
            g = _group(points, sel, units[name])
            out["by_observable"][name] = {k: g[k] for k in ("rms_standardized", "rms", "unit", "rms_percent")}
    return out


def candidate_data(base: StudyArrays, effect: str | None, baseline_free: tuple[str, ...]) -> StudyArrays:
    """``base`` with the free mask and priors of candidate ``effect`` (None: the baseline), whose
    baseline frees the global parameters ``baseline_free``."""
    n_sessions = int(base.radius.shape[0])
    data = eqx.tree_at(lambda d: d.free, base, jnp.asarray(free_mask(n_sessions, baseline_free, effect)))
    if effect is not None and "wall_thickness" in effects_of(effect):
        index = n_sessions + GLOBAL_PARAMETERS.index("thickness")
        data = eqx.tree_at(lambda d: d.prior_std, data, data.prior_std.at[index].set(FREE_THICKNESS_STD))
    return data


def _checked_options(effects, baseline: str, gas: str | None, wrinkle_law: str) -> tuple[tuple[str, ...], str]:
    """(candidate names, gas law) after checking every option."""
    effects = tuple(EFFECTS) if effects is None else check_effect_names(effects)
    if baseline not in BASELINES:
        raise InvalidInputError(f"unknown baseline {baseline!r}. Fix: choose from {', '.join(BASELINES)}")
    gas = gas or BASELINES[baseline]
    gas_law(gas)  # an unknown name fails here, with the valid ones
    if wrinkle_law not in WRINKLE_LAWS:
        raise InvalidInputError(f"unknown wrinkle_law {wrinkle_law!r}. Fix: choose from {', '.join(WRINKLE_LAWS)}")
    return effects, gas


def _fit_candidate_restarted(
    data: StudyArrays, wrinkle_law: str, u_start: np.ndarray, parameters: tuple[str, ...]
) -> CandidateFit:
    """A candidate's fit from its parent's optimum; where it stops short, again with its new
    ``parameters`` started one prior unit either side (an indenter or a gain far from nominal is a
    long way from 0)."""
    fit = fit_candidate(data, wrinkle_law, u_start)
    n_sessions = int(data.radius.shape[0])
    for sign in (1.0, -1.0):
        if fit.converged:
            break
        u = np.asarray(u_start, float).copy()
        for name in parameters:
            u[n_sessions + GLOBAL_PARAMETERS.index(name)] = sign
        retry = fit_candidate(data, wrinkle_law, u)
        if retry.converged or retry.chi2 < fit.chi2:
            fit = retry
    return fit


def _search_effects(base: StudyArrays, effects, baseline_free, wrinkle_law: str, sessions, report_progress):
    """Fit the baseline, every candidate from the baseline's optimum, then the forward search's
    combinations of the winner: (fits and scores by model name, the search's result)."""
    report_progress("baseline")
    fit = fit_candidate(candidate_data(base, None, baseline_free), wrinkle_law, np.zeros(base.free.shape[0]))
    if not fit.converged:
        raise NoConvergenceError(
            f"the baseline fit of {len(sessions)} session(s) of '{sessions[0].object_name}' failed: "
            f"{fit.message}. Fix: check the sessions with `shelljax validate`"
        )
    fits, scores = {"baseline": fit}, {"baseline": loo_score(fit)}

    def children(current):
        used = set(effect_parameters(combination_name(current))) if current else set()
        return [
            tuple(effects_of(combination_name(current + (e,))))
            for e in effects
            if e not in current and not used & set(EFFECTS[e].parameters)
        ]

    def fit_child(child, parent):
        name, parent_name = combination_name(child), combination_name(parent) or "baseline"
        report_progress(name)
        new = tuple(
            p for p in effect_parameters(name) if parent_name == "baseline" or p not in effect_parameters(parent_name)
        )
        fits[name] = _fit_candidate_restarted(
            candidate_data(base, name, baseline_free), wrinkle_law, fits[parent_name].u, new
        )
        if not fits[name].converged:
            return fits[name].message
        scores[name] = loo_score(fits[name])
        return scores[name]

    result = forward_search(
        (), scores["baseline"], children, fit_child, lambda sc: sc.elpd, Margin(WIN_NATS, WIN_SE), MAX_EFFECTS
    )
    report_progress(None)
    return fits, scores, result


def _ranking(fits: dict, scores: dict) -> list[dict]:
    """Every fitted model's entry (single effects and combinations), best score first and failures last."""
    base_score = scores["baseline"]
    ranking = []
    for name, fit in fits.items():
        entry = {"effect": name, "status": "ok" if name in scores else "failed"}
        if name != "baseline":
            entry["parameters"] = _parameter_report(fit, effect_parameters(name)) if fit.converged else {}
        if name not in scores:
            entry.update(score=None, score_se=None, delta=None, delta_se=None, message=fit.message)
        else:
            sc = scores[name]
            diff = sc.elpd - base_score.elpd
            n = diff.size
            entry.update(
                score=sc.total,
                score_se=float(math.sqrt(n * np.var(sc.elpd))),
                delta=float(diff.sum()),
                delta_se=float(math.sqrt(n * np.var(diff))),
                chi2=fit.chi2,
                steps=fit.steps,
            )
        ranking.append(entry)
    ok = [e for e in ranking if e["status"] == "ok"]
    return sorted(ok, key=lambda e: -e["score"]) + [e for e in ranking if e["status"] != "ok"]


def _winner_record(chosen: str, fits: dict, before_est: dict, after_est: dict) -> dict | None:
    if chosen == "baseline":
        return None
    return {
        "effect": chosen,
        "effects": list(effects_of(chosen)),
        "description": "; ".join(EFFECTS[e].description for e in effects_of(chosen)),
        "layer": "+".join(dict.fromkeys(EFFECTS[e].layer for e in effects_of(chosen))),
        "parameters": _parameter_report(fits[chosen], effect_parameters(chosen)),
        "estimates_before": before_est,
        "estimates_after": after_est,
        "gauge_pressure_shift_percent": [
            100 * (a["value"] / b["value"] - 1)
            for a, b in zip(after_est["gauge_pressure"], before_est["gauge_pressure"])
        ],
        "young_modulus_shift_percent": 100
        * (after_est["young_modulus"]["value"] / before_est["young_modulus"]["value"] - 1),
    }


def _baseline_record(
    baseline: str, gas: str, wrinkle_law: str, base: StudyArrays, baseline_free, before_est: dict, study: Study
) -> dict:
    return {
        "name": baseline,
        "gas": gas,
        "wrinkle_law": wrinkle_law,
        "engine": "axisym",
        "indenter_radius": {"value": float(base.indenter_radius), "unit": "m"},
        "free": list(baseline_free),
        "estimates": before_est,
        "noise": {
            "depth_scatter_a": {"value": study.depth_noise[0], "unit": "m^2"},
            "depth_scatter_b": {"value": study.depth_noise[1], "unit": "1"},
            "trial_offset_std": {"value": study.trial_offset_std, "unit": "m"},
        },
    }


def _sessions_record(study: Study) -> list[dict]:
    return [
        {
            "path": str(s.source),
            "object": s.object_name,
            "radius": {"value": s.radius, "unit": "m"},
            "manometer_gauge_pressure": None
            if s.manometer_gauge_pressure is None
            else {"value": s.manometer_gauge_pressure, "unit": "Pa"},
            "trials": int(s.trial_ids.size),
            "samples": int(s.depth.size),
            "shape_points": int(np.sum(study.shape_session == i)),
        }
        for i, s in enumerate(study.sessions)
    ]


def _candidates_beside_measurement(
    effects: tuple[str, ...], baseline_free: tuple[str, ...], measurement: MeasurementPrior | None
) -> tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]:
    """The candidates, the baseline's free parameters and the candidates the measuring chain already
    holds, once a calibrated ``measurement`` (if any) joins the baseline."""
    if measurement is None:
        return effects, baseline_free, ()
    baseline_free += tuple(p for p in measurement.parameters if p not in baseline_free)
    # a candidate whose parameters the calibrated chain already fits would be the baseline again
    in_baseline = tuple(e for e in effects if set(EFFECTS[e].parameters) <= set(measurement.parameters))
    return tuple(e for e in effects if e not in in_baseline), baseline_free, in_baseline


def diagnose(
    sessions: Sequence[Session | str | Path],
    *,
    effects: Sequence[str] | None = None,
    baseline: str = "estimator",
    gas: str | None = None,
    wrinkle_law: str = DEFAULT_OPTIONS.wrinkle_law,
    progress: Callable[[str], None] | bool = True,
    measurement: MeasurementPrior | None = None,
) -> Diagnosis:
    """Diagnose the sim-to-real gap of the sessions of one object (see the module docstring).

    ``effects``: candidate names (default: every one in :data:`EFFECTS`); ``baseline``:
    "estimator" (the fitted estimator's sealed isothermal gas) or "paper" (the paper's prescribed
    pressure); ``gas`` overrides the baseline's gas law ("prescribed", "isothermal", "adiabatic");
    ``wrinkle_law``: "scaling" (n = 1.33 τ^½) or "mechanics" (the engine's count);
    ``measurement``: a calibrated measuring chain as the new baseline (``shelljax.rig``), whose
    parameters every model fits under its calibrated prior, with its reference force and noise model.

    Raises:
        InvalidInputError: sessions of several objects, an unknown effect, baseline, gas or
            wrinkle law, or a study too small to rank.
        NoConvergenceError: the baseline fit failed (a candidate's failure is reported in the
            ranking instead).
    """
    effects, gas = _checked_options(effects, baseline, gas, wrinkle_law)
    sessions = [s if isinstance(s, Session) else load_session(s) for s in sessions]
    study = build_study(sessions, None if measurement is None else measurement.noise)
    base = study_arrays(study, gas=gas_law(gas), force_ref=None if measurement is None else measurement.force_ref)
    base = measured_baseline(base, measurement)
    effects, baseline_free, in_baseline = _candidates_beside_measurement(effects, object_unknowns(study), measurement)
    report_progress = _progress_reporter(progress)
    fits, scores, search = _search_effects(base, effects, baseline_free, wrinkle_law, sessions, report_progress)
    ranking, chosen = _ranking(fits, scores), combination_name(search.chosen) or "baseline"

    regime = fits["baseline"].prediction["wrinkled"]
    points_before = _points(study, scores["baseline"], regime)
    points_after = _points(study, scores[chosen], regime)
    gap_before, gap_after = _gap(points_before), _gap(points_after)
    misfit_p = float(stats.chi2.sf(np.sum(points_after["whitened"] ** 2), points_after["whitened"].size))
    verdict = "unexplained" if misfit_p < MISFIT_P else ("none" if chosen == "baseline" else chosen)
    before_est, after_est = _session_estimates(fits["baseline"]), _session_estimates(fits[chosen])
    where_chosen = _where(study, points_after)
    kept, robust = _robust_report(ranking, fits, scores, search, chosen, misfit_p, where_chosen["misfit_groups"])
    report = {
        "verdict": verdict,
        "ranking": ranking,
        "gap_before": gap_before,
        "gap_after": gap_after,
        "shrink": gap_before["rms_standardized"] / gap_after["rms_standardized"],
        "where": _where(study, points_before),
        "where_after": where_chosen if chosen != "baseline" else None,
        "not_excluded": kept,
        "robust": robust,
        "separating": separating(kept, chosen, robust),
        "winner": _winner_record(chosen, fits, before_est, after_est),
        "misfit_p_value": misfit_p,
        "search": [combination_name(step) or "baseline" for step in search.path],
        "decision": {
            "win_se": WIN_SE,
            "win_nats": WIN_NATS,
            "misfit_p": MISFIT_P,
            "score": "leave-one-trial-out elpd, exact for the model linearised at each optimum",
        },
        "baseline": {
            **_baseline_record(baseline, gas, wrinkle_law, base, baseline_free, before_est, study),
            "measurement": None if measurement is None else measurement.name,
            "effects_in_measurement": list(in_baseline),
        },
        "sessions": _sessions_record(study),
    }
    return Diagnosis(
        report=report, study=study, fits=fits, scores=scores, points_before=points_before, points_after=points_after
    )


def _robust_report(ranking, fits, scores, search, chosen: str, misfit_p: float, misfit_groups: list[str]):
    """(the models not excluded, with their pseudo-BMA+ weights; the robust range over them and the
    chosen model's expansions it must cover)."""
    kept = not_excluded(ranking, scores, WIN_NATS, WIN_SE)
    weights = pseudo_bma_plus(np.stack([scores[k["effect"]].elpd for k in kept]))
    for k, w in zip(kept, weights):
        k["weight"] = float(w)
    structure = ([f"chi2 p = {misfit_p:.1g}"] if misfit_p < MISFIT_P else []) + list(misfit_groups)
    expansions = sorted(
        (combination_name(c) for c in search.children if combination_name(c) in scores),
        key=lambda name: -scores[name].total,
    )
    estimates = {name: _session_estimates(fits[name]) for name in {k["effect"] for k in kept} | {chosen, *expansions}}
    widening = expansion_widening(expansions, estimates, chosen, structure, chosen != "baseline")
    return kept, robust_range(kept, estimates, chosen, widening)


def _progress_reporter(progress):
    """A callable taking the stage's name (None: done): a tqdm bar, the caller's callable, or nothing."""
    if callable(progress):
        return progress
    if not progress:
        return lambda stage: None
    from tqdm.auto import tqdm

    bar = tqdm(desc="diagnose", unit="model")  # the search decides how many models it fits
    state = {"started": False}

    def update(stage):
        if state["started"]:
            bar.update(1)
        state["started"] = True
        if stage is None:
            bar.close()
        else:
            bar.set_postfix_str(stage)

    return update
