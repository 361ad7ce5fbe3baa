"""`shelljax diagnose --study A --study B ...`: the sim-to-real diagnosis of many studies, one work item each.

A study is the sessions of one object: a directory (its ``*.toml``) or a glob pattern (``bundled:``
for the package's files). Each study is a work item (``shelljax.executor``) that diagnoses it and
writes ``<out>/<study>/diagnosis.json``, ``diagnosis.png`` and ``report.md``; ``<out>/items/``
keeps each finished study's record (atomically, as the runner's sessions) and
``<out>/diagnoses.json`` the table of all of them, a failed study with its error.
"""

from __future__ import annotations

import glob
import json
import re
from collections.abc import Sequence
from pathlib import Path

from .._errors import InvalidInputError
from .._files import atomic_write_text, check_output_dir
from ..config import bundled_data_dir
from ..estimate import DEFAULT_OPTIONS
from ..executor import ExecutorOptions, WorkItem, check_executor, check_inputs, run_items

SUMMARY = "diagnoses.json"


def diagnosis_baseline(rig: str | Path | None, gas: str | None, wrinkle_law: str | None):
    """(measuring-chain prior or None, gas law, wrinkle law) of a diagnosis with or without a rig
    file: the rig's chain is the baseline, and its gas and wrinkle law the model's."""
    if rig is None:
        return None, gas, wrinkle_law
    from ..rig import check_compatible, load_rig, rig_measurement

    loaded = load_rig(rig)
    check_compatible(loaded, gas=gas, wrinkle_law=wrinkle_law, where="the diagnosis")
    return rig_measurement(loaded), loaded.gas, loaded.wrinkle_law


def _study_name(spec: str) -> str:
    """A directory's name, or a pattern's file part without its wildcards (``calib_pezzi_*.toml`` → ``calib_pezzi``)."""
    path = Path(spec.removeprefix("bundled:"))
    name = path.name if not glob.has_magic(spec) else re.sub(r"[*?\[\]]+", "", path.name).removesuffix(".toml")
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._-") or "study"


def study_groups(specs: Sequence[str]) -> list[tuple[str, tuple[Path, ...]]]:
    """(name, session files) of each study spec: a directory (its ``*.toml``, sorted) or a glob
    pattern of session files (``bundled:`` for the package's); names made unique.

    Raises:
        InvalidInputError: a spec that names no session file.
    """
    groups, seen = [], {}
    for spec in specs:
        full = str(bundled_data_dir() / spec.removeprefix("bundled:")) if spec.startswith("bundled:") else spec
        files = sorted(Path(full).glob("*.toml")) if Path(full).is_dir() else sorted(map(Path, glob.glob(full)))
        if not files:
            raise InvalidInputError(
                f"--study {spec}: no session file there (looked for {full}{'/*.toml' if Path(full).is_dir() else ''}). "
                "Fix: name a directory of session TOML files, or a pattern such as 'dir/ball_*.toml'"
            )
        name = _study_name(spec)
        name = f"{name}-study" if name == "items" else name  # items/ holds the work items' records
        seen[name] = seen.get(name, 0) + 1
        groups.append((name if seen[name] == 1 else f"{name}-{seen[name]}", tuple(files)))
    return groups


def diagnose_study_item(
    paths: Sequence[str],
    out_dir: str,
    effects: Sequence[str] | None,
    baseline: str,
    gas: str | None,
    wrinkle_law: str | None,
    rig: str | None,
) -> dict:
    """The work item of one study: its diagnosis written into ``out_dir``; returns its summary row (JSON, SI)."""
    from ..diagnose import diagnose
    from ..report import jsonable, write_diagnosis

    measurement, gas, wrinkle_law = diagnosis_baseline(rig, gas, wrinkle_law)
    result = diagnose(
        list(paths),
        effects=effects,
        baseline=baseline,
        gas=gas,
        wrinkle_law=wrinkle_law or DEFAULT_OPTIONS.wrinkle_law,
        progress=False,
        measurement=measurement,
    )
    written = write_diagnosis(result, out_dir)
    report = result.report
    estimates = (report["winner"] or {}).get("estimates_after") or report["baseline"]["estimates"]
    best = next((e for e in report["ranking"] if e["status"] == "ok" and e["effect"] != "baseline"), None)
    return jsonable(
        {
            "verdict": report["verdict"],
            "shrink": float(report["shrink"]),
            "gap_before": float(report["gap_before"]["rms_standardized"]),
            "gap_after": float(report["gap_after"]["rms_standardized"]),
            "best_candidate": None
            if best is None
            else {"effect": best["effect"], "delta_nats": best["delta"], "delta_se_nats": best["delta_se"]},
            "young_modulus": {k: estimates["young_modulus"][k] for k in ("value", "ci95", "unit")},
            "misfit_p_value": float(report["misfit_p_value"]),
            "sessions": len(paths),
            "files": [str(p) for p in written],
        }
    )


def diagnose_studies(
    studies: Sequence[tuple[str, Sequence[Path]]],
    out_dir: str | Path,
    *,
    effects: Sequence[str] | None = None,
    baseline: str = "estimator",
    gas: str | None = None,
    wrinkle_law: str | None = None,
    rig: str | Path | None = None,
    executor: ExecutorOptions | None = None,
    progress: bool | None = None,
    resume: bool = False,
) -> dict:
    """Diagnose every study of ``studies`` ((name, session files), e.g. from :func:`study_groups`)
    into ``out_dir`` (module docstring); return what it writes to ``diagnoses.json``.

    The options are :func:`shelljax.diagnose.diagnose`'s and the CLI's; they are checked (and the
    rig read) before any study runs. A study that fails (sessions of several objects, a baseline
    that does not converge) is recorded with its error; the others go on. ``resume``: diagnose only
    the studies ``out_dir`` has no finished record of (refused when it was started with other
    studies or options).

    Raises:
        InvalidInputError: a bad option or rig, bad executor options, an unreachable scheduler.
        KeyboardInterrupt: after cancelling the studies in flight; the finished ones stay on disk.
    """
    from ..diagnose.internal import check_effect_names

    if effects is not None:
        effects = list(check_effect_names(effects))
    diagnosis_baseline(rig, gas, wrinkle_law)  # a bad or incompatible rig fails here, before any study runs
    out = check_output_dir(out_dir, "--out")
    executor = executor or ExecutorOptions()
    check_executor(executor)  # an unreachable cluster is refused before inputs.json is written
    rig = None if rig is None else str(Path(rig).resolve())
    options = {"effects": effects, "baseline": baseline, "gas": gas, "wrinkle_law": wrinkle_law, "rig": rig}
    check_inputs(
        out,
        {"studies": [[name, [str(p) for p in paths]] for name, paths in studies], "options": options},
        resume=resume,
        what="diagnosis of many studies",
    )
    items = [
        WorkItem(
            f"study{i:03d}-{name}",
            diagnose_study_item,
            ([str(p) for p in paths], str(out / name), effects, baseline, gas, wrinkle_law, rig),
        )
        for i, (name, paths) in enumerate(studies)
    ]
    results = run_items(
        items, run_dir=out, options=executor, resume=resume, progress=progress, desc="diagnosing studies"
    )
    rows = [
        {
            "study": name,
            "directory": str(out / name),
            "session_files": [str(p) for p in paths],
            "status": r.status,
            **({"error": r.error} if r.error else r.value),
            "seconds": r.seconds,
            "seconds_unit": "s",
            "worker": r.worker,
            "resumed": r.resumed,
        }
        for (name, paths), r in zip(studies, results)
    ]
    summary = {"options": options, "executor": executor.describe(), "studies": rows}
    atomic_write_text(out / SUMMARY, json.dumps(summary, indent=1))
    return summary


def diagnoses_table(summary: dict) -> str:
    """Plain text, one line per study: verdict, gap before → after, shrink, best candidate's Δ elpd
    [nats], E [MPa] with its 95 % interval; a failed study with its error."""
    header = [
        "study",
        "sessions",
        "verdict",
        "gap before",
        "gap after",
        "shrink",
        "best candidate Δ [nats]",
        "E [MPa] (95 %)",
    ]
    rows = []
    for s in summary["studies"]:
        if s["status"] != "done":
            rows.append([s["study"], str(len(s["session_files"])), "FAILED: " + s["error"], "", "", "", "", ""])
            continue
        best, e = s["best_candidate"], s["young_modulus"]
        rows.append(
            [
                s["study"],
                str(s["sessions"]),
                s["verdict"],
                f"{s['gap_before']:.3g}",
                f"{s['gap_after']:.3g}",
                f"{s['shrink']:.3g}x",
                "" if best is None else f"{best['effect']} {best['delta_nats']:+.1f} ± {best['delta_se_nats']:.1f}",
                f"{e['value'] / 1e6:.4g} [{e['ci95'][0] / 1e6:.3g}, {e['ci95'][1] / 1e6:.3g}]",
            ]
        )
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in [header, *rows]]
    lines.insert(1, "  ".join("-" * w for w in widths))
    lines.append(
        "gap: held-out rms of standardized residuals (1 is the noise); each study's diagnosis.json and report.md "
        "are in its directory"
    )
    return "\n".join(lines)
