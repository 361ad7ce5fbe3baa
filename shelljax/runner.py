"""Run an experiment config into a fresh run directory: results.json + figures."""

from __future__ import annotations

import datetime as _dt
import json
import platform
import shutil
from pathlib import Path

from tqdm.auto import tqdm

from . import __version__
from .config import ExperimentConfig, load_config
from .estimate import PAPER_KS, PAPER_KS_STD, Estimate, calibrate_ks, estimate_session
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
        if "closed-form" in config.methods:
            result = estimate_session(session, k_s=k_s, through_origin=config.through_origin,
                                      bootstrap_samples=config.bootstrap_samples, seed=config.seed)  # fmt: skip
            block = {name: est.to_dict() for name, est in result.estimates().items()}
            block["bootstrap"] = {name: est.to_dict() for name, est in result.bootstrap.items()}
            block["regression"] = {"slope": {"value": result.regression.slope, "std": result.regression.slope_std, "unit": "N/m"},
                                   "intercept": {"value": result.regression.intercept, "std": result.regression.intercept_std, "unit": "N"},
                                   "residual_std": {"value": result.regression.residual_std, "unit": "N"}}  # fmt: skip
            entry["estimates"]["closed-form"] = block
            manometer = session.manometer_gauge_pressure
            if manometer is not None:
                entry["gauge_pressure_relative_error_vs_manometer"] = result.gauge_pressure.value / manometer - 1.0
                if not entry["used_in_calibration"]:
                    held_out.append((session.object_name, manometer, result.pressure_slope.value, result.pressure_slope.std))
            summary_rows.append({"label": session.source.stem, "gauge_pressure": result.gauge_pressure,
                                 "young_modulus": result.young_modulus, "manometer": manometer})  # fmt: skip
            if config.figures:
                from .plots import plot_force_depth

                fig = plot_force_depth(session, result, figures_dir / f"force_depth_{session.source.stem}.png")
                entry["figures"].append(str(fig.relative_to(run_dir)))
        results["sessions"].append(entry)

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
