"""Rig calibration: the measuring chain learned once from sessions whose gauge pressure is known.

Every calibration session has a manometer reading. Sessions are grouped by object; each object is
one joint problem of the diagnosis (``shelljax.diagnose``: E, h and R per object, P_g per session
with the manometer as its prior) and the rig's parameters are shared by all of them.

**Term selection, out of sample.** A forward search from the ideal rig: at each step every term of a
family not yet in the model is added in turn and refitted, and the best child (by leave-one-trial-out
elpd) is expanded next, for as long as it predicts better than its parent. Real rigs have two or
three imperfections, so several terms can be on at once, and a pair is reached where neither term
alone wins by the margin.

**What the data cannot exclude.** Every fitted model that the best one does not beat by the
diagnosis's margin (Δ elpd ≥ 4 nats and ≥ 2 SE) stays in the rig — less those a simpler model
nested in them predicts better (Occam's window, Madigan & Raftery 1994: a term that does not help
out of sample adds nothing but its noise) — weighted by pseudo-BMA+ (Yao et al. 2018: Bayesian-bootstrap Akaike weights of
the leave-one-trial-out densities). Stacking was not chosen: it gives zero weight to a model whose
predictions the others already make on the calibration object, yet such a model can transfer
differently to another object, and its spread is what the intervals must include.

**Several objects.** Objects share only the rig, so the rig's Laplace posterior is the product of
each object's Gaussian marginal of the rig entries, with the weakly informative prior they all
carry counted once.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from .. import __version__
from .._errors import InvalidInputError, NoConvergenceError
from ..diagnose import GLOBAL_PARAMETERS, build_study, fit_candidate, loo_score, study_arrays
from ..diagnose.internal import (
    MANOMETER_STD,
    PRIOR_STD,
    WIN_NATS,
    WIN_SE,
    ANY_GAIN,
    Margin,
    forward_search,
    object_unknowns,
    pseudo_bma_plus,
    physical,
    widened_grid,
    with_measurement,
)
from .._options import DEFAULT_OPTIONS, ESTIMATOR_GASES, WRINKLE_LAWS
from ..paper import PAPER_INDENTER_RADIUS
from ..physics import gas_law
from ..session import RigidPress, Session, files_sha256, load_rigid_press, load_session
from ._press import PressFit, fit_press, press_data
from ._terms import RIG_TERMS, check_terms, fixed_values, freed_parameters

CALIBRATION_GRID_SPAN = (0.5, 1.7)  # the engine's force grid covers [0.5 F_min, 1.7 F_max]: room for a sensor's gain
MIN_WEIGHT = 1e-3  # a model below this weight is dropped from the rig (its weight goes to the others)
PRECISE_RADIUS = 0.01  # [-] a calibration object's R stated less precisely than this is worth measuring again
_MARGIN = Margin(WIN_NATS, WIN_SE)  # a model the best beats by the diagnosis's margin is excluded
IDENTIFIED = 0.9  # a term is identified when the models holding it weigh ≥ 0.9, or ≤ 0.1


@dataclasses.dataclass(frozen=True)
class RigModel:
    """One model of the measuring chain: its ``terms``, the diagnosis ``parameters`` it fits with their
    ``mean`` and ``covariance`` in the diagnosis's scaled coordinates (u), the scaled values it
    ``fixes``, its leave-one-trial-out ``elpd`` [nats] with ``elpd_se``, its difference to the best
    model ``delta`` ± ``delta_se`` [nats], and its ``weight`` in the rig [-]."""

    terms: tuple[str, ...]
    parameters: tuple[str, ...]
    mean: np.ndarray
    covariance: np.ndarray
    fixes: dict[str, float]
    elpd: float
    elpd_se: float
    delta: float
    delta_se: float
    weight: float


@dataclasses.dataclass(frozen=True)
class Rig:
    """A calibrated rig (docs/rig.md): the ``models`` the data cannot exclude (weights sum to 1),
    the ``excluded`` ones (terms, Δ elpd, SE), the ``inclusion`` probability of every term and the
    terms ``not_identified``; the forward-model options it was made with (``gas``,
    ``wrinkle_law``), the reference force ``force_ref`` [N] of the power laws, the nominal finger
    radius ``indenter_radius`` [m], the depth ``noise`` model (τ_t [m], (a [m²], b [-])), the
    ``calibration`` sessions (path, sha256, object, manometer [Pa]), the calibration objects'
    ``objects`` estimates, the shelljax ``version`` that made it, and the ``name`` of the measuring
    chain the calibration files give (``rig`` in a session), or None, the ``manometer_std`` [-]
    the calibration assumed, and the models whose fit ``failed`` (terms, why), never dropped silently."""

    models: tuple[RigModel, ...]
    excluded: tuple[dict, ...]
    inclusion: dict[str, float]
    not_identified: tuple[str, ...]
    gas: str
    wrinkle_law: str
    force_ref: float
    indenter_radius: float
    noise: tuple[float, tuple[float, float]]
    calibration: tuple[dict, ...]
    objects: tuple[dict, ...]
    version: str = __version__
    name: str | None = None
    manometer_std: float = MANOMETER_STD
    failed: tuple[dict, ...] = ()


@dataclasses.dataclass(frozen=True)
class _Fitted:
    terms: tuple[str, ...]
    fits: list
    press: PressFit | None
    elpd: np.ndarray  # per trial: every object's trials in turn, then the presses'

    @property
    def total(self) -> float:
        return float(np.sum(self.elpd))


def _rig_name(sessions, presses) -> str | None:
    """The one measuring chain the calibration files name (None: none named); several are refused."""
    named = {}
    for item in (*sessions, *presses):
        if item.rig_name is not None:
            named.setdefault(item.rig_name, str(item.source))
    if len(named) > 1:
        listing = "; ".join(f"{source}: rig = {name!r}" for name, source in named.items())
        raise InvalidInputError(
            f"the calibration files were recorded with different rigs ({listing}). Fix: calibrate "
            "each measuring chain on its own sessions (`shelljax rig calibrate` once per rig)"
        )
    return next(iter(named), None)


def _check_sessions(sessions: Sequence[Session]) -> None:
    missing = [s for s in sessions if s.manometer_gauge_pressure is None]
    if missing:
        raise InvalidInputError(
            f"{missing[0].source}: field 'manometer_gauge_pressure': missing; a rig is calibrated where the gauge "
            "pressure is known. Fix: add the manometer reading, or leave this session out of `rig calibrate`"
        )
    for s in sessions:
        if s.wrinkle_counts is None:
            raise InvalidInputError(
                f"{s.source}: field 'wrinkles.counts': missing; the calibration needs the "
                "wrinkle counts to separate E from the rig. Fix: add one count per trial"
            )
    if len(sessions) < 2:
        raise InvalidInputError(
            f"{sessions[0].source}: one session cannot separate a rig from the object. "
            "Fix: calibrate on an object measured at two or more pressures (four are better)"
        )


def pooled_noise(studies) -> tuple[float, tuple[float, float]]:
    """(τ_t [m], (a [m²], b [-])) of several studies, weighted by their trials."""
    weights = np.array([s.n_units for s in studies], float)
    tau = math.sqrt(float(np.average([s.trial_offset_std**2 for s in studies], weights=weights)))
    a = float(np.average([s.depth_noise[0] for s in studies], weights=weights))
    b = float(np.average([s.depth_noise[1] for s in studies], weights=weights))
    return tau, (a, b)


def model_data(base, study, terms, *, rig_prior=None):
    """``base`` arrays with the free mask and fixed values of a rig model with ``terms``;
    ``rig_prior`` = (parameters, mean u, covariance) puts the rig's correlated prior on them."""
    return with_measurement(
        base, free=object_unknowns(study) + freed_parameters(terms), fixes=fixed_values(terms), prior=rig_prior
    )


def fit_model(base, study, terms, wrinkle_law: str, u_start: np.ndarray, *, rig_prior=None):
    """Fit one object's study under a rig model; a fit that stops short is retried once from the
    ideal rig (LM can stall where the engine's round-off meets a trust region that has shrunk)."""
    data = model_data(base, study, terms, rig_prior=rig_prior)
    fit = fit_candidate(data, wrinkle_law, u_start)
    if not fit.converged:
        retry = fit_candidate(data, wrinkle_law, np.zeros(data.u_base.shape[0]))
        if retry.converged or retry.chi2 < fit.chi2:
            fit = retry
    return fit


def _fit_everywhere(objects, terms, wrinkle_law, starts, presses) -> _Fitted | str:
    """The model with ``terms`` fitted on every object and press, or why a fit failed."""
    fits = []
    for (base, study), start in zip(objects, starts):
        fit = fit_model(base, study, terms, wrinkle_law, start)
        if not fit.converged:
            return f"{study.sessions[0].object_name}: {fit.message}"
        fits.append(fit)
    press = None if presses is None else fit_press(presses, terms, float(objects[0][0].force_ref))
    elpd = [loo_score(f).elpd for f in fits] + ([press.elpd] if press is not None else [])
    return _Fitted(terms, fits, press, np.concatenate(elpd))


def _search(objects, terms, wrinkle_law, report, presses) -> tuple[dict, list[dict]]:
    """Forward search from the ideal rig (``diagnose.internal.forward_search``, by any gain out of
    sample): (every fitted model by its terms, the models whose fit failed and why)."""
    report("ideal rig")
    start = _fit_everywhere(objects, (), wrinkle_law, [np.zeros(b.free.shape[0]) for b, _ in objects], presses)
    if isinstance(start, str):
        raise NoConvergenceError(
            f"the calibration fit with an ideal rig did not converge ({start}). Fix: check the "
            "sessions with `shelljax validate` and `shelljax diagnose`"
        )
    searched = {(): start}  # the converged models so far: a child starts from its parent's optima

    def children(current):
        used = {RIG_TERMS[t].family for t in current}
        return [check_terms(current + (t,)) for t in terms if RIG_TERMS[t].family not in used]

    def fit(candidate, parent):
        report("+".join(candidate))
        result = _fit_everywhere(objects, candidate, wrinkle_law, [f.u for f in searched[parent].fits], presses)
        if not isinstance(result, str):
            searched[candidate] = result
        return result

    result = forward_search((), start, children, fit, lambda r: r.elpd, ANY_GAIN)
    return result.fitted, result.failed


def _rig_posterior(result: _Fitted, objects) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """(parameters, mean u, covariance) of the rig entries: the product of every object's marginal
    and the presses' posterior, each of which holds the weak prior once."""
    names = freed_parameters(result.terms)
    if not names:
        return names, np.zeros(0), np.zeros((0, 0))
    factors = []
    for fit, (_, study) in zip(result.fits, objects):
        free = np.flatnonzero(np.asarray(fit.data.free))
        index = [int(np.flatnonzero(free == study.n_sessions + GLOBAL_PARAMETERS.index(p))[0]) for p in names]
        factors.append(
            (
                names,
                fit.u[[study.n_sessions + GLOBAL_PARAMETERS.index(p) for p in names]],
                fit.covariance[np.ix_(index, index)],
            )
        )
    if result.press is not None and result.press.parameters:
        factors.append((result.press.parameters, result.press.mean, result.press.covariance))
    precision, shift = np.zeros((len(names), len(names))), np.zeros(len(names))
    counts = np.zeros(len(names))
    for factor_names, mean, cov in factors:
        index = [names.index(p) for p in factor_names]
        info = np.linalg.inv(cov)
        precision[np.ix_(index, index)] += info
        shift[index] += info @ mean
        counts[index] += 1
    precision -= np.diag((counts - 1) / np.array([PRIOR_STD[p] ** 2 for p in names]))
    covariance = np.linalg.inv(precision)
    return names, covariance @ shift, 0.5 * (covariance + covariance.T)


def _object_summary(fit, study) -> dict:
    phys = {k: np.asarray(v) for k, v in physical(jnp.asarray(fit.u), fit.data).items()}
    free = np.flatnonzero(np.asarray(fit.data.free))
    index = int(np.flatnonzero(free == study.n_sessions + GLOBAL_PARAMETERS.index("young_modulus"))[0])
    rel = math.sqrt(fit.covariance[index, index])
    return {
        "object": study.sessions[0].object_name,
        "radius": {"value": float(np.mean(phys["radius"])), "unit": "m"},
        "young_modulus": {"value": float(phys["young_modulus"]), "relative_std": rel, "unit": "Pa"},
        "thickness": {"value": float(phys["thickness"]), "unit": "m"},
    }


def _objects(sessions, gas, force_ref, manometer_std):
    by_object: dict[str, list[Session]] = {}
    for s in sessions:
        by_object.setdefault(s.object_name, []).append(s)
    studies = [build_study(group, min_trials=2) for group in by_object.values()]
    noise = pooled_noise(studies)
    studies = [build_study(group, noise, min_trials=2) for group in by_object.values()]
    forces = np.concatenate([s.force for s in sessions])
    objects = []
    for study in studies:
        base = study_arrays(
            study,
            gas=gas_law(gas),
            indenter_radius=PAPER_INDENTER_RADIUS,
            force_ref=force_ref,
            manometer_std=manometer_std,
        )
        objects.append((widened_grid(base, forces, CALIBRATION_GRID_SPAN), study))
    return objects, noise


def calibrate_rig(
    sessions: Sequence[Session | str | Path],
    *,
    gas: str = DEFAULT_OPTIONS.gas,
    wrinkle_law: str = DEFAULT_OPTIONS.wrinkle_law,
    terms: Sequence[str] | None = None,
    presses: Sequence = (),
    manometer_std: float = MANOMETER_STD,
    progress: Callable[[str], None] | bool = True,
) -> Rig:
    """Calibrate a rig on ``sessions`` with manometer readings, of one or more objects (module docstring).

    ``gas`` and ``wrinkle_law``: the forward model's options, carried by the rig to every later
    estimate; ``terms``: the candidate terms (default: every one in :data:`RIG_TERMS`);
    ``presses``: rigid-surface press sessions (``shelljax.session.RigidPress`` or their files), which
    measure the pad, the depth zero and the sensor without an object (``_press``); ``manometer_std``
    [-]: the manometer readings' relative standard deviation (its accuracy class).

    Raises:
        InvalidInputError: a session without a manometer reading or wrinkle counts, too few
            sessions, an unknown term, gas or wrinkle law.
        NoConvergenceError: the fit with an ideal rig failed.
    """
    terms = tuple(RIG_TERMS) if terms is None else check_terms_list(terms)
    if gas not in ESTIMATOR_GASES:
        raise InvalidInputError(
            f"unknown gas {gas!r} for an estimate. Fix: choose from {', '.join(ESTIMATOR_GASES)} "
            "(a poke is slow: a sealed object's gas stays isothermal)"
        )
    if wrinkle_law not in WRINKLE_LAWS:
        raise InvalidInputError(f"unknown wrinkle_law {wrinkle_law!r}. Fix: choose from {', '.join(WRINKLE_LAWS)}")
    if not 0 < manometer_std < 0.5:
        raise InvalidInputError(
            f"manometer_std {manometer_std!r} is not a relative std in (0, 0.5). Fix: give the "
            "manometer's accuracy as a fraction, e.g. 0.01 for 1 %"
        )
    sessions = [s if isinstance(s, Session) else load_session(s) for s in sessions]
    if not sessions:
        raise InvalidInputError("no calibration sessions given. Fix: pass session TOML files with manometer readings")
    _check_sessions(sessions)
    _hint_radius(sessions)
    levels = np.concatenate([s.force for s in sessions])
    force_ref = math.sqrt(float(np.min(levels)) * float(np.max(levels)))
    objects, noise = _objects(sessions, gas, force_ref, manometer_std)
    report = _reporter(progress)
    presses = [p if isinstance(p, RigidPress) else load_rigid_press(p) for p in presses]
    name = _rig_name(sessions, presses)
    fitted, failed = _search(objects, terms, wrinkle_law, report, press_data(presses) if presses else None)
    report(None)
    rig = _assemble(fitted, objects, sessions, presses, noise, gas, wrinkle_law, force_ref)
    return dataclasses.replace(rig, name=name, manometer_std=manometer_std, failed=tuple(failed))


class RigWarning(UserWarning):
    """A rig is weaker than it could be, or one of its models could not be used for an estimate."""


def _hint_radius(sessions) -> None:
    """Warn when a calibration object's R is stated loosely: on one object the force gain g and R
    enter as one product (F ∝ g R P_g w), so R's error becomes the rig's gain error, carried to
    every later P_g (docs/rig.md, the transfer study)."""
    loose = [s for s in sessions if s.radius_std > PRECISE_RADIUS * s.radius]
    if loose:
        worst = max(loose, key=lambda s: s.radius_std / s.radius)
        warnings.warn(
            f"{worst.source}: field 'radius_std': the calibration object's radius is stated to "
            f"±{100 * worst.radius_std / worst.radius:.1f} %, and on one object the rig's force gain takes "
            "that error with it to every later P_g. Fix: measure its circumference with a tape (R to about "
            "±0.3 %) and state radius_std (docs/rig.md)",
            RigWarning,
            stacklevel=3,
        )


def check_terms_list(terms) -> tuple[str, ...]:
    """Candidate terms: known names, each once (several of one family may be candidates)."""
    terms = tuple(terms)
    for t in terms:
        check_terms((t,))
    if len(set(terms)) != len(terms):
        raise InvalidInputError(f"terms {list(terms)} name one term twice. Fix: list each once")
    return terms


def _nests(terms, simpler) -> bool:
    """Whether the model of ``terms`` contains the model of ``simpler`` (a power-law pad contains the
    linear and the Hertzian ones)."""
    covered = set(terms) | ({"pad_linear", "pad_hertz"} if "pad_power" in terms else set())
    return set(simpler) < covered and set(simpler) != set(terms)


def _assemble(fitted, objects, sessions, presses, noise, gas, wrinkle_law, force_ref) -> Rig:
    best = max(fitted.values(), key=lambda r: r.total)
    kept, excluded = [], []
    for result in fitted.values():
        beaten, delta, se = _MARGIN.beats(best.elpd, result.elpd) if result is not best else (False, 0.0, 0.0)
        nested_better = any(
            other.total > result.total and _nests(result.terms, other.terms)
            for other in fitted.values()
            if other is not result
        )
        (excluded if beaten or nested_better else kept).append((result, -delta, se))
    weights = pseudo_bma_plus(np.stack([r.elpd for r, _, _ in kept]))
    keep = weights >= MIN_WEIGHT
    excluded += [k for k, w in zip(kept, keep) if not w]
    kept, weights = [k for k, w in zip(kept, keep) if w], weights[keep] / weights[keep].sum()
    models = []
    for (result, delta, se), weight in sorted(zip(kept, weights), key=lambda kw: -kw[1]):
        names, mean, cov = _rig_posterior(result, objects)
        n = result.elpd.size
        models.append(
            RigModel(
                terms=result.terms,
                parameters=names,
                mean=mean,
                covariance=cov,
                fixes=fixed_values(result.terms),
                elpd=result.total,
                elpd_se=float(math.sqrt(n * np.var(result.elpd))),
                delta=delta,
                delta_se=se,
                weight=float(weight),
            )
        )
    inclusion = {t: float(sum(m.weight for m in models if t in m.terms)) for t in RIG_TERMS}
    not_identified = tuple(t for t, p in inclusion.items() if 1 - IDENTIFIED < p < IDENTIFIED)
    calibration = tuple(
        {
            "path": str(s.source),
            "sha256": files_sha256(s.input_files),
            "object": s.object_name,
            "manometer_gauge_pressure": float(s.manometer_gauge_pressure),
        }
        for s in sessions
    )
    calibration += tuple(
        {"path": str(p.source), "sha256": p.sha256, "object": p.object_name, "kind": "rigid_press"} for p in presses
    )
    objects_summary = tuple(_object_summary(f, study) for f, (_, study) in zip(fitted[models[0].terms].fits, objects))
    return Rig(
        models=tuple(models),
        excluded=tuple({"terms": list(r.terms), "delta": d, "delta_se": se} for r, d, se in excluded),
        inclusion=inclusion,
        not_identified=not_identified,
        gas=gas,
        wrinkle_law=wrinkle_law,
        force_ref=force_ref,
        indenter_radius=PAPER_INDENTER_RADIUS,
        noise=noise,
        calibration=calibration,
        objects=objects_summary,
    )


def _reporter(progress):
    if callable(progress):
        return progress
    if not progress:
        return lambda stage: None
    from tqdm.auto import tqdm

    bar = tqdm(desc="rig calibrate", unit="model")

    def update(stage):
        if stage is None:
            bar.close()
            return
        bar.update(1)
        bar.set_postfix_str(stage)

    return update
