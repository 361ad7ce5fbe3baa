"""One session of an experiment config, estimated by every configured method: the runner's work item.

:func:`estimate_session_item` runs where the executor puts it (in-process or on a Dask worker) and
returns JSON only, so that a run on N workers gives the serial run's results.json.
"""

from __future__ import annotations

import contextlib
import warnings
from pathlib import Path

import numpy as np

from .._errors import ShelljaxError
from .._placement import Placement, StageKind, requested_placement
from ..config import ExperimentConfig
from ..estimate import (
    ConvergenceWarning,
    Estimate,
    EstimatorOptions,
    SurrogateWarning,
    compile_posterior_ahead,
    options_forward_model,
    run_estimator,
)
from ..rig import estimate_with_rig, load_rig
from ..session import Session, load_session
from ._compile_log import stage
from ._memory_mappings import release_compiled_programs_if_crowded


def _session_inputs(session: Session) -> dict:
    inputs = {
        "radius": {
            "value": session.radius,
            "std": session.radius_std,
            "unit": "m",
            "source": "mesh sphere fit" if session.mesh_path else "session file",
        },
        "thickness": {"value": session.thickness, "std": session.thickness_std, "unit": "m"},
        "poisson_ratio": {"value": session.poisson_ratio, "unit": "1"},
        "n_samples": int(session.force.size),
        "n_trials": int(session.trial_ids.size),
        "force_levels": {"value": session.force_levels.tolist(), "unit": "N"},
    }
    if session.wrinkle_counts is not None:
        inputs["wrinkle_counts"] = session.wrinkle_counts.tolist()
    if session.manometer_gauge_pressure is not None:
        inputs["manometer_gauge_pressure"] = {"value": session.manometer_gauge_pressure, "unit": "Pa"}
    if session.mass is not None:
        inputs["mass"] = {"value": session.mass, "unit": "kg"}
    if session.fit_rms_residual is not None:
        inputs["sphere_fit_rms_residual"] = {"value": session.fit_rms_residual, "unit": "m"}
    return inputs


def _block(result) -> dict:
    """An estimator's record in results.json: its estimates by name, then everything else it reports."""
    record = result.to_dict()
    estimates = record.pop("estimates")
    return {**estimates, **{key: value for key, value in record.items() if value is not None}}


def _bayes_block(session: Session, options: EstimatorOptions, model, fit, run_dir: Path, figures: bool):
    """Sample the posterior into its record: chain file, caught warnings, figures."""
    chains = run_dir / "chains"
    chains.mkdir(exist_ok=True)
    chain_path = chains / f"{session.source.stem}.h5"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        warnings.simplefilter("always", SurrogateWarning)
        post = run_estimator("bayes", session, options, model=model, fit=fit, backend_path=chain_path)
    block = _block(post)
    block["chain"] = str(chain_path.relative_to(run_dir))
    if caught:
        block["warning"] = str(caught[-1].message)
        for w in caught:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if figures:
        from ..plots import plot_posterior  # matplotlib loads only when figures are asked for

        paths = plot_posterior(post.samples, post.chain, post.names, session.source.stem, run_dir / "figures")
        block["_figures"] = [str(p.relative_to(run_dir)) for p in paths]
    return block, post


@contextlib.contextmanager
def _stage(name: str, stages: list[dict], verbose: bool, placement: Placement):
    """Run a stage of one session (latency-bound: one fit, one chain) where ``placement`` puts it;
    time it and what JAX compiled in it, and append the record, with its device, to ``stages``."""
    with placement.stage(StageKind.LATENCY) as device, stage(name, verbose, stages, device) as log:
        yield log


def _simulation_methods(
    session: Session,
    config: ExperimentConfig,
    options: EstimatorOptions,
    run_dir: Path,
    stages: list[dict],
    verbose: bool,
    rig=None,
):
    """Run ``fit`` and ``bayes`` (those in the config) on one session: per method, (results block,
    result or None). bayes starts from the fit when it converged; each method is a timed stage,
    placed by the config's device request. With a ``rig`` (``shelljax.rig``), both go through it.

    A failure is recorded in the block (``error``) and reported, not raised: one bad session must
    not lose the others' results.
    """
    methods = [m for m in ("fit", "bayes") if m in config.methods]
    placement = requested_placement(config.device)
    model = options_forward_model(session, options) if methods and rig is None else None
    if "bayes" in methods and model is not None and options.surrogate:
        with placement.stage(StageKind.LATENCY):  # compiled for the device the chain runs on
            compile_posterior_ahead(session, model, n_walkers=options.walkers, nuisance=options.nuisance)
    out, fit = {}, None
    for method in methods:
        try:
            with _stage(f"{session.source.name}: {method}", stages, verbose, placement):
                if rig is not None:
                    result = estimate_with_rig(session, rig, method=method, seed=config.estimator_options.seed)
                    out[method] = (_block(result), result)
                elif method == "fit":
                    fit = run_estimator("fit", session, options, model=model)
                    out[method] = (_block(fit), fit)
                else:
                    out[method] = _bayes_block(session, options, model, fit, run_dir, config.figures)
        except ShelljaxError as err:
            warnings.warn(f"{method} failed on {session.source}: {err}", stacklevel=2)
            out[method] = ({"error": f"{type(err).__name__}: {err}"}, None)
    return out


def _plotted(estimates: dict[str, Estimate | None]) -> dict:
    return {"gauge_pressure": estimates.get("gauge_pressure"), "young_modulus": estimates.get("young_modulus")}


def _estimate_session_entry(
    session: Session,
    config: ExperimentConfig,
    options: EstimatorOptions,
    run_dir: Path,
    used_in_calibration: bool,
    held_out: list,
    stages: list[dict],
    verbose: bool,
    rig=None,
):
    """Every configured estimator on one session: (results.json entry, summary-figure row); a
    held-out manometer point of the calibration figure is appended to ``held_out``."""
    entry = {
        "object": session.object_name,
        "session": str(session.source),
        "used_in_calibration": used_in_calibration,
        "input_files": session.input_files,
        "inputs": _session_inputs(session),
        "estimates": {},
        "figures": [],
    }
    row = {"label": session.source.stem, "manometer": session.manometer_gauge_pressure, "estimates": {}}
    closed = run_estimator("closed-form", session, options)
    model_curves: dict[str, np.ndarray] = {}
    if "closed-form" in config.methods:
        entry["estimates"]["closed-form"] = _block(closed)
        row["estimates"]["closed-form"] = _plotted(closed.estimates)
        manometer = session.manometer_gauge_pressure
        if manometer is not None and not used_in_calibration:
            held_out.append((session.object_name, manometer, closed.pressure_slope.value, closed.pressure_slope.std))
    for method, (block, result) in _simulation_methods(session, config, options, run_dir, stages, verbose, rig).items():
        entry["estimates"][method] = block
        if result is not None:
            row["estimates"][method] = _plotted(result.estimates)
            entry["figures"] += block.pop("_figures", [])
            if method == "fit" and rig is None:
                model_curves[f"{method}: {config.estimator_options.forward_model} model"] = result.predicted_depth
    if session.manometer_gauge_pressure is not None:
        for method, estimates in row["estimates"].items():
            error = estimates["gauge_pressure"].value / session.manometer_gauge_pressure - 1.0
            entry["estimates"][method]["gauge_pressure_relative_error_vs_manometer"] = error
    if config.figures:
        from ..plots import plot_force_depth  # matplotlib loads only when figures are asked for

        fig = plot_force_depth(
            session, closed, run_dir / "figures" / f"force_depth_{session.source.stem}.png", model_curves=model_curves
        )
        entry["figures"].append(str(fig.relative_to(run_dir)))
    return entry, row


def estimate_session_item(
    session_path: str,
    config: ExperimentConfig,
    options: EstimatorOptions,
    run_dir: str,
    used_in_calibration: bool,
    verbose: bool,
) -> dict:
    """The work item of one session: every configured method on it, its figures written into
    ``run_dir``; returns ``{"entry", "row", "held_out", "stages"}`` as JSON (estimates as dicts)."""
    session = load_session(session_path)
    rig = None if config.rig is None else load_rig(config.rig)
    held_out: list = []
    stages: list[dict] = []
    with requested_placement(config.device).stage(StageKind.LATENCY):  # the closed form; fit and bayes place their own
        entry, row = _estimate_session_entry(
            session, config, options, Path(run_dir), used_in_calibration, held_out, stages, verbose, rig
        )
    release_compiled_programs_if_crowded()  # bayes compiles programs per session; they accumulate
    row = {
        **row,
        "estimates": {
            method: {name: None if e is None else e.to_dict() for name, e in pair.items()}
            for method, pair in row["estimates"].items()
        },
    }
    return {"entry": entry, "row": row, "held_out": [list(h) for h in held_out], "stages": stages}


def summary_row(row: dict) -> dict:
    """A summary-figure row of :func:`estimate_session_item`'s JSON, its estimates as :class:`Estimate`."""
    return {
        **row,
        "estimates": {
            method: {name: None if e is None else Estimate.from_dict(e) for name, e in pair.items()}
            for method, pair in row["estimates"].items()
        },
    }


def failed_entry(session: Session, used_in_calibration: bool, error: str) -> dict:
    """The results.json entry of a session whose work item failed: its inputs and the error."""
    return {
        "object": session.object_name,
        "session": str(session.source),
        "used_in_calibration": used_in_calibration,
        "input_files": session.input_files,
        "inputs": _session_inputs(session),
        "estimates": {},
        "figures": [],
        "error": error,
    }
