"""Benchmark of the device-side linear solve: host CHOLMOD against block-Jacobi CG in JAX.

Usage: python experiments/bench_device_solve.py [--faces 20000 ...] [--repeats 3]
       [--rows curve drop kernels] [--out results/bench_device_solve.json]
       [--drop-duration S] [--drop-damping C]

Rows: the host path (``DirectSolver``, ``SparseNewton``) runs on the CPU device, the Krylov path on
the default JAX device (a GPU when JAX sees one), whose platform and kind the JSON records; each row
also gives ``cpu_path_s`` (the host path) and ``device_path_s`` (the Krylov path), warm:

- ``curve``: one 7-level indentation curve (depths 2/7 … 2 cm) of a ball of ``--faces`` N faces
  (R = 0.13 m, h = 0.9 mm, E = 2.34 MPa, ν = 0.4, P_g = 1300 Pa, sealed isothermal gas, indenter
  8 mm), with ``shell3d.DirectSolver()`` and ``shell3d.KrylovSolver()``: cold (compiles included)
  and warm wall times (median of ``--repeats``), Newton iterations, CG iterations, and the
  largest relative difference of the indenter forces between the two.
- ``drop``: the 1 m drop of configs/drop.toml (its object, mesh, gas, planes, integrator, Δt;
  the contact damping fixed at ``--drop-damping`` instead of calibrated) for ``--drop-duration``
  seconds (default the config's), with ``dynamics.SparseNewton`` and ``dynamics.KrylovNewton``:
  wall times, Newton iterations and matrices, CG iterations of one solve at the last state, and
  the largest position difference relative to the run's largest displacement.
- ``kernels``: at each N, the CSR product by ``segment_sum`` against ``jax.experimental.sparse``
  BCSR, and CG with the 3×3 block-Jacobi against the point-Jacobi preconditioner (iterations and
  time to a relative residual of 1e-10) on the Hessian at the reference state.

Not a test: numbers depend on the machine, which is named in the output.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

DEPTHS = [0.02 * (i + 1) / 7 for i in range(7)]
ROOT = Path(__file__).resolve().parent.parent


def _place(name: str):
    """The device context of a solver path: the host's CPU for the direct path, JAX's default device
    (the GPU when there is one) for the Krylov path."""
    import contextlib

    import jax

    return contextlib.nullcontext() if name == "krylov" else jax.default_device(jax.devices("cpu")[0])


def _timed(fn, repeats: int):
    """(cold result, cold time [s], median warm time [s], last warm result)."""
    t0 = time.perf_counter()
    cold = fn()
    cold_s = time.perf_counter() - t0
    warm, result = [], cold
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        warm.append(time.perf_counter() - t0)
    return cold, cold_s, statistics.median(warm), result


def _indentation(n_faces: int, linear_solver, tolerance_scale: float = 1.0):
    import shelljax.shell3d as s3
    from shelljax.physics import IsothermalGas, ShellProperties

    pezzi = ShellProperties(gauge_pressure=1300.0, young_modulus=2.34e6, thickness=0.9e-3, poisson_ratio=0.4)
    ball = s3.ball(radius=0.13, thickness=pezzi.thickness, n_triangles=n_faces)
    # Newton's default force tolerance, 1e-8 E h L (L = 2R), scaled.
    atol = tolerance_scale * 1e-8 * pezzi.young_modulus * pezzi.thickness * 0.26
    return s3.Indentation(
        ball,
        pezzi,
        gas=IsothermalGas(),
        indenter_radius=0.008,
        progress=False,
        linear_solver=linear_solver,
        force_tolerance=atol,
    )


def curve_row(n_faces: int, repeats: int, tolerance_scale: float) -> dict:
    import shelljax.shell3d as s3

    row, forces = {"row": "curve", "faces": n_faces, "force_tolerance_scale": tolerance_scale}, {}
    for name, solver in (("direct", s3.DirectSolver()), ("krylov", s3.KrylovSolver())):
        with _place(name):
            sim = _indentation(n_faces, solver, tolerance_scale)
            _, cold, warm, states = _timed(lambda sim=sim: sim.curve(DEPTHS), repeats)
        forces[name] = [s.observables()["force"] for s in states]
        row.update(
            {
                f"{name}_cold_s": cold,
                f"{name}_warm_s": warm,
                f"{name}_newton_iterations": sum(s.iterations for s in states),
                f"{name}_krylov_iterations": sum(s.krylov_iterations for s in states),
            }
        )
        s3.release_factorizations()
    row["dofs"] = 3 * sim.model.mesh.n_vertices + 3
    row["max_force_rel_diff"] = max(abs(a - b) / abs(a) for a, b in zip(forces["direct"], forces["krylov"]))
    row["speedup_warm"] = row["direct_warm_s"] / row["krylov_warm_s"]
    row["cpu_path_s"], row["device_path_s"] = row["direct_warm_s"], row["krylov_warm_s"]
    return row


def drop_row(repeats: int, duration: float | None, damping: float, config: Path) -> dict:
    import jax.numpy as jnp
    import numpy as np

    from shelljax import dynamics as d
    from shelljax.scenario import SCENARIO_CHUNK, build_system, initial_state, load_scenario, resolve_object

    scenario = load_scenario(config)
    system = build_system(scenario, resolve_object(scenario), damping)
    state = initial_state(scenario, system, 1.0)
    duration = scenario.duration if duration is None else duration
    integrator = {"newmark": d.Newmark, "backward-euler": d.BackwardEuler, "tr-bdf2": d.TRBDF2}[scenario.scheme]()
    alpha, beta = scenario.rayleigh
    rayleigh = d.Rayleigh(alpha, beta) if alpha or beta else None
    row = {"row": "drop", "faces": int(system.faces.shape[0]), "dt_s": scenario.dt, "duration_s": duration}
    row["drop_height_m"], row["contact_damping_N_s_per_m"] = 1.0, damping
    positions = {}
    minimisers = {
        "sparse": d.SparseNewton(step_tolerance=scenario.step_tolerance),
        "krylov": d.KrylovNewton(step_tolerance=scenario.step_tolerance),
    }
    for name, minimiser in minimisers.items():

        def run(minimiser=minimiser):
            return d.simulate(
                system,
                state,
                scenario.dt,
                duration,
                integrator=integrator,
                minimiser=minimiser,
                rayleigh=rayleigh,
                chunk=SCENARIO_CHUNK,
                progress=False,
            )

        with _place(name):
            _, cold, warm, trajectory = _timed(run, repeats)
        positions[name] = trajectory["position_m"]
        row.update(
            {
                f"{name}_cold_s": cold,
                f"{name}_warm_s": warm,
                f"{name}_newton_iterations": int(np.sum(trajectory["newton_iterations"])),
                f"{name}_newton_matrices": int(np.sum(trajectory["newton_matrices"])),
            }
        )
        print(f"drop, {name}: cold {cold:.1f} s, warm {warm:.1f} s", flush=True)
    last = d.DynamicState(
        state.time + duration,
        jnp.asarray(positions["krylov"][-1]),
        jnp.zeros_like(state.velocity),
        jnp.zeros_like(state.acceleration),
    )
    potential = d.incremental_potential(system, integrator, last, scenario.dt, rayleigh)
    y = potential.free(last.position)
    rhs = potential.gradient(y)
    row["krylov_iterations_per_solve"] = int(minimisers["krylov"].krylov_iterations(potential, y, rhs))
    travel = float(np.max(np.abs(positions["sparse"] - positions["sparse"][0])))
    row["max_position_rel_diff"] = float(np.max(np.abs(positions["sparse"] - positions["krylov"]))) / travel
    row["speedup_warm"] = row["sparse_warm_s"] / row["krylov_warm_s"]
    row["cpu_path_s"], row["device_path_s"] = row["sparse_warm_s"], row["krylov_warm_s"]
    return row


def kernels_row(n_faces: int, repeats: int) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np
    from jax.experimental import sparse as jsparse

    import shelljax.shell3d as s3
    from shelljax.shell3d.internal import krylov_solve

    sim = _indentation(n_faces, s3.DirectSolver())
    model = sim.model
    operator = model.device_operator(sim.q_reference, sim.params_at(sim.q_reference))
    v = jnp.asarray(np.random.default_rng(0).normal(size=model.n_dofs))
    pattern = model.pattern
    bcsr = jsparse.BCSR(
        (operator.values, jnp.asarray(pattern.indices), jnp.asarray(pattern.indptr, dtype=jnp.int32)),
        shape=(model.n_dofs, model.n_dofs),
    )
    segment = jax.jit(lambda op, v: op.mv(v))
    experimental = jax.jit(lambda m, v: m @ v)
    row = {"row": "kernels", "faces": n_faces, "nnz": pattern.nnz}
    for name, fn, arg in (("segment_sum", segment, operator), ("bcsr", experimental, bcsr)):
        _, _, warm, _ = _timed(lambda fn=fn, arg=arg: fn(arg, v).block_until_ready(), max(repeats, 20))
        row[f"matvec_{name}_s"] = warm
    rhs = jnp.asarray(np.where(model.free, 1.0, 0.0))
    for name, nodal in (("block_jacobi", True), ("point_jacobi", False)):
        _, _, warm, out = _timed(
            lambda nodal=nodal: jax.block_until_ready(krylov_solve(operator, rhs, 1e-10, 20000, nodal)), repeats
        )
        row[f"cg_{name}_iterations"] = int(out[1])
        row[f"cg_{name}_status"] = int(out[2])
        row[f"cg_{name}_s"] = warm
    return row


def _table(rows: list[dict]) -> str:
    lines = ["row      faces   reference [s]   krylov [s]   speed-up   Newton it.   CG it.   max rel. diff"]
    for r in rows:
        if r["row"] == "curve":
            lines.append(
                f"curve   {r['faces']:6d}   {r['direct_warm_s']:12.2f}   {r['krylov_warm_s']:10.2f}   "
                f"{r['speedup_warm']:8.2f}   {r['direct_newton_iterations']:4d}/{r['krylov_newton_iterations']:4d}   "
                f"{r['krylov_krylov_iterations']:6d}   {r['max_force_rel_diff']:.1e} (force)"
            )
        elif r["row"] == "drop":
            lines.append(
                f"drop    {r['faces']:6d}   {r['sparse_warm_s']:12.2f}   {r['krylov_warm_s']:10.2f}   "
                f"{r['speedup_warm']:8.2f}   {r['sparse_newton_iterations']:4d}/{r['krylov_newton_iterations']:4d}   "
                f"{r['krylov_iterations_per_solve']:6d}   {r['max_position_rel_diff']:.1e} (positions)"
            )
        else:
            lines.append(
                f"kernels {r['faces']:6d}   matvec segment_sum {1e3 * r['matvec_segment_sum_s']:.3f} ms, BCSR "
                f"{1e3 * r['matvec_bcsr_s']:.3f} ms; CG block Jacobi {r['cg_block_jacobi_iterations']} it. "
                f"{r['cg_block_jacobi_s']:.3f} s, point Jacobi {r['cg_point_jacobi_iterations']} it. "
                f"{r['cg_point_jacobi_s']:.3f} s"
            )
    return "\n".join(lines)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--faces", type=int, nargs="+", default=[20000], help="ball sizes of the curve and kernel rows")
    p.add_argument("--repeats", type=int, default=3, help="warm repeats per timing (median)")
    p.add_argument("--rows", nargs="+", choices=["curve", "drop", "kernels"], default=["curve", "drop"])
    p.add_argument("--out", type=Path, default=Path("results/bench_device_solve.json"), help="JSON output")
    p.add_argument("--drop-duration", type=float, default=None, help="simulated time [s] (default: the config's)")
    p.add_argument("--drop-damping", type=float, default=20.0, help="contact damping [N·s/m] (not calibrated)")
    p.add_argument(
        "--tolerance-scale",
        type=float,
        default=1.0,
        help="Newton's force tolerance of the curve row as a multiple of the default 1e-8 E h L [-]: the force "
        "difference between the solvers is that of where each Newton stops (≈ 1e-5 at 1; 1e-3 tests the solves)",
    )
    p.add_argument("--config", type=Path, default=ROOT / "configs" / "drop.toml", help="the drop scenario")
    args = p.parse_args(argv)

    import jax

    jax.config.update("jax_enable_x64", True)
    device = jax.devices()[0]
    rows = []
    for name in args.rows:
        if name == "drop":
            rows.append(drop_row(args.repeats, args.drop_duration, args.drop_damping, args.config))
            continue
        for n in args.faces:
            rows.append(
                curve_row(n, args.repeats, args.tolerance_scale) if name == "curve" else kernels_row(n, args.repeats)
            )
    print(_table(rows))
    out = {
        "machine": f"{platform.node()} {platform.machine()} ({platform.system()})",
        "device_platform": device.platform,
        "device_kind": device.device_kind,
        "jax_version": jax.__version__,
        "repeats": args.repeats,
        "rows": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
