"""A scenario's own pictures, across its runs (written in its output directory).

* ``max_deformation.png``: every run's most deformed cross-section, overlaid at equal scale on the
  plane it presses, with a close view of the contact: the flattening grows with the drop height.
* ``trajectory.png``: the centre of mass's path between the planes, with the shell's outline at
  the moments it is most deformed against each plane (or, for straight drops, its height in time).
* ``keyframes.png`` (a held, swung object): the object at a few moments of the swing, coloured by
  how far it departs from the rigid swing, with the planes.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ..dynamics.internal import plane_levels


@dataclasses.dataclass
class RunDigest:
    """What the scenario figures need of one run: its label, a few frames' node positions (n, 3) [m]
    by step, the centre of mass (T, 3) [m] and times (T,) [s], the planes (normals, offsets [m])."""

    label: str
    time_s: np.ndarray
    com_m: np.ndarray
    faces: np.ndarray
    frames: dict[int, np.ndarray]
    plane_names: tuple[str, ...]
    plane_normals: np.ndarray
    plane_levels: np.ndarray
    most_deformed: dict[int, int]  # plane -> step at which the shell is flattest against it
    gravity: np.ndarray


def digest(trajectory, label: str) -> RunDigest:
    """The small part of ``trajectory`` the scenario figures draw."""
    positions = trajectory["position_m"].reshape(len(trajectory["time_s"]), -1, 3)
    most = {}
    for p, n in enumerate(trajectory.plane_normals):
        touching = trajectory["min_gap_m"][:, p] <= trajectory.contact_distances_m[p]
        if touching.any():
            heights = positions @ n
            most[p] = int(np.argmin(np.where(touching, np.ptp(heights, axis=1), np.inf)))
    steps = {0, *most.values()}
    levels = plane_levels(trajectory) if len(trajectory.plane_names) else np.zeros(0)
    return RunDigest(
        label,
        np.asarray(trajectory["time_s"]),
        np.asarray(trajectory["com_position_m"]),
        np.asarray(trajectory.faces),
        {k: positions[k] for k in steps},
        tuple(trajectory.plane_names),
        np.asarray(trajectory.plane_normals),
        np.asarray(levels),
        most,
        np.asarray(trajectory.gravity_m_per_s2),
    )


def _section(nodes: np.ndarray, faces: np.ndarray, origin: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Segments (S, 2, 3) [m] where the plane through ``origin`` with ``normal`` cuts the mesh."""
    import trimesh

    return trimesh.intersections.mesh_plane(trimesh.Trimesh(nodes, faces, process=False), normal, origin)


def _tangents(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.eye(3)[np.argmin(np.abs(normal))]
    first = np.cross(normal, helper)
    first /= np.linalg.norm(first)
    return first, np.cross(normal, first)


def max_deformation_figure(runs: list[RunDigest], path: Path) -> Path | None:
    """Every run's most deformed cross-section on its first touched plane, overlaid at equal scale
    with the free shape. None when no run touches a plane."""
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    runs = [r for r in runs if r.most_deformed]
    if not runs:
        return None
    fig, ax = plt.subplots(figsize=(6, 4.4))
    colours = plt.get_cmap("viridis")(np.linspace(0.0, 0.85, len(runs)))
    size = 0.0
    for j, (run, colour) in enumerate(zip(runs, colours)):
        p = min(run.most_deformed)  # the first plane it flattens on (the ground of a drop)
        normal, level = run.plane_normals[p], run.plane_levels[p]
        along, across = _tangents(normal)
        for step, style in (
            (0, {"color": "0.55", "lw": 1.0, "ls": "--"}),
            (run.most_deformed[p], {"color": colour, "lw": 1.6}),
        ):
            if step == 0 and j:
                continue  # the free shape is the same for every run: draw it once
            nodes = run.frames[step]
            centre = nodes.mean(axis=0)
            rest_lift = (nodes @ normal).min() if step == 0 else level  # the free shape stands on the plane
            seg = _section(nodes, run.faces, centre, across)
            xy = np.stack([(seg - centre) @ along, seg @ normal - rest_lift], axis=-1)
            height = float(np.ptp(nodes @ normal))
            size = max(size, height)
            label = (
                f"free, {1e3 * height:.0f} mm tall"
                if step == 0
                else f"{run.label}: {1e3 * height:.0f} mm at t = {run.time_s[step]:.3f} s"
            )
            ax.add_collection(LineCollection(xy, label=label, **style))
    ax.axhline(0.0, color="k", lw=1.5)
    ax.set_aspect("equal")
    ax.tick_params(labelsize=8)
    ax.set(xlim=(-0.75 * size, 0.75 * size), ylim=(-0.04 * size, 1.06 * size))
    ax.set_xlabel("along the plane, through the centre [m]", fontsize=9)
    ax.set_ylabel(f"height above the {runs[0].plane_names[min(runs[0].most_deformed)]} [m]", fontsize=9)
    ax.set_title("most deformed cross-section of each run", fontsize=10)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2, fontsize=8, frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _view_axes(runs: list[RunDigest]) -> tuple[np.ndarray, np.ndarray | None]:
    """(up, horizontal): up against gravity; horizontal along the runs' largest horizontal travel of
    the centre of mass, None when it stays within a fifth of the shell's size (straight drops)."""
    up = -runs[0].gravity / np.linalg.norm(runs[0].gravity)
    flat = np.concatenate([r.com_m - np.outer(r.com_m @ up, up) for r in runs])
    size = max(np.ptp(r.frames[0], axis=0).max() for r in runs)
    travel = flat - flat.mean(axis=0)
    if np.ptp(np.linalg.norm(travel, axis=1)) < 0.2 * size:
        return up, None
    return up, np.linalg.svd(travel, full_matrices=False)[2][0]


def trajectory_figure(runs: list[RunDigest], path: Path) -> Path:
    """The centre of mass's path in the vertical plane of its travel with the planes seen edge-on and
    the shell's outline where it is most deformed against each (straight drops: height against time)."""
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    up, horizontal = _view_axes(runs)
    fig, ax = plt.subplots(figsize=(6, 4.2))
    colours = plt.get_cmap("viridis")(np.linspace(0.0, 0.85, len(runs)))
    if horizontal is None:
        for run, colour in zip(runs, colours):
            ax.plot(run.time_s, run.com_m @ up, color=colour, label=run.label)
        for p, name in enumerate(runs[0].plane_names):
            if abs(runs[0].plane_normals[p] @ up) > 0.9:
                ax.axhline(runs[0].plane_levels[p] * np.sign(runs[0].plane_normals[p] @ up), color="k", lw=1.5)
                ax.annotate(name, (0.01, 0.02), xycoords="axes fraction", fontsize=8)
        ax.set(xlabel="time [s]", ylabel="height of the centre of mass [m]")
        ax.set_ylim(bottom=min(0.0, ax.get_ylim()[0]))
    else:
        across = np.cross(up, horizontal)
        for run, colour in zip(runs, colours):
            ax.plot(run.com_m @ horizontal, run.com_m @ up, color=colour, lw=1.2, label=f"{run.label}: centre of mass")
            for p, step in sorted(run.most_deformed.items()):
                nodes = run.frames[step]
                seg = _section(nodes, run.faces, nodes.mean(axis=0), across)
                ax.add_collection(LineCollection(np.stack([seg @ horizontal, seg @ up], axis=-1), color=colour, lw=1.0))
                label_at = nodes.mean(axis=0) - 0.22 * np.ptp(nodes @ up) * up
                ax.annotate(
                    f"t = {run.time_s[step]:.3f} s",
                    (label_at @ horizontal, label_at @ up),
                    fontsize=7,
                    ha="center",
                    va="center",
                    bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8},
                )
            start = run.frames[0]
            seg = _section(start, run.faces, start.mean(axis=0), across)
            ax.add_collection(
                LineCollection(np.stack([seg @ horizontal, seg @ up], axis=-1), color="0.6", lw=0.8, ls="--")
            )
        ax.set_aspect("equal")
        ax.autoscale_view()
        _draw_planes_edge_on(ax, runs[0], horizontal, up)
        ax.set(xlabel="horizontal [m]", ylabel="height [m]")
    ax.set_title(
        "centre-of-mass trajectory" + ("" if horizontal is None else " (outlines: start, most deformed)"), fontsize=10
    )
    ax.tick_params(labelsize=8)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _draw_planes_edge_on(ax, run: RunDigest, horizontal: np.ndarray, up: np.ndarray) -> None:
    """Each plane whose normal lies in the (horizontal, up) view as a thick line with its name, the axes widened to show it."""
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    pad = 0.08 * max(x1 - x0, y1 - y0)
    x0, x1, y0, y1 = x0 - pad, x1 + pad, y0 - pad, y1 + pad
    labels = []
    for p, name in enumerate(run.plane_names):
        n = run.plane_normals[p]
        a, b, level = n @ horizontal, n @ up, run.plane_levels[p]
        if np.hypot(a, b) < 0.9:
            continue  # not seen edge-on in this view
        if abs(b) >= abs(a):  # a floor or ceiling: height = (level − a x) / b
            xs = np.array([x0, x1])
            ys = (level - a * xs) / b
        else:  # a wall: x = (level − b y) / a
            ys = np.array([y0, y1])
            xs = (level - b * ys) / a
        x0, x1, y0, y1 = min(x0, *xs), max(x1, *xs), min(y0, *ys), max(y1, *ys)
        ax.plot(xs, ys, color="k", lw=2.0)
        if abs(b) >= abs(a):  # the solid side shaded
            ax.fill_between(xs, ys, y0 if b > 0 else y1, color="0.88", zorder=0)
        else:
            ax.fill_betweenx(ys, xs, x1 if a < 0 else x0, color="0.88", zorder=0)
        labels.append((name, xs, ys, a, b))
    for name, xs, ys, a, b in labels:  # each name on the plane's free side, near its low / left end
        if abs(b) >= abs(a):
            ax.annotate(
                name,
                (x0 + 0.02 * (x1 - x0), np.interp(x0, xs, ys) + 0.01 * np.sign(b) * (y1 - y0)),
                fontsize=8,
                ha="left",
                va="bottom" if b > 0 else "top",
            )
        else:
            x = np.interp(y0, ys, xs) if ys[0] < ys[1] else np.interp(y0, ys[::-1], xs[::-1])
            ax.annotate(
                name,
                (x + 0.01 * np.sign(a) * (x1 - x0), y0 + 0.15 * (y1 - y0)),
                fontsize=8,
                rotation=90,
                ha="left" if a > 0 else "right",
                va="bottom",
            )
    ax.set(xlim=(x0, x1), ylim=(y0, y1))


def keyframe_steps(times: np.ndarray, deviation: np.ndarray, count: int = 6) -> np.ndarray:
    """``count`` steps spread over the run, the one of the largest departure from the rigid motion among them."""
    steps = np.linspace(0, len(times) - 1, count).round().astype(int)
    worst = int(np.argmax(deviation))
    steps[np.argmin(np.abs(steps - worst))] = worst
    return np.unique(steps)


def keyframes_figure(run: RunDigest, rigid: dict[int, np.ndarray], axis: np.ndarray, path: Path) -> Path:
    """The held object at the steps of ``rigid`` (step → its rigid pose (n, 3) [m]) side by side, seen
    along the rotation ``axis``: faces coloured by their distance from the rigid pose [mm], the rigid
    pose in light grey behind, the planes edge-on."""
    import matplotlib as mpl
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    up = -run.gravity / np.linalg.norm(run.gravity)
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    horizontal = np.cross(axis, up)
    horizontal /= np.linalg.norm(horizontal)
    steps = sorted(rigid)
    away = {k: 1e3 * np.linalg.norm(run.frames[k] - rigid[k], axis=1)[run.faces].mean(axis=1) for k in steps}
    norm = mpl.colors.Normalize(0.0, max(max(v.max() for v in away.values()), 1e-3))
    every = np.concatenate([run.frames[k] for k in steps] + [rigid[k] for k in steps])
    xlim = (every @ horizontal).min(), (every @ horizontal).max()
    ylim = (every @ up).min(), (every @ up).max()
    rows = (len(steps) + 2) // 3
    fig, axes = plt.subplots(rows, 3, figsize=(7.2, 1.75 * rows + 0.75), sharex=True, sharey=True, squeeze=False)
    for ax in axes.flat[len(steps) :]:
        ax.set_visible(False)
    for ax, k in zip(axes.flat, steps):
        for nodes, colours, z in ((rigid[k], None, 1), (run.frames[k], plt.get_cmap("plasma")(norm(away[k])), 2)):
            order = np.argsort(-(nodes[run.faces].mean(axis=1) @ axis))  # far faces first
            polys = np.stack([nodes @ horizontal, nodes @ up], axis=-1)[run.faces][order]
            face = (0.85, 0.85, 0.85, 1.0) if colours is None else colours[order]
            ax.add_collection(PolyCollection(polys, facecolors=face, edgecolors="none", zorder=z))
        for p, name in enumerate(run.plane_names):
            n = run.plane_normals[p]
            if abs(n @ horizontal) > 0.9:  # a wall seen edge-on
                ax.axvline(run.plane_levels[p] / (n @ horizontal), color="k", lw=2.0)
            elif abs(n @ up) > 0.9:
                ax.axhline(run.plane_levels[p] / (n @ up), color="k", lw=2.0)
        ax.set(xlim=(xlim[0] - 0.05, xlim[1] + 0.05), ylim=(ylim[0] - 0.03, ylim[1] + 0.03), aspect="equal")
        ax.set_title(f"t = {run.time_s[k]:.2f} s\nup to {away[k].max():.0f} mm", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.locator_params(axis="x", nbins=3)
    for row in axes:
        row[0].set_ylabel("height [m]", fontsize=8)
    fig.supxlabel("horizontal [m]   (grey: the rigid swing; black: the planes)", fontsize=8)
    fig.tight_layout(rect=(0, 0, 0.88, 1))
    cax = fig.add_axes((0.9, 0.2, 0.015, 0.6))
    bar = fig.colorbar(mpl.cm.ScalarMappable(norm, "plasma"), cax=cax)
    bar.set_label("distance from the rigid swing [mm]", fontsize=8)
    bar.ax.tick_params(labelsize=7)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
