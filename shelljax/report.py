"""Writing results to disk: the diagnosis's JSON and figure, and each command's ``report.md``.

A ``report.md`` holds what the command printed (the table, the verdict, the impacts) and its figures
inline, linked relative to the report, so a run directory can be shared as one folder.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ._errors import InvalidInputError
from ._files import atomic_write, atomic_write_text


def jsonable(value):
    """``value`` with numpy scalars and arrays as Python ones and non-finite floats as None."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def write_diagnosis(diagnosis, out_dir: str | Path) -> list[Path]:
    """Write ``diagnosis.json``, ``diagnosis.png`` and ``report.md`` into ``out_dir`` (created).

    The files are written to temporary names and renamed once complete, so an interrupted run
    leaves no half-written file.
    """
    from .plots import plot_diagnosis

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InvalidInputError(f"--out {out}: exists and is not a directory. Fix: name a directory")
    out.mkdir(parents=True, exist_ok=True)
    return [
        atomic_write_text(out / "diagnosis.json", json.dumps(jsonable(diagnosis.report), indent=2)),
        atomic_write(out / "diagnosis.png", lambda path: plot_diagnosis(diagnosis, path)),
        atomic_write_text(out / "report.md", diagnosis_markdown(diagnosis.report)),
    ]


def _image(path: str, caption: str) -> str:
    return f"![{Path(path).stem}]({Path(path).as_posix()})\n\n*{caption}*\n"


def summary_text(report: dict) -> str:
    """A few lines a person reads: verdict, ranking, gap before and after, misfit groups (``shelljax diagnose``)."""
    lines = [f"verdict: {report['verdict']}"]
    if report.get("search"):
        lines.append(f"search (each step beat the last by the margin): {' -> '.join(report['search'])}")
    width = max([26] + [len(e["effect"]) for e in report["ranking"]])  # a combination's name is long
    lines.append(f"{'model':>{width}s} {'elpd_loo':>10s} {'± se':>7s} {'Δ vs baseline':>14s} {'± se':>7s}  parameters")
    for e in report["ranking"]:
        if e["status"] != "ok":
            lines.append(f"{e['effect']:>{width}s}  FAILED: {e['message']}")
            continue
        params = ", ".join(
            f"{k} = {v['value']:.4g} {v['unit']} [{v['ci95'][0]:.3g}, {v['ci95'][1]:.3g}]"
            for k, v in e.get("parameters", {}).items()
        )
        lines.append(
            f"{e['effect']:>{width}s} {e['score']:10.2f} {e['score_se']:7.2f} {e['delta']:14.2f} "
            f"{e['delta_se']:7.2f}  {params}"
        )
    lines.append(
        f"gap (held-out rms of standardized residuals): {report['gap_before']['rms_standardized']:.3g} before, "
        f"{report['gap_after']['rms_standardized']:.3g} after, shrink {report['shrink']:.3g}x"
    )
    for name, g in report["gap_before"]["by_observable"].items():
        after = report["gap_after"]["by_observable"][name]
        lines.append(
            f"  {name:>18s}: rms {g['rms']:.3g} -> {after['rms']:.3g} {g['unit']} "
            f"({g['rms_percent']:.3g} % -> {after['rms_percent']:.3g} % of the measured value)"
        )
    kept = report.get("not_excluded") or []
    if len(kept) > 1:
        lines.append(
            f"not excluded (within {report['decision']['win_nats']:g} nats / {report['decision']['win_se']:g} SE "
            f"of the best): {', '.join(k['effect'] for k in kept)}"
        )
        e = report["robust"]["young_modulus"]
        lines.append(
            f"  E over them: {e['range95'][0]:.4g} … {e['range95'][1]:.4g} Pa (95 %), point values spread "
            f"{e['spread_percent']:.1f} %"
        )
        for s in report.get("separating", [])[:4]:
            lines.append(f"  to separate {s['effect']}: {s['measurement']}")
    if report.get("robust", {}).get("warning"):
        lines.append(f"warning: {report['robust']['warning']}")
    misfit = report["where"]["misfit_groups"]
    lines.append(
        "baseline misfit (p < {:g}): {}".format(report["where"]["misfit_threshold_p"], ", ".join(misfit) or "none")
    )
    return "\n".join(lines)


def diagnosis_markdown(report: dict) -> str:
    """``report.md`` of ``shelljax diagnose``: the verdict, the ranking as printed, the figure."""
    return "\n".join(
        [
            "# Diagnosis: the sim-to-real gap",
            "",
            f"**Verdict:** {report['verdict']}",
            "",
            "```text",
            summary_text(report),
            "```",
            "",
            _image("diagnosis.png", "where the baseline misfits, which effect explains it, how far the gap shrinks"),
            "Everything in numbers: [diagnosis.json](diagnosis.json).",
            "",
        ]
    )


_SESSION_FIGURES = (
    ("force_depth", "force against indentation depth: trials, the OLS line (closed form) and the fitted model"),
    ("corner", "posterior (bayes): marginals and pairs, 2.5 / 50 / 97.5 % quantiles dashed"),
    ("trace", "MCMC trace of every walker (the sampler's log-scaled coordinates)"),
)


def _kind(figure: str) -> str | None:
    return next((k for k, _ in _SESSION_FIGURES if Path(figure).stem.startswith(k + "_")), None)


def write_run_report(results: dict, run_dir: str | Path, table: str) -> Path:
    """``report.md`` of ``shelljax run`` in ``run_dir``: the config, the table as printed, every figure inline."""
    run_dir = Path(run_dir)
    config = results["config"]
    lines = [
        f"# Run `{config['name']}`",
        "",
        config.get("description") or "",
        "",
        f"shelljax {results['shelljax_version']}, {results['created']}, config `{config['path']}` "
        f"(copy: [config.toml](config.toml)); everything in numbers: [results.json](results.json).",
        "",
        "## Estimates",
        "",
        "```text",
        table,
        "```",
        "",
    ]
    if results.get("summary_figure"):
        lines.append(_image(results["summary_figure"], "estimates of every session and method"))
    if results.get("calibration", {}).get("figure"):
        lines.append(_image(results["calibration"]["figure"], "the k_s calibration"))
    for entry in results["sessions"]:
        if entry["figures"]:
            lines += [f"## {Path(entry['session']).stem} ({entry['object']})", ""]
            order = sorted(
                entry["figures"], key=lambda f: [k for k, _ in _SESSION_FIGURES].index(_kind(f)) if _kind(f) else 9
            )
            lines += [_image(f, dict(_SESSION_FIGURES).get(_kind(f), Path(f).stem.replace("_", " "))) for f in order]
    return atomic_write_text(run_dir / "report.md", "\n".join(lines) + "\n")


_IMPACT_HEADER = (
    "| run | plane | onset [s] | COR | contact [ms] | peak force [N] | compression [mm] | contact diameter [mm] |\n"
    "|---|---|---:|---:|---:|---:|---:|---:|"
)
_RUN_FIGURES = (
    ("preview.gif", "the run: faces coloured by membrane strain, contact dark; time, contact force, gauge pressure"),
    ("figures/closeup.png", "the largest contact patch, seen through the plane"),
    ("figures/max_deformation.png", "free and most deformed cross-sections"),
    ("figures/contact_force.png", "contact force"),
    ("figures/energies.png", "energies"),
    ("figures/trajectory.png", "centre of mass against time"),
)
_SCENARIO_FIGURES = {
    "max_deformation.png": "the most deformed cross-section of every run, overlaid with the free shape",
    "trajectory.png": "the centre of mass's trajectory with the planes",
    "keyframes.png": "the swing: the object at a few moments, coloured by its distance from the rigid swing",
}


def _relative(path: str, root: Path) -> str:
    return Path(os.path.relpath(Path(path).resolve(), root.resolve())).as_posix()


def scenario_markdown(summary: dict, out: Path) -> str:
    """``report.md`` of ``shelljax simulate``: parameters, impacts, the scenario's and every run's figures."""
    p = summary["parameters"]
    lines = [
        f"# Scenario `{summary['name']}`",
        "",
        f"Config `{summary['scenario']}`; parameters: {summary['object'].get('parameters', '')}; "
        "everything in numbers: [scenario.json](scenario.json).",
        "",
        "| P_g [Pa] | E [Pa] | ν | h [mm] | m [kg] | gas | faces | Δt [s] | scheme | contact damping [N·s/m] |",
        "|---:|---:|---:|---:|---:|---|---:|---:|---|---:|",
        f"| {p['gauge_pressure_Pa']:.5g} | {p['youngs_modulus_Pa']:.4g} | {p['poisson_ratio']:.3g} | {1e3 * p['thickness_m']:.3g} | "
        f"{p['mass_kg']:.4g} | {p['gas']} | {p['mesh_faces']} | {p['dt_s']:.3g} | {p['scheme']} | {summary['contact_damping_N_s_per_m']:.4g} |",
        "",
    ]
    if summary.get("calibration"):
        c = summary["calibration"]
        lines += [
            f"Contact damping calibrated to COR {c['target_cor']} (got {c['cor']:.4f}) in {len(c['evaluations'])} drops.",
            "",
        ]
    lines += ["## Impacts", "", _IMPACT_HEADER]
    notes = []
    for run in summary["runs"]:
        label = f"drop {run['drop_height_m']:.3g} m" if "drop_height_m" in run else "swing"
        for m in run["impacts"]:
            lines.append(
                f"| {label} | {m['plane']} | {m['onset_s']:.4f} | {m['cor']:.4f} | {1e3 * m['contact_time_s']:.2f} | "
                f"{m['peak_force_N']:.4g} | {1e3 * m['max_compression_m']:.2f} | {1e3 * m['max_contact_diameter_m']:.1f} |"
            )
        if "max_deviation_from_rigid_m" in run:
            notes += [
                "",
                f"Swing: held vertices on the schedule to {run['held_error_m']:.2g} m; largest departure from the rigid "
                f"swing {1e3 * run['max_deviation_from_rigid_m']:.1f} mm at t = {run['time_of_max_deviation_s']:.3f} s; "
                f"peak gauge pressure {run['peak_gas_pressure_Pa']:.5g} Pa.",
                "",
            ]
    if not any(run["impacts"] for run in summary["runs"]):
        lines.append("| (no impact: nothing left a plane within the run) | | | | | | | |")
    lines += notes
    lines.append("")
    for name in summary.get("figures", []):
        lines.append(_image(name, _SCENARIO_FIGURES.get(name, name)))
    for run in summary["runs"]:
        label = f"drop {run['drop_height_m']:.3g} m" if "drop_height_m" in run else "swing"
        rel = _relative(run["directory"], out)
        lines += [f"## {label}", "", f"[results.json]({rel}/results.json)", ""]
        lines += [
            _image(f"{rel}/{f}", caption) for f, caption in _RUN_FIGURES if (Path(run["directory"]) / f).is_file()
        ]
    return "\n".join(lines) + "\n"


def write_scenario_report(summary: dict, out_dir: str | Path) -> Path:
    """Write ``report.md`` of a scenario's summary into ``out_dir``."""
    out = Path(out_dir)
    return atomic_write_text(out / "report.md", scenario_markdown(summary, out))
