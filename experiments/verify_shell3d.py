"""Verification report of the 3D shell engine (shelljax.shell3d) with mesh-convergence rates.

Usage: python experiments/verify_shell3d.py [--out results/verify_shell3d.json] [--quick]

Prints a table and writes JSON. Checks (SI units, E = 1 MPa, ν = 0.3, R = 1 m):
1. Inflation of a Neo-Hookean sphere (h = 0.01 m) against (a) the small-strain law
   p = 2Ehδ/(R²(1−ν)) and (b) the exact p(λ) of the shared compressible plane-stress membrane at
   λ = 1.3; for reference (c) the incompressible-limit curve p = 2μ(h/R)(1/λ − 1/λ⁷) at ν → 0.5
   (a different constitutive law at large stretch: reported, not asserted).
2. Point-load stiffness of a sphere (h = 1e-4 m) pinched at its poles, against Reissner (τ = 0)
   and Vella et al. (2012) for τ = 0.1 … 100, on graded meshes with halving pole edge length.
3. A sealed-gas ball indentation: (P_atm + p)V conservation and indenter/ground force balance.
The observed order of convergence is log(e₁/e₂)/log(h₁/h₂) between successive meshes.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import shelljax.shell3d as s3
from shelljax.physics import ATMOSPHERIC_PRESSURE, ShellProperties, lame_constants_2d, vella_linear_stiffness
from shelljax.shell3d import ModelConfig, ShellModel, rigid_mode_pins
from shelljax.physics import IsothermalGas

E, NU = 1.0e6, 0.3


def sphere_model(mesh):
    top, bottom = int(np.argmax(mesh.vertices[:, 2])), int(np.argmin(mesh.vertices[:, 2]))
    fixed = rigid_mode_pins(mesh.vertices)
    fixed[3 * bottom + 2] = True
    return ShellModel(mesh, mesh.vertices, ModelConfig(mesh.n_vertices), fixed), top, bottom


def params(h, p, nu=NU):
    return s3.ShellParams.of(ShellProperties(gauge_pressure=p, young_modulus=E, thickness=h, poisson_ratio=nu))


def p_exact(lam, h, nu=NU):
    alpha, beta = lame_constants_2d(E, nu)
    return h / lam**2 * (beta * (2 * lam - 2 / lam) + alpha * (lam**3 - 1 / lam))


def inflation(n_faces):
    h = 0.01
    mesh = s3.ShellMesh.sphere(1.0, n_faces)
    model, _, _ = sphere_model(mesh)
    q0 = np.concatenate([mesh.vertices.ravel(), np.zeros(3)])
    v0 = float(model.volume(jnp.asarray(q0)))
    p_small = 2 * E * h * 0.002 / (1 - NU)
    res = model.equilibrium(q0, params(h, p_small), atol=1e-9 * E * h)
    lam = (float(model.volume(jnp.asarray(res.value))) / v0) ** (1 / 3)
    err_small = 2 * E * h * (lam - 1) / (1 - NU) / p_small - 1
    q = res.value
    for lt in (1.1, 1.2, 1.3):
        res = model.equilibrium(q, params(h, p_exact(lt, h)), atol=1e-9 * E * h)
        q = res.value
    lam = (float(model.volume(jnp.asarray(q))) / v0) ** (1 / 3)
    err_large = p_exact(lam, h) / p_exact(1.3, h) - 1
    # Incompressible-limit comparison at ν = 0.499 and a small stretch, where both laws agree.
    nu = 0.499
    mu = E / (2 * (1 + nu))
    p_inc = 2 * mu * h * (1 / 1.01 - 1 / 1.01**7)
    res = model.equilibrium(q0, params(h, p_inc, nu), atol=1e-9 * E * h)
    lam = (float(model.volume(jnp.asarray(res.value))) / v0) ** (1 / 3)
    err_inc = 2 * mu * h * (1 / lam - 1 / lam**7) / p_inc - 1
    edge = np.sqrt(8 * np.pi / (np.sqrt(3) * mesh.n_faces))
    return dict(
        faces=mesh.n_faces,
        edge=edge,
        small_strain=err_small,
        exact_lambda_1p3=err_large,
        incompressible_lambda_1p01=err_inc,
    )


def stiffness(pole_spacing, taus):
    h = 1e-4
    mesh = s3.ShellMesh.sphere(1.0, max_spacing=0.15, pole_spacing=pole_spacing, growth=0.15)
    model, top, bottom = sphere_model(mesh)
    b = E * h**3 / (12 * (1 - NU**2))
    q = np.concatenate([mesh.vertices.ravel(), np.zeros(3)])
    out = {}
    for tau in taus:
        p = tau * 4 * np.sqrt(E * h * b)
        if p > 0:
            q = model.equilibrium(q, params(h, p), atol=1e-10 * E * h).value
        x = q[:-3].reshape(-1, 3)
        r_now = 0.5 * np.linalg.norm(x[top] - x[bottom])
        load = np.zeros(model.n_dofs)
        load[3 * top + 2] = -1.0
        u = model.linear_response(q, params(h, p), load)
        out[tau] = (2.0 / -u[3 * top + 2]) / vella_linear_stiffness(p, r_now, E, h, NU) - 1
    return mesh.n_faces, out


def rate(e1, e2, h1, h2):
    if e1 == 0 or e2 == 0:
        return float("nan")
    return float(np.log(abs(e1) / abs(e2)) / np.log(h1 / h2))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="results/verify_shell3d.json")
    ap.add_argument("--quick", action="store_true", help="coarser meshes (smoke run)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    report = {"machine": f"{platform.node()} {platform.processor() or platform.machine()} ({platform.system()})"}
    sizes = (350, 1400) if args.quick else (350, 1400, 5600)
    infl = [inflation(n) for n in sizes]
    print("\n1. Inflation of a Neo-Hookean sphere (relative errors of pressure)")
    print(f"{'faces':>7} {'edge/R':>8} {'small-strain':>13} {'exact λ=1.3':>12} {'incompr. λ=1.01':>16} {'rate':>6}")
    for i, r in enumerate(infl):
        rt = (
            rate(infl[i - 1]["exact_lambda_1p3"], r["exact_lambda_1p3"], infl[i - 1]["edge"], r["edge"])
            if i
            else float("nan")
        )
        r["rate_exact"] = rt
        print(
            f"{r['faces']:>7} {r['edge']:>8.4f} {r['small_strain']:>13.2e} {r['exact_lambda_1p3']:>12.2e} {r['incompressible_lambda_1p01']:>16.2e} {rt:>6.2f}"
        )
    report["inflation"] = infl
    taus = (0.0, 0.1, 1.0, 10.0, 100.0)
    spacings = (8e-4, 4e-4) if args.quick else (8e-4, 4e-4, 2e-4)
    print("\n2. Point-load stiffness k/k_theory − 1 (τ = 0: Reissner; τ > 0: Vella et al. 2012), h/R = 1e-4")
    print(f"{'pole edge/R':>11} {'faces':>6} " + " ".join(f"{'τ=' + str(t):>9}" for t in taus))
    stiff = []
    for s in spacings:
        n, errs = stiffness(s, taus)
        stiff.append({"pole_spacing": s, "faces": n, "errors": {str(t): e for t, e in errs.items()}})
        print(f"{s:>11.1e} {n:>6} " + " ".join(f"{errs[t]:>9.2e}" for t in taus))
    rates = {}
    for t in taus:
        rates[str(t)] = rate(stiff[-2]["errors"][str(t)], stiff[-1]["errors"][str(t)], spacings[-2], spacings[-1])
    print(f"{'rate':>11} {'':>6} " + " ".join(f"{rates[str(t)]:>9.2f}" for t in taus))
    report["point_load"] = {"rows": stiff, "rates_last_pair": rates}
    # 3. Sealed gas and balance on a ball indentation.
    ball = s3.ball(radius=0.13, thickness=0.9e-3, n_triangles=1000 if args.quick else 3000)
    sim = s3.Indentation(
        ball,
        ShellProperties(gauge_pressure=1300.0, young_modulus=2.34e6, thickness=ball.thickness, poisson_ratio=0.4),
        gas=IsothermalGas(),
        indenter_radius=0.008,
        progress=False,
    )
    rows = []
    p0v0 = (ATMOSPHERIC_PRESSURE + 1300.0) * sim.reference_volume
    print("\n3. Sealed isothermal ball (R = 0.13 m, h = 0.9 mm, E = 2.34 MPa, P_g = 1300 Pa)")
    print(f"{'depth[m]':>9} {'F[N]':>8} {'ground[N]':>10} {'p[Pa]':>9} {'pV/p0V0-1':>10}")
    for st in sim.curve([0.005, 0.01, 0.02]):
        o = st.observables()
        pv = (ATMOSPHERIC_PRESSURE + o["pressure"]) * o["volume"] / p0v0 - 1
        rows.append(dict(o, pv_error=pv))
        print(f"{st.depth:>9.3f} {o['force']:>8.3f} {o['ground_reaction']:>10.3f} {o['pressure']:>9.1f} {pv:>10.1e}")
    report["sealed_ball"] = rows
    report["wall_s"] = time.perf_counter() - t0
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2, default=float))
    print(f"\nwrote {out} ({report['wall_s']:.0f} s)")


if __name__ == "__main__":
    main()
