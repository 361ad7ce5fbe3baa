"""The GPU check (docs/gpu.md): is shelljax faster on a GPU, and never slower? One table, in ≤ 8 min on one GPU.

Rows, each GPU time against CPU time on the same machine, their ratio (CPU / GPU: the GPU's
speed-up), the target and pass/fail:

* ``main job cold`` / ``main job warm``: the README's first command's run, ``shelljax run
  configs/paper.toml``, with ``--device auto`` against ``--device cpu``, each in a fresh process;
  cold with an empty JAX cache directory (``SHELLJAX_CACHE_DIR``), warm again with the cache that
  run filled. Target: ``auto`` no slower (ratio ≥ 0.95: 5 % is one run's timing noise).
* ``1e5 axisym curves``: ``experiments/bench_axisym.py --large N`` run twice, on the accelerator
  and with ``JAX_PLATFORMS=cpu`` (every core); its ``1e5 curves`` row.
* ``3D curve 20k faces``, ``3D curve 80k faces``, ``drop 1 m``: from
  ``experiments/bench_device_solve.py --faces 20000 80000 --rows curve drop --out FILE``, read from
  its JSON (a ``rows`` list whose entries carry a ``row`` name, ``faces`` for curves, the host path's
  ``cpu_path_s`` and the Krylov path's ``device_path_s``); where that script is absent or fails, the rows say so. Targets
  ≥ 2×, ≥ 5×, ≥ 2×.

``--rows cpu-check --against OTHER_CHECKOUT`` is the CPU half of the issue's "never slower": the
main job warm on the CPU with this tree and another checkout (e.g. the commit before a change),
run alternately ``--repeats`` times; this tree's time stands in the GPU column and the other's in
the CPU column, so the ratio is other / this (≥ 0.95: no slower).

Without a GPU, the rows' GPU halves say "no GPU" (the main job still runs ``auto`` against
``cpu``: both on the CPU). ``--quick`` runs small sizes (one session's fit as the main job, 256
curves, 2000 faces): a couple of minutes on a CPU. The parent process never starts JAX, so the
subprocesses have the accelerator's memory to themselves.

    python experiments/bench_gpu.py                # on a GPU machine: writes docs/bench/gpu-<device kind>.json
    python experiments/bench_gpu.py --quick        # a smoke test on any machine: results/gpu-<device kind>-quick.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = ROOT / "experiments"
NO_SLOWER = 0.95  # ratio a "no slower" row must reach: one run's timing noise is about 5 %
TARGETS = {"3D curve 20k faces": 2.0, "3D curve 80k faces": 5.0, "drop 1 m": 2.0}
_PROBE = (
    "import json, jax; ds = jax.devices(); "
    "print(json.dumps({'platform': ds[0].platform, 'kind': ds[0].device_kind, 'jax': jax.__version__}))"
)


def _env(**extra: str) -> dict:
    env = {**os.environ, **extra}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)
    return env


def _device() -> dict:
    """JAX's first device, asked in a subprocess (this process never starts JAX)."""
    proc = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, env=_env(), check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _timed(command: list[str], env: dict, timeout: float, cwd: Path = ROOT) -> tuple[float | None, str]:
    """(wall time [s] or None if it failed, the output's tail); ``cwd``: the checkout ``-m`` imports from."""
    start = time.perf_counter()
    try:
        proc = subprocess.run(command, check=False, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return None, f"timed out after {timeout:.0f} s"
    seconds = time.perf_counter() - start
    tail = (proc.stdout + proc.stderr)[-600:]
    return (seconds if proc.returncode == 0 else None), tail


def _row(name: str, gpu_s, cpu_s, target: float | None, note: str = "") -> dict:
    ratio = cpu_s / gpu_s if gpu_s and cpu_s else None
    passed = None if ratio is None or target is None else ratio >= target
    return {
        "row": name,
        "gpu_s": gpu_s,
        "cpu_s": cpu_s,
        "ratio_cpu_over_gpu": ratio,
        "target_ratio": target,
        "pass": passed,
        "note": note,
    }


def _quick_config(workdir: Path) -> Path:
    """configs/paper.toml cut to one session's closed form and fit (the tests' quick run)."""
    text = (ROOT / "configs" / "paper.toml").read_text()
    text = re.sub(r"(?m)^methods = .*$", 'methods = ["closed-form", "fit"]', text)
    text = re.sub(
        r"(?ms)^\[sessions\]\npaths = \[.*?\]\n", '[sessions]\npaths = ["bundled:sessions/pezzi.toml"]\n', text
    )
    text = re.sub(r"(?ms)^\[calibration\]\n.*?(?=^\[)", "", text)
    path = workdir / "paper-quick.toml"
    path.write_text(text)
    return path


def _main_job_rows(args, workdir: Path, has_gpu: bool) -> list[dict]:
    """Cold and warm ``shelljax run`` with --device auto against --device cpu, each a fresh process."""
    config = _quick_config(workdir) if args.quick else ROOT / "configs" / "paper.toml"
    seconds = {}
    for device in ("auto", "cpu"):
        cache = workdir / f"cache-{device}"
        for phase in ("cold", "warm"):  # the warm run finds the cache the cold one filled
            command = [sys.executable, "-m", "shelljax.cli", "run", str(config), "--device", device]
            command += ["--out", str(workdir / f"runs-{device}-{phase}"), "--quiet"]
            seconds[device, phase], tail = _timed(command, _env(SHELLJAX_CACHE_DIR=str(cache)), args.timeout)
            if seconds[device, phase] is None:
                print(f"main job --device {device} ({phase}) failed: {tail}", file=sys.stderr)
    note = "" if has_gpu else "no GPU: auto ran on the CPU"
    what = "one session's fit" if args.quick else "configs/paper.toml"
    return [
        _row(f"main job {phase} ({what})", seconds["auto", phase], seconds["cpu", phase], NO_SLOWER, note)
        for phase in ("cold", "warm")
    ]


def _axisym_seconds(args, workdir: Path, label: str, env: dict, chunk: int) -> float | None:
    """bench_axisym.py's ``1e5 curves`` time [s] (timed or extrapolated from ``--large``)."""
    out = workdir / f"axisym-{label}.json"
    command = [sys.executable, str(EXPERIMENTS / "bench_axisym.py"), "--out", str(out), "--chunk", str(chunk)]
    command += ["--large", str(args.curves), "--repeats", "1" if args.quick else "3"]
    seconds, tail = _timed(command, env, args.timeout)
    if seconds is None:
        print(f"bench_axisym ({label}) failed: {tail}", file=sys.stderr)
        return None
    rows = json.loads(out.read_text())["rows"]
    return next(r["median_s"] for r in rows if r["case"].startswith("1e5 curves"))


def _axisym_row(args, workdir: Path, has_gpu: bool) -> dict:
    cpu = _axisym_seconds(args, workdir, "cpu", _env(JAX_PLATFORMS="cpu"), 8)
    gpu = _axisym_seconds(args, workdir, "gpu", _env(), 0) if has_gpu else None
    how = "timed" if args.curves == 100_000 else f"extrapolated from {args.curves}"
    return _row(f"1e5 axisym curves ({how})", gpu, cpu, None, "" if has_gpu else "no GPU")


def _solve_rows(args, workdir: Path, has_gpu: bool) -> list[dict]:
    """The 3D curve and drop rows, from bench_device_solve.py's JSON; rows that say why when it is absent."""
    faces = [500] if args.quick else [20000, 80000]
    names = [f"3D curve {f // 1000}k faces" if f >= 1000 else f"3D curve {f} faces" for f in faces] + ["drop 1 m"]
    script = EXPERIMENTS / "bench_device_solve.py"
    if not script.exists():
        return [_row(n, None, None, TARGETS.get(n), "experiments/bench_device_solve.py is absent") for n in names]
    out = workdir / "device-solve.json"
    command = [sys.executable, str(script), "--faces", *map(str, faces), "--rows", "curve", "drop", "--out", str(out)]
    command += ["--repeats", str(args.solve_repeats)]
    if args.quick:  # the drop's first 50 ms (its fall): the Krylov path on a CPU takes minutes per simulated second
        command += ["--drop-duration", "0.05"]
    seconds, tail = _timed(command, _env(), args.timeout)
    if seconds is None or not out.exists():
        return [_row(n, None, None, TARGETS.get(n), f"bench_device_solve.py failed: {tail[-200:]}") for n in names]
    found = json.loads(out.read_text()).get("rows", [])
    rows = []
    for name, face_count in zip(names, [*faces, None]):
        kind = "curve" if face_count else "drop"
        match = [r for r in found if r.get("row") == kind and (face_count is None or r.get("faces") == face_count)]
        if not match:
            rows.append(_row(name, None, None, TARGETS.get(name), "no such row in bench_device_solve.py's JSON"))
            continue
        entry = match[0]
        gpu, cpu = (entry["device_path_s"] if has_gpu else None), entry["cpu_path_s"]
        rows.append(_row(name, gpu, cpu, TARGETS.get(name), "" if has_gpu else "no GPU"))
    return rows


def _commit(tree: Path) -> str | None:
    """The checked-out commit of ``tree`` (None outside git)."""
    proc = subprocess.run(["git", "-C", str(tree), "rev-parse", "HEAD"], check=False, capture_output=True, text=True)
    return proc.stdout.strip() or None


def _cpu_check_row(args, workdir: Path) -> dict:
    """The main job on the CPU, this tree against ``--against`` (another checkout), warm, run
    alternately ``--repeats`` times after one run each to fill their caches; medians [s]."""
    config = _quick_config(workdir) if args.quick else ROOT / "configs" / "paper.toml"
    trees = {"this": ROOT, "base": Path(args.against).resolve()}
    seconds: dict[str, list[float]] = {"this": [], "base": []}
    for repeat in range(args.repeats + 1):  # the first round fills each tree's cache
        for name, tree in trees.items():
            env = _env(SHELLJAX_CACHE_DIR=str(workdir / f"cache-{name}"), JAX_PLATFORMS="cpu")
            env["PYTHONPATH"] = str(tree)
            command = [sys.executable, "-m", "shelljax.cli", "run", str(config), "--quiet"]
            command += ["--out", str(workdir / f"runs-{name}")]
            wall, tail = _timed(command, env, args.timeout, cwd=tree)
            if wall is None:
                raise SystemExit(f"the main job of {tree} failed: {tail}")
            if repeat:
                seconds[name].append(wall)
    this, base = statistics.median(seconds["this"]), statistics.median(seconds["base"])
    row = _row(f"main job warm, CPU: this tree (as GPU) vs {trees['base'].name}", this, base, NO_SLOWER)
    row["note"] = f"medians of {args.repeats}, alternating; this tree: {seconds['this']}, base: {seconds['base']}"
    row["commits"] = {name: _commit(tree) for name, tree in trees.items()}
    return row


def _print(rows: list[dict]) -> None:
    def cell(v, fmt):
        return format(v, fmt) if v is not None else "—".rjust(int(fmt.split(".")[0]))

    print(f"{'row':44s} {'GPU [s]':>9s} {'CPU [s]':>9s} {'CPU/GPU':>8s} {'target':>7s} {'pass':>5s}  note")
    for r in rows:
        verdict = "—" if r["pass"] is None else ("yes" if r["pass"] else "NO")
        target = "—" if r["target_ratio"] is None else f"≥{r['target_ratio']:g}"
        print(
            f"{r['row']:44s} {cell(r['gpu_s'], '9.2f')} {cell(r['cpu_s'], '9.2f')} {cell(r['ratio_cpu_over_gpu'], '8.2f')} "
            f"{target:>7s} {verdict:>5s}  {r['note']}"
        )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.partition("\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small sizes: a couple of minutes on a CPU")
    ap.add_argument(
        "--out",
        default=None,
        help="JSON file (default: docs/bench/gpu-<device kind>.json; with --quick results/gpu-<device kind>-quick.json)",
    )
    ap.add_argument("--curves", type=int, default=None, help="axisym batch timed (default 100000; 256 with --quick)")
    ap.add_argument("--timeout", type=float, default=400.0, help="limit of each subprocess [s]")
    ap.add_argument(
        "--rows",
        nargs="+",
        choices=["main", "axisym", "solve", "cpu-check"],
        default=["main", "axisym", "solve"],
        help="what to run; cpu-check: the main job on the CPU, this tree against --against",
    )
    ap.add_argument(
        "--solve-repeats", type=int, default=1, help="bench_device_solve.py's --repeats (1 keeps the check in 8 min)"
    )
    ap.add_argument("--against", default=None, help="cpu-check: another checkout of shelljax (e.g. the commit before)")
    ap.add_argument("--repeats", type=int, default=3, help="cpu-check: alternating runs of each tree")
    args = ap.parse_args(argv)
    args.curves = args.curves or (256 if args.quick else 100_000)
    device = _device()
    has_gpu = device["platform"] in ("gpu", "cuda", "rocm")
    slug = re.sub(r"[^a-z0-9]+", "-", device["kind"].lower()).strip("-") if has_gpu else "no-gpu"
    # a quick run is a smoke test of the script, not a figure for the docs
    default = Path("results") / f"gpu-{slug}-quick.json" if args.quick else ROOT / "docs" / "bench" / f"gpu-{slug}.json"
    out = Path(args.out) if args.out else default
    start = time.perf_counter()
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="bench-gpu-") as tmp:
        if "main" in args.rows:
            rows += _main_job_rows(args, Path(tmp), has_gpu)
        if "axisym" in args.rows:
            rows.append(_axisym_row(args, Path(tmp), has_gpu))
        if "solve" in args.rows:
            rows += _solve_rows(args, Path(tmp), has_gpu)
        if "cpu-check" in args.rows:
            if args.against is None:
                ap.error("--rows cpu-check needs --against OTHER_CHECKOUT")
            rows.append(_cpu_check_row(args, Path(tmp)))
    machine = {
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "jax": device["jax"],
        "device": device["kind"],
    }
    print(f"machine: {machine}")
    _print(rows)
    record = {
        "machine": machine,
        "quick": args.quick,
        "units": "s; ratio_cpu_over_gpu = cpu_s / gpu_s (the GPU's speed-up) [-]",
        "total_wall_s": time.perf_counter() - start,
        "rows": rows,
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(record, indent=1))
    print(f"wrote {out} ({record['total_wall_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
