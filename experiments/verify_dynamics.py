"""Expensive verifications of the 3D shell in motion (docs/dynamics.md, *Verified on the 3D shell*).

For one ball (default: R = 5 cm, 200 faces, P_g = 5 kPa, E = 2 MPa, h = 0.5 mm, 0.1 kg), parts:

* energy: the drift of an undamped Newmark bounce, and backward Euler's COR, against Δt;
* model: contact time and peak force of a drop against the 1-DOF model m ẍ = −F_ground(x) fed
  with the engine's own quasi-static ground force–compression curve, and against the textbook
  pressurized ball k = 2πR P_g; the contact diameter at the peak against the quasi-static one;
* adiabatic: adiabatic against isothermal gas;
* cor: COR(c = 0) and `calibrate_contact_damping` to 0.6, 0.75, 0.9 (the issue's item 2);
* diameter: the maximum contact diameter of drops from several heights against the quasi-static
  state at the same ground force, on two meshes and two schemes (item 4);
* convergence: contact time, peak force, compression and COR at a fixed c under Δt and mesh
  refinement (item 6).

    python3 experiments/verify_dynamics.py [--parts cor,diameter,convergence] [--out docs/bench/verify-dynamics.json]

    python3 experiments/verify_dynamics.py --parts diameter --diameter-faces 1000 --diameter-schemes backward_euler

Each part's results replace that part's key in the JSON file; the other keys are kept (the diameter
part's meshes accumulate).
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import shelljax.shell3d as s3
from shelljax import InvalidInputError, NoConvergenceError
from shelljax import dynamics as d
from shelljax.physics import AdiabaticGas, IsothermalGas, STANDARD_GRAVITY as G, ShellProperties

jax.config.update("jax_enable_x64", True)

PARTS = ("energy", "model", "adiabatic", "cor", "diameter", "convergence")
TARGETS = (0.6, 0.75, 0.9)


@functools.cache
def _shell(radius, thickness, faces):
    return s3.ball(radius, thickness, n_triangles=faces)


def make_system(args, gas=IsothermalGas(), gravity=G, faces=None):
    shell = _shell(args.radius, args.thickness, faces or args.faces)
    ground = d.Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], d.BarrierContact(args.ghat, 1e3), name="ground")
    return d.shell_system(
        shell,
        ShellProperties(
            gauge_pressure=args.pressure, young_modulus=args.young, thickness=shell.thickness, poisson_ratio=0.4
        ),
        gas=gas,
        mass=args.mass,
        planes=[ground],
        gravity=gravity,
    )


def contact_diameter(x, ghat):
    """Diameter [m] of the vertices within the barrier's range of the ground (2 × their largest distance from their centroid)."""
    nodes = np.asarray(x).reshape(-1, 3)
    touching = nodes[nodes[:, 2] < ghat]
    if len(touching) < 2:
        return 0.0
    return 2.0 * float(np.max(np.linalg.norm(touching[:, :2] - touching[:, :2].mean(axis=0), axis=1)))


def edge_contact_diameter(x, edges, level):
    """Sub-vertex contact diameter [m] on the ground z = 0 (``shelljax.dynamics.contact_diameter``)."""
    nodes = np.asarray(x).reshape(-1, 3)
    return d.contact_diameter(nodes, edges, nodes[:, 2], np.array([0.0, 0.0, 1.0]), level)


def touching_com_height(system, ghat):
    """Centre-of-mass height [m] of the inflated ball whose lowest vertex is ``ghat`` above the ground (compression 0)."""
    x = np.asarray(system.inflated).reshape(-1, 3)
    return float(system.centre_of_mass(system.inflated)[2]) - float(x[:, 2].min()) + ghat


def with_damping(system, c):
    return system.with_planes([eqx.tree_at(lambda p: p.damping, system.planes[0], jnp.asarray(c))])


def run_drop(system, args, height, dt, duration, integrator=None, damping=0.0):
    """The trajectory of a drop from ``height`` [m], started 2ĝ above the ground at the impact speed, or the failure message."""
    speed = math.sqrt(2 * G * (height - 2 * args.ghat))
    damped = with_damping(system, damping)
    state = d.drop_state(damped, damped.inflated, 2 * args.ghat, velocity=[0.0, 0.0, -speed])
    try:
        return d.simulate(
            damped,
            state,
            dt,
            duration,
            integrator=integrator or d.Newmark(),
            minimiser=d.SparseNewton(),
            progress=False,
        )
    except NoConvergenceError as err:
        return str(err).splitlines()[0]


def drop(system, args, dt, duration, integrator=None, damping=0.0, height=None):
    """Summary of one drop: energy change, the first impact's contact time [s], peak force [N], compression [m], COR, diameters [m]."""
    start = time.perf_counter()
    traj = run_drop(system, args, height or args.height, dt, duration, integrator, damping)
    if isinstance(traj, str):
        return {"dt_s": dt, "failed": traj}
    impacts = d.measured_cor(traj)
    e = traj["total_energy_J"]
    out = {
        "dt_s": dt,
        "seconds": time.perf_counter() - start,
        "steps": len(e) - 1,
        "max_energy_change_per_mgH": float(np.max(np.abs(e - e[0])) / (args.mass * G * (height or args.height))),
    }
    if impacts:
        m = impacts[0]
        out.update(
            contact_time_s=m.contact_time_s,
            peak_force_N=m.peak_force_N,
            max_compression_m=m.max_compression_m,
            cor=bounce_cor(impacts),
        )
        k = int(np.argmax(traj["contact_force_N"][:, 0, 2]))
        out["diameter_at_peak_m"] = contact_diameter(traj["position_m"][k], args.ghat)
        out["edge_diameter_at_peak_m"] = edge_contact_diameter(
            traj["position_m"][k], d.mesh_edges(np.asarray(system.surface_faces())), args.ghat
        )
    return out


def quasi_static_curve(args, levels, faces=None):
    """(compression [m], ground force [N], vertex diameter [m], edge diameter [m]) of the ball resting under gravity × each level.

    Compression is the centre of mass's descent below its height when the lowest vertex is ĝ above the ground.
    """
    base = make_system(args, faces=faces)
    edges = d.mesh_edges(np.asarray(base.surface_faces()))
    z_touch = touching_com_height(base, args.ghat)
    rows = []
    for level in levels:
        system = eqx.tree_at(lambda s: s.gravity, base, base.gravity * level)
        state = d.drop_state(system, system.inflated, args.ghat / 2)
        # Backward Euler at Δt = 10 ms damps the contact mode (ω ≈ 100 /s) by ~0.7 per step: 50 steps settle.
        traj = d.simulate(
            system, state, 0.01, 0.5, integrator=d.BackwardEuler(), minimiser=d.SparseNewton(), progress=False
        )
        x = traj["position_m"][-1]
        rows.append(
            (
                z_touch - float(system.centre_of_mass(jnp.asarray(x))[2]),
                level * G * args.mass,
                contact_diameter(x, args.ghat),
                edge_contact_diameter(x, edges, args.ghat),
            )
        )
    return np.array(rows)


def part_energy(args, report):
    system = make_system(args)
    report["newmark"] = [drop(system, args, dt, args.duration) for dt in (1e-3, 5e-4, 2.5e-4)]
    report["backward_euler"] = [drop(system, args, dt, args.duration, d.BackwardEuler()) for dt in (2e-3, 1e-3, 5e-4)]


def part_model(args, report):
    reference = drop(make_system(args), args, 2.5e-4, args.duration)
    curve = quasi_static_curve(args, (1.0, 3.0, 6.0, 10.0, 15.0, 20.0))
    report["model_reference_newmark"] = reference
    report["quasi_static"] = {
        "compression_m": curve[:, 0].tolist(),
        "force_N": curve[:, 1].tolist(),
        "diameter_m": curve[:, 2].tolist(),
        "edge_diameter_m": curve[:, 3].tolist(),
    }
    one_dof = d.PointMassOnGround(args.mass, [d.ground(d.TabulatedCompressionCurve(curve[:, 0], curve[:, 1]))])
    speed = math.sqrt(2 * G * (args.height - 2 * args.ghat))
    traj = d.simulate(
        one_dof, d.initial_state(one_dof, [0.0, 0.0, 0.0], [0.0, 0.0, -speed]), 2e-5, args.duration, progress=False
    )
    m = d.measured_cor(traj)[0]
    report["one_dof"] = {
        "contact_time_s": m.contact_time_s,
        "peak_force_N": m.peak_force_N,
        "max_compression_m": m.max_compression_m,
    }
    k = d.pressurized_ball_stiffness(args.radius, args.pressure)
    report["textbook"] = {
        "stiffness_N_per_m": k,
        "contact_time_s": d.pressurized_ball_contact_time(args.mass, args.radius, args.pressure),
        "peak_force_N": speed * math.sqrt(k * args.mass),
    }
    report["quasi_static_diameter_at_peak_m"] = float(np.interp(reference["peak_force_N"], curve[:, 1], curve[:, 2]))


def part_adiabatic(args, report):
    report["adiabatic"] = drop(make_system(args, gas=AdiabaticGas()), args, 2.5e-4, args.duration)


def bounce_cor(impacts):
    """COR [-] of the first bounce: √(apex after the last contact of the record / (v_in²/2g) of the first contact).

    Under Newmark the membrane's vibration can lift the ball off for ~1 ms just before the release
    and land it again: `measured_cor` then sees two impacts, and the first one's COR (its apex a
    fraction of a millimetre) jumps from ~0.8 to ~0.1 as c crosses that threshold. The last
    impact's apex is the bounce; the record must end before the next real impact.
    """
    bounce = [m.bounce_height_m for m in impacts if np.isfinite(m.bounce_height_m)][-1]
    # A bounce below the onset height (the ball stays pressed until the record ends) counts as COR 0.
    return math.sqrt(max(bounce, 0.0) / (impacts[0].speed_in_m_per_s ** 2 / (2 * G)))


def calibrations(args, system, integrator, dt, duration, bracket=(0.0, 10.0)):
    """COR(c = 0) and the calibration to each target at one (scheme, Δt): c [N·s/m], COR, relative error, runs; or the error raised."""

    @functools.cache  # every target of this (scheme, Δt) reuses the runs already made
    def cor(c):
        traj = run_drop(system, args, args.height, dt, duration, integrator, c)
        if isinstance(traj, str):
            raise NoConvergenceError(traj)
        return bounce_cor(d.measured_cor(traj))

    out = {"dt_s": dt, "scheme": type(integrator).__name__, "cor_at_c0": cor(0.0), "targets": {}, "evaluations": []}
    for target in TARGETS:
        start = time.perf_counter()
        try:
            cal = d.calibrate_contact_damping(cor, target, bracket, rtol=2e-3)
            out["targets"][str(target)] = {
                "damping_N_s_per_m": cal.damping,
                "cor": cal.cor,
                "relative_error": (cal.cor - target) / target,
                "runs": len(cal.evaluations),
                "seconds": time.perf_counter() - start,
            }
            out["evaluations"] += cal.evaluations
        except InvalidInputError as err:
            out["targets"][str(target)] = {"unreachable": str(err)}
        print(type(integrator).__name__, dt, target, out["targets"][str(target)], flush=True)
    return out


def part_cor(args, report):
    system = make_system(args)
    schemes = {"backward_euler": d.BackwardEuler(), "newmark": d.Newmark()}
    report["cor_calibration"] = {}
    for case in args.cor_cases:
        scheme, dt = case.split(":")
        # Newmark's COR(c) falls faster and is ragged above ~8 N·s/m (docs/dynamics.md).
        bracket = (0.0, 8.0) if scheme == "newmark" else (0.0, 10.0)
        report["cor_calibration"][case] = calibrations(
            args, system, schemes[scheme], float(dt), args.duration, bracket=bracket
        )


def impact_extremes(traj, system, args, window):
    """Peak ground force [N] (raw, and averaged over ``window`` [s]), max compression [m] and max diameters [m] up to the deepest point."""
    force = traj["contact_force_N"][:, 0, 2]
    dt = float(traj["time_s"][1] - traj["time_s"][0])
    n = max(1, int(round(window / dt)))
    smooth = np.convolve(force, np.ones(n) / n, mode="same")
    z = traj["com_position_m"][:, 2]
    deepest = int(np.argmin(z)) + 1
    edges = d.mesh_edges(np.asarray(system.surface_faces()))
    diam = [edge_contact_diameter(x, edges, args.ghat) for x in traj["position_m"][:deepest]]
    vert = [contact_diameter(x, args.ghat) for x in traj["position_m"][:deepest]]
    e = traj["total_energy_J"][:deepest]
    return {
        "peak_force_N": float(force.max()),
        "smoothed_peak_force_N": float(smooth.max()),
        "force_at_deepest_N": float(force[deepest - 1]),
        "max_compression_m": touching_com_height(system, args.ghat) - float(z.min()),
        "max_edge_diameter_m": float(max(diam)),
        "max_vertex_diameter_m": float(max(vert)),
        "energy_change_to_deepest_J": float(np.max(np.abs(e - e[0]))),
    }


def part_diameter(args, report):
    out = {}
    for faces in args.diameter_faces:
        # Newmark's Δt resolves the membrane waves, whose period scales with the vertex spacing (~1 ms at 210 faces).
        newmark_dt = math.floor(2.5e-4 * min(1.0, math.sqrt(200 / faces)) / 5e-5 + 1e-9) * 5e-5
        curve = quasi_static_curve(args, (0.5, 1.0, 2.0, 4.0, 7.0, 10.0, 14.0, 20.0, 27.0), faces=faces)
        system = make_system(args, faces=faces)
        entry = {
            "faces": int(system.surface_faces().shape[0]),
            "quasi_static": {
                "compression_m": curve[:, 0].tolist(),
                "force_N": curve[:, 1].tolist(),
                "vertex_diameter_m": curve[:, 2].tolist(),
                "edge_diameter_m": curve[:, 3].tolist(),
            },
            "drops": [],
        }
        schemes = {"newmark": (d.Newmark(), newmark_dt), "backward_euler": (d.BackwardEuler(), 2.5e-4)}
        for scheme, (integrator, dt) in ((k, schemes[k]) for k in args.diameter_schemes):
            for height in args.heights:
                # The deepest point comes before half the contact time (≤ 25 ms here) plus the 2ĝ approach.
                traj = run_drop(system, args, height, dt, 0.032, integrator)
                row = {"scheme": scheme, "dt_s": dt, "height_m": height}
                if isinstance(traj, str):
                    row["failed"] = traj
                else:
                    row.update(impact_extremes(traj, system, args, window=1e-3))
                    qs = lambda f, col: float(np.interp(f, curve[:, 1], curve[:, col]))  # noqa: E731
                    row["qs_edge_diameter_at_peak_m"] = qs(row["peak_force_N"], 3)
                    row["qs_edge_diameter_at_smoothed_peak_m"] = qs(row["smoothed_peak_force_N"], 3)
                    row["qs_vertex_diameter_at_peak_m"] = qs(row["peak_force_N"], 2)
                    row["qs_edge_diameter_at_compression_m"] = float(
                        np.interp(row["max_compression_m"], curve[:, 0], curve[:, 3])
                    )
                    row["qs_force_at_compression_N"] = float(
                        np.interp(row["max_compression_m"], curve[:, 0], curve[:, 1])
                    )
                print(faces, json.dumps(row), flush=True)
                entry["drops"].append(row)
        out[str(entry["faces"])] = entry
    report["max_diameter"] = out


def observed_orders(values):
    """log2 of successive difference ratios of a quantity under halving refinement (NaN where not monotone)."""
    v = np.asarray(values, dtype=float)
    diffs = np.diff(v)
    return [float(math.log2(a / b)) if a * b > 0 else float("nan") for a, b in zip(diffs[:-1], diffs[1:])]


def part_convergence(args, report):
    keys = ("contact_time_s", "peak_force_N", "max_compression_m", "cor")
    system = make_system(args)
    in_time = [
        drop(system, args, dt, args.duration, d.BackwardEuler(), damping=args.damping)
        for dt in (2e-3, 1e-3, 5e-4, 2.5e-4)
    ]
    in_mesh = [
        drop(make_system(args, faces=f), args, 5e-4, args.duration, d.BackwardEuler(), damping=args.damping)
        for f in args.mesh_faces
    ]
    for row, f in zip(in_mesh, args.mesh_faces):
        row["faces"] = int(make_system(args, faces=f).surface_faces().shape[0])
    report["convergence"] = {
        "damping_N_s_per_m": args.damping,
        "scheme": "BackwardEuler",
        "time_step": in_time,
        "time_step_orders": {k: observed_orders([r.get(k, np.nan) for r in in_time]) for k in keys},
        "mesh_dt_s": 5e-4,
        "mesh": in_mesh,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--parts", default="energy,model,adiabatic", help=f"comma-separated, of {', '.join(PARTS)}")
    p.add_argument("--faces", type=int, default=200)
    p.add_argument(
        "--diameter-faces",
        type=lambda s: [int(v) for v in s.split(",")],
        default=[200, 500],
        help="the diameter part's meshes",
    )
    p.add_argument(
        "--diameter-schemes",
        type=lambda s: s.split(","),
        default=["newmark", "backward_euler"],
        help="the diameter part's schemes",
    )
    p.add_argument(
        "--mesh-faces",
        type=lambda s: [int(v) for v in s.split(",")],
        default=[200, 500, 1000],
        help="the convergence part's meshes",
    )
    p.add_argument(
        "--heights",
        type=lambda s: [float(v) for v in s.split(",")],
        default=[0.005, 0.01, 0.02, 0.05],
        help="drop heights [m]",
    )
    p.add_argument(
        "--cor-cases",
        type=lambda s: s.split(","),
        default=["backward_euler:1e-3", "newmark:2.5e-4", "backward_euler:2.5e-4"],
        help="the cor part's scheme:Δt [s] cases",
    )
    p.add_argument("--damping", type=float, default=2.0, help="the convergence part's fixed c [N·s/m]")
    p.add_argument("--radius", type=float, default=0.05)
    p.add_argument("--thickness", type=float, default=0.5e-3)
    p.add_argument("--young", type=float, default=2e6)
    p.add_argument("--pressure", type=float, default=5000.0)
    p.add_argument("--mass", type=float, default=0.1)
    p.add_argument("--ghat", type=float, default=5e-4)
    p.add_argument("--height", type=float, default=0.02)
    p.add_argument("--duration", type=float, default=0.06)
    p.add_argument("--out", default="docs/bench/verify-dynamics.json")
    args = p.parse_args()
    parts = args.parts.split(",")
    if unknown := set(parts) - set(PARTS):
        p.error(f"unknown parts {sorted(unknown)}; choose from {', '.join(PARTS)}")
    report = {}
    for part in parts:
        start = time.perf_counter()
        globals()[f"part_{part}"](args, report)
        report.setdefault("seconds", {})[part] = time.perf_counter() - start
        print(json.dumps({k: v for k, v in report.items()}, indent=1, default=str), flush=True)
    out = Path(args.out)
    # Re-read just before writing: parts run in separate processes share the file.
    merged = json.loads(out.read_text()) if out.is_file() else {}
    merged.setdefault("ball", {}).update({k: v for k, v in vars(args).items() if k not in ("parts", "out")})
    seconds = {**merged.get("seconds", {}), **report.pop("seconds")}
    for key, value in report.items():  # the diameter part's meshes accumulate
        merged[key] = (
            {**merged[key], **value} if isinstance(value, dict) and isinstance(merged.get(key), dict) else value
        )
    merged.update(seconds=seconds, machine="shared 2-core x86-64 VM, heavy load (other jobs)")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(merged, indent=1, default=str))


if __name__ == "__main__":
    main()
