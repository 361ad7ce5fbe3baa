"""Run an experiment config into a fresh run directory: results.json + figures."""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as _dt
import json
import platform
import shutil
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from .. import __version__
from .._errors import ShelljaxError
from ..config import ExperimentConfig, load_config
from ..estimate import (
    ConvergenceWarning,
    Estimate,
    EstimatorOptions,
    SurrogateWarning,
    calibrate_ks,
    options_forward_model,
    paper_k_s,
    run_estimator,
)
from ..rig import estimate_with_rig, load_rig
from ..session import Session, file_sha256, load_session
from ._compile_log import compile_log
from ._memory_mappings import release_compiled_programs_if_crowded


def _fresh_run_dir(config: ExperimentConfig, output_dir: Path | None) -> Path:
    base = Path(output_dir) if output_dir is not None else config.output_dir
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    run_dir = base / f"{config.name}-{stamp}"
    k = 1
    while run_dir.exists():
        k += 1
        run_dir = base / f"{config.name}-{stamp}-{k}"
    (run_dir / "figures").mkdir(parents=True)
    return run_dir


def _session_inputs(session: Session) -> dict:
    inputs = {
        "radius": {"value": session.radius, "std": session.radius_std, "unit": "m",
                   "source": "mesh sphere fit" if session.mesh_path else "session file"},
        "thickness": {"value": session.thickness, "std": session.thickness_std, "unit": "m"},
        "poisson_ratio": {"value": session.poisson_ratio, "unit": "1"},
        "n_samples": int(session.force.size),
        "n_trials": int(session.trial_ids.size),
        "force_levels": {"value": session.force_levels.tolist(), "unit": "N"},
    }  # fmt: skip
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


def _estimator_options(config: ExperimentConfig, k_s: Estimate) -> EstimatorOptions:
    return dataclasses.replace(config.estimator_options, k_s=k_s)


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
def _stage(name: str, stages: list[dict], verbose: bool):
    """Time a stage of the run and what JAX compiled in it; append the record to ``stages``."""
    start = time.perf_counter()
    with compile_log() as log:
        yield
    wall = time.perf_counter() - start
    stages.append({"stage": name, "wall_seconds": wall, **log.to_dict()})
    if verbose:
        tqdm.write(f"{name}: {wall:.1f} s; {log.summary()}", file=sys.stderr)


def _simulation_methods(session: Session, config: ExperimentConfig, options: EstimatorOptions, run_dir: Path,
                        stages: list[dict], verbose: bool, rig=None):  # fmt: skip
    """Run ``fit`` and ``bayes`` (those in the config) on one session: per method, (results block,
    result or None). bayes starts from the fit when it converged; each method is a timed stage.
    With a ``rig`` (``shelljax.rig``), both go through it.

    A failure is recorded in the block (``error``) and reported, not raised: one bad session must
    not lose the others' results.
    """
    methods = [m for m in ("fit", "bayes") if m in config.methods]
    model = options_forward_model(session, options) if methods and rig is None else None
    out, fit = {}, None
    for method in methods:
        try:
            with _stage(f"{session.source.name}: {method}", stages, verbose):
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


def _calibration(config: ExperimentConfig, calibration_sessions: list[Session]):
    """(k_s calibration or None, the k_s [-] the closed form uses)."""
    if calibration_sessions:
        calibration = calibrate_ks(calibration_sessions, through_origin=config.estimator_options.through_origin)
        return calibration, calibration.k_s
    if config.k_s is not None:
        return None, Estimate.lognormal(config.k_s, (config.k_s_std or 0.0) / config.k_s, "1", "given in config")
    return None, paper_k_s()


def _results_header(config: ExperimentConfig, k_s: Estimate) -> dict:
    return {
        "shelljax_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "machine": platform.platform(),
        "config": {"path": str(config.source), "sha256": file_sha256(config.source), "name": config.name,
                   "description": config.description, "methods": list(config.methods),
                   "bootstrap_samples": config.estimator_options.bootstrap_samples, "seed": config.estimator_options.seed},  # fmt: skip
        "units": "SI: Pa, m, N, kg; '1' marks dimensionless quantities",
        "k_s": k_s.to_dict(),
        "sessions": [],
    }


def _estimate_session_entry(session: Session, config: ExperimentConfig, options: EstimatorOptions, run_dir: Path,
                            used_in_calibration: bool, held_out: list, stages: list[dict], verbose: bool,
                            rig=None):  # fmt: skip
    """Every configured estimator on one session: (results.json entry, summary-figure row)."""
    entry = {"object": session.object_name, "session": str(session.source),
             "used_in_calibration": used_in_calibration, "input_files": session.input_files,
             "inputs": _session_inputs(session), "estimates": {}, "figures": []}  # fmt: skip
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

        fig = plot_force_depth(session, closed, run_dir / "figures" / f"force_depth_{session.source.stem}.png",
                               model_curves=model_curves)  # fmt: skip
        entry["figures"].append(str(fig.relative_to(run_dir)))
    return entry, row


def _calibration_record(calibration) -> dict:
    return {
        "k_s": calibration.k_s.to_dict(),
        "points": [{"session": src, "object": obj, "manometer_gauge_pressure": {"value": float(p), "unit": "Pa"},
                    "pressure_slope": {"value": float(ph), "std": float(sd), "unit": "Pa"}}
                   for src, obj, p, ph, sd in zip(calibration.sources, calibration.objects, calibration.gauge_pressures,
                                                  calibration.pressure_slopes, calibration.pressure_slope_stds)],
    }  # fmt: skip


def run_experiment(config_path: str | Path, *, output_dir: str | Path | None = None, progress: bool | None = None,
                   verbose: bool = False) -> Path:  # fmt: skip
    """Run the experiment config at ``config_path``; return the run directory.

    Every session is loaded and validated before anything is written, so a bad input fails the run
    without leaving a half-written directory. ``progress``: None shows a bar on a terminal only;
    ``verbose``: print each stage's wall time and what JAX compiled in it (results.json has it always).
    """
    config = load_config(config_path)
    disable = None if progress is None else not progress
    calibration_sessions = [load_session(p) for p in config.calibration_sessions]
    sessions = [load_session(p) for p in tqdm(config.sessions, desc="loading sessions", disable=disable)]
    calibration, k_s = _calibration(config, calibration_sessions)
    options = _estimator_options(config, k_s)
    rig = None if config.rig is None else load_rig(config.rig)

    run_dir = _fresh_run_dir(config, None if output_dir is None else Path(output_dir))
    shutil.copy2(config.source, run_dir / "config.toml")
    results = _results_header(config, k_s)
    if config.rig is not None:
        results["rig"] = {"path": str(config.rig), "sha256": file_sha256(config.rig)}
    summary_rows: list[dict] = []
    held_out: list[tuple[str, float, float, float]] = []
    calibration_files = {str(s.source) for s in calibration_sessions}
    stages: list[dict] = []
    for session in tqdm(sessions, desc="estimating", disable=disable):
        entry, row = _estimate_session_entry(session, config, options, run_dir, str(session.source) in calibration_files,
                                             held_out, stages, verbose=verbose, rig=rig)  # fmt: skip
        summary_rows.append(row)
        results["sessions"].append(entry)
        release_compiled_programs_if_crowded()  # bayes compiles programs per session; they accumulate

    if calibration is not None:
        results["calibration"] = _calibration_record(calibration)
    if config.figures:
        from ..plots import plot_calibration, plot_estimate_summary  # matplotlib loads only when figures are asked for

        if calibration is not None:
            plot_calibration(calibration, held_out, run_dir / "figures" / "calibration.png")
            results["calibration"]["figure"] = "figures/calibration.png"
        if summary_rows:
            plot_estimate_summary(summary_rows, run_dir / "figures" / "estimates.png")
            results["summary_figure"] = "figures/estimates.png"
    results["compilation"] = {"stages": stages, "unit": "s",
                              "total_seconds": sum(s["total_seconds"] for s in stages)}  # fmt: skip
    (run_dir / "results.json").write_text(json.dumps(results, indent=2))
    return run_dir


def _cell(block: dict, quantity: str, scale: float) -> str:
    if quantity not in block:
        return "failed" if "error" in block else ""
    est = block[quantity]
    return f"{est['value'] / scale:.4g} ± {est['std'] / scale:.2g}"


def summary_table(results: dict) -> str:
    """Plain-text table of P_g [kPa] and E [MPa] (value ± std) per session and method, side by side.

    ``results``: the dict written to ``results.json``. Sessions used in the k_s calibration are
    left out (their pressures are known); the manometer column shows held-out truths.
    """
    methods = list(results["config"]["methods"])
    header = ["session", "manometer P_g [kPa]"] + [f"P_g {m} [kPa]" for m in methods] + [f"E {m} [MPa]" for m in methods]
    rows = []
    for entry in results["sessions"]:
        if entry["used_in_calibration"]:
            continue
        manometer = entry["inputs"].get("manometer_gauge_pressure")
        row = [Path(entry["session"]).stem, f"{manometer['value'] / 1e3:.4g}" if manometer else ""]
        blocks = [entry["estimates"].get(m, {}) for m in methods]
        row += [_cell(b, "gauge_pressure", 1e3) for b in blocks] + [_cell(b, "young_modulus", 1e6) for b in blocks]
        rows.append(row)
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in [header, *rows]]
    lines.insert(1, "  ".join("-" * w for w in widths))
    k_s = results["k_s"]
    lines.append(f"closed form with k_s = {k_s['value']:.3g} ± {k_s['std']:.2g} ({k_s['method']}); "
                 "fit/bayes need no k_s; failures are explained in results.json")  # fmt: skip
    return "\n".join(lines)
