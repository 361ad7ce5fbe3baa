"""Fidelity of the real-time runtime against the implicit reference (shelljax.dynamics.simulate).

The same ball (configs/drop.toml's Pezzi ball: R 0.13 m, h 0.9 mm, ν 0.4, E 2.34 MPa, P_g 1300 Pa,
0.8 kg, adiabatic gas; the rest shape, inflated state and masses of ``dynamics.shell_system``,
which ``RealtimeShell.from_system`` copies) dropped from ``--height`` onto the ground, once with
``dynamics.simulate`` (``--integrator``, default BackwardEuler, at ``--dt``, barrier contact
ĝ = 1 mm, κ = 1e3 J/m², as the configs) and once with ``shelljax.realtime`` (penalty contact,
velocity Verlet at its stable Δt), both with the ground's friction ``--friction`` and the same
centre-of-mass contact dashpot c = ``--damping`` N·s/m. One impact analysis for both (contact
while the ground force exceeds 2 % of its peak, so the barrier's 1 mm range and the penalty's
penetration count alike):

| quantity | criterion (issue #48) |
|---|---|
| COR (normal COM speed out / in) | ± 0.02 |
| contact time, maximum compression (COM travel past the free shape's height) | ± 3 % |
| peak ground force (``--force-window`` 2 ms moving average: the barrier's per-step force flickers) | ± 5 % |
| peak gauge pressure | ± 1 % |
| free-flight energy drift of the realtime run | < 0.5 %/s |
| static poke force (``--poke``: 8 mm sphere pressed 20 mm into the ball on the ground, no gravity) vs ``shell3d.Indentation`` | ± 2 % |

Prints the table and writes ``--json`` (default docs/bench/realtime-fidelity.json).

    python3 experiments/verify_realtime.py [--faces 2000] [--integrator BackwardEuler] [--dt 1e-4] [--poke]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from shelljax import dynamics as d
from shelljax import realtime as rt
from shelljax.physics import Plane, ShellProperties
from shelljax.shell3d import Shell, ShellMesh

ROOT = Path(__file__).resolve().parents[1]
PEZZI = {"gauge_pressure": 1300.0, "young_modulus": 2.34e6, "thickness": 0.9e-3, "poisson_ratio": 0.4}
RADIUS, MASS = 0.13, 0.8
CRITERIA = {"cor": ("abs", 0.02), "contact_time_s": ("rel", 0.03), "max_compression_m": ("rel", 0.03),
            "peak_force_N": ("rel", 0.05), "peak_gauge_pressure_Pa": ("rel", 0.01)}  # fmt: skip


def impact(time_s, com_z, com_vz, force_z, pressure, rest_height, force_window=2e-3):
    """Impact metrics from per-step arrays: COM height [m] and vertical speed [m/s], ground force
    [N], gauge pressure [Pa]; ``rest_height`` [m]: the COM's height above the ground when the free
    shape just touches it."""
    # The barrier's per-step force flickers as vertices enter and leave its range: the contact
    # window and the peak are taken on a ``force_window`` [s] moving average of the force (both
    # runs), the raw peak beside it.
    n = max(1, round(force_window / np.median(np.diff(time_s))))
    smooth = np.convolve(force_z, np.ones(n) / n, mode="same")
    peak = float(smooth.max())
    on = np.flatnonzero(smooth > 0.02 * peak)
    if on.size == 0:
        raise RuntimeError("no impact in the record: lengthen the duration")
    # The first impact: its samples above the threshold, merging gaps shorter than 10 ms.
    gaps = np.flatnonzero(np.diff(time_s[on]) > 1e-2)
    run = on[: gaps[0] + 1] if gaps.size else on
    i0, i1 = int(run[0]), int(run[-1])
    if i1 == time_s.size - 1:
        raise RuntimeError("the record ends during the impact: lengthen the duration")
    force_z = smooth

    def crossing(i, j):  # time where the force crosses the threshold between steps i and j
        f0, f1 = force_z[i] - 0.02 * peak, force_z[j] - 0.02 * peak
        return time_s[i] + (time_s[j] - time_s[i]) * f0 / (f0 - f1) if f0 != f1 else time_s[i]

    t_on = crossing(i0 - 1, i0) if i0 > 0 else time_s[i0]
    t_off = crossing(i1, i1 + 1) if i1 + 1 < time_s.size else time_s[i1]
    v_in = float(np.interp(t_on, time_s, com_vz))
    v_out = float(np.interp(t_off, time_s, com_vz))
    window = slice(max(i0 - 1, 0), i1 + 2)
    return {
        "peak_force_N": float(smooth[window].max()),
        "cor": -v_out / v_in, "contact_time_s": float(t_off - t_on), "impact_speed_m_per_s": -v_in,
        "max_compression_m": float(rest_height - com_z[window].min()),
        "peak_gauge_pressure_Pa": float(pressure[window].max()),
    }  # fmt: skip


def ground(damping, friction, law=True):
    law = d.BarrierContact(1e-3, 1e3) if law else None
    return Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], law, friction=friction, damping=damping, name="ground")


def reference_run(system, height, dt, duration, integrator):
    state = d.drop_state(system, system.inflated, height)
    t = time.perf_counter()
    trajectory = d.simulate(system, state, dt, duration, integrator=integrator, minimiser=d.SparseNewton(), progress=False)
    wall = time.perf_counter() - t
    r = trajectory.records
    return r, wall


def realtime_run(shell, height, duration):
    shell.drop(height)
    start = shell.energies()["total"]
    rows = []
    t = time.perf_counter()
    dt = shell.stable.dt_s
    while shell.time < duration:
        f = shell.frame(dt, substeps=1)
        rows.append((f.time_s, f.com_m[2], f.com_velocity_m_per_s[2], f.plane_forces_N[0, 2], f.gauge_pressure_Pa,
                     f.energies_J["total"]))  # fmt: skip
    wall = time.perf_counter() - t
    a = np.array(rows)
    return {"time_s": a[:, 0], "com_z": a[:, 1], "com_vz": a[:, 2], "force_z": a[:, 3], "pressure": a[:, 4],
            "total_energy_J": a[:, 5], "start_energy_J": start, "wall_s": wall}  # fmt: skip


def free_flight_drift(shell, seconds=1.0):
    """Relative total-energy drift per second [1/s] of the realtime ball falling freely (no planes),
    from windowed means (the first and last 0.1 s) over ``seconds``."""
    shell.set_planes(())
    spin = np.cross([5.0, 0.0, 0.0], shell.x - shell.com()[0])  # 5 rad/s: the shell stretches and vibrates
    shell.set_state(shell.x, spin + np.array([0.5, 0.0, 1.0]))
    totals, times = [], []
    while shell.time < seconds:
        f = shell.frame(1.0 / 60.0)
        totals.append(f.energies_J["total"])
        times.append(f.time_s)
    totals = np.array(totals)
    scale = abs(totals[0]) + shell.total_mass * 9.80665 * seconds**2 * 9.80665  # |E| plus the fall's potential range
    k = max(1, len(totals) // 10)
    return float((totals[-k:].mean() - totals[:k].mean()) / scale / seconds), float(np.ptp(totals) / scale)


def poke(faces, depth=0.02, radius=0.008, stiffness_factor=10.0, friction=0.05):
    """Static poke force [N] at ``depth`` [m]: shell3d.Indentation (quasi-static, barrier) and the
    realtime ball relaxed under a sphere collider (no gravity, penalty), same mesh and gas."""
    from shelljax import shell3d as s3

    shell = Shell(mesh=ShellMesh.sphere(RADIUS, faces, pole_refinement=1.0), thickness=PEZZI["thickness"])
    props = ShellProperties(**PEZZI)
    sim = s3.Indentation(shell, props, gas="isothermal", indenter_radius=radius, ground=True)
    ref = float(sim.solve(depth=depth).observables()["force"])
    system = d.shell_system(shell, props, gas="isothermal", mass=MASS, gravity=0.0)
    # The engine pins the shell's horizontal rigid modes (its indenter and ground frictionless);
    # here a little friction on the ground (μ = ``friction``) keeps the squeezed ball from
    # slipping out sideways (with μ = 0.5 on both it read +2.9 % at 2k faces: friction stiffens).
    # A static poke does not need the dynamic default spring (k = 0.25 m ω_max², ≈ 1 mm under the
    # indenter): ``stiffness_factor`` × it keeps the penetrations below 0.1 mm, at a smaller Δt.
    probe = rt.RealtimeShell.from_system(system, planes=[ground(0.0, friction, law=False)], gravity=0.0)
    ball = rt.RealtimeShell.from_system(system, planes=[ground(0.0, friction, law=False)], gravity=0.0,
                                        contact_stiffness=stiffness_factor * float(probe.k_contact.max()))  # fmt: skip
    ball.drop(0.0)
    top = int(np.argmax(ball.x[:, 2]))
    touch = ball.x[top] + np.array([0.0, 0.0, radius])
    steps = 40
    for k in range(1, steps + 1):  # press in slowly, relaxing at each depth
        ball.set_collider(rt.Collider.sphere(touch - np.array([0.0, 0.0, depth * k / steps]), radius))
        ball.relax(0.02 if k < steps else 0.2)
    forces = [ball.frame(1.0 / 600.0).collider_force_N[2] for _ in range(20)]
    com, _ = ball.com()
    return {"reference_force_N": ref, "realtime_force_N": float(-np.mean(forces)), "depth_m": depth,
            "realtime_com_offset_m": float(np.hypot(com[0] - touch[0], com[1] - touch[1])),
            "contact_stiffness_N_per_m": float(ball.k_contact.max()), "realtime_dt_s": ball.stable.dt_s,
            "ground_friction": friction}


def poke_entry(faces):
    """The poke comparison at ``faces``, printed as a table row."""
    p = poke(faces)
    err = p["realtime_force_N"] / p["reference_force_N"] - 1.0
    ok = abs(err) <= 0.02
    print(f"{'static poke force [N]':<24} {p['reference_force_N']:>12.5g} {p['realtime_force_N']:>12.5g} {err:>+10.3g} "
          f"{'±0.02':>10} {'yes' if ok else 'NO'}  ({faces} faces)")  # fmt: skip
    return {**p, "faces": faces, "error": err, "tolerance": 0.02, "ok": bool(ok)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--faces", type=int, default=2000)
    parser.add_argument("--height", type=float, default=0.5, help="drop height of the lowest point [m]")
    parser.add_argument("--integrator", default="BackwardEuler", help="a shelljax.dynamics integrator class name")
    parser.add_argument("--dt", type=float, default=1e-4, help="the reference's time step [s]")
    parser.add_argument("--damping", type=float, default=0.0, help="contact dashpot c [N·s/m]")
    parser.add_argument("--friction", type=float, default=0.5)
    parser.add_argument("--poke", action="store_true", help="also the static poke force (slow)")
    parser.add_argument("--force-window", type=float, default=2e-3, help="moving average of the force for its peak [s]")
    parser.add_argument("--save", action="store_true", help="also save both runs' series (.npz beside --json)")
    parser.add_argument("--json", type=Path, default=ROOT / "docs" / "bench" / "realtime-fidelity.json")
    parser.add_argument("--poke-only", action="store_true", help="only the poke, added to an existing --json")
    args = parser.parse_args()
    if args.poke_only:
        result = json.loads(args.json.read_text()) if args.json.is_file() else {}
        result["poke"] = poke_entry(args.faces)
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1))
        print(f"wrote {args.json}")
        return

    shell = Shell(mesh=ShellMesh.sphere(RADIUS, args.faces, pole_refinement=1.0), thickness=PEZZI["thickness"])
    t = time.perf_counter()
    system = d.shell_system(shell, ShellProperties(**PEZZI), gas="adiabatic", mass=MASS,
                            planes=[ground(args.damping, args.friction)])  # fmt: skip
    setup_s = time.perf_counter() - t
    fall = np.sqrt(2 * args.height / 9.80665)
    duration = fall + 0.15  # the impact lasts ≈ 60 ms; the record must cover it
    integrator = getattr(d, args.integrator)()
    ref, ref_wall = reference_run(system, args.height, args.dt, duration, integrator)
    if args.save:
        np.savez(args.json.with_suffix(".reference.npz"), **{k: np.asarray(v) for k, v in ref.items() if np.asarray(v).dtype != object})
    rest_height = float(np.asarray(system.centre_of_mass(system.inflated))[2] - np.asarray(system.inflated).reshape(-1, 3)[:, 2].min())
    ref_metrics = impact(ref["time_s"], ref["com_position_m"][:, 2], ref["com_velocity_m_per_s"][:, 2],
                         ref["contact_force_N"][:, 0, 2], ref["gas_pressure_Pa"], rest_height, args.force_window)  # fmt: skip

    ball = rt.RealtimeShell.from_system(system, planes=[ground(args.damping, args.friction, law=False)])
    real = realtime_run(ball, args.height, duration)
    if args.save:
        np.savez(args.json.with_suffix(".realtime.npz"), **{k: np.asarray(v) for k, v in real.items()})
    real_metrics = impact(real["time_s"], real["com_z"], real["com_vz"], real["force_z"], real["pressure"], rest_height,
                          args.force_window)
    # The realtime run's own Δt sensitivity: the same drop at a quarter of its stable Δt.
    fine = rt.RealtimeShell.from_system(system, planes=[ground(args.damping, args.friction, law=False)],
                                        safety=0.25 * ball.stable.safety)  # fmt: skip
    real_fine = realtime_run(fine, args.height, duration)
    fine_metrics = impact(real_fine["time_s"], real_fine["com_z"], real_fine["com_vz"], real_fine["force_z"],
                          real_fine["pressure"], rest_height, args.force_window)  # fmt: skip
    drift, spread = free_flight_drift(rt.RealtimeShell.from_system(system))

    rows = {}
    print(f"{args.faces}-face ball, {args.height} m drop; reference {args.integrator} at dt {args.dt} s; "
          f"realtime velocity Verlet at dt {ball.stable.dt_s:.3g} s")
    print(f"{'quantity':<24} {'reference':>12} {'realtime':>12} {'error':>10} {'criterion':>10} ok {'realtime Δt/4':>14}")
    for key, (kind, tol) in CRITERIA.items():
        a, b, c = ref_metrics[key], real_metrics[key], fine_metrics[key]
        err = b - a if kind == "abs" else (b - a) / a
        ok = abs(err) <= tol
        rows[key] = {"reference": a, "realtime": b, "error": err, "error_kind": kind, "tolerance": tol, "ok": bool(ok),
                     "realtime_quarter_dt": c}  # fmt: skip
        print(f"{key:<24} {a:>12.5g} {b:>12.5g} {err:>+10.3g} {('±' + str(tol)):>10} {'yes' if ok else 'NO ':<3} {c:>14.5g}")
    rows["free_flight_energy_drift_per_s"] = {"realtime": drift, "tolerance": 0.005, "ok": bool(abs(drift) < 0.005),
                                              "peak_to_peak_fraction": spread}  # fmt: skip
    print(f"{'free-flight drift [1/s]':<24} {'':>12} {drift:>12.3g} {'':>10} {'<0.005':>10} {'yes' if abs(drift) < 0.005 else 'NO'}")
    result = {"faces": int(shell.mesh.n_faces), "height_m": args.height, "integrator": args.integrator,
              "reference_dt_s": args.dt, "realtime_dt_s": ball.stable.dt_s, "damping_N_s_per_m": args.damping,
              "friction": args.friction, "setup_s": setup_s, "reference_wall_s": ref_wall, "realtime_wall_s": real["wall_s"],
              "reference": ref_metrics, "realtime": real_metrics, "realtime_quarter_dt": fine_metrics,
              "comparison": rows}  # fmt: skip
    if args.poke:
        result["poke"] = poke_entry(args.faces)
    print(f"wall: reference {ref_wall:.1f} s, realtime {real['wall_s']:.1f} s (per-substep frames, Python overhead included)")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1))
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
