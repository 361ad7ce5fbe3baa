"""Writing a run: ``results.json`` (units in every field name), figures, and mesh frames.

Layout of ``out_dir``: ``results.json``; ``figures/trajectory.png``, ``figures/energies.png``,
``figures/contact_force.png``; for systems with faces, ``frames/frame_XXXX.ply`` or ``.glb`` (trimesh),
``preview.gif`` (matplotlib: it follows the shell at equal scale, with the planes drawn, faces coloured by
membrane areal strain, time, contact force and gauge pressure written on it; the frames carry the same colours
as vertex colours) and, where it touches a plane, ``figures/max_deformation.png`` (its rest and most compressed
cross-sections) and ``figures/closeup.png`` (the state of the largest contact patch, zoomed on it, seen
through the plane).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from .._errors import InvalidInputError
from .._files import atomic_write_text
from . import _render
from ._cor import Impact, measured_cor
from ._run import Trajectory

# Per-step fields left out of results.json: bulky (all positions) or solver internals.
_NOT_IN_JSON = ("position_m", "residual_history_N")


def results_dict(trajectory: Trajectory, impacts: tuple[Impact, ...]) -> dict:
    """The JSON-ready content of ``results.json``: per-step arrays and the impact summary."""
    steps = {k: np.asarray(v).tolist() for k, v in trajectory.records.items() if k not in _NOT_IN_JSON}
    steps = {
        k: [None if isinstance(x, float) and not np.isfinite(x) else x for x in v]
        if np.ndim(trajectory.records[k]) == 1
        else v
        for k, v in steps.items()
    }
    return {
        "units": "SI; every field name ends in its unit (_s, _m, _m_per_s, _N, _Pa, _m3, _J); contact_force_N is (step, plane, xyz)",
        "dt_s": trajectory.dt_s,
        "gravity_m_per_s2": trajectory.gravity_m_per_s2.tolist(),
        "planes": [
            {
                "name": n,
                "normal": trajectory.plane_normals[i].tolist(),
                "contact_distance_m": float(trajectory.contact_distances_m[i]),
            }
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


def plane_levels(trajectory: Trajectory) -> np.ndarray:
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
        extent = np.where(
            trajectory["min_gap_m"][:, p] <= trajectory.contact_distances_m[p],
            heights.max(axis=1) - heights.min(axis=1),
            np.inf,
        )
        if extent.min() < best_extent:
            best, best_extent = (int(np.argmin(extent)), p), float(extent.min())
    return best


def _max_deformation_figure(trajectory: Trajectory, path: Path) -> Path:
    """The rest shape and the most compressed one, a cross-section through the centre, side by
    side at equal scale with the plane they press on."""
    import matplotlib.pyplot as plt

    step, p = most_deformed_step(trajectory)
    normal, level = trajectory.plane_normals[p], plane_levels(trajectory)[p]
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
        ax.plot(
            (nodes - centre)[band] @ along + offset,
            heights[band],
            ".",
            ms=2,
            color=colour,
            label=f"{label}, t = {trajectory['time_s'][k]:.3f} s",
        )
    ax.axhline(0.0, color="k", lw=1.5, label=trajectory.plane_names[p])
    ax.set(
        aspect="equal",
        xlabel="along the plane [m]",
        ylabel="height above the plane [m]",
        title=f"height {1e3 * extents[0]:.1f} mm free, {1e3 * extents[1]:.1f} mm most deformed",
    )
    ax.legend(loc="upper center", fontsize=8, ncol=3, bbox_to_anchor=(0.5, -0.22))
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _mesh_frames(
    trajectory: Trajectory, out: Path, max_frames: int, mesh_format: str, preview_gif: bool = True
) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import trimesh

    positions = trajectory["position_m"]
    picks = np.unique(np.linspace(0, len(positions) - 1, min(max_frames, len(positions))).astype(int))
    touches = len(trajectory.plane_names) > 0
    if touches:  # the frame that shows the physics is always among them
        picks = np.unique(
            np.append(picks[:-1] if len(picks) >= max_frames else picks, most_deformed_step(trajectory)[0])
        )
    nodes = positions.reshape(len(positions), -1, 3)
    strain = _render.face_strain(nodes[picks], trajectory.faces, nodes[0])
    limit = _render.strain_limit(strain)
    levels = plane_levels(trajectory) if touches else np.zeros(0)
    frames = out / "frames"
    frames.mkdir(exist_ok=True)
    written = []
    for j, k in enumerate(picks):
        # vertex colours (the faces' strain averaged, contact dark): PLY and glTF keep them (COLOR_0)
        rgba = _render.frame_rgba(trajectory, k, strain[j], limit, levels)
        colours = _render.vertex_rgba_uint8(rgba, trajectory.faces, nodes.shape[1])
        mesh = trimesh.Trimesh(nodes[k], trajectory.faces, vertex_colors=colours, process=False)
        written.append(frames / f"frame_{j:04d}.{mesh_format}")
        mesh.export(written[-1])
    if touches:
        written.append(_max_deformation_figure(trajectory, out / "figures" / "max_deformation.png"))
        largest = _render.largest_contact_step(trajectory, levels)
        if largest is not None:
            step, plane = largest
            written.append(
                _render.closeup(
                    trajectory,
                    step,
                    plane,
                    out / "figures" / "closeup.png",
                    _render.face_strain(nodes[step], trajectory.faces, nodes[0]),
                    limit,
                    levels,
                )
            )
    if not preview_gif:
        return written
    written.append(_render.preview(trajectory, picks, out / "preview.gif", strain, limit, levels))
    return written


def write_results(
    trajectory: Trajectory,
    out_dir: str | os.PathLike,
    *,
    max_frames: int = 30,
    mesh_format: str = "ply",
    figures: bool = True,
    preview_gif: bool = True,
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
    atomic_write_text(out / "results.json", json.dumps(results_dict(trajectory, impacts), indent=1))
    written = [out / "results.json", *(_plots(trajectory, out / "figures") if figures else [])]
    if trajectory.faces is not None and max_frames > 0:
        written += _mesh_frames(trajectory, out, max_frames, mesh_format, preview_gif)
    return written
