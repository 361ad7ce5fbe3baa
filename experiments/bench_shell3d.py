"""Benchmark of the 3D shell engine: a 7-level indentation curve of a ball on the ground.

Usage: python experiments/bench_shell3d.py [--sizes 1000 5000 20000 80000] [--repeats 1]
       [--out results/bench_shell3d.json]

Ball R = 0.13 m, h = 0.9 mm, E = 2.34 MPa, ν = 0.4, P_g = 1300 Pa (sealed isothermal gas),
indenter radius 8 mm, depths 2/7 … 2 cm. Each size runs in its own subprocess so that the peak
resident memory (ru_maxrss) is per size. Reported: setup (mesh, rest shape, reference state,
includes compiling the free-shell functions), cold curve (includes compiling the contact model),
warm curve (median over repeats; compile ≈ cold − warm), Newton iterations, Hessian
factorizations and CG Hessian-vector products per level, peak RSS, the element-Hessian assembly throughput against the XLA
cost-analysis flop count of that kernel, and one factorization + solve of the final Hessian.
Not a test: numbers depend on the machine, which is named in the output.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path
from shelljax.physics import IsothermalGas

DEPTHS = [0.02 * (i + 1) / 7 for i in range(7)]


def run_one(n_triangles: int, repeats: int) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    import shelljax.shell3d as s3
    from shelljax.physics import ShellProperties

    t0 = time.perf_counter()
    pezzi = ShellProperties(gauge_pressure=1300.0, young_modulus=2.34e6, thickness=0.9e-3, poisson_ratio=0.4)
    ball = s3.ball(radius=0.13, thickness=pezzi.thickness, n_triangles=n_triangles)
    sim = s3.Indentation(ball, pezzi, gas=IsothermalGas(), indenter_radius=0.008, progress=False)
    setup = time.perf_counter() - t0
    t0 = time.perf_counter()
    states = sim.curve(DEPTHS)
    cold = time.perf_counter() - t0
    warm = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        states = sim.curve(DEPTHS)
        warm.append(time.perf_counter() - t0)
    model = sim.model
    q = jnp.asarray(states[-1].q)
    params = model.host_params(sim.params_at(states[-1].q))
    model.hessian_values(q, params).block_until_ready()
    reps, t0 = 5, time.perf_counter()
    for _ in range(reps):
        model.hessian_values(q, params).block_until_ready()
    t_hess = (time.perf_counter() - t0) / reps
    try:
        # XLA's cost analysis counts a loop body once: count the flops of the face kernel over all
        # faces at once (the same arithmetic as the chunked loop that was timed).
        cost = s3.face_hessians.lower(q, params, model.geometry, model.jit_config, 0, ball.mesh.n_faces)
        cost = cost.compile().cost_analysis()
        cost = cost[0] if isinstance(cost, (list, tuple)) else cost
        flops = float(cost.get("flops", float("nan")))
    except Exception:  # cost analysis is backend-dependent
        flops = float("nan")
    mat, rank_one = model.host_hessian(states[-1].q, sim.params_at(states[-1].q))
    s3.SparseSolver(mat, rank_one, symmetric=True)  # the pattern's symbolic analysis, done once
    t_fact = []
    for _ in range(reps):
        t0 = time.perf_counter()
        solver = s3.SparseSolver(mat, rank_one, symmetric=True)
        solver.apply_inverse(np.ones(mat.shape[0]))
        t_fact.append(time.perf_counter() - t0)
    obs = states[-1].observables()
    return {
        "faces": ball.mesh.n_faces,
        "dofs": model.n_dofs,
        "nnz": model.pattern.nnz,
        "setup_s": setup,
        "curve_cold_s": cold,
        "curve_warm_s": float(np.median(warm)),
        "compile_s_estimate": cold - float(np.median(warm)),
        "newton_iterations": [s.iterations for s in states],
        "factorizations": [s.factorizations for s in states],
        "hessian_products": [s.products for s in states],
        "factorization_method": solver.method,
        "factorization_s": float(np.median(t_fact)),
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "hessian_assembly_s": t_hess,
        "hessian_faces_per_s": ball.mesh.n_faces / t_hess,
        "hessian_gflop": flops / 1e9,
        "hessian_gflops_per_s": flops / 1e9 / t_hess,
        "final_force_N": obs["force"],
        "final_w0_m": obs["w0"],
        "rest_mismatch_m": sim.rest_mismatch,
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 5000, 20000, 80000])
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--out", default="results/bench_shell3d.json")
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        print(json.dumps(run_one(args.one, args.repeats)))
        return
    machine = (
        f"{platform.node()}: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, {platform.system()}"
    )
    rows = []
    for n in args.sizes:
        out = subprocess.run(
            [sys.executable, __file__, "--one", str(n), "--repeats", str(args.repeats)], capture_output=True, text=True
        )
        if out.returncode != 0:
            print(f"size {n}: failed\n{out.stderr[-2000:]}")
            rows.append({"target_faces": n, "error": out.stderr[-2000:]})
            continue
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
    print(f"machine: {machine}")
    hdr = (
        f"{'faces':>7} {'dofs':>7} {'setup[s]':>9} {'compile[s]':>10} {'curve[s]':>9} {'Newton its/level':>24} "
        f"{'factorizations/level':>24} {'CG products/level':>28} {'peak[MiB]':>10} {'assembly[ms]':>12} {'GFLOP/s':>8} {'factor[ms]':>10} {'F(2cm)[N]':>9}"
    )
    print(hdr)
    for r in rows:
        if "error" in r:
            print(f"{r['target_faces']:>7} failed")
            continue
        its = ",".join(str(i) for i in r["newton_iterations"])
        facts = ",".join(str(i) for i in r["factorizations"])
        products = ",".join(str(i) for i in r.get("hessian_products", []))
        print(
            f"{r['faces']:>7} {r['dofs']:>7} {r['setup_s']:>9.1f} {r['compile_s_estimate']:>10.1f} {r['curve_warm_s']:>9.1f} "
            f"{its:>24} {facts:>24} {products:>28} {r['peak_rss_mib']:>10.0f} {1e3 * r['hessian_assembly_s']:>12.1f} "
            f"{r['hessian_gflops_per_s']:>8.2f} {1e3 * r['factorization_s']:>10.1f} {r['final_force_N']:>9.3f}"
        )
    path = Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"machine": machine, "depths_m": DEPTHS, "rows": rows}, indent=2))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
