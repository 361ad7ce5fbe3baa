"""Fidelity of the real-time runtime against the implicit reference (issue #48's table).

The same ball (configs/drop.toml's Pezzi ball: R 0.13 m, h 0.9 mm, ν 0.4, E 2.34 MPa, P_g 1300 Pa,
0.8 kg, adiabatic gas; the rest shape, inflated state and masses of ``dynamics.shell_system``,
which ``RealtimeShell.from_system`` copies) in the issue's cases, once with ``dynamics.simulate``
(``--integrator``, default TRBDF2, at ``--dt`` 62.5 µs and ``--coarse-dt`` 125 µs for its own
Δt-convergence; barrier contact ĝ = 1 mm, κ = 1e3 J/m², as the configs) and with
``shelljax.realtime`` (velocity Verlet at its stable Δt; the same barrier on the planes, continued
linearly by the contact springs where it gets stiffer than they; and at Δt/4 and with 4× stiffer
contact springs, for its own convergence; ``--realtime-contact spring`` for plain springs behind
the planes):

* ``drop-0.25``, ``drop-0.5``, ``drop-1.0``: dropped from rest, lowest point 0.25, 0.5, 1.0 m above
  the ground;
* ``wall``: configs/bounce.toml's throw: 0.3 m above the ground at 3 m/s towards a wall 0.4 m
  ahead (both planes μ = 0.5), first the wall's impact, then the ground's;
* the static poke (an 8 mm sphere 20 mm into the ball on the ground, no gravity) against
  ``shell3d.Indentation``'s quasi-static solve;
* the realtime's free-flight energy drift per second, and its zero-damping COR against 0.97.

One impact analysis for both (``impact``): contact while the COM is lower than where the free
shape touches the plane; COR = COM normal speed out / in at those instants; compression = the
COM's travel past that height; peak force and peak gauge pressure of the signals low-passed at
``--peak-cutoff`` (60 Hz, zero phase: the breathing mode at 150 Hz and the vertices' chatter
above 360 Hz are what neither engine converges; docs/realtime.md).

The reference runs are slow (2.5–7 min each on 2 shared cores): each is cached under ``--cache``
(runs/.cache/realtime-fidelity by default, git-ignored) keyed by its case, mesh, scheme and Δt,
and ``--reference-only`` fills the cache (run it in the background with nohup). Without it, the
script runs the realtime side (seconds), reads the cached references, and prints the table with
"pending" for references not yet computed. Writes ``--json`` (docs/bench/realtime-fidelity.json).

    nohup python3 experiments/verify_realtime.py --reference-only --poke > runs/verify_realtime.log 2>&1 &
    python3 experiments/verify_realtime.py [--faces 2000] [--poke]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path

import jax
import numpy as np
from scipy.signal import butter, sosfiltfilt

jax.config.update("jax_enable_x64", True)
ROOT = Path(__file__).resolve().parents[1]

from shelljax import dynamics as d
from shelljax import realtime as rt
from shelljax.physics import Plane, ShellProperties
from shelljax.realtime import SAFETY
from shelljax.shell3d import Shell, ShellMesh
from shelljax.physics import AdiabaticGas, IsothermalGas

PEZZI = {"gauge_pressure": 1300.0, "young_modulus": 2.34e6, "thickness": 0.9e-3, "poisson_ratio": 0.4}
RADIUS, MASS = 0.13, 0.8
G = 9.80665
#: The issue's criteria per impact quantity: ("abs" | "rel", tolerance).
CRITERIA = {
    "cor": ("abs", 0.02),
    "contact_time_s": ("rel", 0.03),
    "max_compression_m": ("rel", 0.03),
    "peak_force_N": ("rel", 0.05),
    "peak_gauge_pressure_Pa": ("rel", 0.01),
}
#: The cases: drops from rest (lowest point ``height`` [m] above the ground) and the wall throw.
CASES = {
    "drop-0.25": {"height_m": 0.25},
    "drop-0.5": {"height_m": 0.5},
    "drop-1.0": {"height_m": 1.0},
    "wall": {"height_m": 0.3, "velocity_m_per_s": (3.0, 0.0, 0.0), "wall_gap_m": 0.4},
}
#: Records kept in the cache (per step); the per-vertex positions are left out (48 MB a run at 2k faces).
KEPT = (
    "time_s",
    "com_position_m",
    "com_velocity_m_per_s",
    "contact_force_N",
    "gas_pressure_Pa",
    "total_energy_J",
    "newton_iterations",
)


def moving_average(time_s, signal, window):
    """``signal`` averaged over a centred window of ``window`` [s] (its sampling read from ``time_s``)."""
    n = max(1, round(window / np.median(np.diff(time_s))))
    return np.convolve(signal, np.ones(n) / n, mode="same")


def low_pass(time_s, signal, cutoff_hz):
    """``signal`` low-passed at ``cutoff_hz`` [Hz]: a 4-pole Butterworth filter run forwards and
    backwards (zero phase, as SAE J211's channel filters for impact forces), its sampling from ``time_s``."""
    sampling_hz = 1.0 / np.median(np.diff(time_s))
    return sosfiltfilt(butter(4, cutoff_hz, fs=sampling_hz, output="sos"), signal)


def impact(time_s, com_height, com_speed, force, pressure, rest_height, peak_cutoff_hz=60.0, after=0.0):
    """The first impact on one plane after ``after`` [s], from per-step arrays: the COM's height
    above the plane [m] and normal velocity [m/s], the plane's normal force on the shell [N], the
    gauge pressure [Pa]; ``rest_height`` [m]: the COM's height when the free shape touches the plane.

    The contact lasts while the COM is below ``rest_height`` (its crossings interpolated linearly):
    the ball's own contact, which the vertices' chatter on the plane does not move. COR = COM
    normal speed out / in at those crossings; compression = ``rest_height`` − the lowest COM height.
    Peak force and pressure are those of the signals low-passed at ``peak_cutoff_hz`` (default
    60 Hz: below the ball's breathing mode, 150 Hz, and the vertices' chatter, 360 Hz and up, which
    neither engine converges; the impact pulse, 50–75 ms long, keeps its peak to 0.2 %;
    docs/realtime.md). The raw peaks, the 8 ms-averaged ones and the contact time by the force's
    threshold (2 % of its 2 ms-averaged peak) are kept beside them."""
    below = np.flatnonzero((com_height < rest_height) & (time_s >= after))
    if below.size == 0:
        raise RuntimeError("no impact in the record: lengthen the duration")
    gaps = np.flatnonzero(np.diff(time_s[below]) > 1e-2)
    run = below[: gaps[0] + 1] if gaps.size else below
    i0, i1 = int(run[0]), int(run[-1])
    if i0 == 0 or i1 == time_s.size - 1:
        raise RuntimeError("the record starts or ends during the impact: lengthen the duration")

    def crossing(i, j, signal, level):  # the time where ``signal`` crosses ``level`` between steps i and j
        a, b = signal[i] - level, signal[j] - level
        return time_s[i] + (time_s[j] - time_s[i]) * a / (a - b) if a != b else time_s[i]

    t_on, t_off = crossing(i0 - 1, i0, com_height, rest_height), crossing(i1, i1 + 1, com_height, rest_height)
    v_in, v_out = float(np.interp(t_on, time_s, com_speed)), float(np.interp(t_off, time_s, com_speed))
    window = slice(i0 - 1, i1 + 2)
    smooth = moving_average(time_s, force, 2e-3)
    level = 0.02 * float(smooth[window].max())
    on = np.flatnonzero(smooth[window] > level) + i0 - 1
    return {
        "start_s": float(t_on),
        "cor": -v_out / v_in,
        "contact_time_s": float(t_off - t_on),
        "impact_speed_m_per_s": -v_in,
        "max_compression_m": float(rest_height - com_height[window].min()),
        "peak_force_N": float(low_pass(time_s, force, peak_cutoff_hz)[window].max()),
        "peak_gauge_pressure_Pa": float(low_pass(time_s, pressure, peak_cutoff_hz)[window].max()),
        "peak_force_raw_N": float(force[window].max()),
        "peak_force_8ms_N": float(moving_average(time_s, force, 8e-3)[window].max()),
        "peak_gauge_pressure_raw_Pa": float(pressure[window].max()),
        "peak_gauge_pressure_8ms_Pa": float(moving_average(time_s, pressure, 8e-3)[window].max()),
        "contact_time_force_threshold_s": float(time_s[on[-1]] - time_s[on[0]]) if on.size else None,
    }


def planes_for(case, damping, friction, barrier=True, slip_tolerance=1e-4):
    """The case's planes (``physics.Plane``): the ground, and for ``wall`` the wall [m]; the
    reference's friction smooths slips below ``slip_tolerance`` [m] a step."""
    law = d.BarrierContact(1e-3, 1e3) if barrier else None
    kw = {"friction": friction, "slip_tolerance": slip_tolerance, "damping": damping}
    out = [Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], law, **kw, name="ground")]
    if "wall_gap_m" in CASES[case]:
        x_wall = RADIUS + CASES[case]["wall_gap_m"]  # the ball's centre starts at x = 0
        out.append(Plane([x_wall, 0.0, 0.0], [-1.0, 0.0, 0.0], law, **kw, name="wall"))
    return out


def duration_for(case):
    """Simulated time [s] of a case: the fall, and 0.15 s for the impact (≈ 65 ms) and the rebound."""
    c = CASES[case]
    return float(np.sqrt(2 * c["height_m"] / G) + 0.15)


def build_system(faces, case, damping, friction, slip_tolerance=1e-4):
    shell = Shell(mesh=ShellMesh.sphere(RADIUS, faces, pole_refinement=1.0), thickness=PEZZI["thickness"])
    return d.shell_system(
        shell,
        ShellProperties(**PEZZI),
        gas=AdiabaticGas(),
        mass=MASS,
        planes=planes_for(case, damping, friction, slip_tolerance=slip_tolerance),
    )


def cache_path(cache, case, faces, integrator, dt, damping, friction, slip_velocity):
    key = json.dumps([case, CASES[case], faces, integrator, dt, damping, friction, slip_velocity], sort_keys=True)
    return cache / f"{case}-{faces}-{integrator}-{dt:g}-{hashlib.sha1(key.encode()).hexdigest()[:8]}.npz"


def reference_run(case, faces, integrator, dt, damping, friction, slip_velocity, cache):
    """The reference trajectory of ``case`` (per-step arrays of ``KEPT``; ``failed`` set if Newton
    failed), from ``cache`` or computed and stored there. Its lagged friction smooths slips below a
    displacement ε = ``slip_velocity`` × Δt a step [m]: the same slip velocity [m/s] at every Δt
    (a fixed ε would weaken the friction as Δt shrinks)."""
    path = cache_path(cache, case, faces, integrator, dt, damping, friction, slip_velocity)
    if path.is_file():
        z = np.load(path, allow_pickle=False)
        return {k: z[k] for k in z.files}
    system = build_system(faces, case, damping, friction, slip_tolerance=slip_velocity * dt)
    c = CASES[case]
    state = d.drop_state(system, system.inflated, c["height_m"], velocity=c.get("velocity_m_per_s"))
    start = time.perf_counter()
    try:
        r = d.simulate(
            system,
            state,
            dt,
            duration_for(case),
            integrator=getattr(d, integrator)(),
            minimiser=d.SparseNewton(),
            progress=False,
        ).records
        out = {k: np.asarray(r[k]) for k in KEPT}
    except Exception as error:  # noqa: BLE001 - a failed reference is a result to report, not a crash
        out = {"failed": np.asarray(str(error).splitlines()[0])}
    out["wall_s"] = np.asarray(time.perf_counter() - start)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **out)
    tmp.replace(path)
    return out


def realtime_run(shell, case, duration):
    """Per-substep arrays of the realtime run of ``case`` (frames of one substep)."""
    c = CASES[case]
    shell.drop(c["height_m"], velocity=c.get("velocity_m_per_s", (0.0, 0.0, 0.0)))
    rows, forces = [], []
    t = time.perf_counter()
    dt = shell.stable.dt_s
    while shell.time < duration:
        f = shell.frame(dt, substeps=1)
        rows.append((f.time_s, *f.com_m, *f.com_velocity_m_per_s, f.gauge_pressure_Pa, f.energies_J["total"]))
        forces.append(f.plane_forces_N.copy())
    wall = time.perf_counter() - t
    a = np.array(rows)
    return {
        "time_s": a[:, 0],
        "com_position_m": a[:, 1:4],
        "com_velocity_m_per_s": a[:, 4:7],
        "contact_force_N": np.array(forces),
        "gas_pressure_Pa": a[:, 7],
        "total_energy_J": a[:, 8],
        "wall_s": wall,
    }


def case_impacts(case, record, system, peak_cutoff_hz):
    """The case's impacts (``ground``; for ``wall`` first ``wall`` then ``ground``) from a record."""
    planes = planes_for(case, 0.0, 0.0)
    x0 = np.asarray(system.inflated).reshape(-1, 3)
    com0 = np.asarray(system.centre_of_mass(system.inflated))
    out, after = {}, 0.0
    for p in [1, 0] if len(planes) > 1 else [0]:
        n = np.asarray(planes[p].normal, dtype=float)
        point = np.asarray(planes[p].point, dtype=float)
        rest_height = float(np.max((com0 - x0) @ n))  # the COM's height over the free shape's lowest point along n
        height = (record["com_position_m"] - point) @ n
        speed = record["com_velocity_m_per_s"] @ n
        force = record["contact_force_N"][:, p, :] @ n
        m = impact(
            record["time_s"],
            height,
            speed,
            force,
            record["gas_pressure_Pa"],
            rest_height,
            peak_cutoff_hz=peak_cutoff_hz,
            after=after,
        )
        out[planes[p].name] = m
        after = m["start_s"] + m["contact_time_s"]
    return out


def free_flight_drift(shell, seconds=1.0):
    """Relative total-energy drift per second [1/s] of the realtime ball falling freely and
    spinning (no planes), from windowed means (the first and last 0.1 s) over ``seconds``."""
    shell.set_planes(())
    spin = np.cross([5.0, 0.0, 0.0], shell.x - shell.com()[0])  # 5 rad/s: the shell stretches and vibrates
    shell.set_state(shell.x, spin + np.array([0.5, 0.0, 1.0]))
    totals = []
    while shell.time < seconds:
        totals.append(shell.frame(1.0 / 60.0).energies_J["total"])
    totals = np.array(totals)
    scale = abs(totals[0]) + shell.total_mass * G * seconds**2 * G  # |E| plus the fall's potential range
    k = max(1, len(totals) // 10)
    return float((totals[-k:].mean() - totals[:k].mean()) / scale / seconds), float(np.ptp(totals) / scale)


def static_force(ball):
    """The collider's push [N] on the shell at rest in its current state (no substep taken)."""
    return float(-ball.contact_forces()[1][2])


def poke(
    faces,
    depth=0.02,
    radius=0.008,
    friction=0.0,
    stiffness_factor=30.0,
    stages=40,
    tolerance=1e-3,
    max_blocks=16,
    cache=None,
):
    """Static poke force [N] at ``depth`` [m]: shell3d.Indentation (quasi-static, barrier, no
    gravity) and the realtime ball (penalty) relaxed under a sphere collider whose lowest point is
    at the engine's solved indenter height above the ground, same mesh and gas.

    The engine's ``depth`` counts from its start, where its barrier keeps half its range ĝ
    (0.2 mm at 2k faces) between the indenter and the top and between the bottom and the ground;
    ``depth`` below the touching point (the realtime's former reading) squeezes the realtime ball
    by about ĝ = 0.4 mm more: +2.5 % of the force. The same indenter height compares one
    configuration, different only in the contacts (barrier at vertices: ≈ 0.04 mm standoff;
    penalty at vertices, ``stiffness_factor`` × the dynamic default spring; the hand's triangle
    backstop is not engaged by this sphere). As the engine,
    the ground is frictionless and the shell held under the sphere; the reading is taken once
    settled (the force changes by < ``tolerance`` per five relaxations)."""
    from shelljax import shell3d as s3

    shell = Shell(mesh=ShellMesh.sphere(RADIUS, faces, pole_refinement=1.0), thickness=PEZZI["thickness"])
    props = ShellProperties(**PEZZI)
    path = None if cache is None else cache / f"poke-{faces}-{depth:g}-{radius:g}.json"
    if path is not None and path.is_file():
        ref = json.loads(path.read_text())
    else:
        sim = s3.Indentation(shell, props, gas=IsothermalGas(), indenter_radius=radius, ground=True)
        state = sim.solve(depth=depth)
        ref = {
            "force_N": float(state.observables()["force"]),
            "activation_distance_m": float(sim.activation_distance),
            "indenter_bottom_m": float(state.indenter_center[2] - radius),
        }  # above the ground (z = 0) [m]
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(ref))
    system = d.shell_system(shell, props, gas=IsothermalGas(), mass=MASS, gravity=0.0)
    # The engine's indenter and ground are frictionless (``friction`` 0 here too: the realtime's
    # velocity-regularised friction cannot hold a static load, it only slows the creep). A static
    # reading does not need the dynamic default spring (≈ 1 mm under the indenter): the force
    # converges towards hard contact as the springs stiffen (docs/realtime.md), and
    # ``stiffness_factor`` × it is within 0.3 % of that limit, at a smaller Δt.
    ground = Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], friction=friction, name="ground")
    probe = rt.RealtimeShell.from_system(system, planes=[ground], gravity=0.0)
    ball = rt.RealtimeShell.from_system(
        system, planes=[ground], gravity=0.0, contact_stiffness=stiffness_factor * float(probe.contact.stiffness.max())
    )
    ball.drop(0.0)
    top = int(np.argmax(ball.x[:, 2]))
    touch = np.array([ball.x[top, 0], ball.x[top, 1], ball.x[top, 2] + radius])
    travel = float(ball.x[top, 2] - ref["indenter_bottom_m"])  # into the free shape [m]

    def relax_under_the_sphere():
        # The engine pins the shell's horizontal rigid modes; here the shell is shifted back under
        # the sphere after each relaxation (a rigid shift: no force changes), as those pins hold it.
        ball.relax(0.02)
        ball.x[:, :2] += touch[:2] - ball.x[top, :2]

    for k in range(1, stages + 1):  # press in slowly, relaxing at each depth
        ball.set_collider(rt.Collider.sphere(touch - np.array([0.0, 0.0, travel * k / stages]), radius))
        relax_under_the_sphere()
    # Settle in short, strongly damped relaxations until the force at rest changes by less than
    # ``tolerance`` per block of five (the squeezed shell keeps creeping after the pressing).
    force, settles = static_force(ball), 0
    for _ in range(max_blocks):
        for _ in range(5):
            relax_under_the_sphere()
        settles += 5
        previous, force = force, static_force(ball)
        if abs(force - previous) < tolerance * abs(force):
            break
    com, _ = ball.com()
    return {
        "reference_force_N": ref["force_N"],
        "realtime_force_N": force,
        "depth_m": depth,
        "settle_relaxations": settles,
        "last_block_change_N": float(force - previous),
        "travel_into_free_shape_m": travel,
        "reference_activation_distance_m": ref["activation_distance_m"],
        "realtime_com_offset_m": float(np.hypot(com[0] - touch[0], com[1] - touch[1])),
        "contact_stiffness_N_per_m": float(ball.contact.stiffness.max()),
        "realtime_dt_s": ball.stable.dt_s,
        "ground_friction": friction,
        "stiffness_factor": stiffness_factor,
    }


def row(reference, realtime, kind, tol, **extra):
    """One table row: the error (``kind`` "abs" or "rel") against ``tol``; None where pending."""
    if reference is None or realtime is None:
        return {
            "reference": reference,
            "realtime": realtime,
            "error": None,
            "error_kind": kind,
            "tolerance": tol,
            "ok": None,
            **extra,
        }
    err = realtime - reference if kind == "abs" else (realtime - reference) / reference
    return {
        "reference": reference,
        "realtime": realtime,
        "error": err,
        "error_kind": kind,
        "tolerance": tol,
        "ok": bool(abs(err) <= tol),
        **extra,
    }


def print_table(rows):
    head = f"{'quantity':<38} {'reference':>10} {'realtime':>10} {'error':>9} {'criterion':>9} {'ok':<4}"
    print(head + f" {'ref 2Δt':>10} {'rt Δt/4':>10} {'rt 4k':>10}")
    fmt = lambda v: "—" if v is None else f"{v:.5g}"
    for name, r in rows.items():
        ref = "pending" if r["reference"] is None and r["error_kind"] in ("abs", "rel") else fmt(r["reference"])
        err = "" if r["error"] is None else f"{r['error']:+.3g}"
        crit = ("±" if r["error_kind"] in ("abs", "rel") else r["error_kind"]) + f"{r['tolerance']:g}"
        ok = "—" if r["ok"] is None else ("yes" if r["ok"] else "NO")
        extra = " ".join(f"{fmt(r.get(k)):>10}" for k in ("reference_coarse", "realtime_quarter_dt", "realtime_stiff"))
        print(f"{name:<38} {ref:>10} {fmt(r['realtime']):>10} {err:>9} {crit:>9} {ok:<4} {extra}")


def pick(impacts, plane, key):
    """``impacts[plane][key]``, or None where the reference is pending or failed."""
    return impacts[plane][key] if plane in impacts else None


def cached_impacts(case, system, args, dt):
    """The reference's impacts at ``dt`` from the cache: a dict, {"pending": path} or {"failed": why}."""
    path = cache_path(
        args.cache, case, args.faces, args.integrator, dt, args.damping, args.friction, args.slip_velocity
    )
    if not path.is_file():
        return {"pending": str(path)}
    ref = reference_run(
        case, args.faces, args.integrator, dt, args.damping, args.friction, args.slip_velocity, args.cache
    )
    if "failed" in ref:
        return {"failed": str(ref["failed"]), "wall_s": float(ref["wall_s"])}
    return {**case_impacts(case, ref, system, args.peak_cutoff), "wall_s": float(ref["wall_s"])}


def realtime_impacts(system, case, args, **options):
    barrier = args.realtime_contact == "barrier"
    # a blow-up in a fidelity run is reported, not stepped around by redone frames
    ball = rt.RealtimeShell.from_system(
        system,
        planes=planes_for(case, args.damping, args.friction, barrier=barrier),
        slip_velocity=args.slip_velocity,
        max_refinements=0,
        **options,
    )
    real = realtime_run(ball, case, duration_for(case))
    return {**case_impacts(case, real, system, args.peak_cutoff), "dt_s": ball.stable.dt_s, "wall_s": real["wall_s"]}


def poke_row(args, result):
    """The static poke's table row; its details (and the penalty's convergence) into ``result``."""
    p = poke(args.faces, cache=args.cache)
    # The penalty's own convergence: the force with springs 3× softer and 3× stiffer.
    p["realtime_force_by_stiffness_factor_N"] = {
        f"{f:g}": poke(args.faces, cache=args.cache, stiffness_factor=f)["realtime_force_N"] for f in (10.0, 100.0)
    }
    result["poke"] = p
    return row(p["reference_force_N"], p["realtime_force_N"], "rel", 0.02)


def reference_convergence(args):
    """The reference's COR, contact time, compression and 60 Hz peaks per case at each of
    ``args.convergence``'s steps, and their spread [%] (max − min over the mean)."""
    keys = ("cor", "contact_time_s", "max_compression_m", "peak_force_N", "peak_gauge_pressure_Pa")
    out = {
        "integrator": args.integrator,
        "slip_velocity_m_per_s": args.slip_velocity,
        "steps_s": args.convergence,
        "cases": {},
    }
    print(
        f"{'case, impact':<22} {'quantity':<24} "
        + " ".join(f"{dt * 1e3:>9.4g} ms" for dt in args.convergence)
        + "  spread"
    )
    for case in args.cases:
        system = build_system(args.faces, case, args.damping, args.friction)
        runs = {
            dt: reference_run(
                case, args.faces, args.integrator, dt, args.damping, args.friction, args.slip_velocity, args.cache
            )
            for dt in args.convergence
        }
        impacts = {dt: case_impacts(case, r, system, args.peak_cutoff) for dt, r in runs.items() if "failed" not in r}
        out["cases"][case] = {f"{dt:g}": m for dt, m in impacts.items()}
        for plane in next(iter(impacts.values()), {}):
            for key in keys:
                values = np.array([impacts[dt][plane][key] for dt in impacts])
                spread = float(np.ptp(values) / abs(values.mean()))
                out["cases"][case][f"{plane} {key} spread"] = spread
                print(
                    f"{case + ', ' + plane:<22} {key:<24} "
                    + " ".join(f"{v:>12.5g}" for v in values)
                    + f"  {100 * spread:5.2f} %"
                )
    args.convergence_json.write_text(json.dumps(out, indent=1))
    print(f"wrote {args.convergence_json}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--faces", type=int, default=2000)
    parser.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES))
    parser.add_argument("--integrator", default="TRBDF2", help="a shelljax.dynamics integrator class name")
    parser.add_argument("--dt", type=float, default=6.25e-5, help="the reference's time step [s]")
    parser.add_argument(
        "--coarse-dt",
        type=float,
        default=1.25e-4,
        help="a coarser reference step [s], for the reference's own Δt-convergence (0: none)",
    )
    parser.add_argument("--damping", type=float, default=0.0, help="contact dashpot c [N·s/m]")
    parser.add_argument("--friction", type=float, default=0.5)
    parser.add_argument(
        "--slip-velocity",
        type=float,
        default=0.1,
        help="both engines' friction regularisation [m/s]: the realtime's v_ε, the reference's "
        "slip tolerance ε = v_ε Δt (configs' ε = 0.1 mm at Δt = 1 ms)",
    )
    parser.add_argument(
        "--realtime-contact",
        choices=("barrier", "spring"),
        default="barrier",
        help="the realtime's planes: the reference's barrier (continued by the contact spring where it "
        "gets stiffer) or the plain spring behind the plane",
    )
    parser.add_argument(
        "--peak-cutoff",
        type=float,
        default=60.0,
        help="low-pass cut-off for the peak force and pressure [Hz] (docs/realtime.md: below the "
        "ball's breathing mode and the vertices' chatter, which neither engine converges)",
    )
    parser.add_argument("--poke", action="store_true", help="also the static poke force (≈ 2 min)")
    parser.add_argument("--cache", type=Path, default=ROOT / "runs" / ".cache" / "realtime-fidelity")
    parser.add_argument("--reference-only", action="store_true", help="only fill the reference cache (slow)")
    parser.add_argument("--poke-only", action="store_true", help="only the static poke, into the existing --json")
    parser.add_argument("--json", type=Path, default=ROOT / "docs" / "bench" / "realtime-fidelity.json")
    parser.add_argument(
        "--convergence",
        type=float,
        nargs="+",
        default=None,
        metavar="DT",
        help="only the reference's own convergence over these steps [s] (e.g. 1e-3 5e-4 2.5e-4, "
        "#48 part 1), into --convergence-json; runs the references that are not cached",
    )
    parser.add_argument("--convergence-json", type=Path, default=ROOT / "docs" / "bench" / "reference-convergence.json")
    args = parser.parse_args()
    steps = [args.dt] + ([args.coarse_dt] if args.coarse_dt else [])

    if args.reference_only:
        for dt in steps:
            for case in args.cases:
                t = time.perf_counter()
                r = reference_run(
                    case, args.faces, args.integrator, dt, args.damping, args.friction, args.slip_velocity, args.cache
                )
                status = f"failed: {r['failed']}" if "failed" in r else "ok"
                print(
                    f"{time.strftime('%H:%M:%S')} {case} {args.integrator} dt {dt:g} s: {status} "
                    f"({time.perf_counter() - t:.0f} s)",
                    flush=True,
                )
        if args.poke:
            print(f"{time.strftime('%H:%M:%S')} poke reference {poke(args.faces, cache=args.cache)}", flush=True)
        return

    if args.convergence:
        return reference_convergence(args)

    if args.poke_only:
        result = json.loads(args.json.read_text())
        result["comparison"]["static poke force [N]"] = poke_row(args, result)
        print_table({"static poke force [N]": result["comparison"]["static poke force [N]"]})
        args.json.write_text(json.dumps(result, indent=1))
        print(f"wrote {args.json}")
        return

    result = {
        "faces": None,
        "integrator": args.integrator,
        "reference_dt_s": args.dt,
        "coarse_dt_s": args.coarse_dt,
        "damping_N_s_per_m": args.damping,
        "friction": args.friction,
        "slip_velocity_m_per_s": args.slip_velocity,
        "peak_cutoff_Hz": args.peak_cutoff,
        "cases": {},
    }
    rows = {}
    for case in args.cases:
        system = build_system(args.faces, case, args.damping, args.friction)
        result["faces"] = int(np.asarray(system.surface_faces()).shape[0])
        real = realtime_impacts(system, case, args)
        # The realtime's own convergence: a quarter of its Δt, and contact springs 4× stiffer.
        fine = realtime_impacts(system, case, args, safety=0.25 * SAFETY)
        probe = rt.RealtimeShell.from_system(system)
        stiff = realtime_impacts(system, case, args, contact_stiffness=4.0 * float(np.median(probe.contact.stiffness)))
        refs = {f"{dt:g}": cached_impacts(case, system, args, dt) for dt in steps}
        result["cases"][case] = {
            "realtime": real,
            "realtime_quarter_dt": fine,
            "realtime_stiff_contact": stiff,
            "reference": refs,
        }
        main_ref = refs[f"{args.dt:g}"]
        coarse = refs.get(f"{args.coarse_dt:g}", {})
        for plane in ("wall", "ground") if "wall_gap_m" in CASES[case] else ("ground",):
            for key, (kind, tol) in CRITERIA.items():
                rows[f"{case} {plane} {key}"] = row(
                    pick(main_ref, plane, key),
                    real[plane][key],
                    kind,
                    tol,
                    reference_coarse=pick(coarse, plane, key),
                    realtime_quarter_dt=fine[plane][key],
                    realtime_stiff=stiff[plane][key],
                )
    cors = [m["cor"] for e in result["cases"].values() for m in e["realtime"].values() if isinstance(m, dict)]
    if args.damping == 0.0:
        rows["zero-damping COR (lowest of the impacts)"] = {
            "reference": None,
            "realtime": min(cors),
            "error": None,
            "error_kind": "≥",
            "tolerance": 0.97,
            "ok": bool(min(cors) >= 0.97),
        }
    drift, spread = free_flight_drift(rt.RealtimeShell.from_system(build_system(args.faces, "drop-0.5", 0.0, 0.0)))
    rows["free-flight energy drift [1/s]"] = {
        "reference": None,
        "realtime": drift,
        "error": None,
        "error_kind": "<",
        "tolerance": 0.005,
        "ok": bool(abs(drift) < 0.005),
        "peak_to_peak_fraction": spread,
    }
    if args.poke:
        rows["static poke force [N]"] = poke_row(args, result)
    result["comparison"] = rows
    print(
        f"{result['faces']}-face ball; reference {args.integrator} at {args.dt:g} s (and {args.coarse_dt:g} s); "
        f"peak force and pressure low-passed at {args.peak_cutoff:g} Hz"
    )
    print_table(rows)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1))
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
