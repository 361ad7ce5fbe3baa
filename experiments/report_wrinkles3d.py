"""3D wrinkle counts against the axisymmetric count and n ≈ 1.33 τ^½, and a full-size
cross-validation of the two engines.

Pezzi-like ball (R = 0.13 m, P_g = 1.3 kPa, E = 2.34 MPa, ν = 0.4, prescribed gas, 8 mm finger,
ground) with the wall thickness h chosen so that τ = P_g R² / √(E h B) = 10, 40, 100. For each τ,
the 3D curve is displacement-controlled through the indenter travels of the axisymmetric curve at
forces every 2.5 N, up to the first at which its local dimple reaches −W(0) = w0 E h / (P_g R²)
≥ ``--depth`` (past the onset of hoop compression at 2.52; the docs use 5 for τ = 40 and 100, 7
for τ = 10, whose wrinkles appear later). At every level:

* the 3D engine's dominant angular mode of the normal displacement and its amplitude
  (``shelljax.shell3d.wrinkle_spectrum``, rings of 5 mm out to 10 cm around the indenter), on
  ``ball(R, h, n, pole_refinement=6)`` meshes of every ``--faces`` size (the refinement study),
  on a uniform icosphere (``--mesh icosphere``: no rings or sectors, an independent mesh), or on
  ``shelljax.geometry.sphere_mesh``'s random layout (``--mesh random``: seeded random vertices refined about the indenter,
  no rings, sectors or spirals);
* the axisymmetric engine's continuous count n (docs/axisym.md, *Wrinkle count*) at the 3D force;
* 1.33 τ^½;
* the observables of both engines at the 3D force (top drop, H, D_u, D_l, d), the axisymmetric
  one relaxed (default) and unrelaxed.

``ball()`` meshes are built in six sectors around the poles, which shows up as a small mode-6
(mode 9 or 12 on finer meshes) displacement under any poke (docs/shell3d.md, *Wrinkles*): a count
is a wrinkle count only where its amplitude has grown well above that floor, and converged where
the meshes agree.

Every curve runs in a child process that checkpoints after each level (``/tmp``), under a watchdog
that restarts it when XLA's CPU runtime wedges (``shelljax.virtual``); finished curves
are kept in ``--out`` and a rerun skips them. Newton's tolerance is ``FORCE_TOLERANCE``.

    python experiments/report_wrinkles3d.py --taus 40 100 --faces 24000 48000 --out wrinkles3d.json
    python experiments/report_wrinkles3d.py --taus 10 --depth 7 --faces 24000 48000 --out wrinkles3d.json
    python experiments/report_wrinkles3d.py --taus 100 --faces 20480 --mesh icosphere --out wrinkles3d.json
    python experiments/report_wrinkles3d.py --taus 100 --depth 4.2 --faces 15500 23500 --mesh random --out wrinkles3d.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from long_runs import Checkpoint, Watchdog, run_with_restarts

from shelljax.paper import DEFAULT_POISSON_RATIO as POISSON
from shelljax.physics import ShellProperties, scaling_wrinkle_count, tau
from shelljax.virtual import FORCE_TOLERANCE, NEWTON_ITERATIONS, RADIUS, solve_curve

GAUGE_PRESSURE = 1300.0  # [Pa]
YOUNG_MODULUS = 2.34e6  # [Pa]
REFERENCE_THICKNESS = 0.9e-3  # [m]: τ = 37 (the Pezzi-like ball)
FORCE_STEP = 2.5  # [N]
POLE_REFINEMENT = 6.0


def thickness_for(target_tau: float) -> float:
    """h [m] giving τ = ``target_tau`` at the Pezzi-like P_g, E, R (τ ∝ h⁻²)."""
    reference_tau = tau(GAUGE_PRESSURE, RADIUS, YOUNG_MODULUS, REFERENCE_THICKNESS, POISSON)
    return REFERENCE_THICKNESS * float(np.sqrt(reference_tau / target_tau))


def dimensionless_depth(w0, thickness):
    """−W(0) = w0 E h / (P_g R²) [-] for dimple depths w0 [m]."""
    return np.asarray(w0) * YOUNG_MODULUS * thickness / (GAUGE_PRESSURE * RADIUS**2)


# compared observable → (its name in shelljax.shell3d.observables, its axisymmetric CurveResult field)
COMPARED = {
    "top_drop": ("w0", "top_drop"),
    "H": ("H", "height"),
    "D_u": ("D_u", "upper_diameter"),
    "D_l": ("D_l", "contact_diameter"),
    "D_l_mesh": ("D_l_mesh", "contact_diameter_mesh"),
    "d": ("d", "sunken_depth"),
}


def axisym_curve(thickness: float, forces, relax: bool = True, raise_on_failure: bool = True) -> dict:
    """Axisymmetric curve at ``forces`` [N] (default Setup, 101 elements): the local dimple depth
    "w0" [m], wrinkle count "n" [-], indenter "travel" [m], the COMPARED observables [m] and
    "converged" [bool] per force."""
    from shelljax.axisym import indentation_curves

    shell = ShellProperties(
        gauge_pressure=GAUGE_PRESSURE,
        young_modulus=YOUNG_MODULUS,
        thickness=thickness,
        poisson_ratio=POISSON,
        radius=RADIUS,
    )
    res = indentation_curves(shell, np.asarray(forces), relax=relax, raise_on_failure=raise_on_failure)
    out = {
        "w0": np.asarray(res.w0)[0],
        "n": np.asarray(res.wrinkle_count)[0],
        "travel": np.asarray(res.travel)[0],
        "converged": np.asarray(res.converged)[0],
    }
    out.update({k: np.asarray(getattr(res, field))[0] for k, (_, field) in COMPARED.items()})
    return out


def travels_for(thickness: float, depth: float) -> tuple[float, ...]:
    """Indenter travels [m] of the axisymmetric curve at forces every FORCE_STEP, up to the first
    force whose −W(0) ≥ ``depth``. The 3D curves are displacement-controlled: under force control
    the 3D Newton loses the indenter past ≈ 15 N on thin walls (docs/estimators.md)."""
    grid = FORCE_STEP * np.arange(1, 25)
    # thin walls meet the ground well inside the grid (no ball state past it): only the levels up
    # to the requested depth are used, and they must have converged
    curve = axisym_curve(thickness, grid, raise_on_failure=False)
    reached = np.nonzero(curve["converged"] & (dimensionless_depth(curve["w0"], thickness) >= depth))[0]
    if reached.size == 0 or not curve["converged"][: reached[0] + 1].all():
        raise SystemExit(
            f"h = {thickness * 1e3:.3f} mm: −W(0) = {depth} not reached by a converged level "
            f"of the {grid[0]}..{grid[-1]} N grid"
        )
    return tuple(float(t) for t in curve["travel"][: reached[0] + 1])


def run_child(args):
    """Solve one (τ, faces) 3D curve and append it to ``args.out``."""
    import jax

    jax.config.update("jax_cpu_enable_async_dispatch", False)  # XLA:CPU wedged long runs (docs/shell3d.md)
    watchdog = Watchdog(args.watchdog).start()
    target_tau, faces = args.taus[0], args.faces[0]
    h = thickness_for(target_tau)
    travels = travels_for(h, args.depth)
    ckpt = Checkpoint(
        Path(
            f"/tmp/shelljax_wrinkles3d_tau{target_tau:g}_{faces}{'' if args.mesh == 'ball' else '_' + args.mesh}_depth.npz"
        ),
        watchdog,
    )
    curve = solve_curve(
        (GAUGE_PRESSURE, YOUNG_MODULUS, h),
        faces,
        POLE_REFINEMENT,
        ckpt,
        travels=travels,
        force_tolerance=FORCE_TOLERANCE,
        mesh=args.mesh,
        max_newton_iterations=NEWTON_ITERATIONS,
    )
    curve["target_tau"], curve["requested_faces"], curve["target_depth"] = target_tau, faces, args.depth
    data = json.loads(args.out.read_text()) if args.out.exists() else {"runs": []}
    data["runs"].append(curve)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(data, indent=1))


def report(out: Path) -> dict:
    """Print the wrinkle-count and cross-validation tables of every finished run in ``out``."""
    data = json.loads(out.read_text())
    # a deeper run of the same τ and mesh contains the shallower one's levels: keep the deepest
    deepest = {}
    for r in data["runs"]:
        r.setdefault("mesh", "ball")
        key = (r["target_tau"], r["requested_faces"], r["mesh"])
        if key not in deepest or r["target_depth"] > deepest[key]["target_depth"]:
            deepest[key] = r
    runs = sorted(deepest.values(), key=lambda r: (r["target_tau"], r["mesh"], r["n_faces"]))
    # both axisymmetric hoop models at each run's 3D forces, solved once for both tables
    axisym = [
        {
            "relaxed": axisym_curve(r["thickness"], r["force"]),
            "unrelaxed": axisym_curve(r["thickness"], r["force"], relax=False),
        }
        for r in runs
    ]
    rows, cross = [], []
    print(
        "\nDominant mode (m ≥ 2) and the dominant one of m ≥ 3 with its growth since the first level "
        "(wrinkles grow; a mesh's pattern and the m = 2 ovalisation of a faceted mesh are there from the start):"
    )
    print(
        "| τ | h [mm] | faces | F [N] | −W(0) (3D) | 3D mode (amplitude [mm]) | m ≥ 3 (amplitude [mm], growth) "
        "| axisym n | 1.33 τ^½ |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for run, models in zip(runs, axisym):
        relaxed = models["relaxed"]
        scaling = float(
            scaling_wrinkle_count(
                run["gauge_pressure"], run["radius"], run["young_modulus"], run["thickness"], run["poisson_ratio"]
            )
        )
        modes = np.asarray(run.get("modes", []))
        per_mode = np.asarray(run.get("mode_amplitude", []))  # (levels, modes) [m]
        for i, force in enumerate(run["force"]):
            row = {
                "tau": run["tau"],
                "thickness": run["thickness"],
                "n_faces": run["n_faces"],
                "mesh": run["mesh"],
                "force": force,
                "W0_3d": float(dimensionless_depth(run["w0"][i], run["thickness"])),
                "mode_3d": run["wrinkle_mode"][i],
                "amplitude_3d": run["wrinkle_amplitude"][i],
                "n_axisym": float(relaxed["n"][i]),
                "n_scaling": float(scaling),
            }
            above2 = "n/a"
            if per_mode.size:
                k = int(np.argmax(np.where(modes >= 3, per_mode[i], -np.inf)))
                row.update(
                    mode_3d_m3=int(modes[k]),
                    amplitude_rss_3d_m3=float(per_mode[i, k]),
                    growth_3d_m3=float(per_mode[i, k] / per_mode[0, k]),
                )
                above2 = f"{row['mode_3d_m3']} ({1e3 * row['amplitude_rss_3d_m3']:.2f}, ×{row['growth_3d_m3']:.1f})"
            rows.append(row)
            print(
                f"| {row['tau']:.0f} | {1e3 * row['thickness']:.3f} | {row['n_faces']} {row['mesh']} | {force:.1f} | "
                f"{row['W0_3d']:.2f} | {row['mode_3d']} ({1e3 * row['amplitude_3d']:.2f}) | {above2} | "
                f"{row['n_axisym']:.2f} | {scaling:.2f} |"
            )
    print("\nCross-validation, 3D engine vs axisymmetric (relaxed / unrelaxed), relative difference axisym/3D − 1:")
    print(
        "| τ | faces | F [N] | "
        + " | ".join(f"{k} 3D [mm]" for k in COMPARED)
        + " | "
        + " | ".join(f"{k} relaxed / unrelaxed" for k in COMPARED)
        + " |"
    )
    print("|---|---:|---:|" + "---:|" * (2 * len(COMPARED)))
    for run, models in zip(runs, axisym):
        if "observables" not in run or any(name not in run["observables"][0] for name, _ in COMPARED.values()):
            continue
        for i, force in enumerate(run["force"]):
            three_d = {k: run["observables"][i][name] for k, (name, _) in COMPARED.items()}
            diff = {m: {k: float(c[k][i] / three_d[k] - 1.0) for k in COMPARED} for m, c in models.items()}
            cross.append(
                {
                    "tau": run["tau"],
                    "n_faces": run["n_faces"],
                    "mesh": run["mesh"],
                    "force": force,
                    "shell3d": three_d,
                    "axisym": {m: {k: float(c[k][i]) for k in COMPARED} for m, c in models.items()},
                    "rel_diff": diff,
                }
            )
            print(
                f"| {run['tau']:.0f} | {run['n_faces']} {run['mesh']} | {force:.1f} | "
                + " | ".join(f"{1e3 * three_d[k]:.1f}" for k in COMPARED)
                + " | "
                + " | ".join(f"{100 * diff['relaxed'][k]:+.1f} / {100 * diff['unrelaxed'][k]:+.1f} %" for k in COMPARED)
                + " |"
            )
    data["rows"], data["cross_validation"] = rows, cross
    out.write_text(json.dumps(data, indent=1))
    return data


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--taus", type=float, nargs="+", default=[10.0, 40.0, 100.0])
    ap.add_argument("--faces", type=int, nargs="+", default=[24000, 48000])
    ap.add_argument("--depth", type=float, default=5.0, help="deepest −W(0) to reach (axisymmetric estimate)")
    ap.add_argument(
        "--mesh",
        default="ball",
        choices=["ball", "icosphere", "random"],
        help="ball: ring mesh refined at the poles; icosphere: uniform, no sectors (an independent check); "
        "random: seeded random vertices, no rings, sectors or spirals, refined about the indenter",
    )
    ap.add_argument("--out", type=Path, default=Path("wrinkles3d.json"))
    ap.add_argument("--restarts", type=int, default=5)
    ap.add_argument("--watchdog", type=float, default=1800.0, help="seconds without a solved level before a restart")
    ap.add_argument("--child", action="store_true", help="(internal) solve one (τ, faces) curve in this process")
    args = ap.parse_args(argv)
    if min(args.taus) <= 0 or min(args.faces) < 20 or args.depth <= 0:
        ap.error(f"--taus and --depth must be > 0 and --faces ≥ 20; got {args.taus}, {args.depth}, {args.faces}")
    import shelljax  # noqa: F401  (float64)

    if args.child:
        run_child(args)
        return
    for target_tau in args.taus:
        for faces in args.faces:
            done = json.loads(args.out.read_text())["runs"] if args.out.exists() else []
            if any(
                (r["target_tau"], r["requested_faces"], r["target_depth"], r.get("mesh", "ball"))
                == (target_tau, faces, args.depth, args.mesh)
                for r in done
            ):
                continue
            t0 = time.perf_counter()
            cmd = [
                sys.executable,
                __file__,
                "--child",
                "--taus",
                str(target_tau),
                "--faces",
                str(faces),
                "--depth",
                str(args.depth),
                "--out",
                str(args.out),
                "--watchdog",
                str(args.watchdog),
                "--mesh",
                args.mesh,
            ]
            ok = run_with_restarts(cmd, args.restarts, f"τ = {target_tau:g}, {faces} faces")
            print(
                f"τ = {target_tau:g}, {faces} faces: {'done' if ok else 'FAILED'} ({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
    if args.out.exists():
        report(args.out)


if __name__ == "__main__":
    main()
