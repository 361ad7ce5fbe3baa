"""Benchmark of the real-time runtime (shelljax.realtime) on the CPU: the Pezzi-like ball bouncing
off a wall and the ground at 60 Hz frames, and the stiff inflatable hammer.

For each mesh size (``--faces``): the stable Δt (element estimate and the spectral one used),
substeps per 60 Hz frame, wall-clock and CPU µs per substep, and the real-time factor
(simulated time / wall-clock time) per frame, median and 99th percentile (the p99 frame is the
slowest 1 %: RT factor = frame Δt / p99 frame wall time). Then the kernel technology: Numba's
membrane + bending (+ gas) force evaluation against ``jax.jit`` of ``jax.grad`` of shell3d's
energies on the same ~2000-face mesh, per call and amortised inside a jitted loop of substeps.
Then the cost per frame [µs] of a ``--display-faces`` display mesh embedded on the 2k-face ball
(``RealtimeShell.embed``). Writes ``--json`` (default docs/bench/realtime-cpu-2core.json).

    python3 experiments/bench_realtime.py [--faces 500 1000 2000 4000] [--duration 2.0]

Timings on a shared, loaded machine are noisy: each number is a median of repeats, the CPU time
(process time, which excludes the time other processes hold the cores) is printed beside the
wall time, and ratios are taken within one run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from shelljax import realtime as rt
from shelljax.dynamics import BarrierContact
from shelljax.geometry import sphere_mesh
from shelljax.physics import Plane, ShellProperties
from shelljax.shell3d import Shell, ShellMesh
from shelljax.physics import AdiabaticGas

PEZZI = {"gauge_pressure": 1300.0, "young_modulus": 2.34e6, "thickness": 0.9e-3, "poisson_ratio": 0.4, "radius": 0.13}
MASS = 0.8
FRAME = 1.0 / 60.0


def planes(contact="barrier"):
    """configs/bounce.toml's ground and wall (friction 0.5; its barrier ĝ = 1 mm, κ = 1e3 J/m², or
    ``contact="spring"``: the runtime's spring behind the plane), with a contact dashpot c = 5 N·s/m."""
    law = BarrierContact(1e-3, 1e3) if contact == "barrier" else None
    return [
        Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], law, friction=0.5, damping=5.0, name="ground"),
        Plane([0.53, 0.0, 0.0], [-1.0, 0.0, 0.0], law, friction=0.5, damping=5.0, name="wall"),
    ]


def ball(n_faces, contact="barrier", **options):
    shell = Shell(mesh=ShellMesh.sphere(PEZZI["radius"], n_faces, pole_refinement=1.0), thickness=PEZZI["thickness"])
    return rt.RealtimeShell.from_shell(
        shell,
        ShellProperties(**PEZZI),
        mass=MASS,
        gas=AdiabaticGas(),
        rest_shape="small-strain",
        planes=planes(contact),
        **options,
    )


def run_frames(shell, duration):
    """Frames of 1/60 s over ``duration`` [s]: per-frame wall [s], CPU [s] and substeps."""
    walls, cpus, steps, forces = [], [], [], []
    for _ in range(round(duration / FRAME)):
        c = time.process_time()
        w = time.perf_counter()
        frame = shell.frame(FRAME)
        walls.append(time.perf_counter() - w)
        cpus.append(time.process_time() - c)
        steps.append(frame.substeps)
        forces.append(np.abs(frame.plane_forces_N).max())
    return np.array(walls), np.array(cpus), np.array(steps), np.array(forces)


def bounce_row(n_faces, duration, parallel=False, contact="barrier"):
    t = time.perf_counter()
    shell = ball(n_faces, contact, parallel=parallel)
    load_s = time.perf_counter() - t
    shell.drop(0.3)
    shell.relax(0.05)  # the small-strain start settles to its inflated shape (in the air)
    shell.drop(0.3, velocity=(3.0, 0.0, 0.0), centre_xy=(0.0, 0.0))  # configs/bounce.toml's launch
    shell.frame(FRAME)  # warm
    walls, cpus, steps, forces = run_frames(shell, duration)
    n = int(steps[0])
    stable = shell.stable
    return {
        "faces": int(shell.geometry.faces.shape[0]),
        "vertices": int(shell.x.shape[0]),
        "load_s": load_s,
        "element_dt_s": stable.element_s,
        "spectral_dt_s": stable.spectral_s,
        "stable_dt_s": stable.dt_s,
        "substeps_per_frame": n,
        "us_per_substep_wall_median": float(np.median(walls) / n * 1e6),
        "us_per_substep_cpu_median": float(np.median(cpus) / n * 1e6),
        "realtime_factor_median": float(FRAME / np.median(walls)),
        "realtime_factor_p99": float(FRAME / np.percentile(walls, 99)),
        "realtime_factor_cpu_median": float(FRAME / np.median(cpus)),
        "realtime_factor_cpu_p99": float(FRAME / np.percentile(cpus, 99)),
        "frames": int(walls.size),
        "max_contact_force_N": float(forces.max()),
        "parallel": parallel,
        "final_com_m": shell.com()[0].tolist(),
    }


def embedding_row(n_faces=2000, display_faces=20000, duration=0.5):
    """A ``display_faces`` sphere mesh embedded on the ``n_faces`` simulated ball: its build time
    [s] and its cost per frame [µs] (placing the display vertices from the simulated ones), beside
    the frame's own cost, during the bounce."""
    shell = ball(n_faces)
    shell.drop(0.3)
    shell.relax(0.05)
    fine, fine_faces = sphere_mesh(PEZZI["radius"], display_faces)
    fine = fine + (shell.com()[0] - fine.mean(axis=0))
    t = time.perf_counter()
    display = shell.embed(fine, fine_faces)
    build_s = time.perf_counter() - t
    out = np.empty((display.n_vertices, 3))
    display.positions(shell.x, out)  # compile / load the kernel
    shell.drop(0.3, velocity=(3.0, 0.0, 0.0), centre_xy=(0.0, 0.0))
    frames, places = [], []
    for _ in range(round(duration / FRAME)):
        w = time.perf_counter()
        shell.frame(FRAME)
        frames.append(time.perf_counter() - w)
        w = time.perf_counter()
        display.positions(shell.x, out)
        places.append(time.perf_counter() - w)
    return {
        "faces": int(shell.geometry.faces.shape[0]),
        "display_faces": len(fine_faces),
        "display_vertices": int(display.n_vertices),
        "build_s": build_s,
        "max_offset_m": float(display.offset_m.max()),
        "us_per_frame_median": float(np.median(places) * 1e6),
        "us_per_frame_p99": float(np.percentile(places, 99) * 1e6),
        "frame_us_median": float(np.median(frames) * 1e6),
    }


def median_time(fn, repeats=7, number=20):
    fn()
    walls, cpus = [], []
    for _ in range(repeats):
        c = time.process_time()
        w = time.perf_counter()
        for _ in range(number):
            fn()
        walls.append((time.perf_counter() - w) / number)
        cpus.append((time.process_time() - c) / number)
    return float(np.median(walls)), float(np.median(cpus))


def kernel_comparison(n_faces=2000):
    """µs per force evaluation: Numba (serial, parallel) vs jax.jit(jax.grad) of shell3d's energies."""
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    from shelljax.shell3d import ShellGeometry, ShellParams, elastic_energy, enclosed_volume

    shell = ball(n_faces)
    x = shell.x.copy()
    rng = np.random.default_rng(0)
    x += 1e-3 * rng.standard_normal(x.shape)
    force = np.zeros_like(x)
    out = {"faces": int(shell.geometry.faces.shape[0])}
    out["numba_serial_us"] = median_time(lambda: shell.elastic_forces(x, with_energy=False, out=force))
    out["numba_serial_with_gas_us"] = median_time(
        lambda: (shell.elastic_forces(x, with_energy=False, out=force), shell.gas_state(x))
    )
    out["numba_parallel_us"] = median_time(lambda: shell.elastic_forces(x, parallel=True, with_energy=False, out=force))
    metric = np.linalg.inv(
        np.stack(
            [
                np.stack([shell.geometry.rest_inv[:, 0], shell.geometry.rest_inv[:, 1]], 1),
                np.stack([shell.geometry.rest_inv[:, 1], shell.geometry.rest_inv[:, 2]], 1),
            ],
            1,
        )
    )
    curvature = np.stack(
        [
            np.stack([shell.geometry.rest_b[:, 0], shell.geometry.rest_b[:, 1]], 1),
            np.stack([shell.geometry.rest_b[:, 1], shell.geometry.rest_b[:, 2]], 1),
        ],
        1,
    )
    geometry = ShellGeometry(
        jnp.asarray(shell.geometry.stencil),
        jnp.asarray(metric),
        jnp.asarray(curvature),
        jnp.asarray(shell.geometry.rest_area),
        jnp.asarray(shell.vertex_area),
    )
    params = ShellParams(
        young_modulus=shell.properties.young_modulus,
        poisson_ratio=shell.properties.poisson_ratio,
        thickness=shell.properties.thickness,
        gauge_pressure=shell.properties.gauge_pressure,
    )
    stencil = jnp.asarray(shell.geometry.stencil)

    def energy(y):
        return elastic_energy(y, params, geometry) - shell.properties.gauge_pressure * enclosed_volume(y, stencil)

    grad = jax.jit(jax.grad(energy))
    xj = jnp.asarray(x)
    t = time.perf_counter()
    grad(xj).block_until_ready()
    out["jax_compile_s"] = time.perf_counter() - t
    out["jax_grad_us"] = median_time(lambda: grad(xj).block_until_ready())
    masses = jnp.asarray(shell.body.masses)[:, None]

    @jax.jit
    def verlet(x0, v0, dt):
        def body(_, state):
            x, v, f = state
            v = v + 0.5 * dt * f / masses
            x = x + dt * v
            f = -jax.grad(energy)(x)
            return x, v + 0.5 * dt * f / masses, f

        return jax.lax.fori_loop(0, 50, body, (x0, v0, -jax.grad(energy)(x0)))

    v0 = jnp.zeros_like(xj)
    verlet(xj, v0, 1e-5)[0].block_until_ready()
    wall, cpu = median_time(lambda: verlet(xj, v0, 1e-5)[0].block_until_ready(), repeats=5, number=2)
    out["jax_fori_loop_us_per_substep"] = (wall / 50, cpu / 50)
    x_nb, v_nb = x.copy(), np.zeros_like(x)
    shell.set_planes(())

    def numba_loop():
        shell.x, shell.v = x_nb.copy(), v_nb.copy()
        shell.advance(50, 1e-5)

    wall, cpu = median_time(numba_loop, repeats=5, number=2)
    out["numba_advance_us_per_substep"] = (wall / 50, cpu / 50)
    out["ratio_jax_grad_over_numba_serial_wall"] = out["jax_grad_us"][0] / out["numba_serial_with_gas_us"][0]
    out["ratio_jax_grad_over_numba_serial_cpu"] = out["jax_grad_us"][1] / out["numba_serial_with_gas_us"][1]
    out["ratio_jax_loop_over_numba_advance_cpu"] = (
        out["jax_fori_loop_us_per_substep"][1] / out["numba_advance_us_per_substep"][1]
    )
    for key, value in list(out.items()):
        if key.endswith(("_us", "per_substep")):
            out[key] = {"wall_us": value[0] * 1e6, "cpu_us": value[1] * 1e6}
    return out


def hammer_rows(duration):
    """The inflatable hammer (sessions/hammer.toml: h = 0.3 mm, ν = 0.4, 0.09 kg; E = 53.98 MPa,
    P_g = 3955 Pa as configs/hammer.toml) dropped onto the ground: configs/hammer.toml's mesh
    (hammer-coarse.stl refined to ~1000 faces) and the session's own hammer.stl (5250 faces)."""
    from shelljax import dynamics as d
    from shelljax import shell3d as s3

    data = ROOT / "shelljax" / "data" / "meshes"
    props = ShellProperties(gauge_pressure=3955.0, young_modulus=53.98e6, thickness=0.3e-3, poisson_ratio=0.4)
    rows = []
    for name, shell in (
        ("hammer-coarse.stl refined to 1000", d.remeshed(s3.load(data / "hammer-coarse.stl", 0.3e-3), 1000)),
        ("hammer.stl (bundled, 5250)", s3.load(data / "hammer.stl", 0.3e-3)),
    ):
        for safety in (0.9, 0.6, 0.4):  # the first safety factor on the spectral Δt that runs
            t = time.perf_counter()
            h = rt.RealtimeShell.from_shell(
                shell,
                props,
                mass=0.09,
                gas=AdiabaticGas(),
                rest_shape="small-strain",
                safety=safety,
                planes=[Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], friction=0.5, damping=1.0)],
            )
            load_s = time.perf_counter() - t
            row = {
                "mesh": name,
                "faces": int(h.geometry.faces.shape[0]),
                "safety": safety,
                "load_s": load_s,
                "element_dt_s": h.stable.element_s,
                "spectral_dt_at_load_s": h.stable.spectral_s,
            }
            try:
                h.drop(0.1)
                h.relax(
                    min(0.01, 4000 * h.stable.dt_s)
                )  # the small-strain start (a uniform shrink) is not its equilibrium
                h.drop(0.05)
                n = h.substeps_for(FRAME)
                row.update(
                    {"spectral_dt_s": h.stable.spectral_s, "stable_dt_s": h.stable.dt_s, "substeps_per_frame": n}
                )
                # Frames of the hammer need thousands of substeps: time blocks of ≤ 2000 substeps at the
                # frame's substep and scale to a frame (RT factor = frame / (n × time per substep)).
                block = min(n, 2000)
                walls, cpus = [], []
                for _ in range(5):
                    c, w = time.process_time(), time.perf_counter()
                    status, done = h.advance(block, FRAME / n)
                    walls.append((time.perf_counter() - w) / done)
                    cpus.append((time.process_time() - c) / done)
                    if status != 0:
                        raise rt.BlowUpError(
                            f"status {status} after {done} substeps", reason="not finite", time_s=h.time, dt_s=FRAME / n
                        )
            except rt.BlowUpError as err:
                row["blew_up"] = str(err).split("\n")[0]
                rows.append(row)
                continue
            break
        row.update(
            {
                "blocks_of_substeps": block,
                "us_per_substep_wall_median": float(np.median(walls) * 1e6),
                "us_per_substep_cpu_median": float(np.median(cpus) * 1e6),
                "realtime_factor_median": float(FRAME / (n * np.median(walls))),
                "realtime_factor_cpu_median": float(FRAME / (n * np.median(cpus))),
            }
        )
        rows.append(row)
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--faces", type=int, nargs="+", default=[500, 1000, 2000, 4000])
    parser.add_argument("--duration", type=float, default=2.0, help="simulated seconds per mesh [s]")
    parser.add_argument("--parallel", action="store_true", help="Numba's threaded kernel (prange over faces)")
    parser.add_argument(
        "--contact",
        choices=("barrier", "spring"),
        default="barrier",
        help="the planes' law: configs/bounce.toml's barrier (default) or the runtime's plain spring",
    )
    parser.add_argument("--skip-jax", action="store_true")
    parser.add_argument("--skip-hammer", action="store_true")
    parser.add_argument("--display-faces", type=int, default=20000, help="display mesh embedded on 2k faces (0: skip)")
    parser.add_argument("--json", type=Path, default=ROOT / "docs" / "bench" / "realtime-cpu-2core.json")
    args = parser.parse_args()
    load = os.getloadavg()
    rows = []
    print(
        f"{'faces':>6} {'dt_elem ms':>10} {'dt ms':>7} {'sub/fr':>6} {'us/sub wall':>11} {'us/sub cpu':>10} "
        f"{'RT med':>7} {'RT p99':>7} {'RTcpu med':>9} {'RTcpu p99':>9}"
    )
    for n in args.faces:
        r = bounce_row(n, args.duration, args.parallel, args.contact)
        rows.append(r)
        print(
            f"{r['faces']:>6} {r['element_dt_s'] * 1e3:>10.4f} {r['stable_dt_s'] * 1e3:>7.4f} {r['substeps_per_frame']:>6} "
            f"{r['us_per_substep_wall_median']:>11.1f} {r['us_per_substep_cpu_median']:>10.1f} "
            f"{r['realtime_factor_median']:>7.2f} {r['realtime_factor_p99']:>7.2f} "
            f"{r['realtime_factor_cpu_median']:>9.2f} {r['realtime_factor_cpu_p99']:>9.2f}",
            flush=True,
        )
    result = {
        "machine": {
            "cpus": os.cpu_count(),
            "platform": platform.platform(),
            "load_average_at_start": load,
            "note": "shared machine, loaded by other jobs: wall times noisy; CPU (process) time beside them",
        },
        "frame_s": FRAME,
        "scenario": "configs/bounce.toml's ball (R 0.13 m, h 0.9 mm, E 2.34 MPa, P_g 1300 Pa, "
        "0.8 kg, adiabatic) launched at 3 m/s, 0.3 m up, at the wall then the ground; Numba serial kernels",
        "contact": args.contact,
        "bounce": rows,
    }
    if args.display_faces:
        e = result["embedding"] = embedding_row(display_faces=args.display_faces)
        print(
            f"\ndisplay mesh: {e['display_faces']} faces ({e['display_vertices']} vertices) on {e['faces']}: "
            f"build {e['build_s']:.2f} s, {e['us_per_frame_median']:.0f} µs per frame (p99 {e['us_per_frame_p99']:.0f}) "
            f"beside the frame's {e['frame_us_median']:.0f} µs; offsets up to {e['max_offset_m'] * 1e3:.2f} mm"
        )
    if not args.skip_jax:
        result["kernels"] = kernel_comparison()
        k = result["kernels"]
        print(f"\nkernels at {k['faces']} faces (µs per force evaluation, wall / cpu):")
        for key in (
            "numba_serial_us",
            "numba_serial_with_gas_us",
            "numba_parallel_us",
            "jax_grad_us",
            "numba_advance_us_per_substep",
            "jax_fori_loop_us_per_substep",
        ):
            print(f"  {key:<34} {k[key]['wall_us']:>9.1f} {k[key]['cpu_us']:>9.1f}")
        print(
            f"  jax.grad / numba (cpu): {k['ratio_jax_grad_over_numba_serial_cpu']:.2f}; "
            f"jitted loop / numba advance (cpu): {k['ratio_jax_loop_over_numba_advance_cpu']:.2f}"
        )
    if not args.skip_hammer:
        result["hammer"] = hammer_rows(args.duration)
        print("\nhammer:")
        for r in result["hammer"]:
            if "blew_up" in r:
                print(f"  {r['mesh']:<36} safety {r['safety']}: {r['blew_up'][:120]}")
                continue
            print(
                f"  {r['mesh']:<36} faces {r['faces']:>5} dt_elem {r['element_dt_s'] * 1e6:8.3f} µs  dt {r['stable_dt_s'] * 1e6:8.3f} µs  "
                f"substeps/frame {r['substeps_per_frame']:>6}  µs/substep cpu {r['us_per_substep_cpu_median']:7.1f}  "
                f"RT med {r['realtime_factor_median']:.4f} (cpu {r['realtime_factor_cpu_median']:.4f}) safety {r['safety']}"
            )
    result["load_average_at_end"] = os.getloadavg()
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1))
    print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
