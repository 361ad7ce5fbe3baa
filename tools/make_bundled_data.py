"""Regenerate the bundled virtual measurement sessions in shelljax/data/sessions/.

These are NOT real measurements. They are virtual experiments of the axisymmetric Neo-Hookean
shell engine (``shelljax.axisym``) at a finer mesh (201 meridian elements) than the estimators'
forward model uses (101), with the sealed (isothermal) gas of each object's volume (the mesh's, for
mesh sessions), and with realistic measurement noise (documented in shelljax/data/README.md):

    forces per trial: level + N(0, 0.05 N), 0.01 N resolution, levels 5–20 N in 2.5 N steps
    depth = w0_engine(F) · (1 + ε) + δ_trial,  ε ~ N(0, 2 %),  δ_trial ~ N(0, 0.5 mm)
    depth rounded to 0.5 mm (ruler resolution)
    wrinkles per trial n = round(1.33 τ^½ + N(0, 0.5)),  τ = P_g R² / √(E h B)

w0_engine is the local dimple depth (the paper's −w(0)) of the engine's force-controlled curve
through the trial's own forces. The notes give the truth and the engine's noise-free
k_s = s / (π R P_g), s the slope of the closed form's regression F = s w(0) + c. The engine's
mechanical wrinkle count is zero for the yoga and beach balls at 5–20 N (before the wrinkling
onset, docs/axisym.md), so the counts come from Vella et al.'s law, which the estimators then
use too (``wrinkle_law = "scaling"``).
Run:  python tools/make_bundled_data.py
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import tomli_w

from shelljax.config import bundled_data_dir
from shelljax.geometry import HAMMER_HEAD_RADIUS, HAMMER_POKE_POINT, enclosed_volume, load_mesh
from shelljax.paper import DEFAULT_POISSON_RATIO, PAPER_FORCES
from shelljax.physics import ShellProperties, scaling_wrinkle_count, tau
from shelljax.physics import IsothermalGas

SESSIONS = bundled_data_dir() / "sessions"
FORCE_LEVELS = np.asarray(PAPER_FORCES)  # [N]
N_TRIALS = 3
N_ELEMENTS = 201  # the estimators' forward model uses the engine's default of 101
POISSON = DEFAULT_POISSON_RATIO

# name: radius [m] (None: from mesh), thickness [m], E [Pa], mass [kg]
OBJECTS = {
    "pezzi-ball": dict(radius=0.13, thickness=0.9e-3, young_modulus=2.34e6, mass=0.80),
    "yoga-ball": dict(radius=0.325, thickness=2.0e-3, young_modulus=1.34e6, mass=1.10),
    "beach-ball": dict(
        radius=0.25,
        thickness=0.25e-3,
        young_modulus=4.10e6,
        mass=0.12,
        mesh="../meshes/beach_ball.ply",
        poke_point=[0.0, 0.0, 0.25],
    ),
    "inflatable-hammer": dict(
        radius=None, thickness=0.3e-3, young_modulus=53.98e6, mass=0.09, mesh="../meshes/hammer.stl", poke_point=None
    ),
}


def _mesh_volume_ratio(mesh_file: str, radius: float) -> float:
    """Enclosed volume of the bundled mesh over 4/3 π R³ [-]: the sealed gas of a non-ball."""
    return enclosed_volume(load_mesh(SESSIONS / mesh_file)) / (4.0 / 3.0 * math.pi * radius**3)


def engine_depths(gauge_pressure, obj, radius, forces, gas_volume_ratio):
    """Noise-free local dimple depths w0 [m] of the engine at increasing ``forces`` [N]."""
    from shelljax.axisym import CurvePhysics, indentation_curves

    shell = ShellProperties(
        gauge_pressure=gauge_pressure,
        young_modulus=obj["young_modulus"],
        thickness=obj["thickness"],
        poisson_ratio=POISSON,
        radius=radius,
    )
    curve = indentation_curves(
        shell,
        np.asarray(forces),
        n_elements=N_ELEMENTS,
        gas=IsothermalGas(),
        physics=CurvePhysics(gas_volume_ratio=gas_volume_ratio),
        workers=1,
    )
    return np.asarray(curve.w0[0])


def make_session(rng, name, slug, gauge_pressure, *, manometer: bool, role: str, inline: bool = False):
    """Write one virtual session (TOML, and CSV unless ``inline``) at ``gauge_pressure`` [Pa]; return its slug."""
    obj = dict(OBJECTS[name])
    radius = obj["radius"]
    geometry: dict = {}
    volume_ratio = 1.0
    if "mesh" in obj:
        poke = obj["poke_point"]
        if name == "inflatable-hammer":
            poke, radius = HAMMER_POKE_POINT, HAMMER_HEAD_RADIUS
        volume_ratio = _mesh_volume_ratio(obj["mesh"], radius)
        geometry = {"mesh": obj["mesh"], "poke_point": [float(v) for v in poke], "length_unit": "m"}
    else:
        geometry = {"radius": radius, "radius_std": 0.02 * radius, "length_unit": "m"}
    tau_value = float(tau(gauge_pressure, radius, obj["young_modulus"], obj["thickness"], POISSON))
    count_mean = float(scaling_wrinkle_count(gauge_pressure, radius, obj["young_modulus"], obj["thickness"], POISSON))
    rows, counts, slopes = [], [], []
    for trial in range(1, N_TRIALS + 1):
        offset = rng.normal(0.0, 0.5e-3)
        forces = np.round(FORCE_LEVELS + rng.normal(0.0, 0.05, FORCE_LEVELS.size), 2)
        depths = engine_depths(gauge_pressure, obj, radius, forces, volume_ratio)
        slopes.append(np.polyfit(depths, forces, 1)[0])  # the closed form's regression F = s w + c [N/m]
        for force, depth in zip(forces, depths * (1 + rng.normal(0, 0.02, forces.size)) + offset):
            rows.append((trial, float(force), round(depth * 2e3) / 2))  # mm, 0.5 mm resolution
        counts.append(int(round(count_mean + rng.normal(0.0, 0.5))))
    k_s = float(np.mean(slopes)) / (math.pi * radius * gauge_pressure)
    doc: dict = {
        "schema_version": 1,
        "object": name,
        "notes": (
            f"VIRTUAL session ({role}) generated by tools/make_bundled_data.py with the "
            f"axisymmetric shell engine ({N_ELEMENTS} elements, sealed isothermal gas, gas volume "
            f"{volume_ratio:.3f} x 4/3 pi R^3): true P_g = {gauge_pressure:.1f} Pa, "
            f"E = {obj['young_modulus']:.4g} Pa, h = {obj['thickness']:.4g} m, R = {radius:.4g} m; "
            f"tau = {tau_value:.1f}, noise-free k_s = {k_s:.3f}"
        ),
        "poisson_ratio": POISSON,
        "mass": obj["mass"],
    }
    if manometer:
        doc["manometer_gauge_pressure"] = round(gauge_pressure / 1e3, 3)
        doc["pressure_unit"] = "kPa"
    doc["geometry"] = geometry
    doc["wall"] = {
        "thickness": obj["thickness"] * 1e3,
        "thickness_std": 0.05 * obj["thickness"] * 1e3,
        "thickness_unit": "mm",
    }
    if inline:
        doc["indentation"] = {
            "force_unit": "N",
            "depth_unit": "mm",
            "trial": [r[0] for r in rows],
            "force": [r[1] for r in rows],
            "depth": [r[2] for r in rows],
        }
    else:
        csv_name = f"{slug}.csv"
        (SESSIONS / csv_name).write_text("trial,force,depth\n" + "".join(f"{t},{f:.2f},{d:.1f}\n" for t, f, d in rows))
        doc["indentation"] = {"force_unit": "N", "depth_unit": "mm", "trials_csv": csv_name}
    doc["wrinkles"] = {"counts": counts}
    (SESSIONS / f"{slug}.toml").write_text(tomli_w.dumps(doc))
    return slug


def main():
    SESSIONS.mkdir(parents=True, exist_ok=True)
    for old in SESSIONS.glob("*"):
        old.unlink()
    rng = np.random.default_rng(20261122)
    for p in (900, 1050, 1200, 1350, 1500, 1650):
        make_session(rng, "pezzi-ball", f"calib_pezzi_{p:04d}Pa", p, manometer=True, role="calibration")
    for p in (800, 1000, 1200, 1400):
        make_session(rng, "yoga-ball", f"calib_yoga_{p:04d}Pa", p, manometer=True, role="calibration")
    for p in (1100, 1450):
        make_session(rng, "pezzi-ball", f"heldout_pezzi_{p:04d}Pa", p, manometer=True, role="held-out test")
    for p in (900, 1300):
        make_session(rng, "yoga-ball", f"heldout_yoga_{p:04d}Pa", p, manometer=True, role="held-out test")
    make_session(rng, "pezzi-ball", "pezzi", 1300.0, manometer=False, role="test", inline=True)
    make_session(rng, "yoga-ball", "yoga", 1000.0, manometer=False, role="test")
    make_session(rng, "beach-ball", "beach", 800.0, manometer=False, role="test")
    make_session(rng, "inflatable-hammer", "hammer", 3955.0, manometer=False, role="test")
    print(f"wrote {len(list(SESSIONS.glob('*.toml')))} sessions to {SESSIONS}")


if __name__ == "__main__":
    # no options: --help says what the script writes before it overwrites anything
    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args()
    main()
