"""PNG rendering of an indentation state (matplotlib, headless)."""

from __future__ import annotations

import numpy as np


def plot_state(state, path) -> None:
    """Write a PNG [path]: 3D view of the deformed shell and its cross-section near y = 0 [m]."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = state.vertices
    faces = state.sim.model.mesh.faces
    obs = state.observables()
    fig = plt.figure(figsize=(10, 4.5))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    ax.plot_trisurf(
        x[:, 0], x[:, 1], x[:, 2], triangles=faces, cmap="viridis", linewidth=0.05, edgecolor="k", alpha=0.9
    )
    span = np.ptp(x, axis=0).max() / 2
    mid = 0.5 * (x.max(axis=0) + x.min(axis=0))
    for set_lim, m in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), mid):
        set_lim(m - span, m + span)
    ax.set_title("deformed shell [m]")
    ax2 = fig.add_subplot(1, 2, 2)
    band = np.abs(x[:, 1]) < 0.02 * np.ptp(x[:, 0])
    ax2.plot(x[band, 0], x[band, 2], ".", ms=2, label="shell (|y| small)")
    c = state.indenter_center
    t = np.linspace(0, 2 * np.pi, 200)
    r = state.sim.indenter_radius
    ax2.plot(c[0] + r * np.cos(t), c[2] + r * np.sin(t), "r-", label="indenter")
    ax2.axhline(0.0, color="k", lw=1, label="ground")
    ax2.set_aspect("equal")
    ax2.set_xlabel("x [m]")
    ax2.set_ylabel("z [m]")
    ax2.set_title(f"F = {obs['force']:.3g} N, w0 = {obs['w0'] * 1e3:.3g} mm, p = {obs['pressure']:.4g} Pa")
    ax2.legend(loc="lower right", fontsize=7)
    fig.tight_layout()
    fig.savefig(str(path), dpi=120)
    plt.close(fig)
