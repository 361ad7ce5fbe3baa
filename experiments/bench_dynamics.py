"""Benchmark of the 3D shell in motion: a ball of N faces dropped onto the ground, steps of Δt.

The Pezzi ball (R = 0.13 m, h = 0.9 mm, 1300 Pa, 0.8 kg; by default isothermal gas and backward
Euler, as the configs) starts ``--height`` above a barrier ground, so that it touches down within
the measured steps. Per mesh it reports the
setup (rest-shape solve, pattern), the compilation (first chunk less its steps), the seconds per
step (median over the timed chunks), Newton's iterations per step, where a step's time goes
(isolated, jitted pieces at a contact state times their count per step: Hessian assembly, host
factorisation and solves, gradients and energies; "other" is the rest of the measured step) and
the time that 1 s of motion would take. The issue's case is 1 s of a 5k-face ball at 1 ms
(``--faces 5000 --chunk 100 --chunks 10``: 1.1 s of motion, the first 0.1 s compiling).

    python3 experiments/bench_dynamics.py [--faces 2000 5000] [--dt 1e-3] [--chunk 25] [--chunks 4]
        [--json docs/bench/dynamics-cpu-2core.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import shelljax.shell3d as s3
from shelljax import dynamics as d
from shelljax.physics import ShellProperties, gas_law

jax.config.update("jax_enable_x64", True)


def _median_time(fn, *args, repeats: int = 7) -> float:
    """Median wall time [s] of ``fn(*args)`` (results blocked on), after one warm-up call."""
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def _system(faces: int, gas: str):
    shell = s3.ball(0.13, 0.9e-3, n_triangles=faces)
    ground = d.Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], d.BarrierContact(1e-3, 1e3), name="ground")
    return shell, d.shell_system(
        shell,
        ShellProperties(gauge_pressure=1300.0, young_modulus=2.34e6, thickness=shell.thickness, poisson_ratio=0.4),
        gas=gas_law(gas),
        mass=0.8,
        planes=[ground],
    )


def breakdown(system, state, dt: float, integrator) -> dict:
    """Isolated timings [s] of one step's pieces at ``state``: Newton's matrix (shell Hessian and
    point blocks), its host factorisation with a solve, a solve with a kept factorisation, and one
    gradient and one energy of the step's incremental potential."""
    potential = d.incremental_potential(system, integrator, state, jnp.asarray(dt))
    y = potential.free(state.position)
    rhs = -potential.gradient(y)

    def matrix(p, y):
        x = p.full(y)
        return p.system.hessian_parts(x), p.point_hessian_blocks(x)

    def fresh_solve(p, y, b):
        s3.release_factorizations(keep_analyses=True)
        return solve(p, y, b)

    solve = eqx.filter_jit(lambda p, y, b: d.SparseNewton().linear_solve(p, y, b))
    hessian = _median_time(eqx.filter_jit(matrix), potential, y)
    return {
        "hessian_s": hessian,
        "host_factorisation_s": max(_median_time(fresh_solve, potential, y, rhs) - hessian, 0.0),
        "host_kept_solve_s": max(_median_time(solve, potential, y, rhs) - hessian, 0.0),
        "gradient_s": _median_time(eqx.filter_jit(lambda p, y: p.gradient(y)), potential, y),
        "energy_s": _median_time(eqx.filter_jit(lambda p, y: p.value(y)), potential, y),
    }


def run(faces: int, dt: float, height: float, chunk: int, chunks: int, integrator, gas: str, reuse: bool) -> dict:
    """Drop a ``faces``-face ball from ``height`` [m]: a compiling chunk, then ``chunks`` timed ones;
    ``reuse``: keep Newton's matrix while it contracts (``SparseNewton(reuse_matrix=...)``)."""
    rollout = eqx.filter_jit(d.rollout)
    start = time.perf_counter()
    shell, system = _system(faces, gas)
    setup = time.perf_counter() - start
    state = d.drop_state(system, system.inflated, height)
    timings, iterations, matrices, gaps = [], [], [], []
    for _ in range(chunks + 1):
        start = time.perf_counter()
        # A compiled roll-out, as simulate's chunks, returning the whole state to start the next one.
        state, record = rollout(system, state, jnp.asarray(dt), chunk, integrator, d.SparseNewton(reuse_matrix=reuse))
        jax.block_until_ready(state)
        timings.append(time.perf_counter() - start)
        if not np.all(np.asarray(record.converged)):
            k = int(np.flatnonzero(~np.asarray(record.converged))[0])
            raise RuntimeError(
                f"step {len(timings) * chunk - chunk + k + 1} did not converge ({faces} faces, {gas} gas)"
            )
        iterations.append(np.asarray(record.newton_iterations))
        matrices.append(np.asarray(record.newton_matrices))
        gaps.append(np.asarray(record.min_gap_m)[:, 0])
    per_step = float(np.median(timings[1:])) / chunk
    parts = breakdown(system, state, dt, integrator)
    newton = float(np.mean(np.concatenate(iterations[1:])))
    fresh = float(np.mean(np.concatenate(matrices[1:])))
    touching = np.concatenate(gaps[1:]) < 1e-3
    hessian = fresh * parts["hessian_s"]
    host = fresh * parts["host_factorisation_s"] + (newton - fresh) * parts["host_kept_solve_s"]
    # Each iteration: a gradient and at least one energy in the line search; one more of each to start.
    energies = (newton + 1.0) * (parts["gradient_s"] + parts["energy_s"])
    return {
        "faces": int(shell.mesh.n_faces),
        "dofs": 3 * shell.mesh.n_vertices,
        "dt_s": dt,
        "integrator": type(integrator).__name__,
        "gas": gas,
        "reuse_matrix": reuse,
        "setup_s": setup,
        "compile_s": timings[0] - per_step * chunk,
        "steps_per_chunk": chunk,
        "timed_chunks": chunks,
        "seconds_per_step": per_step,
        "chunk_seconds": timings[1:],
        "newton_iterations_per_step": newton,
        "newton_matrices_per_step": fresh,
        "steps_in_contact": int(np.sum(touching)),
        "newton_matrices_per_step_in_contact": float(np.mean(np.concatenate(matrices[1:])[touching]))
        if touching.any()
        else None,
        "min_gap_m": float(np.min(np.concatenate(gaps))),
        "final_gap_m": float(gaps[-1][-1]),
        "breakdown_s_per_step": {
            "hessian_assembly": hessian,
            "host_factorisation_solve": host,
            "gradients_energies": energies,
            "other": per_step - hessian - host - energies,
        },
        "isolated_s": parts,
        "projected_1s_of_motion_s": per_step / dt,
    }


def table(rows: list[dict]) -> str:
    """The results as a fixed-width text table."""
    head = (
        f"{'faces':>6} {'reuse':>5} {'setup s':>8} {'compile s':>9} {'ms/step':>8} {'Newton':>6} {'matrix':>6} "
        f"{'Hess ms':>8} {'host ms':>8} {'grad ms':>8} {'other ms':>8} {'1 s [s]':>8}"
    )
    lines = [head]
    for r in rows:
        b = {k: 1e3 * v for k, v in r["breakdown_s_per_step"].items()}
        lines.append(
            f"{r['faces']:>6} {str(r['reuse_matrix']):>5} {r['setup_s']:>8.1f} {r['compile_s']:>9.1f} {1e3 * r['seconds_per_step']:>8.1f} "
            f"{r['newton_iterations_per_step']:>6.2f} {r['newton_matrices_per_step']:>6.2f} {b['hessian_assembly']:>8.1f} {b['host_factorisation_solve']:>8.1f} "
            f"{b['gradients_energies']:>8.1f} {b['other']:>8.1f} {r['projected_1s_of_motion_s']:>8.1f}"
        )
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--faces", type=int, nargs="+", default=[2000])
    p.add_argument("--dt", type=float, default=1e-3)
    p.add_argument("--chunk", type=int, default=25, help="steps per compiled chunk")
    p.add_argument("--chunks", type=int, default=4, help="timed chunks after the compiling one")
    p.add_argument("--height", type=float, default=0.005, help="drop height [m] (contact within the first steps)")
    p.add_argument("--integrator", choices=["newmark", "backward-euler"], default="backward-euler")
    p.add_argument("--gas", choices=["isothermal", "adiabatic", "prescribed"], default="isothermal")
    p.add_argument(
        "--reuse",
        choices=["kept", "fresh", "both"],
        default="both",
        help="Newton's matrix: kept while it contracts (simplified Newton, the default), fresh every iteration, or both",
    )
    p.add_argument("--json", type=Path, default=None, help="write the results here")
    args = p.parse_args()
    integrator = d.Newmark() if args.integrator == "newmark" else d.BackwardEuler()
    reuses = {"kept": [True], "fresh": [False], "both": [True, False]}[args.reuse]
    rows = [
        run(f, args.dt, args.height, args.chunk, args.chunks, integrator, args.gas, r)
        for f in args.faces
        for r in reuses
    ]
    print(table(rows))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        machine = {
            "machine": f"{platform.machine()}, {os.cpu_count()} cores",
            "load_average": os.getloadavg(),
            "date": time.strftime("%Y-%m-%d", time.gmtime()),
        }
        args.json.write_text(json.dumps(machine | {"runs": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
