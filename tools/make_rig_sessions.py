"""Regenerate the bundled rig sessions in shelljax/data/sessions/rig/ (virtual, not measurements).

One imperfect measuring chain — a Hertzian finger pad compressing 4 mm at 20 N, a 15 mm finger
instead of the assumed 8 mm, and a force sensor reading 8 % low (true force = 1.08 × recorded) —
measures a calibration ball at four pressures with a manometer, and two other objects at two
pressures each without one. The calibration ball's radius is measured with a tape (±0.3 %), the
others' from their meshes (±2 %): docs/rig.md says why. Reality, protocol and noise are experiments/rig_transfer_study.py's
(the axisymmetric engine at 201 elements, sealed isothermal gas); each session's notes give its
truth. They feed `shelljax rig calibrate`, the README's example and notebooks/rig_calibration.ipynb.

Run:  python tools/make_rig_sessions.py
"""

from __future__ import annotations

import argparse
import numpy as np
from experiment_scripts import load_experiment

from shelljax.config import bundled_data_dir
from shelljax.session import load_session, write_session

write_object = load_experiment("rig_transfer_study").write_object

RIG = {
    "pad": {"kind": "hertz", "compression_at_20N": 4e-3, "f0": 8.0},
    "finger": {"radius": 15e-3},
    "sensor": {"kind": "gain", "gain": 1.08, "exponent": 1.0, "beta": 0.0},
}
OBJECTS = {  # name: radius [m], its stated relative std [-], thickness [m], E [Pa], pressures [Pa], manometer
    "calib_ball": (0.15, 0.003, 1.0e-3, 2.0e6, (1000.0, 1300.0, 1650.0, 2000.0), True),  # R by a tape round it
    "toy": (0.09, 0.02, 0.8e-3, 3.0e6, (2200.0, 3500.0), False),  # R from a photogrammetry mesh
    "big_ball": (0.28, 0.02, 1.5e-3, 1.5e6, (800.0, 1300.0), False),
}


def main():
    out = bundled_data_dir() / "sessions" / "rig"
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(2046)
    for name, (radius, radius_std, thickness, young, pressures, manometer) in OBJECTS.items():
        obj = dict(radius=radius, radius_std=radius_std, thickness=thickness, young_modulus=young)
        for path, pressure in zip(write_object(rng, obj, RIG, pressures, out, name, manometer), pressures):
            s = load_session(path)
            truth = (
                f"virtual session (tools/make_rig_sessions.py): truth P_g = {pressure:.1f} Pa, E = {young:.4g} Pa; "
                "rig: Hertzian pad 4 mm at 20 N, 15 mm finger, force sensor reading 8 % low"
            )
            target = out / f"{name}_{pressure:04.0f}Pa.toml"
            write_session(
                target,
                object_name=s.object_name,
                radius=s.radius,
                radius_std=s.radius_std,
                thickness=s.thickness,
                thickness_std=s.thickness_std,
                trial=s.trial,
                force=s.force,
                depth=s.depth,
                wrinkle_counts=s.wrinkle_counts,
                manometer_gauge_pressure=s.manometer_gauge_pressure,
                poisson_ratio=s.poisson_ratio,
                notes=truth,
            )
            path.unlink()
            print(f"written: {target}")
    return 0


if __name__ == "__main__":
    # no options: --help says what the script writes before it overwrites anything
    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args()
    raise SystemExit(main())
