"""Writing a run: ``results.json`` (units in every field name), figures, and mesh frames.

Layout of ``out_dir``: ``results.json``; ``figures/trajectory.png``, ``figures/energies.png``,
``figures/contact_force.png``; for systems with faces, ``frames/frame_XXXX.ply`` or ``.glb`` (trimesh) and
``preview.gif`` (matplotlib).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np

from .._errors import InvalidInputError
from ._cor import Impact, measured_cor
from ._run import Trajectory

# Per-step fields left out of results.json: bulky (all positions) or solver internals.
_NOT_IN_JSON = ("position_m", "residual_history_N")


def _atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename, so readers never see half a file."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def results_dict(trajectory: Trajectory, impacts: tuple[Impact, ...]) -> dict:
    """The JSON-ready content of ``results.json``: per-step arrays and the impact summary."""
    steps = {k: np.asarray(v).tolist() for k, v in trajectory.records.items() if k not in _NOT_IN_JSON}
    steps = {k: [None if isinstance(x, float) and not np.isfinite(x) else x for x in v] if np.ndim(trajectory.records[k]) == 1 else v for k, v in steps.items()}
    return {
        "units": "SI; every field name ends in its unit (_s, _m, _m_per_s, _N, _Pa, _m3, _J); contact_force_N is (step, plane, xyz)",
        "dt_s": trajectory.dt_s,
        "gravity_m_per_s2": trajectory.gravity_m_per_s2.tolist(),
        "planes": [
            {"name": n, "normal": trajectory.plane_normals[i].tolist(), "contact_distance_m": float(trajectory.contact_distances_m[i])}
            for i, n in enumerate(trajectory.plane_names)
        ],
        "steps": steps,
        "summary": {"impacts": [m.to_dict() for m in impacts]},
    }


def _plots(trajectory: Trajectory, figures: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = trajectory["time_s"]
    written = []
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for i, axis in enumerate("xyz"):
        ax.plot(t, trajectory["com_position_m"][:, i], label=f"centre of mass {axis}")
    ax.set(xlabel="time [s]", ylabel="position [m]", title="trajectory")
    ax.legend()
    written.append(figures / "trajectory.png")
    fig.tight_layout(), fig.savefig(written[-1], dpi=120), plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 3.5))
    for kind in ("kinetic", "elastic", "gas", "gravity", "contact", "total"):
        e = trajectory[f"{kind}_energy_J"]
        ax.plot(t, e - (e[0] if kind in ("gas", "gravity", "total") else 0.0), label=kind)
    # the note on which curves are changes goes in the title: a long y-label is taller than the axes and clips
    ax.set(xlabel="time [s]", ylabel="energy [J]")
    ax.set_title("energies (gas, gravity, total: change from t = 0)", fontsize=10)
    ax.legend(fontsize=8)
    written.append(figures / "energies.png")
    fig.tight_layout(), fig.savefig(written[-1], dpi=120), plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 3.5))
    for i, name in enumerate(trajectory.plane_names):
        ax.plot(t, trajectory["contact_force_N"][:, i] @ trajectory.plane_normals[i], label=f"{name} (normal)")
    ax.set(xlabel="time [s]", ylabel="contact force [N]", title="contact force")
    ax.legend()
    written.append(figures / "contact_force.png")
    fig.tight_layout(), fig.savefig(written[-1], dpi=120), plt.close(fig)
    return written


def _mesh_frames(trajectory: Trajectory, out: Path, max_frames: int, mesh_format: str, preview_gif: bool = True) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import trimesh
    from matplotlib.animation import FuncAnimation, PillowWriter

    positions = trajectory["position_m"]
    picks = np.unique(np.linspace(0, len(positions) - 1, min(max_frames, len(positions))).astype(int))
    frames = out / "frames"
    frames.mkdir(exist_ok=True)
    written = []
    for j, k in enumerate(picks):
        mesh = trimesh.Trimesh(positions[k].reshape(-1, 3), trajectory.faces, process=False)
        written.append(frames / f"frame_{j:04d}.{mesh_format}")
        mesh.export(written[-1])
    if not preview_gif:
        return written
    fig = plt.figure(figsize=(4, 4))
    ax = fig.add_subplot(projection="3d")
    nodes = positions[picks].reshape(len(picks), -1, 3)
    lo, hi = nodes.min(axis=(0, 1)), nodes.max(axis=(0, 1))

    def draw(j):
        ax.clear()
        ax.plot_trisurf(*nodes[j].T, triangles=trajectory.faces, color="tab:orange", alpha=0.8)
        ax.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), zlim=(min(lo[2], 0.0), hi[2]), title=f"t = {trajectory['time_s'][picks[j]]:.3f} s")

    FuncAnimation(fig, draw, frames=len(picks)).save(out / "preview.gif", writer=PillowWriter(fps=10))
    plt.close(fig)
    return written + [out / "preview.gif"]


def write_results(
    trajectory: Trajectory, out_dir: str | os.PathLike, *, max_frames: int = 30, mesh_format: str = "ply",
    figures: bool = True, preview_gif: bool = True,
) -> list[Path]:
    """Write ``results.json``, the figures and (with faces) mesh frames and a GIF to ``out_dir``; the paths written.

    ``mesh_format``: ``"ply"`` or ``"glb"`` (binary glTF), one file per frame, at most ``max_frames``
    (0: none); ``figures``: the PNG plots; ``preview_gif``: the animation of the frames.
    """
    if mesh_format not in ("ply", "glb"):
        raise InvalidInputError(f"mesh_format must be 'ply' or 'glb' (binary glTF); got {mesh_format!r}.")
    out = Path(out_dir)
    (out / "figures").mkdir(parents=True, exist_ok=True)
    impacts = measured_cor(trajectory)
    _atomic_write_text(out / "results.json", json.dumps(results_dict(trajectory, impacts), indent=1))
    written = [out / "results.json", *(_plots(trajectory, out / "figures") if figures else [])]
    if trajectory.faces is not None and max_frames > 0:
        written += _mesh_frames(trajectory, out, max_frames, mesh_format, preview_gif)
    return written
