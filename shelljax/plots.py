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


def plot_force_depth(
    session: Session,
    result: ClosedFormResult,
    path: Path,
    level: float = 0.99,
    model_curves: dict[str, np.ndarray] | None = None,
) -> Path:
    """F against w(0): mean depth per force level ± std over trials, OLS line and its confidence band.

    The paper's gauge-pressure figure, panel (b). ``model_curves``: label → predicted depth [m] at
    the session's recorded forces (e.g. the fitted shell model), drawn as lines.
    """
    fig, ax = plt.subplots(figsize=(5, 4), dpi=120)
    levels = session.force_levels
    mean = np.array([session.depth[session.force == f].mean() for f in levels])
    std = np.array(
        [session.depth[session.force == f].std(ddof=1) if np.sum(session.force == f) > 1 else 0.0 for f in levels]
    )
    ax.scatter(session.depth * 1e3, session.force, s=8, color="0.7", label="samples", zorder=1)
    ax.errorbar(
        mean * 1e3, levels, xerr=std * 1e3, fmt="o", color="C0", capsize=3, label="mean ± std over trials", zorder=3
    )
    reg = result.regression
    w = np.linspace(0.0, session.depth.max() * 1.1, 100)
    lo, hi = reg.band(w, level)
    ax.plot(
        w * 1e3,
        reg.slope * w + reg.intercept,
        color="C1",
        label=f"OLS: P̂ = {result.pressure_slope.value:.0f} ± {result.pressure_slope.std:.0f} Pa",
    )
    ax.fill_between(w * 1e3, lo, hi, color="C1", alpha=0.25, label=f"{level:.0%} confidence band")
    order = np.argsort(session.force)
    for i, (label, depth) in enumerate((model_curves or {}).items()):
        ax.plot(np.asarray(depth)[order] * 1e3, session.force[order], color=f"C{i + 2}", lw=1.5, label=label)
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
        ax.errorbar(
            calibration.gauge_pressures[sel] / 1e3,
            calibration.pressure_slopes[sel] / 1e3,
            yerr=calibration.pressure_slope_stds[sel] / 1e3,
            fmt="o",
            color=f"C{i}",
            capsize=3,
            label=f"train: {obj}",
        )
    for i, obj in enumerate(sorted({h[0] for h in held_out})):
        pts = np.array([h[1:] for h in held_out if h[0] == obj])
        ax.errorbar(
            pts[:, 0] / 1e3,
            pts[:, 1] / 1e3,
            yerr=pts[:, 2] / 1e3,
            fmt="s",
            mfc="none",
            color=f"C{i + 3}",
            capsize=3,
            label=f"test: {obj}",
        )
    everything = np.concatenate([calibration.gauge_pressures, [h[1] for h in held_out]])
    p = np.linspace(0, everything.max() * 1.1, 50)
    k = calibration.k_s
    ax.plot(p / 1e3, k.value * p / 1e3, color="k", label=f"k_s = {k.value:.3f} ± {k.std:.3f}")
    ax.fill_between(
        p / 1e3, k.ci95[0] * p / 1e3, k.ci95[1] * p / 1e3, color="k", alpha=0.15, label="95 % interval of k_s"
    )
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

    ``rows``: dicts with ``label``, ``manometer`` [Pa] or None, and ``estimates``: method →
    {"gauge_pressure": Estimate, "young_modulus": Estimate or None}.
    """
    fig, axes = plt.subplots(1, 2, figsize=(9, 0.35 * len(rows) + 1.5), dpi=120, sharey=True)
    y = np.arange(len(rows))
    for ax, key, scale, label in (
        (axes[0], "gauge_pressure", 1e3, "gauge pressure P_g [kPa]"),
        (axes[1], "young_modulus", 1e6, "Young's modulus E [MPa]"),
    ):
        methods = sorted({m for row in rows for m in row["estimates"]})
        for i, row in enumerate(rows):
            for j, method in enumerate(methods):
                est = row["estimates"].get(method, {}).get(key)
                if est is None:
                    continue
                offset = 0.25 * (j - (len(methods) - 1) / 2)
                ax.errorbar(
                    est.value / scale,
                    i + offset,
                    xerr=[[(est.value - est.ci95[0]) / scale], [(est.ci95[1] - est.value) / scale]],
                    fmt="o",
                    color=f"C{j}",
                    capsize=3,
                    label=method if (i == 0 and key == "gauge_pressure") else None,
                )
            if key == "gauge_pressure" and row.get("manometer") is not None:
                ax.plot(row["manometer"] / scale, i, "x", color="C3", ms=8)
        ax.set_xlabel(label)
        ax.set_xscale("log")
        # 1-2-5 ticks: a range within one decade (the pressures) still gets labelled ticks
        ax.xaxis.set_major_locator(matplotlib.ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.tick_params(axis="x", labelsize=8)
        ax.grid(alpha=0.3, which="both")
    axes[0].set_yticks(y, [r["label"] for r in rows], fontsize=7)
    axes[0].plot([], [], "x", color="C3", label="manometer")
    # below the axes, never over a session's intervals
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(
        handles,
        labels,
        loc="lower center",
        ncol=len(labels),
        fontsize=7,
        frameon=False,
        title="95 % intervals",
        title_fontsize=7,
    )
    fig.tight_layout(rect=(0, 0.5 / fig.get_figheight(), 1, 1))
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_posterior(
    samples: dict[str, np.ndarray], chain: np.ndarray, names: tuple[str, ...], stem: str, directory: Path
) -> list[Path]:
    """Corner plot of the posterior samples (SI, P_g in kPa, E in MPa) and trace plot of the chain.

    ``samples``: flat physical samples by name; ``chain``: raw (steps, walkers, dim) chain in the
    sampler's coordinates; returns the two PNG paths.
    """
    import corner

    scale = {
        "gauge_pressure": (1e3, "P_g [kPa]"),
        "young_modulus": (1e6, "E [MPa]"),
        "thickness": (1e-3, "h [mm]"),
        "radius": (1e-3, "R [mm]"),
        "depth_offset": (1e-3, "offset [mm]"),
        "force_gain": (1.0, "gain [-]"),
        "depth_noise": (1e-3, "σ_w [mm]"),
    }
    data = np.stack([samples[n] / scale[n][0] for n in names], axis=1)
    fig = corner.corner(
        data,
        labels=[scale[n][1] for n in names],
        quantiles=[0.025, 0.5, 0.975],
        show_titles=True,
        title_fmt=".3g",
        title_kwargs={"fontsize": 8},
    )
    corner_path = directory / f"corner_{stem}.png"
    fig.savefig(corner_path, dpi=90)
    plt.close(fig)
    fig, axes = plt.subplots(len(names), 1, figsize=(7, 1.4 * len(names)), sharex=True, dpi=100)
    # At most ~700 points a walker: the 700-pixel-wide axes show no more, and drawing them all is slow.
    every = max(1, chain.shape[0] // 700)
    steps = np.arange(0, chain.shape[0], every)
    for ax, i, name in zip(np.atleast_1d(axes), range(len(names)), names):
        ax.plot(steps, chain[::every, :, i], color="k", alpha=0.15, lw=0.5)
        ax.set_ylabel(scale[name][1].split(" ")[0] + " (u)", fontsize=7)
    np.atleast_1d(axes)[-1].set_xlabel("step")
    fig.suptitle(f"MCMC trace, {stem} (sampler coordinates: log-scaled)", fontsize=9)
    fig.tight_layout()
    trace_path = directory / f"trace_{stem}.png"
    fig.savefig(trace_path)
    plt.close(fig)
    return [corner_path, trace_path]


def _which_panel(ax, report: dict, chosen: str) -> None:
    """The diagnosis's WHICH panel: each candidate's Δ elpd ± 2 SE and its margin to win."""
    ranked = [e for e in report["ranking"] if e["effect"] != "baseline"]
    y = np.arange(len(ranked))
    for yi, e in zip(y, ranked):
        if e["status"] != "ok":
            ax.text(0, yi, "  fit failed", va="center", fontsize=7, color="C3")
            continue
        ax.errorbar(
            e["delta"], yi, xerr=2 * e["delta_se"], fmt="o", color="C2" if e["effect"] == chosen else "C0", capsize=3
        )
        ax.plot(max(4.0, 2 * e["delta_se"]), yi, "|", color="C3", ms=10)
    ax.axvline(0, color="k", lw=0.8)
    ax.set_yticks(y, [e["effect"] for e in ranked], fontsize=7)
    ok = [e for e in ranked if e["status"] == "ok"]
    reach = max([abs(e["delta"]) + 2 * e["delta_se"] for e in ok] + [max(4.0, 2 * e["delta_se"]) for e in ok] + [1.0])
    if reach > 50.0:  # symlog only where a candidate is far off; within it, plain ticks (symlog's are unreadable there)
        ax.set_xscale("symlog", linthresh=5)
        ax.xaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
    ax.set_ylim(-0.6, len(ranked) - 0.4)
    ax.set_xlabel(
        "Δ elpd_loo vs baseline [nats]: how much better the model\npredicts trials it never saw "
        "(± 2 SE; red tick: margin to clear)",
        fontsize=8,
    )
    ax.set_title(f"WHICH: verdict = {report['verdict']}", fontsize=9)


def _how_sure_panel(ax, report: dict, chosen: str) -> None:
    """The robust 95 % ranges of E and every session's P_g (grey) against the chosen model's own
    intervals (colour), in % of the chosen model's value, with the kept models' point values."""
    robust = report["robust"]
    rows = [("E", robust["young_modulus"])] + [(f"P_g[{i}]", g) for i, g in enumerate(robust["gauge_pressure"])]
    chosen_values = [report["winner"]["estimates_after"] if report["winner"] else report["baseline"]["estimates"]]
    centers = [chosen_values[0]["young_modulus"]["value"]] + [g["value"] for g in chosen_values[0]["gauge_pressure"]]
    for y, ((label, r), center) in enumerate(zip(rows, centers)):
        pct = lambda v: 100.0 * (v / center - 1.0)  # noqa: E731
        lo, hi = pct(r["range95"][0]), pct(r["range95"][1])
        ax.plot([lo, hi], [y, y], color="0.6", lw=9, solid_capstyle="butt", label="robust range" if y == 0 else None)
        own = [pct(v) for v in r["chosen_ci95"]]
        ax.plot(own, [y, y], color="C2", lw=3, label=f"{chosen} 95 %" if y == 0 else None)
        values = [pct(v) for v in r["values"].values()]
        ax.plot(values, [y] * len(values), "k|", ms=12, label="models kept (point values)" if y == 0 else None)
    ax.axvline(0, color="k", lw=0.6)
    ax.set_yticks(range(len(rows)), [r[0] for r in rows], fontsize=7)
    ax.set_ylim(len(rows) - 0.5, -0.5)
    ax.set_xlabel("value relative to the chosen model's estimate [%]", fontsize=8)
    ax.set_title("HOW SURE: E and P_g over the models the data cannot exclude", fontsize=9)
    ax.legend(fontsize=6, loc="upper center", bbox_to_anchor=(0.5, -0.28), ncol=3, frameon=False)


def _separating_text(ax, report: dict) -> None:
    """Which extra measurement would tell the remaining models apart, and why the range is wide."""
    ax.axis("off")
    lines = [f"Search: {' → '.join(report.get('search', []))}", "", "To narrow the range, measure:"]
    for item in report.get("separating", [])[:6]:
        lines.append(f"• {item['effect']}: {item['measurement']}")
    if len(lines) == 3:
        lines.append("• nothing: every other model is excluded")
    if report["robust"].get("warning"):
        lines += ["", "Warning:", report["robust"]["warning"]]
    import textwrap

    text = "\n".join(textwrap.fill(line, 62, subsequent_indent="   ") for line in lines)
    ax.text(0.0, 1.0, text, va="top", ha="left", fontsize=7, transform=ax.transAxes)
    ax.set_title("WHAT NEXT", fontsize=9)


def plot_diagnosis(diagnosis, path: Path) -> Path:
    """The sim-to-real diagnosis at a glance (``shelljax.diagnose.Diagnosis``).

    Top left: held-out standardized depth residuals against force, per session, under the baseline
    (filled) and the chosen model (open). Top right: held-out RMS of standardized residuals per
    observable, regime and session, before and after, with misfit groups marked. Bottom left: each
    candidate's elpd difference to the baseline ± 2 SE and its decision margin max(4 nats, 2 SE). Middle right:
    LOO-PIT histograms (uniform when the model predicts held-out trials well). Bottom: the robust
    ranges of E and P_g against the chosen model's intervals, and the measurements that would separate
    the models kept.
    """
    report, study = diagnosis.report, diagnosis.study
    before, after = diagnosis.points_before, diagnosis.points_after
    chosen = report["winner"]["effect"] if report["winner"] else "baseline"
    fig, axes = plt.subplots(3, 2, figsize=(12, 12.5), dpi=110, height_ratios=(1, 1, 0.7))
    ax = axes[0, 0]
    depth = before["observable"] == "depth"
    for i, s in enumerate(study.sessions):
        sel = depth & (before["session"] == i)
        label = Path(str(s.source)).stem
        ax.plot(before["force"][sel], before["z"][sel], "o", color=f"C{i}", ms=4, label=label)
        if chosen != "baseline":
            ax.plot(before["force"][sel], after["z"][sel], "o", mfc="none", color=f"C{i}", ms=5)
    ax.axhspan(-2, 2, color="0.9", zorder=0)
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xlabel("recorded force F [N]")
    ax.set_ylabel("held-out standardized depth residual [-]")
    ax.set_title(f"WHERE: baseline (filled){'' if chosen == 'baseline' else f' vs {chosen} (open)'}", fontsize=9)
    ax.legend(fontsize=6, ncol=2)

    ax = axes[0, 1]
    groups = [("obs", k, v) for k, v in report["where"]["by_observable"].items()]
    groups += [("regime", k, v) for k, v in report["where"]["by_regime"].items()]
    groups += [("session", Path(v["session"]).stem, v) for v in report["where"]["by_session"]]
    after_where = report.get("where_after") or report["where"]
    after_groups = (
        [v for v in after_where["by_observable"].values()]
        + list(after_where["by_regime"].values())
        + after_where["by_session"]
    )
    y = np.arange(len(groups))
    ax.barh(y + 0.2, [g[2]["rms_standardized"] for g in groups], height=0.4, color="C3", label="baseline")
    if chosen != "baseline":
        ax.barh(y - 0.2, [g["rms_standardized"] for g in after_groups], height=0.4, color="C0", label=chosen)
    for yi, g in zip(y, groups):
        if g[2]["misfit"]:
            ax.text(g[2]["rms_standardized"], yi + 0.2, f" p={g[2]['p_value']:.1g}", va="center", fontsize=6)
    ax.axvline(1.0, color="k", lw=0.8, ls="--")
    ax.set_yticks(y, [f"{g[0]}: {g[1]}" for g in groups], fontsize=6)
    ax.set_xlabel("held-out RMS of standardized residuals [-] (1 = noise)")
    ax.set_title("WHERE: misfit by group", fontsize=9)
    ax.legend(fontsize=7)

    _which_panel(axes[1, 0], report, chosen)

    ax = axes[1, 1]
    bins = np.linspace(0, 1, 11)
    ax.hist(before["pit"], bins=bins, histtype="step", color="C3", lw=1.5, label="baseline", density=True)
    if chosen != "baseline":
        ax.hist(after["pit"], bins=bins, histtype="step", color="C0", lw=1.5, label=chosen, density=True)
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xlabel(
        "LOO-PIT [-]: where each held-out datum falls in its predictive\ndistribution "
        "(flat at 1: unseen trials predicted well; U: too confident)",
        fontsize=8,
    )
    ax.set_ylabel("density")
    ax.set_title(
        f"HOW FAR: gap {report['gap_before']['rms_standardized']:.2f} → "
        f"{report['gap_after']['rms_standardized']:.2f} (shrink {report['shrink']:.2g}×)",
        fontsize=9,
    )
    ax.legend(fontsize=7)
    _how_sure_panel(axes[2, 0], report, chosen)
    _separating_text(axes[2, 1], report)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return Path(path)
