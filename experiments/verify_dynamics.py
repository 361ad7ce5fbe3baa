"""Expensive verifications of the 3D shell in motion (docs/dynamics.md, *Verified on the 3D shell*).

For one ball (default: R = 5 cm, 200 faces, P_g = 5 kPa, E = 2 MPa, h = 0.5 mm, 0.1 kg):

1. energy: the drift of an undamped Newmark bounce, and backward Euler's COR, against Δt;
2. contact time and peak force of a drop against the 1-DOF model m ẍ = −F_ground(x) fed with the
   engine's own quasi-static ground force–compression curve, and against the textbook
   pressurized ball k = 2πR P_g;
3. the maximum contact diameter against the quasi-static state at the same ground force;
4. adiabatic against isothermal gas.

    python3 experiments/verify_dynamics.py [--faces 200] [--height 0.02] [--out runs/verify_dynamics.json]
"""

from __future__ import annotations

import argparse
import json
import math
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import shelljax.shell3d as s3
from shelljax import NoConvergenceError
from shelljax import dynamics as d
from shelljax.physics import STANDARD_GRAVITY as G

jax.config.update("jax_enable_x64", True)


def make_system(args, gas="isothermal", gravity=G):
    shell = s3.ball(args.radius, args.thickness, n_triangles=args.faces)
    ground = d.Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], d.BarrierContact(args.ghat, 1e3), name="ground")
    return d.shell_system(shell, args.young, 0.4, args.pressure, gas=gas, mass=args.mass, planes=[ground], gravity=gravity)


def contact_diameter(x, ghat):
    """Diameter [m] of the vertices within the barrier's range of the ground (2 × their largest distance from their centroid)."""
    nodes = np.asarray(x).reshape(-1, 3)
    touching = nodes[nodes[:, 2] < ghat]
    if len(touching) < 2:
        return 0.0
    return 2.0 * float(np.max(np.linalg.norm(touching[:, :2] - touching[:, :2].mean(axis=0), axis=1)))


def drop(system, args, dt, duration, integrator=None, damping=0.0):
    system = system.with_planes([eqx.tree_at(lambda p: p.damping, system.planes[0], jnp.asarray(damping))])
    speed = math.sqrt(2 * G * (args.height - 2 * args.ghat))
    state = d.drop_state(system, system.inflated, 2 * args.ghat, velocity=[0.0, 0.0, -speed])
    start = time.perf_counter()
    try:
        traj = d.simulate(system, state, dt, duration, integrator=integrator or d.Newmark(), minimiser=d.SparseNewton(), progress=False)
    except NoConvergenceError as err:
        return {"dt_s": dt, "failed": str(err).splitlines()[0]}
    seconds = time.perf_counter() - start
    impacts = d.measured_cor(traj)
    e = traj["total_energy_J"]
    out = {"dt_s": dt, "seconds": seconds, "steps": len(e) - 1, "max_energy_change_per_mgH": float(np.max(np.abs(e - e[0])) / (args.mass * G * args.height))}
    if impacts:
        m = impacts[0]
        out.update(contact_time_s=m.contact_time_s, peak_force_N=m.peak_force_N, max_compression_m=m.max_compression_m,
                   cor=math.sqrt(max(m.bounce_height_m, 0.0) / (m.speed_in_m_per_s**2 / (2 * G))))  # fmt: skip
        k = int(np.argmax(traj["contact_force_N"][:, 0, 2]))
        out["diameter_at_peak_m"] = contact_diameter(traj["position_m"][k], args.ghat)
    return out


def quasi_static_curve(args, levels):
    """(compression [m], ground force [N], contact diameter [m]) of the ball resting under gravity scaled by each level."""
    base = make_system(args)
    rows = []
    for level in levels:
        system = eqx.tree_at(lambda s: s.gravity, base, base.gravity * level)
        state = d.drop_state(system, system.inflated, args.ghat / 2)
        z0 = float(system.centre_of_mass(state.position)[2])
        # Backward Euler at Δt = 10 ms damps the contact mode (ω ≈ 100 /s) by ~0.7 per step: 50 steps settle.
        traj = d.simulate(system, state, 0.01, 0.5, integrator=d.BackwardEuler(), minimiser=d.SparseNewton(), progress=False)
        x = traj["position_m"][-1]
        rows.append((z0 - float(system.centre_of_mass(jnp.asarray(x))[2]), level * G * args.mass, contact_diameter(x, args.ghat)))
    return np.array(rows)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--faces", type=int, default=200)
    p.add_argument("--radius", type=float, default=0.05)
    p.add_argument("--thickness", type=float, default=0.5e-3)
    p.add_argument("--young", type=float, default=2e6)
    p.add_argument("--pressure", type=float, default=5000.0)
    p.add_argument("--mass", type=float, default=0.1)
    p.add_argument("--ghat", type=float, default=5e-4)
    p.add_argument("--height", type=float, default=0.02)
    p.add_argument("--duration", type=float, default=0.06)
    p.add_argument("--out", default="runs/verify_dynamics.json")
    p.add_argument("--skip-dt-study", action="store_true", help="only the finest Newmark drop, not the Δt study")
    args = p.parse_args()
    report = {"ball": vars(args)}
    system = make_system(args)
    steps = (2.5e-4,) if args.skip_dt_study else (1e-3, 5e-4, 2.5e-4)
    report["newmark"] = [drop(system, args, dt, args.duration) for dt in steps]
    if not args.skip_dt_study:
        report["backward_euler"] = [drop(system, args, dt, args.duration, d.BackwardEuler()) for dt in (2e-3, 1e-3, 5e-4)]
    print(json.dumps(report, indent=1), flush=True)
    reference = report["newmark"][-1]  # the finest Δt
    curve = quasi_static_curve(args, (1.0, 3.0, 6.0, 10.0, 15.0, 20.0))
    report["quasi_static"] = {"compression_m": curve[:, 0].tolist(), "force_N": curve[:, 1].tolist(), "diameter_m": curve[:, 2].tolist()}
    one_dof = d.PointMassOnGround(args.mass, [d.ground(d.TabulatedCompressionCurve(curve[:, 0], curve[:, 1]))])
    speed = math.sqrt(2 * G * (args.height - 2 * args.ghat))
    traj = d.simulate(one_dof, d.initial_state(one_dof, [0.0, 0.0, 0.0], [0.0, 0.0, -speed]), 2e-5, args.duration, progress=False)
    m = d.measured_cor(traj)[0]
    report["one_dof"] = {"contact_time_s": m.contact_time_s, "peak_force_N": m.peak_force_N, "max_compression_m": m.max_compression_m}
    radius = args.radius
    report["textbook"] = {"stiffness_N_per_m": d.pressurized_ball_stiffness(radius, args.pressure),
                          "contact_time_s": d.pressurized_ball_contact_time(args.mass, radius, args.pressure),
                          "peak_force_N": speed * math.sqrt(d.pressurized_ball_stiffness(radius, args.pressure) * args.mass)}  # fmt: skip
    report["quasi_static_diameter_at_peak_m"] = float(np.interp(reference["peak_force_N"], curve[:, 1], curve[:, 2]))
    report["adiabatic"] = drop(make_system(args, gas="adiabatic"), args, 2.5e-4, args.duration)
    print(json.dumps(report, indent=1))
    from pathlib import Path

    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
