"""Benchmark of the executor layer: serial against a local Dask cluster, and a scaling model.

Three measurements, each serial (in-process) and on a ``LocalCluster`` of ``--workers`` processes:

1. a catalogue: ``shelljax run`` on a config of ``--sessions`` sessions (16 objects of the rig
   transfer study's generator at two pressures each, without manometer; closed form, fit and
   bayes), with the run directories' results.json compared value for value;
2. a diagnosis of ``--studies`` studies (the blind gap study's generator, one random effect each),
   one work item per study, verdicts and estimates compared;
3. the executor's own costs: starting the cluster, the first item on a fresh worker (importing
   shelljax and loading or compiling its programs), and the scheduler's overhead per item
   (``--noop-items`` items that do nothing).

From them, a scaling model T(N items, W workers) = start + first item + ⌈N/W⌉ (t_item + overhead),
and its prediction for 1000 objects on 100 workers. Prints a table, writes JSON.

``--case paper`` measures the issue's own criterion instead: ``shelljax run configs/paper.toml``
serially and with ``--workers``, each a fresh process as a user runs it, ``--repeats`` times
alternating (the first serial run also fills the persistent caches), results.json values compared,
and the load average [-] before and after each run recorded (the machine may be shared).

Run:  python experiments/bench_cluster.py --workers 2 --out docs/bench/cluster-cpu-2core.json
      python experiments/bench_cluster.py --case paper --repeats 2 --out docs/bench/cluster-paper-cpu-2core.json
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from shelljax.executor import ExecutorOptions, WorkItem, run_items


def noop(index: int) -> dict:
    """A work item that does nothing: what the scheduler costs per item."""
    return {"index": index}


def first_item_cost() -> dict:
    """Import shelljax and run one fit on a bundled session: a fresh worker's first item [s]."""
    start = time.perf_counter()
    from shelljax.config import bundled_data_dir
    from shelljax.estimate import EstimatorOptions, run_estimator
    from shelljax.session import load_session

    imported = time.perf_counter() - start
    session = load_session(bundled_data_dir() / "sessions" / "heldout_pezzi_1100Pa.toml")
    options = EstimatorOptions(gas="isothermal", wrinkle_law="scaling")
    run_estimator("fit", session, options)
    first = time.perf_counter() - start
    run_estimator("fit", session, options)
    second = time.perf_counter() - start - first
    return {"import_seconds": imported, "first_fit_seconds": first - imported, "warm_fit_seconds": second}


def write_catalogue(directory: Path, n_sessions: int, seed: int) -> Path:
    """``n_sessions`` session files (n/2 objects × 2 pressures) and a config that runs them."""
    from rig_transfer_study import draw_object, write_object

    rng = np.random.default_rng(seed)
    paths = []
    while len(paths) < n_sessions:
        obj = draw_object(rng, (0.08, 0.30), log_radius=True)
        pressures = obj["low_pressure"] * np.array([1.0, rng.uniform(1.4, 2.0)])
        try:
            paths += write_object(rng, obj, {}, pressures, directory, f"object{len(paths) // 2}", manometer=False)
        except Exception:  # noqa: BLE001 - reality has no ball state there: draw another object
            continue
    config = directory / "catalogue.toml"
    listed = ", ".join(f'"{p.name}"' for p in paths[:n_sessions])
    config.write_text(f"""name = "catalogue"
output_dir = "runs"
seed = 0

[estimators]
methods = ["closed-form", "fit", "bayes"]
bootstrap_samples = 200
forward_model = "axisym"
gas = "isothermal"
wrinkle_law = "scaling"

[sessions]
paths = [{listed}]

[outputs]
figures = false
""")
    return config


def _values(tree, prefix=""):
    """Every number in a results tree, by its path, except wall times and dates."""
    out = {}
    if isinstance(tree, dict):
        for key, value in tree.items():
            if key in ("seconds", "wall_seconds", "created", "compilation", "executor", "seconds_unit", "worker"):
                continue
            out.update(_values(value, f"{prefix}/{key}"))
    elif isinstance(tree, list):
        for i, value in enumerate(tree):
            out.update(_values(value, f"{prefix}/{i}"))
    elif isinstance(tree, (int, float)) and not isinstance(tree, bool):
        out[prefix] = tree
    return out


def catalogue(config: Path, options: ExecutorOptions, out: Path) -> tuple[float, dict, float]:
    """Run the catalogue: (wall time [s], results.json, this process's CPU time [s], all threads)."""
    from shelljax.runner import run_experiment

    start, cpu_start = time.perf_counter(), time.process_time()
    run_dir = run_experiment(config, output_dir=out, progress=False, executor=options)
    seconds, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    results = json.loads((run_dir / "results.json").read_text())
    return seconds, results, cpu


def diagnosis_items(directory: Path, n_studies: int, seed: int) -> list[WorkItem]:
    import blind_gap_study as blind
    import cloudpickle

    cloudpickle.register_pickle_by_value(blind)  # the workers cannot import the experiments' scripts
    rng = np.random.default_rng(seed)
    effects = [e for e in blind.EFFECTS if e != "self_weight"]
    items = []
    for i in range(n_studies):
        effect = effects[i % len(effects)]
        study = directory / f"study{i}"
        study.mkdir(parents=True)
        paths, label = blind.make_study(rng, effect, study, with_shape=True)
        items.append(WorkItem(f"study{i}", blind.diagnose_study, (i, effect, [str(p) for p in paths], label)))
    return items


def paper_run(config: Path, workers: int | None, out: Path) -> tuple[float, dict, float]:
    """``shelljax run CONFIG [--workers N]`` in a fresh process, as a user types it: (wall time [s],
    results.json, CPU time [s] of it and its workers)."""
    import os
    import subprocess

    command = [sys.executable, "-m", "shelljax.cli", "run", str(config), "--out", str(out), "--quiet"]
    root = Path(__file__).resolve().parents[1]
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]),
    }  # this checkout's shelljax
    start, cpu_start = time.perf_counter(), _children_cpu_seconds()
    subprocess.run(
        command + ([] if workers is None else ["--workers", str(workers)]),
        check=True,
        cwd=root,
        env=env,
        stdout=subprocess.DEVNULL,
    )
    seconds, cpu = time.perf_counter() - start, _children_cpu_seconds() - cpu_start
    (run_dir,) = out.iterdir()
    return seconds, json.loads((run_dir / "results.json").read_text()), cpu


def _children_cpu_seconds() -> float:
    """User + system CPU time [s] of this process's finished children (a Dask run's workers included)."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def paper(workers: int, repeats: int, tmp: Path) -> dict:
    """``shelljax run configs/paper.toml`` serially and on ``workers``, alternating ``repeats`` times."""
    import os

    config = Path(__file__).resolve().parents[1] / "configs" / "paper.toml"
    runs, reference = [], None
    for k in range(repeats):
        for n in (None, workers):
            load_before = os.getloadavg()[0]
            seconds, results, cpu = paper_run(config, n, tmp / f"paper{k}-{n or 0}")
            values = _values(results["sessions"])
            reference = reference or values
            stages = results["compilation"]["stages"]
            runs.append(
                {
                    "workers": n,
                    "seconds": seconds,
                    "cpu_cores": cpu / seconds,
                    "load_average_before": load_before,
                    "load_average_after": os.getloadavg()[0],
                    "values_compared": len(values),
                    "values_identical_to_first_serial": values == reference,
                    "items_seconds": [item["seconds"] for item in results["items"]],
                    "compile_seconds": results["compilation"]["total_seconds"],
                    "trace_seconds": sum(s["trace_seconds"] for s in stages),
                    "programs_compiled": sum(s["programs_compiled"] for s in stages),
                    "persistent_cache_hits": sum(s["persistent_cache_hits"] for s in stages),
                }
            )
            print(json.dumps(runs[-1]), flush=True)
    serial = [r["seconds"] for r in runs if r["workers"] is None]
    cluster = [r["seconds"] for r in runs if r["workers"] is not None]
    return {
        "config": str(config),
        "sessions": len(results["sessions"]),
        "runs": runs,
        "serial_seconds_best": min(serial),
        "cluster_seconds_best": min(cluster),
        "speedup_best_of_each": min(serial) / min(cluster),
        "speedup_bound": workers / float(np.median([r["cpu_cores"] for r in runs if r["workers"] is None])),
        "values_identical": all(r["values_identical_to_first_serial"] for r in runs),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--case", choices=["catalogue-diagnosis", "paper"], default="catalogue-diagnosis")
    parser.add_argument("--repeats", type=int, default=2, help="--case paper: serial/cluster pairs")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--sessions", type=int, default=32)
    parser.add_argument("--studies", type=int, default=8)
    parser.add_argument("--noop-items", type=int, default=200)
    parser.add_argument("--seed", type=int, default=49)
    parser.add_argument("--skip", nargs="*", default=[], choices=["catalogue", "diagnosis"])
    parser.add_argument(
        "--out",
        default=None,
        help="JSON to write (default: docs/bench/cluster-cpu-2core.json, "
        "or cluster-paper-cpu-2core.json for --case paper)",
    )
    args = parser.parse_args()
    bench = Path(__file__).resolve().parents[1] / "docs" / "bench"
    args.out = args.out or str(
        bench / ("cluster-paper-cpu-2core.json" if args.case == "paper" else "cluster-cpu-2core.json")
    )
    if args.case == "paper":
        with tempfile.TemporaryDirectory() as tmp:
            report = {
                "machine": platform.platform(),
                "cpus": len(__import__("os").sched_getaffinity(0)),
                "workers": args.workers,
                "unit": "s",
                "paper": paper(args.workers, args.repeats, Path(tmp)),
            }
        print(json.dumps({k: v for k, v in report["paper"].items() if k != "runs"}, indent=1))
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(report, indent=1))
        return 0
    cluster = ExecutorOptions(workers=args.workers)
    report = {"machine": platform.platform(), "workers": args.workers, "unit": "s"}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        # the executor's own costs
        start = time.perf_counter()
        run_items([WorkItem("probe", noop, (0,))], options=cluster)
        startup = time.perf_counter() - start
        first = run_items([WorkItem("first", first_item_cost)], options=ExecutorOptions(workers=1))[0]
        if first.status != "done":
            raise SystemExit(f"the first-item probe failed: {first.error}")
        costs = first.value
        start = time.perf_counter()
        run_items([WorkItem(f"noop{i}", noop, (i,)) for i in range(args.noop_items)], options=cluster)
        overhead = max(time.perf_counter() - start - startup, 0.0) / args.noop_items
        report["costs"] = {"cluster_start_seconds": startup, "scheduler_overhead_per_item_seconds": overhead, **costs}
        if "catalogue" not in args.skip:
            config = write_catalogue(tmp / "catalogue", args.sessions, args.seed)
            serial_s, serial, serial_cpu = catalogue(config, ExecutorOptions(), tmp / "serial")
            cluster_s, parallel, _ = catalogue(config, cluster, tmp / "cluster")
            a, b = _values(serial["sessions"]), _values(parallel["sessions"])
            # the serial run already keeps serial_cpu / serial_s cores busy (its batches' threads):
            # N workers on N cores can at best make it N / that faster
            report["catalogue"] = {
                "sessions": args.sessions,
                "serial_seconds": serial_s,
                "cluster_seconds": cluster_s,
                "speedup": serial_s / cluster_s,
                "serial_cpu_cores": serial_cpu / serial_s,
                "speedup_bound": args.workers * serial_s / serial_cpu,
                "values_compared": len(a),
                "values_identical": a == b,
                "differing": sorted(k for k in a if a.get(k) != b.get(k))[:20],
            }
            rows.append(("catalogue (closed form, fit, bayes)", args.sessions, serial_s, cluster_s, a == b))
            print(json.dumps(report["catalogue"]), flush=True)
        if "diagnosis" not in args.skip:
            items = diagnosis_items(tmp / "studies", args.studies, args.seed)
            start = time.perf_counter()
            serial = run_items(items)
            serial_s = time.perf_counter() - start
            start = time.perf_counter()
            parallel = run_items(items, options=cluster)
            cluster_s = time.perf_counter() - start
            same = [s.value == p.value for s, p in zip(serial, parallel)]
            # wall times differ by design; everything else must not
            strip = [{k: v for k, v in (r.value or {}).items() if k != "seconds"} for r in serial]
            strip_p = [{k: v for k, v in (r.value or {}).items() if k != "seconds"} for r in parallel]
            identical = strip == strip_p
            report["diagnosis"] = {
                "studies": args.studies,
                "serial_seconds": serial_s,
                "cluster_seconds": cluster_s,
                "speedup": serial_s / cluster_s,
                "values_identical": identical,
                "items_identical_with_wall_times": sum(same),
                "per_study_seconds": float(np.median([r.value["seconds"] for r in serial if r.status == "done"])),
            }
            rows.append((f"diagnosis of {args.studies} studies", args.studies, serial_s, cluster_s, identical))
    model = report["costs"]
    per_item = report.get("catalogue", {}).get("serial_seconds", 0.0) / max(args.sessions, 1)
    if per_item:
        predicted = (
            model["cluster_start_seconds"]
            + model["import_seconds"]
            + model["first_fit_seconds"]
            + math.ceil(1000 / 100) * (per_item + model["scheduler_overhead_per_item_seconds"])
        )
        report["scaling_model"] = {
            "per_session_seconds": per_item,
            "predicted_1000_objects_100_workers_seconds": predicted,
            "formula": "start + first item + ceil(N/W) (t_item + overhead)",
        }
    lines = [
        f"{'workload':<40s} {'items':>6s} {'serial [s]':>11s} {f'{args.workers} workers [s]':>12s} "
        f"{'speedup':>8s} {'identical':>10s}"
    ]
    for name, n, s, c, same in rows:
        lines.append(f"{name:<40s} {n:6d} {s:11.1f} {c:12.1f} {s / c:8.2f} {str(same):>10s}")
    lines.append(json.dumps(report["costs"], indent=1))
    if "scaling_model" in report:
        lines.append(json.dumps(report["scaling_model"], indent=1))
    print("\n".join(lines))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
