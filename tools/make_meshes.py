"""Regenerate the bundled meshes in shelljax/data/meshes (deterministic).

    python tools/make_meshes.py

- hammer.stl: inflatable hammer toy (shelljax.geometry.make_hammer_mesh, defaults), binary STL, m.
- beach_ball.ply: icosphere R = 0.25 m (4 subdivisions) with photogrammetry-like radial noise,
  Gaussian σ = 1e-4 m, seed 20260322, binary PLY, m.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import trimesh

from shelljax.geometry import make_ball_mesh, make_hammer_mesh

OUT = Path(__file__).resolve().parents[1] / "shelljax" / "data" / "meshes"
BEACH_BALL_RADIUS = 0.25  # [m]
NOISE_STD = 1e-4  # [m], radial
SEED = 20260322


def beach_ball() -> trimesh.Trimesh:
    ball = make_ball_mesh(BEACH_BALL_RADIUS, subdivisions=4)
    rng = np.random.default_rng(SEED)
    v = np.asarray(ball.vertices, dtype=np.float64)
    r = np.linalg.norm(v, axis=1, keepdims=True)
    v = v * (1.0 + rng.normal(0.0, NOISE_STD, size=r.shape) / r)
    return trimesh.Trimesh(vertices=v, faces=ball.faces, process=False)


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for name, mesh in [("hammer.stl", make_hammer_mesh()), ("beach_ball.ply", beach_ball())]:
        path = OUT / name
        mesh.export(path)
        print(
            f"{path}: {len(mesh.vertices)} vertices, {len(mesh.faces)} faces, "
            f"{path.stat().st_size / 1e3:.0f} kB, watertight={mesh.is_watertight}, "
            f"volume={mesh.volume:.6g} m^3"
        )


if __name__ == "__main__":
    # no options: --help says what the script writes before it overwrites anything
    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args()
    main()
