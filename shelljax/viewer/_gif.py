"""The GIF of a headless replay, drawn with the scenario previews' renderer
(``shelljax.dynamics.internal``: the shell at equal scale, faces coloured by membrane areal strain
against the rest shape, faces touching a plane dark, the planes in grey), with the hand as an
orange sphere and the time, gauge pressure [Pa], contact forces [N] and real-time factor written
on each frame. A fixed camera frames the whole motion, so a throw is seen to travel."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..dynamics import internal as render
from ._headless import Replay

#: Distance [m] to a plane within which a face counts as touching it (drawn dark).
TOUCH_DISTANCE_M = 1e-3


def _caption(replay: Replay, row: int, blown: bool) -> str:
    row = min(row, replay.time_s.size - 1)
    if row < 0:
        return "blow-up before the first frame"
    forces = "  ".join(
        f"{name} {np.linalg.norm(replay.plane_forces_N[row, i]):.1f} N" for i, name in enumerate(replay.plane_names)
    )
    hand = np.linalg.norm(replay.collider_force_N[row])
    action = replay.action[row] or "free"
    text = (
        f"t = {replay.time_s[row]:.2f} s  {action}{'  (held)' if replay.holding[row] else ''}\n"
        f"P_g {replay.gauge_pressure_Pa[row]:.0f} Pa   hand {hand:.1f} N\n{forces}   RT ×{replay.real_time_factor[row]:.1f}"
    )
    return "BLOW-UP: simulation stopped\n" + text if blown else text


def _hand_sphere(ax, centre, radius: float) -> None:
    u, v = np.meshgrid(np.linspace(0.0, 2.0 * np.pi, 13), np.linspace(0.0, np.pi, 7))
    ax.plot_surface(
        centre[0] + radius * np.cos(u) * np.sin(v),
        centre[1] + radius * np.sin(u) * np.sin(v),
        centre[2] + radius * np.cos(v),
        color=(1.0, 0.55, 0.1),
        linewidth=0,
        zorder=4,
        shade=True,
    )


def _view(replay: Replay) -> tuple[np.ndarray, float]:
    """A fixed cube (centre [m], half-width [m]) holding every kept shape."""
    lo, hi = replay.shapes_m.min(axis=(0, 1)), replay.shapes_m.max(axis=(0, 1))
    return 0.5 * (lo + hi), 0.55 * float((hi - lo).max())


def write_gif(replay: Replay, path: str | Path, *, hand_radius: float, gif_fps: float, dpi: int = 64) -> Path:
    """Write the replay's kept shapes as a GIF at ``gif_fps`` [1/s] to ``path``; returns it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation, PillowWriter

    rest = replay.shapes_m[0]
    strain = render.face_strain(replay.shapes_m, replay.faces, rest)
    limit = render.strain_limit(strain)
    normals = list(replay.planes.normal)
    levels = [float(point @ normal) for point, normal in zip(replay.planes.point, replay.planes.normal)]
    centre, half = _view(replay)
    fig = plt.figure(figsize=(4.6, 4.4))
    ax = fig.add_axes((0.0, 0.0, 0.82, 0.84), projection="3d")
    render.strain_colourbar(fig, limit)
    caption = fig.text(0.03, 0.985, "", va="top", fontsize=7.5, family="monospace")
    blown_at = len(replay.shape_frames) - 1 if replay.blow_up else -1

    def draw(j):
        ax.clear()
        nodes = replay.shapes_m[j]
        touching = render.contact_faces(nodes, replay.faces, normals, levels, [TOUCH_DISTANCE_M] * len(levels))
        rgba = render.strain_rgba(strain[j], limit, touching)
        render.draw_shell(ax, nodes, replay.faces, rgba, centre, half, list(zip(normals, levels)))
        row = int(replay.shape_frames[j])
        hand = replay.hand_m[min(row, len(replay.hand_m) - 1)] if len(replay.hand_m) else np.full(3, np.nan)
        if np.all(np.isfinite(hand)) and j != blown_at:
            _hand_sphere(ax, hand, hand_radius)
        caption.set_text(_caption(replay, row, j == blown_at))
        caption.set_color("red" if j == blown_at else "black")

    FuncAnimation(fig, draw, frames=len(replay.shape_frames)).save(path, writer=PillowWriter(fps=gif_fps), dpi=dpi)
    plt.close(fig)
    return Path(path)
