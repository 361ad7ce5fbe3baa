"""A scenario's ``[sweep]``: one whole scenario per value of one parameter, each a work item.

Each value is a work item (``shelljax.executor``) that runs :func:`run_scenario` on the config
with the parameter set to that value, into ``<out>/<key>_<value>/``, in-process or on Dask
workers; ``<out>/items/`` keeps each finished value's record and ``<out>/sweep.json`` the table
of all of them (a failed value with its error). Each value's run is the same computation wherever
it runs, so ``--workers N`` gives the serial sweep's values.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from .._errors import InvalidInputError
from .._files import atomic_write_text, check_output_dir
from ..executor import ExecutorOptions, WorkItem, check_executor, check_inputs, run_items
from ..session import file_sha256
from ._load import Scenario, load_scenario
from ._run import run_scenario

SWEEP_SUMMARY = "sweep.json"
_UNITS = {"_Pa": "Pa", "_kg": "kg", "_m": "m", "_s": "s", "_N_s_per_m": "N·s/m"}


def parameter_unit(parameter: str) -> str:
    """The SI unit of a sweep parameter, from its key's suffix ("1" for a dimensionless one)."""
    return next((unit for suffix, unit in _UNITS.items() if parameter.endswith(suffix)), "1")


def value_directory(parameter: str, value: float) -> str:
    """The directory name of one value's scenario, e.g. ``gauge_pressure_Pa_1300``."""
    return f"{parameter.split('.')[1]}_{value:g}"


def simulate_sweep_value(
    config: str, value: float, out_dir: str, session: str | None = None, device: str = "auto"
) -> dict:
    """The work item of one sweep value: the config's scenario with the parameter at ``value``,
    run into ``out_dir`` with the sweep's ``device`` request (it may differ from the config's:
    ``--device``); returns the summary :func:`run_scenario` writes (JSON)."""
    scenario = dataclasses.replace(load_scenario(config, value=value), device=device)
    return run_scenario(scenario, out_dir, session=session, progress=False)


def _row(value: float, result) -> dict:
    """One value's line of sweep.json: where it ran, its contact damping [N·s/m] and each run's impacts."""
    row = {
        "value": value,
        "status": result.status,
        "seconds": result.seconds,
        "worker": result.worker,
        "resumed": result.resumed,
    }
    if result.status != "done":
        return {**row, "error": result.error}
    summary = result.value
    return {
        **row,
        "directory": str(Path(summary["runs"][0]["directory"]).parent) if summary["runs"] else None,
        "parameters": summary["parameters"],
        "contact_damping_N_s_per_m": summary["contact_damping_N_s_per_m"],
        "runs": [
            {k: v for k, v in run.items() if k in ("drop_height_m", "directory", "impacts")} for run in summary["runs"]
        ],
    }


def run_sweep(
    scenario: Scenario,
    out_dir: str | Path | None = None,
    *,
    session: str | Path | None = None,
    executor: ExecutorOptions | None = None,
    progress: bool = True,
    resume: bool = False,
) -> dict:
    """Run every value of ``scenario.sweep`` (module docstring) into ``out_dir`` (default: the
    config's output_dir/name); return what it writes to ``sweep.json``. ``resume``: run only the
    values ``out_dir`` has no finished record of (refused when its config or session has changed).

    Raises:
        InvalidInputError: a config without [sweep], bad executor options, an unreachable scheduler.
        KeyboardInterrupt: after cancelling the values in flight; the finished ones stay on disk.
    """
    if scenario.sweep is None:
        raise InvalidInputError(
            f'{scenario.source}: no [sweep] table to run. Fix: add [sweep] parameter = "..." '
            "and values = [...] (docs/cluster.md), or run the scenario itself"
        )
    sweep = scenario.sweep
    out = check_output_dir(out_dir if out_dir is not None else scenario.output_dir / scenario.name, "--out")
    executor = executor or ExecutorOptions()
    check_executor(executor)  # an unreachable cluster is refused before anything is written
    items = [
        WorkItem(
            f"value{i:03d}-{value_directory(sweep.parameter, v)}",
            simulate_sweep_value,
            (
                str(scenario.source),
                v,
                str(out / value_directory(sweep.parameter, v)),
                None if session is None else str(session),
                scenario.device,
            ),
        )
        for i, v in enumerate(sweep.values)
    ]
    check_inputs(
        out,
        {
            "config": str(Path(scenario.source).resolve()),
            "config_sha256": file_sha256(scenario.source),
            "session": None if session is None else str(Path(session).resolve()),
        },
        resume=resume,
        what="sweep",
    )
    results = run_items(
        items, run_dir=out, options=executor, resume=resume, progress=progress, desc=f"sweeping {sweep.parameter}"
    )
    summary = {
        "scenario": str(scenario.source),
        "name": scenario.name,
        "parameter": sweep.parameter,
        "unit": parameter_unit(sweep.parameter),
        "executor": executor.describe(),
        "values": [_row(v, r) for v, r in zip(sweep.values, results)],
    }
    atomic_write_text(out / SWEEP_SUMMARY, json.dumps(summary, indent=1))
    return summary


def sweep_table(summary: dict) -> str:
    """Plain text: per value and drop, the first impact's COR, contact time [ms], peak force [N] and
    compression [mm]; a failed value with its error."""
    head = f"{summary['parameter']} [{summary['unit']}]"
    header = [head, "drop [m]", "plane", "COR", "contact [ms]", "peak force [N]", "compression [mm]"]
    rows = []
    for entry in summary["values"]:
        if entry["status"] != "done":
            rows.append([f"{entry['value']:g}", "failed: " + entry["error"], "", "", "", "", ""])
            continue
        for run in entry["runs"]:
            drop = f"{run['drop_height_m']:.3g}" if "drop_height_m" in run else "swing"
            first = run["impacts"][0] if run["impacts"] else None
            rows.append(
                [f"{entry['value']:g}", drop]
                + (
                    ["no impact", "", "", "", ""]
                    if first is None
                    else [
                        first["plane"],
                        f"{first['cor']:.4f}",
                        f"{1e3 * first['contact_time_s']:.2f}",
                        f"{first['peak_force_N']:.4g}",
                        f"{1e3 * first['max_compression_m']:.2f}",
                    ]
                )
            )
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in [header, *rows]]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)
