"""Cold start: how long a new user waits, from a fresh virtual environment and an empty JAX cache.

Measures, each as the median of ``--repeats`` runs (wall clock, seconds):

* ``install``: ``pip install .`` in a fresh venv (the README's first command's first half);
* ``main_job_cold``: then ``shelljax run configs/paper.toml`` with an empty compilation cache (its
  second half);
* ``main_job_warm``: the same job again, with the cache the first run filled;
* ``fit_new_object_cold``: ``shelljax estimate SESSION --method fit`` on an object the main job
  does not fit (a calibration session), with an empty cache;
* ``fit_new_object_after_main``: the same after the main job filled the cache (compilation
  shared across objects shows here);
* ``suite_cold``: ``pip install ".[test]" && python -m pytest`` in a fresh clone of HEAD with an
  empty cache (the README's second command).

Every run gets its own venv under ``--workdir`` (pip's wheel cache is used, so "install" measures
resolving and installing, not downloading; pass ``--no-pip-cache`` for a first-ever install). The
compilation cache of each run is a fresh ``SHELLJAX_CACHE_DIR``.

Usage::

    python experiments/bench_coldstart.py [--repeats 3] [--measures main,fit,suite] [--out docs/bench/coldstart-cpu-2core.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# A bundled session the main job calibrates k_s on but never fits (the fit has not seen it).
NEW_OBJECT = ROOT / "shelljax" / "data" / "sessions" / "calib_yoga_1200Pa.toml"


def _timed(command: str, cwd: Path, env: dict, log: Path) -> float:
    """Wall time [s] of ``command`` (bash); raises with the log's tail when it fails."""
    start = time.perf_counter()
    with log.open("w") as out:
        rc = subprocess.run(["bash", "-c", command], cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT).returncode
    seconds = time.perf_counter() - start
    if rc != 0:
        tail = log.read_text()[-3000:]
        raise SystemExit(f"`{command}` failed (exit {rc}) after {seconds:.0f} s; log {log}:\n{tail}")
    return seconds


def _environment(workdir: Path, name: str, pip_cache: bool) -> tuple[Path, dict]:
    """A fresh venv and an empty compilation cache; (venv bin dir, environment)."""
    venv = workdir / f"venv-{name}"
    subprocess.run(["python3", "-m", "venv", str(venv)], check=True)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = f"{venv / 'bin'}:{env['PATH']}"
    env["SHELLJAX_CACHE_DIR"] = str(workdir / f"jax-cache-{name}")
    if not pip_cache:
        env["PIP_NO_CACHE_DIR"] = "1"
    return venv / "bin", env


def _main_and_fit(workdir: Path, repeat: int, pip_cache: bool) -> dict:
    _, env = _environment(workdir, f"main-{repeat}", pip_cache)
    logs = workdir / f"logs-{repeat}"
    logs.mkdir(exist_ok=True)
    fit = f"shelljax estimate {NEW_OBJECT} --method fit --gas isothermal --wrinkle-law scaling --json"  # the main job's options
    times = {}
    cold_env = dict(env, SHELLJAX_CACHE_DIR=str(workdir / f"jax-cache-fit-{repeat}"))
    install, _ = _readme_commands()[0].split(" && ")
    main_job = f"shelljax run configs/paper.toml --out {workdir}/runs --quiet"
    times["install"] = _timed(f"{install} -q", ROOT, env, logs / "install.log")
    times["main_job_cold"] = _timed(main_job, ROOT, env, logs / "main_cold.log")
    times["main_job_warm"] = _timed(main_job, ROOT, env, logs / "main_warm.log")
    times["fit_new_object_after_main"] = _timed(fit, ROOT, env, logs / "fit_after_main.log")
    times["fit_new_object_cold"] = _timed(fit, ROOT, cold_env, logs / "fit_cold.log")
    return times


def _suite(workdir: Path, repeat: int, pip_cache: bool) -> dict:
    clone = workdir / f"clone-{repeat}"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    _, env = _environment(workdir, f"suite-{repeat}", pip_cache)
    return {"suite_cold": _timed(_readme_commands()[1], clone, env, workdir / f"suite-{repeat}.log")}


def _readme_commands() -> list[str]:
    """The README's two commands (its first code block), verbatim: what a newcomer pastes."""
    text = (ROOT / "README.md").read_text()
    block = text.split("```bash\n", 1)[1].split("```", 1)[0]
    return [line for line in block.splitlines() if line.strip()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--measures", default="main,fit,suite", help="comma-separated subset of main,fit,suite (fit runs with main)"
    )
    parser.add_argument(
        "--workdir", default=None, help="where venvs, caches and clones go (default: a temporary directory, removed)"
    )
    parser.add_argument("--no-pip-cache", action="store_true", help="install without pip's wheel cache")
    parser.add_argument("--out", default=str(ROOT / "docs" / "bench" / "coldstart-cpu-2core.json"))
    args = parser.parse_args()
    measures = set(args.measures.split(","))
    workdir = Path(args.workdir or tempfile.mkdtemp(prefix="shelljax-coldstart-"))
    workdir.mkdir(parents=True, exist_ok=True)
    runs = []
    try:
        for repeat in range(args.repeats):
            times = {}
            if measures & {"main", "fit"}:
                times.update(_main_and_fit(workdir, repeat, not args.no_pip_cache))
            if "suite" in measures:
                times.update(_suite(workdir, repeat, not args.no_pip_cache))
            runs.append(times)
            print(
                f"repeat {repeat + 1}/{args.repeats}: " + ", ".join(f"{k} {v:.0f} s" for k, v in times.items()),
                flush=True,
            )
    finally:
        if args.workdir is None:
            shutil.rmtree(workdir, ignore_errors=True)
    medians = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    # issue #57's targets, after the install for the main job and the fit, with it for the suite
    targets = {"main_job_cold": 45.0, "main_job_warm": 12.0, "fit_new_object_cold": 8.0, "suite_cold": 480.0}
    print("\n| measure | median [s] | runs [s] | target [s] |\n|---|---:|---|---:|")
    for key, median in medians.items():
        target = targets.get(key)
        print(
            f"| {key} | {median:.0f} | {', '.join(f'{r[key]:.0f}' for r in runs)} | {'' if target is None else f'{target:.0f}'} |"
        )
    record = {
        "unit": "s",
        "medians": medians,
        "runs": runs,
        "targets": targets,
        "repeats": args.repeats,
        "pip_cache": not args.no_pip_cache,
        "cores": os.cpu_count(),
        "machine": platform.platform(),
        "python": platform.python_version(),
        "date": time.strftime("%Y-%m-%d %H:%M"),
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(record, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
