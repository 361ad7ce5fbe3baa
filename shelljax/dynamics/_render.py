"""Pictures of a shell in motion: per-face membrane strain, the coloured preview GIF and the close-up.

The colour of a face is its membrane areal strain ΔA/A [-] against the first recorded state (the
inflated shape at t = 0): red where the wall is stretched further, blue where it is relieved (the
contact patch flattens, the gas is squeezed). One colour scale serves a whole run, so frames compare.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

STRAIN_COLOURMAP = "coolwarm"
CONTACT_RGBA = (0.1, 0.1, 0.1, 1.0)  # faces touching a plane


def contact_faces(nodes: np.ndarray, faces: np.ndarray, normals, levels, distances) -> np.ndarray:
    """Faces (F,) bool whose three nodes (n, 3) [m] are all within their plane's contact distance [m]."""
    near = np.zeros(len(nodes), dtype=bool)
    for n, level, distance in zip(normals, levels, distances):
        near |= nodes @ np.asarray(n) - level <= distance
    return near[faces].all(axis=1)


def face_areas(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Triangle areas [m²] of node positions (..., n, 3) [m]: shape (..., F)."""
    p = positions[..., faces, :]  # (..., F, 3, 3)
    return 0.5 * np.linalg.norm(np.cross(p[..., 1, :] - p[..., 0, :], p[..., 2, :] - p[..., 0, :]), axis=-1)


def face_strain(positions: np.ndarray, faces: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Membrane areal strain ΔA/A [-] of each face, positions (..., n, 3) against ``reference`` (n, 3) [m]."""
    return face_areas(positions, faces) / face_areas(reference, faces) - 1.0


def largest_contact_step(trajectory, plane_levels) -> tuple[int, int] | None:
    """(step, plane) of the largest contact patch (total area [m²] of the faces touching a plane):
    where the shell is most deformed against it (a ball's flattest moment, a hammer head's squash);
    None if no face ever touches a plane."""
    nodes = trajectory["position_m"].reshape(len(trajectory["time_s"]), -1, 3)
    best, best_area = None, 0.0
    for p, (n, level, distance) in enumerate(
        zip(trajectory.plane_normals, plane_levels, trajectory.contact_distances_m)
    ):
        for k in np.flatnonzero(
            trajectory["min_gap_m"][:, p] <= distance
        ):  # only the steps in contact: memory stays O(F)
            touching = (nodes[k] @ np.asarray(n) - level <= distance)[trajectory.faces].all(axis=1)
            area = float(face_areas(nodes[k], trajectory.faces[touching]).sum())
            if area > best_area:
                best, best_area = (int(k), p), area
    return best


def strain_limit(strain: np.ndarray) -> float:
    """A symmetric colour limit [-] for ``strain``: its 99th percentile of |ΔA/A| (at least 1e-4)."""
    return max(float(np.percentile(np.abs(strain), 99.0)), 1e-4)


def strain_rgba(strain: np.ndarray, limit: float, touching: np.ndarray | None = None) -> np.ndarray:
    """RGBA [0, 1] of each strain value on the symmetric scale ±``limit``: shape (..., 4); the
    faces ``touching`` a plane (same shape as ``strain``, bool) in ``CONTACT_RGBA``."""
    import matplotlib

    rgba = matplotlib.colormaps[STRAIN_COLOURMAP](np.clip(0.5 + 0.5 * strain / limit, 0.0, 1.0))
    if touching is not None:
        rgba[touching] = CONTACT_RGBA
    return rgba


def frame_rgba(trajectory, step: int, strain: np.ndarray, limit: float, plane_levels) -> np.ndarray:
    """Face colours (F, 4) of ``step``: its ``strain`` (F,) on ±``limit``, the faces touching a plane dark."""
    nodes = trajectory["position_m"][step].reshape(-1, 3)
    touching = contact_faces(
        nodes, trajectory.faces, trajectory.plane_normals, plane_levels, trajectory.contact_distances_m
    )
    return strain_rgba(strain, limit, touching)


def vertex_rgba_uint8(face_rgba: np.ndarray, faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """Vertex colours (n, 4) uint8: the mean of the colours of the faces around each vertex."""
    total = np.zeros((n_vertices, 4))
    count = np.zeros(n_vertices)
    for corner in range(3):
        np.add.at(total, faces[:, corner], face_rgba)
        np.add.at(count, faces[:, corner], 1.0)
    return np.round(255.0 * total / np.maximum(count, 1.0)[:, None]).astype(np.uint8)


def _shaded(nodes: np.ndarray, faces: np.ndarray, rgba: np.ndarray) -> np.ndarray:
    """``rgba`` dimmed by a light from the upper front, so the 3D shape reads."""
    p = nodes[faces]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    light = np.array([-0.4, -0.6, 0.7]) / np.linalg.norm([-0.4, -0.6, 0.7])
    out = rgba.copy()
    out[:, :3] *= (0.55 + 0.45 * np.abs(n @ light))[:, None]
    return out


def _tangents(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.eye(3)[np.argmin(np.abs(normal))]
    first = np.cross(normal, helper)
    first /= np.linalg.norm(first)
    return first, np.cross(normal, first)


def draw_shell(ax, nodes, faces, rgba, centre, half, planes=(), planes_in_front: bool = False) -> None:
    """Draw the shell (n, 3) with face colours ``rgba`` in a cube of half-width ``half`` [m] about
    ``centre``, with ``planes`` [(normal, offset)] as translucent grey squares behind it (in front
    of it with ``planes_in_front``: a view through the plane)."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    ax.computed_zorder = False  # the planes stay behind the shell (sorting by depth would put the ground over it)
    for n, level in planes:
        u, v = _tangents(np.asarray(n))
        foot = centre - ((centre @ n) - level) * n
        corners = np.array([foot + half * (a * u + b * v) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
        ax.add_collection3d(
            Poly3DCollection(
                [corners], facecolor=(0.5, 0.5, 0.5, 0.25), edgecolor="0.4", lw=0.5, zorder=3 if planes_in_front else 1
            )
        )
    ax.add_collection3d(
        Poly3DCollection(nodes[faces], facecolors=_shaded(nodes, faces, rgba), edgecolor="none", zorder=2)
    )
    ax.set(
        xlim=(centre[0] - half, centre[0] + half),
        ylim=(centre[1] - half, centre[1] + half),
        zlim=(centre[2] - half, centre[2] + half),
    )
    ax.set_box_aspect((1, 1, 1))
    ax.locator_params(nbins=4)
    ax.tick_params(labelsize=6, pad=0)
    for axis in "xyz":
        getattr(ax, f"set_{axis}label")(f"{axis} [m]", fontsize=7, labelpad=-4)


def status_line(trajectory, step: int) -> str:
    """Time, each plane's normal contact force and the gauge pressure at ``step``, for a caption."""
    forces = ", ".join(
        f"{name} {float(trajectory['contact_force_N'][step, i] @ trajectory.plane_normals[i]):.1f} N"
        for i, name in enumerate(trajectory.plane_names)
    )
    text = f"t = {trajectory['time_s'][step]:.3f} s"
    if forces:
        text += f"   contact: {forces}"
    return text + f"\ngauge pressure {trajectory['gas_pressure_Pa'][step]:.0f} Pa"


def strain_colourbar(fig, limit: float, rect=(0.85, 0.24, 0.025, 0.5)) -> None:
    import matplotlib as mpl
    from matplotlib.patches import Patch

    cax = fig.add_axes(rect)
    bar = fig.colorbar(
        mpl.cm.ScalarMappable(mpl.colors.Normalize(-100 * limit, 100 * limit), STRAIN_COLOURMAP), cax=cax
    )
    bar.set_label("membrane areal strain ΔA/A vs t = 0 [%]", fontsize=7)
    bar.ax.tick_params(labelsize=6)
    fig.legend(
        handles=[Patch(color=CONTACT_RGBA, label="in contact")],
        loc="lower right",
        fontsize=7,
        frameon=False,
        bbox_to_anchor=(0.99, 0.08),
    )


def preview(trajectory, picks: np.ndarray, path: Path, strain: np.ndarray, limit: float, plane_levels) -> Path:
    """An animation of the frames ``picks``: the shell at equal scale, faces coloured by ``strain``
    (len(picks), F), the planes drawn, time, contact force and gauge pressure written on it."""
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation, PillowWriter

    fig = plt.figure(figsize=(4.6, 4.4))
    ax = fig.add_axes((0.0, 0.0, 0.82, 0.86), projection="3d")
    strain_colourbar(fig, limit)
    caption = fig.text(0.03, 0.975, "", va="top", fontsize=8, family="monospace")
    nodes = trajectory["position_m"][picks].reshape(len(picks), -1, 3)
    half = 0.75 * np.ptp(nodes[0], axis=0).max()
    planes = list(zip(trajectory.plane_normals, plane_levels))

    def draw(j):
        ax.clear()
        rgba = frame_rgba(trajectory, picks[j], strain[j], limit, plane_levels)
        draw_shell(ax, nodes[j], trajectory.faces, rgba, nodes[j].mean(axis=0), half, planes)
        caption.set_text(status_line(trajectory, picks[j]))

    FuncAnimation(fig, draw, frames=len(picks)).save(path, writer=PillowWriter(fps=10))
    plt.close(fig)
    return path


def closeup(trajectory, step: int, plane: int, path: Path, strain: np.ndarray, limit: float, plane_levels) -> Path:
    """State ``step`` seen through plane ``plane`` (drawn translucent), zoomed on its contact patch,
    faces coloured by ``strain`` (F,), with the state written on it."""
    import matplotlib.pyplot as plt

    nodes = trajectory["position_m"][step].reshape(-1, 3)
    normal = np.asarray(trajectory.plane_normals[plane])
    size = np.ptp(nodes, axis=0).max()
    gaps = nodes @ normal - plane_levels[plane]
    patch = nodes[gaps <= trajectory.contact_distances_m[plane]]
    patch = patch if len(patch) else nodes[gaps <= gaps.min() + 0.05 * size]
    u, v = _tangents(normal)
    diameter = max(np.ptp(patch @ u), np.ptp(patch @ v))
    half = max(0.6 * diameter, 0.3 * size)
    centre = patch.mean(axis=0) + 0.7 * half * normal
    fig = plt.figure(figsize=(5, 4.4))
    ax = fig.add_axes((0.0, 0.0, 0.84, 0.86), projection="3d")
    draw_shell(
        ax,
        nodes,
        trajectory.faces,
        frame_rgba(trajectory, step, strain, limit, plane_levels),
        centre,
        half,
        [(normal, plane_levels[plane])],
        planes_in_front=True,
    )
    # the camera behind the plane, looking at the patch through it, a little from the side
    if abs(normal[2]) > 0.9:
        ax.view_init(elev=-25.0 * np.sign(normal[2]), azim=-60.0)
    else:
        ax.view_init(elev=15.0, azim=float(np.degrees(np.arctan2(-normal[1], -normal[0]))) + 35.0)
    strain_colourbar(fig, limit)
    fig.text(0.03, 0.975, "largest contact: " + status_line(trajectory, step), va="top", fontsize=8, family="monospace")
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
