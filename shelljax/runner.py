"""Run an experiment config into a fresh run directory: results.json + figures."""

from __future__ import annotations

import datetime as _dt
import json
import platform
import shutil
import warnings
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from . import __version__
from ._errors import ShelljaxError
from ._memory_mappings import release_compiled_programs_if_crowded
from .config import ExperimentConfig, load_config
from .estimate import (
    PAPER_KS,
    PAPER_KS_STD,
    ConvergenceWarning,
    Estimate,
    SurrogateWarning,
    calibrate_ks,
    estimate_session,
    fit_session,
    forward_model_for,
    sample_posterior,
)
from .session import Session, file_sha256, load_session


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


def _closed_form_block(result) -> dict:
    block = {name: est.to_dict() for name, est in result.estimates().items()}
    block["bootstrap"] = {name: est.to_dict() for name, est in result.bootstrap.items()}
    block["regression"] = {"slope": {"value": result.regression.slope, "std": result.regression.slope_std, "unit": "N/m"},
                           "intercept": {"value": result.regression.intercept, "std": result.regression.intercept_std, "unit": "N"},
                           "residual_std": {"value": result.regression.residual_std, "unit": "N"}}  # fmt: skip
    return block


def _simulation_method(method: str, session: Session, config: ExperimentConfig, run_dir: Path):
    """Run ``fit`` or ``bayes`` on one session: (results block, plotted estimates, model depths [m]).

    A failure is recorded in the block (``error``) and reported, not raised: one bad session must
    not lose the others' results.
    """
    options = {"gas": config.gas, "wrinkle_law": config.wrinkle_law} if config.forward_model == "axisym" else {}
    model = forward_model_for(session, config.forward_model, **options)
    try:
        if method == "fit":
            result = fit_session(session, model, nuisance=config.nuisance)
            block = {name: est.to_dict() for name, est in result.estimates.items()}
            block.update(chi2=result.chi2, dof=result.dof, iterations=result.steps,
                         predicted_wrinkle_count=result.predicted_wrinkle_count,
                         depth_noise={"value": result.problem.depth_noise, "unit": "m"})  # fmt: skip
            return block, _plotted(result.estimates), result.predicted_depth
        chains = run_dir / "chains"
        chains.mkdir(exist_ok=True)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", ConvergenceWarning)
            warnings.simplefilter("always", SurrogateWarning)
            post = sample_posterior(session, model, nuisance=config.nuisance, n_walkers=config.bayes_walkers,
                                    max_steps=config.bayes_max_steps, backend_path=chains / f"{session.source.stem}.h5",
                                    seed=config.seed, surrogate=config.bayes_surrogate)  # fmt: skip
        block = {name: {**est.to_dict(), "ci68": list(post.intervals68[name])} for name, est in post.estimates.items()}
        block.update(converged=post.converged, steps=post.n_steps, effective_samples=post.effective_samples,
                     autocorr_time={"value": post.autocorr_time, "unit": "steps"},
                     failed_forward_solves=post.failed_forward, acceptance_fraction=post.acceptance_fraction,
                     chain=str((chains / f"{session.source.stem}.h5").relative_to(run_dir)))  # fmt: skip
        if post.surrogate is not None:
            block["surrogate"] = post.surrogate
        if caught:
            block["warning"] = str(caught[-1].message)
            for w in caught:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        if config.figures:
            from .plots import plot_posterior

            paths = plot_posterior(post.samples, post.chain, post.names, session.source.stem, run_dir / "figures")
            block["_figures"] = [str(p.relative_to(run_dir)) for p in paths]
        return block, _plotted(post.estimates), None
    except ShelljaxError as err:
        warnings.warn(f"{method} failed on {session.source}: {err}", stacklevel=2)
        return {"error": f"{type(err).__name__}: {err}"}, None, None


def _plotted(estimates: dict[str, Estimate]) -> dict:
    return {"gauge_pressure": estimates["gauge_pressure"], "young_modulus": estimates["young_modulus"]}


def run_experiment(config_path: str | Path, *, output_dir: str | Path | None = None, progress: bool | None = None) -> Path:
    """Run the experiment config at ``config_path``; return the run directory.

    Every session is loaded and validated before anything is written, so a bad input fails the run
    without leaving a half-written directory. ``progress``: None shows a bar on a terminal only.
    """
    config = load_config(config_path)
    disable = None if progress is None else not progress
    calibration_sessions = [load_session(p) for p in config.calibration_sessions]
    sessions = [load_session(p) for p in tqdm(config.sessions, desc="loading sessions", disable=disable)]

    if calibration_sessions:
        calibration = calibrate_ks(calibration_sessions, through_origin=config.through_origin)
        k_s = calibration.k_s
    else:
        calibration = None
        if config.k_s is not None:
            k_s = Estimate.lognormal(config.k_s, (config.k_s_std or 0.0) / config.k_s, "1", "given in config")
        else:
            k_s = Estimate.lognormal(PAPER_KS, PAPER_KS_STD / PAPER_KS, "1", "paper's calibrated value (Section 4.1)")

    run_dir = _fresh_run_dir(config, None if output_dir is None else Path(output_dir))
    shutil.copy2(config.source, run_dir / "config.toml")
    figures_dir = run_dir / "figures"
    results: dict = {
        "shelljax_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "machine": platform.platform(),
        "config": {"path": str(config.source), "sha256": file_sha256(config.source), "name": config.name,
                   "description": config.description, "methods": list(config.methods),
                   "bootstrap_samples": config.bootstrap_samples, "seed": config.seed},  # fmt: skip
        "units": "SI: Pa, m, N, kg; '1' marks dimensionless quantities",
        "k_s": k_s.to_dict(),
        "sessions": [],
    }
    summary_rows: list[dict] = []
    held_out: list[tuple[str, float, float, float]] = []
    calibration_files = {str(s.source) for s in calibration_sessions}
    for session in tqdm(sessions, desc="estimating", disable=disable):
        entry = {"object": session.object_name, "session": str(session.source),
                 "used_in_calibration": str(session.source) in calibration_files,
                 "input_files": session.input_files, "inputs": _session_inputs(session),
                 "estimates": {}, "figures": []}  # fmt: skip
        row = {"label": session.source.stem, "manometer": session.manometer_gauge_pressure, "estimates": {}}
        closed = estimate_session(session, k_s=k_s, through_origin=config.through_origin,
                                  bootstrap_samples=config.bootstrap_samples, seed=config.seed)  # fmt: skip
        model_curves: dict[str, np.ndarray] = {}
        if "closed-form" in config.methods:
            entry["estimates"]["closed-form"] = _closed_form_block(closed)
            row["estimates"]["closed-form"] = {"gauge_pressure": closed.gauge_pressure, "young_modulus": closed.young_modulus}
            manometer = session.manometer_gauge_pressure
            if manometer is not None and not entry["used_in_calibration"]:
                held_out.append((session.object_name, manometer, closed.pressure_slope.value, closed.pressure_slope.std))
        for method in ("fit", "bayes"):
            if method not in config.methods:
                continue
            block, estimates, curve = _simulation_method(method, session, config, run_dir)
            entry["estimates"][method] = block
            if estimates:
                row["estimates"][method] = estimates
                entry["figures"] += block.pop("_figures", [])
            if curve is not None:
                model_curves[f"{method}: {config.forward_model} model"] = curve
        if session.manometer_gauge_pressure is not None:
            for method, estimates in row["estimates"].items():
                error = estimates["gauge_pressure"].value / session.manometer_gauge_pressure - 1.0
                entry["estimates"][method]["gauge_pressure_relative_error_vs_manometer"] = error
        summary_rows.append(row)
        if config.figures:
            from .plots import plot_force_depth

            fig = plot_force_depth(session, closed, figures_dir / f"force_depth_{session.source.stem}.png",
                                   model_curves=model_curves)  # fmt: skip
            entry["figures"].append(str(fig.relative_to(run_dir)))
        results["sessions"].append(entry)
        release_compiled_programs_if_crowded()  # each object compiles its own engine

    if calibration is not None:
        results["calibration"] = {
            "k_s": calibration.k_s.to_dict(),
            "points": [{"session": src, "object": obj, "manometer_gauge_pressure": {"value": float(p), "unit": "Pa"},
                        "pressure_slope": {"value": float(ph), "std": float(sd), "unit": "Pa"}}
                       for src, obj, p, ph, sd in zip(calibration.sources, calibration.objects, calibration.gauge_pressures,
                                                      calibration.pressure_slopes, calibration.pressure_slope_stds)],
        }  # fmt: skip
    if config.figures:
        from .plots import plot_calibration, plot_estimate_summary

        if calibration is not None:
            plot_calibration(calibration, held_out, figures_dir / "calibration.png")
            results["calibration"]["figure"] = "figures/calibration.png"
        if summary_rows:
            plot_estimate_summary(summary_rows, figures_dir / "estimates.png")
            results["summary_figure"] = "figures/estimates.png"
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
