"""Figures of a run (matplotlib, Agg backend, PNG): regression, calibration, estimate summary."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import matplotlib.ticker

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .estimate import ClosedFormResult, KsCalibration  # noqa: E402
from .session import Session  # noqa: E402


def plot_force_depth(session: Session, result: ClosedFormResult, path: Path, level: float = 0.99) -> Path:
    """F against w(0): mean depth per force level ± std over trials, OLS line and its confidence band.

    The paper's gauge-pressure figure, panel (b).
    """
    fig, ax = plt.subplots(figsize=(5, 4), dpi=120)
    levels = session.force_levels
    mean = np.array([session.depth[session.force == f].mean() for f in levels])
    std = np.array([session.depth[session.force == f].std(ddof=1) if np.sum(session.force == f) > 1 else 0.0
                    for f in levels])  # fmt: skip
    ax.scatter(session.depth * 1e3, session.force, s=8, color="0.7", label="samples", zorder=1)
    ax.errorbar(mean * 1e3, levels, xerr=std * 1e3, fmt="o", color="C0", capsize=3,
                label="mean ± std over trials", zorder=3)  # fmt: skip
    reg = result.regression
    w = np.linspace(0.0, session.depth.max() * 1.1, 100)
    lo, hi = reg.band(w, level)
    ax.plot(w * 1e3, reg.slope * w + reg.intercept, color="C1",
            label=f"OLS: P̂ = {result.pressure_slope.value:.0f} ± {result.pressure_slope.std:.0f} Pa")  # fmt: skip
    ax.fill_between(w * 1e3, lo, hi, color="C1", alpha=0.25, label=f"{level:.0%} confidence band")
    ax.set_xlabel("indentation depth |w(0)| [mm]")
    ax.set_ylabel("force F [N]")
    ax.set_title(f"{session.object_name} ({session.source.stem})", fontsize=10)
    ax.legend(fontsize=7, loc="upper left")
    ax.set_xlim(left=0)
    ax.set_ylim(bottom=0)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_calibration(calibration: KsCalibration, held_out: list[tuple[str, float, float, float]], path: Path) -> Path:
    """P̂ against manometer P_g with the k_s line (the paper's gauge-pressure figure, panel c).

    ``held_out``: (object, manometer P_g [Pa], P̂ [Pa], std of P̂ [Pa]) of sessions not used to fit.
    """
    fig, ax = plt.subplots(figsize=(5, 4), dpi=120)
    for i, obj in enumerate(sorted(set(calibration.objects))):
        sel = np.array([o == obj for o in calibration.objects])
        ax.errorbar(calibration.gauge_pressures[sel] / 1e3, calibration.pressure_slopes[sel] / 1e3,
                    yerr=calibration.pressure_slope_stds[sel] / 1e3, fmt="o", color=f"C{i}", capsize=3,
                    label=f"train: {obj}")  # fmt: skip
    for i, obj in enumerate(sorted({h[0] for h in held_out})):
        pts = np.array([h[1:] for h in held_out if h[0] == obj])
        ax.errorbar(pts[:, 0] / 1e3, pts[:, 1] / 1e3, yerr=pts[:, 2] / 1e3, fmt="s", mfc="none",
                    color=f"C{i + 3}", capsize=3, label=f"test: {obj}")  # fmt: skip
    everything = np.concatenate([calibration.gauge_pressures, [h[1] for h in held_out]])
    p = np.linspace(0, everything.max() * 1.1, 50)
    k = calibration.k_s
    ax.plot(p / 1e3, k.value * p / 1e3, color="k", label=f"k_s = {k.value:.3f} ± {k.std:.3f}")
    ax.fill_between(p / 1e3, k.ci95[0] * p / 1e3, k.ci95[1] * p / 1e3, color="k", alpha=0.15, label="95 % interval of k_s")
    ax.set_xlabel("manometer gauge pressure P_g [kPa]")
    ax.set_ylabel("P̂ = F / (π R w(0)) [kPa]")
    ax.legend(fontsize=7)
    ax.set_xlim(left=0)
    ax.set_ylim(bottom=0)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_estimate_summary(rows: list[dict], path: Path) -> Path:
    """P_g and E per session with 95 % intervals; manometer readings where known.

    ``rows``: dicts with ``label``, ``gauge_pressure`` and ``young_modulus`` (Estimate or None),
    ``manometer`` [Pa] or None.
    """
    fig, axes = plt.subplots(1, 2, figsize=(9, 0.35 * len(rows) + 1.5), dpi=120, sharey=True)
    y = np.arange(len(rows))
    for ax, key, scale, label in ((axes[0], "gauge_pressure", 1e3, "gauge pressure P_g [kPa]"),
                                  (axes[1], "young_modulus", 1e6, "Young's modulus E [MPa]")):  # fmt: skip
        for i, row in enumerate(rows):
            est = row.get(key)
            if est is None:
                continue
            ax.errorbar(est.value / scale, i, xerr=[[(est.value - est.ci95[0]) / scale], [(est.ci95[1] - est.value) / scale]],
                        fmt="o", color="C0", capsize=3)  # fmt: skip
            if key == "gauge_pressure" and row.get("manometer") is not None:
                ax.plot(row["manometer"] / scale, i, "x", color="C3", ms=8)
        ax.set_xlabel(label)
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.grid(alpha=0.3, which="both")
    axes[0].set_yticks(y, [r["label"] for r in rows], fontsize=7)
    axes[0].plot([], [], "x", color="C3", label="manometer")
    axes[0].errorbar([], [], xerr=[], fmt="o", color="C0", label="closed form, 95 % interval")
    axes[0].legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
