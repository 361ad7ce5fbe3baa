"""The reference integrator on the Pezzi-like ball (docs/dynamics.md, *The reference integrator*).

The ball of configs/drop.toml (bundled Pezzi session, P_g and E from its `fit` estimate, ~2000
faces, sealed adiabatic gas, ground barrier ĝ = 1 mm) dropped from 1 m with no contact damping:
started 2ĝ above the ground at the impact speed √(2g(H − 2ĝ)), as the scenario's calibration drops
(free flight is integrated exactly by every scheme here). Per (scheme, Δt): the first impact's COR
√(bounce / drop), contact time, maximum compression, peak force (``measured_cor``, chatter
merged), the energy left, Newton work and wall time. Then ``calibrate_contact_damping`` to a few
target CORs at one (scheme, Δt), each COR run as the drop above.

    python3 experiments/verify_reference_integrator.py [--parts drops,calibration,testball]
        [--cases tr-bdf2:1e-3,tr-bdf2:5e-4,tr-bdf2:2.5e-4,backward-euler:1e-3,tr-bdf2:1e-3:0.1]  (scheme:Δt[:height])
        [--targets 0.6,0.7,0.8] [--calibration-case tr-bdf2:1e-3] [--out docs/bench/reference-integrator.json]

Each part's results replace that part's key in the JSON file (the drops of other cases are kept);
the others are kept. ``testball``: TR-BDF2, Newmark and backward Euler on verify_dynamics' 210-face
test ball (2 cm drop), as docs/dynamics.md reports.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from pathlib import Path

import jax
import numpy as np

from shelljax import InvalidInputError, NoConvergenceError
from shelljax import dynamics as d
from shelljax.scenario import build_system, eqx_replace_damping, load_scenario, resolve_object

jax.config.update("jax_enable_x64", True)

SCHEMES = {"tr-bdf2": d.TRBDF2, "backward-euler": d.BackwardEuler, "newmark": d.Newmark}


def drop(
    system, scheme: str, dt: float, height: float, damping: float, duration: float, max_steps: int, tolerance: float
) -> dict:
    """One drop's first impact and cost; ``{"failed": message}`` where a step did not converge."""
    ground = eqx_replace_damping(system.planes[0], damping)
    one = system.with_planes([ground])
    g = float(np.linalg.norm(np.asarray(system.gravity)))
    gap0 = 2.0 * float(ground.law.contact_distance())
    speed = math.sqrt(2.0 * g * (height - gap0))
    state = d.drop_state(one, np.asarray(one.inflated), gap0, velocity=list(-speed * np.asarray(ground.normal)))
    start = time.perf_counter()
    row = {"scheme": scheme, "dt_s": dt, "damping_N_s_per_m": damping, "height_m": height}
    try:
        traj = d.simulate(
            one,
            state,
            dt,
            duration,
            integrator=SCHEMES[scheme](),
            minimiser=d.SparseNewton(step_tolerance=tolerance, max_steps=max_steps),
            chunk=25,
            progress=False,
        )
    except NoConvergenceError as err:
        return {**row, "failed": str(err).splitlines()[0], "seconds": time.perf_counter() - start}
    impacts = d.measured_cor(traj)
    energy = traj["total_energy_J"]
    kinetic0 = float(traj["kinetic_energy_J"][0])
    row.update(
        seconds=time.perf_counter() - start,
        steps=len(energy) - 1,
        newton_iterations_per_step=float(np.mean(traj["newton_iterations"][1:])),
        newton_matrices_per_step=float(np.mean(traj["newton_matrices"][1:])),
        energy_lost_per_impact_kinetic=float((energy[0] - energy[-1]) / kinetic0),
        impacts=len(impacts),
    )
    if impacts:
        m = impacts[0]
        # The run starts 2ĝ above the plane: the drop height is the onset speed's v²/2g (as the scenario's calibration).
        cor = math.sqrt(max(m.bounce_height_m, 0.0) / (m.speed_in_m_per_s**2 / (2.0 * g)))
        row.update(
            cor=cor,
            bounce_height_m=m.bounce_height_m,
            cor_from_speeds=m.cor_from_speeds,
            contact_time_s=m.contact_time_s,
            max_compression_m=m.max_compression_m,
            peak_force_N=m.peak_force_N,
            speed_in_m_per_s=m.speed_in_m_per_s,
            speed_out_m_per_s=m.speed_out_m_per_s,
        )
    return row


def setup(args):
    scenario = load_scenario(args.config)
    start = time.perf_counter()
    obj = resolve_object(scenario)
    system = build_system(scenario, obj)
    info = {
        "config": args.config,
        "gauge_pressure_Pa": obj.properties.gauge_pressure,
        "youngs_modulus_Pa": obj.properties.young_modulus,
        "poisson_ratio": obj.properties.poisson_ratio,
        "thickness_m": obj.shell.thickness,
        "faces": int(obj.shell.mesh.n_faces),
        "mass_kg": float(np.sum(np.asarray(system.node_masses))),
        "gas": scenario.gas,
        "barrier": {
            "activation_distance_m": scenario.planes[0].activation_distance,
            "stiffness_J_per_m2": scenario.planes[0].barrier_stiffness,
        },
        "friction": scenario.planes[0].friction,
        "setup_seconds": time.perf_counter() - start,
    }
    return scenario, system, info


def part_drops(args, scenario, system, report):
    rows = []
    for case in args.cases:
        scheme, dt, *height = case.split(":")
        row = drop(
            system,
            scheme,
            float(dt),
            float(height[0]) if height else args.height,
            0.0,
            args.duration,
            args.max_steps,
            scenario.step_tolerance,
        )
        print(json.dumps(row), flush=True)
        rows.append(row)
    report["drops"] = rows
    for scheme in sorted({r["scheme"] for r in rows}):
        done = [r for r in rows if r["scheme"] == scheme and "cor" in r and r["height_m"] == args.height]
        if len(done) > 1:
            finest = min(done, key=lambda r: r["dt_s"])
            report.setdefault("spread_against_finest", {})[scheme] = {
                str(r["dt_s"]): {
                    k: r[k] / finest[k] - 1.0 for k in ("cor", "contact_time_s", "max_compression_m", "peak_force_N")
                }
                for r in done
            }


def part_calibration(args, scenario, system, report):
    scheme, dt = args.calibration_case.split(":")

    runs = {}  # every target reuses the runs already made

    def cor(c):
        if float(c) not in runs:
            row = drop(
                system, scheme, float(dt), args.height, float(c), args.duration, args.max_steps, scenario.step_tolerance
            )
            print(json.dumps(row), flush=True)
            if "failed" in row:
                raise NoConvergenceError(row["failed"])
            runs[float(c)] = row
        return runs[float(c)].get("cor", 0.0)

    out = {"scheme": scheme, "dt_s": float(dt), "bracket_N_s_per_m": args.bracket, "targets": {}}
    for target in args.targets:
        start = time.perf_counter()
        try:
            cal = d.calibrate_contact_damping(cor, target, tuple(args.bracket), rtol=args.rtol)
            out["targets"][str(target)] = {
                "damping_N_s_per_m": cal.damping,
                "cor": cal.cor,
                "relative_error": cal.cor / target - 1.0,
                "runs": len(cal.evaluations),
                "seconds": time.perf_counter() - start,
            }
        except InvalidInputError as err:
            out["targets"][str(target)] = {"unreachable": str(err)}
        print(target, out["targets"][str(target)], flush=True)
    out["evaluations"] = [runs[c] for c in sorted(runs)]
    report["calibration"] = out


def part_testball(args, scenario, system, report):
    """TR-BDF2 against Newmark and backward Euler on verify_dynamics' 210-face test ball (2 cm drop, frictionless)."""
    import verify_dynamics as vd  # the sibling script, found beside this one

    ball = argparse.Namespace(
        radius=0.05,
        thickness=0.5e-3,
        young=2e6,
        pressure=5000.0,
        mass=0.1,
        ghat=5e-4,
        height=0.02,
        duration=0.06,
        faces=200,
    )
    small = vd.make_system(ball)
    rows = []
    for case in args.testball_cases:
        scheme, dt = case.split(":")
        start = time.perf_counter()
        traj = vd.run_drop(small, ball, ball.height, float(dt), ball.duration, SCHEMES[scheme](), 0.0)
        row = {"scheme": scheme, "dt_s": float(dt)}
        if isinstance(traj, str):
            row["failed"] = traj
        else:
            impacts = d.measured_cor(traj)
            e = traj["total_energy_J"]
            row.update(
                cor=vd.bounce_cor(impacts),
                contact_time_s=impacts[0].contact_time_s,
                max_compression_m=impacts[0].max_compression_m,
                energy_lost_per_impact_kinetic=float((e[0] - e[-1]) / traj["kinetic_energy_J"][0]),
                newton_iterations_per_step=float(np.mean(traj["newton_iterations"][1:])),
            )
        row["seconds"] = time.perf_counter() - start
        print(json.dumps(row), flush=True)
        rows.append(row)
    report["test_ball"] = {"ball": {k: v for k, v in vars(ball).items()}, "runs": rows}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--parts", default="drops,calibration")
    p.add_argument("--config", default="configs/drop.toml")
    p.add_argument(
        "--cases",
        type=lambda s: s.split(","),
        default=["tr-bdf2:1e-3", "tr-bdf2:5e-4", "tr-bdf2:2.5e-4", "backward-euler:1e-3"],
    )
    p.add_argument("--calibration-case", default="tr-bdf2:1e-3")
    p.add_argument(
        "--testball-cases",
        type=lambda s: s.split(","),
        default=[
            "tr-bdf2:1e-3",
            "tr-bdf2:5e-4",
            "tr-bdf2:2.5e-4",
            "tr-bdf2:1e-4",
            "tr-bdf2:5e-5",
            "newmark:2.5e-4",
            "backward-euler:2.5e-4",
        ],
    )
    p.add_argument("--targets", type=lambda s: [float(v) for v in s.split(",")], default=[0.6, 0.7, 0.8])
    p.add_argument("--bracket", type=lambda s: [float(v) for v in s.split(",")], default=[0.0, 20.0])
    p.add_argument("--rtol", type=float, default=1e-2, help="Brent's relative tolerance on c (the scenario's)")
    p.add_argument("--height", type=float, default=1.0, help="drop height [m]")
    p.add_argument(
        "--duration",
        type=float,
        default=0.1,
        help="run length [s]: past the release (~65 ms); the apex is extrapolated ballistically",
    )
    p.add_argument("--max-steps", type=int, default=50, help="SparseNewton's iterations per stage")
    p.add_argument("--out", default="docs/bench/reference-integrator.json")
    args = p.parse_args()
    scenario, system, info = setup(args)
    report = {}
    for part in args.parts.split(","):
        start = time.perf_counter()
        {"drops": part_drops, "calibration": part_calibration, "testball": part_testball}[part](
            args, scenario, system, report
        )
        report.setdefault("seconds", {})[part] = time.perf_counter() - start
    out = Path(args.out)
    merged = json.loads(out.read_text()) if out.is_file() else {}
    seconds = {**merged.get("seconds", {}), **report.pop("seconds")}
    if "drops" in report and "drops" in merged:  # runs of other cases are kept; a case run again is replaced
        key = lambda r: (r["scheme"], r["dt_s"], r["height_m"], r["damping_N_s_per_m"])  # noqa: E731
        new = {key(r) for r in report["drops"]}
        report["drops"] = [r for r in merged["drops"] if key(r) not in new] + report["drops"]
        report["spread_against_finest"] = {
            **merged.get("spread_against_finest", {}),
            **report.get("spread_against_finest", {}),
        }
    merged.update(report)
    merged.update(
        ball=info,
        seconds=seconds,
        machine=f"shared 2-core x86-64 VM, JAX CPU ({platform.machine()}), other jobs running",
        date=time.strftime("%Y-%m-%d", time.gmtime()),
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(merged, indent=1, default=str))


if __name__ == "__main__":
    main()
