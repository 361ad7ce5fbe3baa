"""Solve the noise-free 3D curves of the virtual balls (``shelljax.virtual``) into curves.json.

Each parameter set of ``shelljax.virtual.PARAMETER_SETS`` is one work item (``shelljax.executor``:
in-process, or on ``--workers N`` / ``--cluster``), solved in a child process under a watchdog; a
child whose XLA run wedged is restarted and resumes from its per-level checkpoint in /tmp. Each
finished set is kept in ``<out>.parts/`` (its curve and its item record) and merged into ``--out``
in set order, so an interrupted run keeps the sets it finished and a rerun skips them.

With ``--sessions DIR`` it draws the noisy test sessions of those curves into session files
instead (``shelljax.virtual.write_sessions``: one work item per session with its own seed, on
``--workers N`` or ``--cluster`` as well as in-process, the same files either way).

Usage::

    python tools/make_virtual_sessions.py --curves [--n-triangles 12000] [--sets 0,1,2] [--watchdog 600] [--workers 2]
    python tools/make_virtual_sessions.py --sessions virtual-sessions/ [--realisations 4] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from experiment_scripts import load_experiment

from shelljax import virtual
from shelljax.executor import add_executor_arguments, executor_options

long_runs = load_experiment("long_runs")


def _parse(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--curves", action="store_true", help="solve the 3D curves (slow: minutes per set)")
    ap.add_argument("--n-triangles", type=int, default=12000)
    ap.add_argument("--pole-refinement", type=float, default=6.0)
    ap.add_argument("--sets", default="", help="comma-separated indices (default: all)")
    ap.add_argument("--out", type=Path, default=virtual.CURVES_PATH)
    ap.add_argument("--restarts", type=int, default=10, help="child restarts per set after a wedged run")
    ap.add_argument(
        "--watchdog",
        type=float,
        default=600.0,
        help="seconds without a solved level before a child is restarted (raise it for fine meshes)",
    )
    ap.add_argument("--child", action="store_true", help="(internal) solve the given sets in this process")
    ap.add_argument(
        "--one-set", action="store_true", help="(internal) one set's work item: its watched child, restarted"
    )
    ap.add_argument(
        "--sessions",
        type=Path,
        default=None,
        metavar="DIR",
        help="draw the noisy test sessions of the curves in --out into session files in DIR",
    )
    ap.add_argument("--realisations", type=int, default=2, help="--sessions: noise draws per curve and noise level")
    ap.add_argument("--base-seed", type=int, default=2026, help="--sessions: seed of the first draw (each has its own)")
    add_executor_arguments(ap, resume=False)
    args = ap.parse_args(argv)
    if not args.curves and args.sessions is None:
        ap.error("nothing to do: pass --curves or --sessions DIR")
    return args


def _write_sessions(args) -> None:
    """Draw every test session of the curves in ``args.out`` into ``args.sessions``, one work item each."""
    index = virtual.write_sessions(
        virtual.load_curves(args.out),
        args.sessions,
        realisations=args.realisations,
        base_seed=args.base_seed,
        executor=executor_options(args),
        progress=True,
    )
    failed = [entry for entry in index if entry["status"] != "done"]
    print(f"{len(index) - len(failed)} sessions written to {args.sessions} (index: {args.sessions / 'sessions.json'})")
    for entry in failed:
        print(f"  {entry['name']}: FAILED ({entry['error']})")


def _solve_sets(args, sets) -> None:
    """Solve ``sets`` in this process and append each finished curve to ``args.out``."""
    watchdog = long_runs.Watchdog(args.watchdog).start()
    data = (
        json.loads(args.out.read_text())
        if args.out.exists()
        else {"description": virtual.CURVES_DESCRIPTION, "curves": []}
    )
    done = {(c["gauge_pressure"], c["young_modulus"], c["thickness"], c["n_faces"]) for c in data["curves"]}
    for i in sets:
        p = virtual.PARAMETER_SETS[i]
        t0 = time.perf_counter()
        checkpoint = long_runs.Checkpoint(Path(f"/tmp/shelljax_virtual_set{i}_{args.n_triangles}_travel.npz"), watchdog)
        try:
            c = virtual.solve_curve(
                p,
                args.n_triangles,
                args.pole_refinement,
                checkpoint,
                force_tolerance=virtual.FORCE_TOLERANCE,
                max_newton_iterations=virtual.NEWTON_ITERATIONS,
            )
        except Exception as err:  # record and continue: one failed set must not lose the others
            print(f"set {i} {p}: FAILED ({type(err).__name__}: {str(err)[:200]})", flush=True)
            continue
        if (c["gauge_pressure"], c["young_modulus"], c["thickness"], c["n_faces"]) in done:
            continue
        c["set"] = i
        data["curves"].append(c)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(data, indent=1))
        print(
            f"set {i} {p}: tau={c['tau']:.0f} faces={c['n_faces']} pole_edge={c['pole_edge'] * 1e3:.2f} mm "
            f"w0={[round(w * 1e3, 1) for w in c['w0']]} mm ({time.perf_counter() - t0:.0f} s)",
            flush=True,
        )


def main(argv=None):
    import jax

    # Synchronous dispatch: XLA:CPU wedged long runs (docs/shell3d.md, *XLA:CPU hangs*).
    jax.config.update("jax_cpu_enable_async_dispatch", False)
    args = _parse(argv)
    if args.sessions is not None:
        _write_sessions(args)
        return
    sets = [int(s) for s in args.sets.split(",")] if args.sets else range(len(virtual.PARAMETER_SETS))
    if args.child:
        _solve_sets(args, sets)
        return
    if args.one_set:
        (i,) = sets
        long_runs.run_with_restarts(_command(args, i, args.out, "--child"), args.restarts, f"set {i}")
        return
    _solve_on_executor(args, sets)


def _command(args, index: int, out: Path, mode: str) -> list[str]:
    """This tool on set ``index`` alone, into ``out``, as ``mode`` (--child or --one-set)."""
    return [
        sys.executable,
        str(Path(__file__).resolve()),
        "--curves",
        mode,
        "--sets",
        str(index),
        "--out",
        str(out),
        "--n-triangles",
        str(args.n_triangles),
        "--pole-refinement",
        str(args.pole_refinement),
        "--watchdog",
        str(args.watchdog),
        "--restarts",
        str(args.restarts),
    ]


def solve_set(command: list[str], part: str) -> dict:
    """The work item of one set: run ``command`` (the tool on that set, ``--one-set``) and return
    the curve it wrote to ``part`` (JSON, SI; raises when the set was not solved)."""
    import subprocess

    subprocess.run(command, check=False)
    curves = json.loads(Path(part).read_text())["curves"] if Path(part).exists() else []
    if not curves:
        raise RuntimeError(f"{part}: the set was not solved (its child's output above says why)")
    return curves[0]


def _solve_on_executor(args, sets) -> None:
    """Every set a work item; the finished ones merged into ``args.out`` in set order."""
    from shelljax.executor import WorkItem, run_items

    parts = args.out.with_name(args.out.name + ".parts")
    parts.mkdir(parents=True, exist_ok=True)
    items = [
        WorkItem(
            f"set{i}", solve_set, (_command(args, i, parts / f"set{i}.json", "--one-set"), str(parts / f"set{i}.json"))
        )
        for i in sets
    ]
    results = run_items(
        items, run_dir=parts, resume=True, options=executor_options(args), progress=True, desc="curve sets"
    )
    data = (
        json.loads(args.out.read_text())
        if args.out.exists()
        else {"description": virtual.CURVES_DESCRIPTION, "curves": []}
    )
    key = ("gauge_pressure", "young_modulus", "thickness", "n_faces")
    have = {tuple(c[k] for k in key) for c in data["curves"]}
    data["curves"] += [r.value for r in results if r.status == "done" and tuple(r.value[k] for k in key) not in have]
    data["curves"].sort(key=lambda c: c.get("set", -1))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(data, indent=1))
    for r in results:
        print(f"{r.key}: {'solved' if r.status == 'done' else 'FAILED (' + str(r.error) + ')'}", flush=True)


if __name__ == "__main__":
    main()
