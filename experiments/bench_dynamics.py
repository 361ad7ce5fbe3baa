"""Benchmark of the 3D shell in motion: a ball of N faces dropped onto the ground, Newmark at Δt.

The issue's case is 1 s of a 5k-face ball at Δt = 1 ms (``--faces 5000 --duration 1.0``); the
defaults run a shorter piece of it and report the time per step, split into compilation (the
first chunk) and the steps after it.

    python3 experiments/bench_dynamics.py [--faces 2000] [--dt 1e-3] [--steps 40]
"""

from __future__ import annotations

import argparse
import json
import time

import jax

import shelljax.shell3d as s3
from shelljax import dynamics as d

jax.config.update("jax_enable_x64", True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--faces", type=int, default=2000)
    p.add_argument("--dt", type=float, default=1e-3)
    p.add_argument("--steps", type=int, default=40)
    p.add_argument("--height", type=float, default=0.005, help="drop height [m] (contact within the first steps)")
    args = p.parse_args()
    start = time.perf_counter()
    shell = s3.ball(0.13, 0.9e-3, n_triangles=args.faces)
    ground = d.Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], d.BarrierContact(1e-3, 1e3), name="ground")
    system = d.shell_system(shell, 2.34e6, 0.4, 1300.0, gas="adiabatic", mass=0.8, planes=[ground])
    setup = time.perf_counter() - start
    state = d.drop_state(system, system.inflated, args.height)
    chunk = args.steps // 2
    timings = []
    for _ in range(2):
        start = time.perf_counter()
        traj = d.simulate(system, state, args.dt, chunk * args.dt, minimiser=d.SparseNewton(), chunk=chunk, progress=False)
        timings.append(time.perf_counter() - start)
        state = d.initial_state(system, traj["position_m"][-1], None)
    out = {"faces": int(shell.mesh.n_faces), "dofs": 3 * shell.mesh.n_vertices, "dt_s": args.dt, "setup_s": setup,
           "first_chunk_s (with compilation)": timings[0], "steps_per_chunk": chunk, "seconds_per_step": timings[1] / chunk,
           "newton_iterations_mean": float(traj["newton_iterations"][1:].mean()),
           "projected_1s_s": timings[1] / chunk / args.dt}  # fmt: skip
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
