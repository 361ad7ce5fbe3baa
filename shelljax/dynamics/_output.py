"""Writing a run: ``results.json`` (units in every field name), figures, and mesh frames.

Layout of ``out_dir``: ``results.json``; ``figures/trajectory.png``, ``figures/energies.png``,
``figures/contact_force.png``; for systems with faces, ``frames/frame_XXXX.ply`` or ``.glb`` (trimesh),
``preview.gif`` (matplotlib: it follows the shell at equal scale, with the planes drawn) and, where it
touches a plane, ``figures/max_deformation.png`` (its rest and most compressed cross-sections).
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


def _plane_levels(trajectory: Trajectory) -> np.ndarray:
    """Each plane's offset along its normal [m]: the record keeps the smallest gap, so it is
    min(x·n) − min gap (at step 0; the planes do not move)."""
    nodes = trajectory["position_m"][0].reshape(-1, 3)
    return np.array([(nodes @ n).min() - trajectory["min_gap_m"][0, p] for p, n in enumerate(trajectory.plane_normals)])


def _tangents(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane of ``normal``."""
    helper = np.eye(3)[np.argmin(np.abs(normal))]
    first = np.cross(normal, helper)
    first /= np.linalg.norm(first)
    return first, np.cross(normal, first)


def most_deformed_step(trajectory: Trajectory) -> tuple[int, int]:
    """(step, plane) at which the shell is most compressed against a plane: its smallest extent [m]
    along that plane's normal, over the steps where it touches the plane."""
    positions = trajectory["position_m"].reshape(len(trajectory["time_s"]), -1, 3)
    best, best_extent = (0, 0), np.inf
    for p, n in enumerate(trajectory.plane_normals):
        heights = positions @ n
        extent = np.where(trajectory["min_gap_m"][:, p] <= trajectory.contact_distances_m[p],
                          heights.max(axis=1) - heights.min(axis=1), np.inf)  # fmt: skip
        if extent.min() < best_extent:
            best, best_extent = (int(np.argmin(extent)), p), float(extent.min())
    return best


def _max_deformation_figure(trajectory: Trajectory, path: Path) -> Path:
    """The rest shape and the most compressed one, a cross-section through the centre, side by
    side at equal scale with the plane they press on."""
    import matplotlib.pyplot as plt

    step, p = most_deformed_step(trajectory)
    normal, level = trajectory.plane_normals[p], _plane_levels(trajectory)[p]
    along, across = _tangents(normal)
    fig, ax = plt.subplots(figsize=(6, 3.4))
    extents = []
    for k, colour, label in ((0, "0.6", "free, placed on the plane"), (step, "tab:orange", "most deformed")):
        nodes = trajectory["position_m"][k].reshape(-1, 3)
        centre = nodes.mean(axis=0)
        heights = nodes @ normal - (level if k else (nodes @ normal).min())
        size = np.ptp(nodes @ along)
        band = np.abs((nodes - centre) @ across) < 0.08 * size
        extents.append(np.ptp(heights))
        offset = 0.0 if k == 0 else 1.3 * size
        ax.plot((nodes - centre)[band] @ along + offset, heights[band], ".", ms=2, color=colour,
                label=f"{label}, t = {trajectory['time_s'][k]:.3f} s")  # fmt: skip
    ax.axhline(0.0, color="k", lw=1.5, label=trajectory.plane_names[p])
    ax.set(aspect="equal", xlabel="along the plane [m]", ylabel="height above the plane [m]",
           title=f"height {1e3 * extents[0]:.1f} mm free, {1e3 * extents[1]:.1f} mm most deformed")
    ax.legend(loc="upper center", fontsize=8, ncol=3, bbox_to_anchor=(0.5, -0.22))
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _mesh_frames(trajectory: Trajectory, out: Path, max_frames: int, mesh_format: str, preview_gif: bool = True) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import trimesh

    positions = trajectory["position_m"]
    picks = np.unique(np.linspace(0, len(positions) - 1, min(max_frames, len(positions))).astype(int))
    if len(trajectory.plane_names):  # the frame that shows the physics is always among them
        picks = np.unique(np.append(picks[:-1] if len(picks) >= max_frames else picks, most_deformed_step(trajectory)[0]))
    frames = out / "frames"
    frames.mkdir(exist_ok=True)
    written = []
    for j, k in enumerate(picks):
        mesh = trimesh.Trimesh(positions[k].reshape(-1, 3), trajectory.faces, process=False)
        written.append(frames / f"frame_{j:04d}.{mesh_format}")
        mesh.export(written[-1])
    if len(trajectory.plane_names):
        written.append(_max_deformation_figure(trajectory, out / "figures" / "max_deformation.png"))
    if not preview_gif:
        return written
    written.append(_preview(trajectory, picks, out / "preview.gif"))
    return written


def _preview(trajectory: Trajectory, picks: np.ndarray, path: Path) -> Path:
    """An animation that follows the shell at equal scale, with the planes it may touch."""
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation, PillowWriter

    fig = plt.figure(figsize=(4, 4))
    ax = fig.add_subplot(projection="3d")
    nodes = trajectory["position_m"][picks].reshape(len(picks), -1, 3)
    half = 0.75 * np.ptp(nodes[0], axis=0).max()
    levels = _plane_levels(trajectory) if len(trajectory.plane_names) else ()

    def draw(j):
        ax.clear()
        centre = nodes[j].mean(axis=0)
        for n, level in zip(trajectory.plane_normals, levels):
            u, v = _tangents(n)
            foot = centre - ((centre @ n) - level) * n
            corners = np.array([foot + half * (a * u + b * v) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
            ax.plot_trisurf(*corners.T, triangles=[[0, 1, 2], [0, 2, 3]], color="0.5", alpha=0.25)
        ax.plot_trisurf(*nodes[j].T, triangles=trajectory.faces, color="tab:orange", alpha=0.85)
        ax.set(xlim=(centre[0] - half, centre[0] + half), ylim=(centre[1] - half, centre[1] + half),
               zlim=(centre[2] - half, centre[2] + half), title=f"t = {trajectory['time_s'][picks[j]]:.3f} s")  # fmt: skip
        ax.set_box_aspect((1, 1, 1))
        ax.locator_params(nbins=4)
        ax.tick_params(labelsize=7)

    FuncAnimation(fig, draw, frames=len(picks)).save(path, writer=PillowWriter(fps=10))
    plt.close(fig)
    return path


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
