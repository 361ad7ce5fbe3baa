"""Benchmark of the hammer swing (``configs/hammer.toml``): set-up, compilation and time per step.

Runs the config's swing (held vertices turned on the schedule, the wall) on a mesh of
``--faces`` triangles for ``--duration`` seconds, prints a table and writes the timings, what
the run shows (held vertices on the schedule, wall contact, the bending, the gas pressure) and
the outputs (``--out``: results.json, figures, frames, preview.gif) to ``--json``.

    python3 experiments/bench_hammer.py [--faces 1000] [--duration 1.5] [--out runs/hammer-bench]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import jax
import numpy as np

from shelljax import dynamics as d
from shelljax.scenario import build_system, hold, load_scenario, resolve_object

jax.config.update("jax_enable_x64", True)
ROOT = Path(__file__).resolve().parents[1]


def axis(points: np.ndarray) -> np.ndarray:
    """Principal direction (3,) of a point cloud (N, 3) [m]."""
    centred = points - points.mean(axis=0)
    return np.linalg.svd(centred, full_matrices=False)[2][0]


def bending(system, trajectory, head: np.ndarray, handle: np.ndarray) -> np.ndarray:
    """Per step, the change [deg] of the angle between the head's and the handle's axes from the rest angle
    (0 for the rigid swing): how much the head–handle joint and the handle bend."""

    def angle(x):
        a, b = axis(x[head]), axis(x[handle])
        return np.degrees(np.arccos(min(abs(float(a @ b)), 1.0)))

    rest = angle(np.asarray(system.inflated).reshape(-1, 3))
    return np.array([angle(x.reshape(-1, 3)) - rest for x in trajectory["position_m"]])


def run(args):
    """(scenario, system, trajectory, timings [s]) of the swing."""
    timings = {}
    start = time.perf_counter()
    scenario = load_scenario(args.config)
    scenario = dataclasses.replace(
        scenario,
        mesh_faces=args.faces or scenario.mesh_faces,
        duration=args.duration,
        max_frames=args.frames,
        step_tolerance=args.tolerance or scenario.step_tolerance,
    )
    obj = resolve_object(scenario)
    timings["mesh_s"] = time.perf_counter() - start
    system = hold(scenario, build_system(scenario, obj, scenario.contact_damping or 0.0))
    timings["setup_s"] = time.perf_counter() - start - timings["mesh_s"]
    state = d.initial_state(system, system.posed(0.0))
    options = dict(
        integrator=d.BackwardEuler() if scenario.scheme == "backward-euler" else d.Newmark(),
        minimiser=d.SparseNewton(step_tolerance=scenario.step_tolerance),
        chunk=args.chunk,
    )
    start = time.perf_counter()
    d.simulate(system, state, scenario.dt, args.chunk * scenario.dt, progress=False, **options)
    first = time.perf_counter() - start
    start = time.perf_counter()
    trajectory = d.simulate(system, state, scenario.dt, scenario.duration, progress=True, **options)
    steps = len(trajectory["time_s"]) - 1
    timings["seconds_per_step"] = (time.perf_counter() - start) / steps
    # The first chunk compiled the program that the full run reuses.
    timings["compile_s"] = first - args.chunk * timings["seconds_per_step"]
    timings["run_s"] = timings["seconds_per_step"] * steps
    return scenario, system, trajectory, timings


def summary(scenario, system, trajectory) -> dict:
    """What the run shows: held vertices on the schedule, wall contact, bending, gas pressure."""
    times, positions = trajectory["time_s"], trajectory["position_m"]
    held = np.asarray(system.prescribed_vertices)
    schedule = np.stack([np.asarray(system.prescribed_positions(t)) for t in times])
    rest = np.asarray(system.inflated).reshape(-1, 3)
    head = np.flatnonzero(rest[:, 2] > -0.06)  # the head: its axis is z = 0, radius 8 cm
    handle = np.flatnonzero(
        (rest[:, 2] < -0.12) & (rest[:, 2] > rest[:, 2].min() + 0.03)
    )  # the handle, clear of joint and hand
    bend = bending(system, trajectory, head, handle)
    rigid = np.stack([np.asarray(system.posed(t)) for t in times])
    deviation = np.linalg.norm((positions - rigid).reshape(len(times), -1, 3), axis=2).max(axis=1)
    wall = np.linalg.norm(trajectory["contact_force_N"][:, 0], axis=1)
    pressure = trajectory["gas_pressure_Pa"]
    touch = np.flatnonzero(trajectory["min_gap_m"][:, 0] < trajectory.contact_distances_m[0])
    return {
        "faces": int(np.asarray(system.faces).shape[0]),
        "vertices": int(rest.shape[0]),
        "held_vertices": int(held.size),
        "dt_s": scenario.dt,
        "duration_s": float(times[-1]),
        "steps": int(len(times) - 1),
        "newton_iterations_mean": float(trajectory["newton_iterations"][1:].mean()),
        "newton_iterations_max": int(trajectory["newton_iterations"].max()),
        "held_error_m": float(
            np.max(np.abs(positions.reshape(len(times), -1, 3)[:, held].reshape(len(times), -1) - schedule))
        ),
        "wall_first_contact_s": float(times[touch[0]]) if touch.size else None,
        "wall_min_gap_m": float(trajectory["min_gap_m"][:, 0].min()),
        "wall_peak_force_N": float(wall.max()),
        "wall_peak_force_time_s": float(times[np.argmax(wall)]),
        "gas_pressure_start_Pa": float(pressure[0]),
        "gas_pressure_peak_Pa": float(pressure.max()),
        "gas_pressure_peak_time_s": float(times[np.argmax(pressure)]),
        "head_handle_angle_change_max_deg": float(np.max(np.abs(bend))),
        "head_handle_angle_change_max_time_s": float(times[np.argmax(np.abs(bend))]),
        "head_handle_angle_change_end_deg": float(bend[-1]),
        "max_deviation_from_rigid_m": float(deviation.max()),
        "max_deviation_time_s": float(times[np.argmax(deviation)]),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default=str(ROOT / "configs" / "hammer.toml"))
    p.add_argument(
        "--faces", type=int, default=None, help="triangles of the refined hammer (default: the config's mesh_faces)"
    )
    p.add_argument("--duration", type=float, default=1.5, help="seconds of the swing to run")
    p.add_argument("--chunk", type=int, default=50, help="steps per compiled chunk")
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--tolerance", type=float, default=None, help="Newton's step tolerance [m] (default: the config's)")
    p.add_argument("--out", default=str(ROOT / "runs" / "hammer-bench"))
    p.add_argument("--json", default=str(ROOT / "docs" / "bench" / "hammer-cpu-2core.json"))
    args = p.parse_args()
    scenario, system, trajectory, timings = run(args)
    d.write_results(trajectory, args.out, max_frames=scenario.max_frames, mesh_format=scenario.mesh_frames)
    out = {
        "machine": "shared 2-core x86-64 VM",
        "config": str(Path(args.config).name),
        "timings_s": timings,
        "run": summary(scenario, system, trajectory),
        "outputs": args.out,
    }
    for table in (timings, out["run"]):
        for key, value in table.items():
            print(f"{key:>38s}  {value:.4g}" if isinstance(value, float) else f"{key:>38s}  {value}")
    Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
