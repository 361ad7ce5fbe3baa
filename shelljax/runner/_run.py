"""Run an experiment config into a fresh run directory: results.json, figures and report.md.

Each session is one work item (``_session.estimate_session_item``) run by ``shelljax.executor``,
in-process or on Dask workers; ``run.json`` in the run directory names the config (and its
sha256) so that an interrupted run can be resumed.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import platform
import shutil
import sys
import warnings
from pathlib import Path

from tqdm.auto import tqdm

from .. import __version__
from .._errors import InvalidInputError
from .._files import atomic_write_text, check_output_dir
from .._placement import StageKind, requested_placement
from ..config import ExperimentConfig, load_config
from ..estimate import Estimate, EstimatorOptions, calibrate_ks, paper_k_s
from ..executor import ExecutorOptions, WorkItem, check_executor, read_item, run_items
from ..report import write_run_report
from ..rig import load_rig
from ..session import Session, file_sha256, load_session
from ._session import estimate_session_item, failed_entry, summary_row

MANIFEST = "run.json"  # what an interrupted run needs to be resumed


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


def _estimator_options(config: ExperimentConfig, k_s: Estimate) -> EstimatorOptions:
    return dataclasses.replace(config.estimator_options, k_s=k_s)


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
        "config": {
            "path": str(config.source),
            "sha256": file_sha256(config.source),
            "name": config.name,
            "description": config.description,
            "methods": list(config.methods),
            "bootstrap_samples": config.estimator_options.bootstrap_samples,
            "seed": config.estimator_options.seed,
        },
        "units": "SI: Pa, m, N, kg; '1' marks dimensionless quantities",
        "k_s": k_s.to_dict(),
        "sessions": [],
    }


def _calibration_record(calibration) -> dict:
    return {
        "k_s": calibration.k_s.to_dict(),
        "points": [
            {
                "session": src,
                "object": obj,
                "manometer_gauge_pressure": {"value": float(p), "unit": "Pa"},
                "pressure_slope": {"value": float(ph), "std": float(sd), "unit": "Pa"},
            }
            for src, obj, p, ph, sd in zip(
                calibration.sources,
                calibration.objects,
                calibration.gauge_pressures,
                calibration.pressure_slopes,
                calibration.pressure_slope_stds,
            )
        ],
    }


def _session_items(
    config: ExperimentConfig,
    sessions: list[Session],
    options: EstimatorOptions,
    run_dir: Path,
    calibration_files: set[str],
    verbose: bool,
) -> list[WorkItem]:
    """One work item per session, keyed by its position and file name (unique in a run); its seeds
    are the config's, in ``options``, as in a serial run."""
    return [
        WorkItem(
            f"session{i:04d}-{s.source.stem}",
            estimate_session_item,
            (str(s.source), config, options, str(run_dir), str(s.source) in calibration_files, verbose),
        )
        for i, s in enumerate(sessions)
    ]


def _write_manifest(run_dir: Path, config: ExperimentConfig, items: list[WorkItem]) -> None:
    manifest = {
        "config": str(Path(config.source).resolve()),
        "config_sha256": file_sha256(config.source),
        "shelljax_version": __version__,
        "items": [item.key for item in items],
    }
    atomic_write_text(run_dir / MANIFEST, json.dumps(manifest, indent=1))


def _resumed_config(run_dir: Path, config_path: str | Path | None) -> Path:
    """The config of the interrupted run in ``run_dir``, checked unchanged since it started."""
    manifest_path = run_dir / MANIFEST
    if not manifest_path.exists():
        raise InvalidInputError(
            f"--resume {run_dir}: no {MANIFEST} there, so it is not a run directory shelljax can "
            "resume. Fix: give the directory `shelljax run` printed, or start a fresh run"
        )
    manifest = json.loads(manifest_path.read_text())
    original = Path(manifest["config"])
    if config_path is not None and Path(config_path).resolve() != original:
        raise InvalidInputError(
            f"--resume {run_dir}: that run is of {original}, not of {config_path}. Fix: leave the "
            "config out, or resume the run of this config"
        )
    if not original.exists() or file_sha256(original) != manifest["config_sha256"]:
        raise InvalidInputError(
            f"--resume {run_dir}: its config {original} is gone or has changed since the run "
            "started, so its finished sessions no longer answer it. Fix: start a fresh run"
        )
    return original


def _write_results(
    config: ExperimentConfig,
    k_s: Estimate,
    calibration,
    sessions: list[Session],
    calibration_files: set[str],
    done: list,
    where: tuple,
    run_dir: Path,
) -> None:
    """results.json, the run's figures and report.md from the sessions' item results, in config
    order; ``where``: (the executor's options, the device placement)."""
    results = _results_header(config, k_s)
    executor, placement = where
    results["executor"] = executor.describe()
    results["placement"] = placement.describe()
    if config.rig is not None:
        results["rig"] = {"path": str(config.rig), "sha256": file_sha256(config.rig)}
    summary_rows: list[dict] = []
    held_out: list[tuple[str, float, float, float]] = []
    stages: list[dict] = []
    for session, result in zip(sessions, done):
        if result.status != "done":
            warnings.warn(f"{session.source}: {result.error}", stacklevel=2)
            results["sessions"].append(failed_entry(session, str(session.source) in calibration_files, result.error))
            continue
        results["sessions"].append(result.value["entry"])
        summary_rows.append(summary_row(result.value["row"]))
        held_out += [tuple(h) for h in result.value["held_out"]]
        stages += result.value["stages"]
    results["items"] = [
        {
            "key": r.key,
            "status": r.status,
            "seconds": r.seconds,
            "worker": r.worker,
            "resumed": r.resumed,
            **({"error": r.error} if r.error else {}),
        }
        for r in done
    ]

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
    results["compilation"] = {"stages": stages, "unit": "s", "total_seconds": sum(s["total_seconds"] for s in stages)}
    atomic_write_text(run_dir / "results.json", json.dumps(results, indent=2))
    write_run_report(results, run_dir, summary_table(results))


def run_experiment(
    config_path: str | Path | None = None,
    *,
    output_dir: str | Path | None = None,
    progress: bool | None = None,
    verbose: bool = False,
    executor: ExecutorOptions | None = None,
    resume: str | Path | None = None,
    device: str | None = None,
) -> Path:
    """Run the experiment config at ``config_path``; return the run directory.

    Every session is loaded and validated before anything is written, so a bad input fails the run
    without leaving a half-written directory. Each session is a work item (``shelljax.executor``):
    ``executor`` says where they run (None: the config's [executor], else in-process), each finished
    one is recorded in the run directory, and ``resume`` (a run directory) finishes an interrupted
    run, skipping the sessions it finished. ``progress``: None shows a bar on a terminal only;
    ``verbose``: print each stage's wall time and what JAX compiled in it (results.json has it always).
    ``device``: ``auto``, ``cpu`` or ``gpu`` (None: the config's [compute] device), where each stage
    runs (``shelljax.Placement``, docs/gpu.md); the sessions' work items carry it to the workers.

    Raises:
        InvalidInputError: a bad config, session or option; a run directory that cannot be resumed.
        KeyboardInterrupt: after the sessions in flight are cancelled; the run directory is resumable.
    """
    if resume is not None:
        config_path = _resumed_config(Path(resume), config_path)
    elif config_path is None:
        raise InvalidInputError("no experiment config given. Fix: shelljax run configs/paper.toml, or --resume RUN_DIR")
    config = load_config(config_path)
    if device is not None:
        config = dataclasses.replace(config, device=device)
    placement = requested_placement(config.device)  # 'gpu' without one is refused before anything is written
    executor = executor or config.executor
    if resume is None:  # every output checked before any work; nothing is created until all are
        check_output_dir(
            config.output_dir if output_dir is None else output_dir,
            "--out" if output_dir is not None else f"{config.source}: output_dir",
        )
    check_executor(executor)  # an unreachable cluster is refused before the run directory exists
    disable = None if progress is None else not progress
    calibration_sessions = [load_session(p) for p in config.calibration_sessions]
    sessions = [load_session(p) for p in tqdm(config.sessions, desc="loading sessions", disable=disable)]
    with placement.stage(StageKind.LATENCY):  # the closed form's k_s calibration: a few small regressions
        calibration, k_s = _calibration(config, calibration_sessions)
    options = _estimator_options(config, k_s)
    if config.rig is not None:
        load_rig(config.rig)  # a bad rig file fails here, before anything is written

    calibration_files = {str(s.source) for s in calibration_sessions}
    if resume is None:
        run_dir = _fresh_run_dir(config, None if output_dir is None else Path(output_dir))
        shutil.copy2(config.source, run_dir / "config.toml")
    else:
        run_dir = Path(resume)
    items = _session_items(config, sessions, options, run_dir, calibration_files, verbose)
    if resume is None:
        _write_manifest(run_dir, config, items)
    try:
        done = run_items(
            items, run_dir=run_dir, options=executor, resume=resume is not None, progress=progress, desc="estimating"
        )
    except InvalidInputError:
        if resume is None:  # refused before any session ran: a fresh run leaves nothing behind
            shutil.rmtree(run_dir, ignore_errors=True)
        raise
    except KeyboardInterrupt:
        finished = sum(read_item(run_dir, item.key) is not None for item in items)
        tqdm.write(
            f"interrupted: {finished} of {len(items)} sessions finished in {run_dir}; finish the run with "
            f"`shelljax run --resume {run_dir}`",
            file=sys.stderr,
        )
        raise

    _write_results(config, k_s, calibration, sessions, calibration_files, done, (executor, placement), run_dir)
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
    header = (
        ["session", "manometer P_g [kPa]"] + [f"P_g {m} [kPa]" for m in methods] + [f"E {m} [MPa]" for m in methods]
    )
    rows = []
    for entry in results["sessions"]:
        if entry["used_in_calibration"]:
            continue
        manometer = entry["inputs"].get("manometer_gauge_pressure")
        row = [Path(entry["session"]).stem, f"{manometer['value'] / 1e3:.4g}" if manometer else ""]
        blocks = [entry["estimates"].get(m, {"error": entry["error"]} if "error" in entry else {}) for m in methods]
        row += [_cell(b, "gauge_pressure", 1e3) for b in blocks] + [_cell(b, "young_modulus", 1e6) for b in blocks]
        rows.append(row)
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in [header, *rows]]
    lines.insert(1, "  ".join("-" * w for w in widths))
    k_s = results["k_s"]
    lines.append(
        f"closed form with k_s = {k_s['value']:.3g} ± {k_s['std']:.2g} ({k_s['method']}); "
        "fit/bayes need no k_s; failures are explained in results.json"
    )
    return "\n".join(lines)
