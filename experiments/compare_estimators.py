"""Closed form vs fit vs bayes on virtual experiments from the 3D engine.

Sessions: ``shelljax.virtual`` (noise-free 3D curves bundled in
``shelljax/data/virtual/curves.json``, noisy sessions drawn reproducibly). For P_g [Pa] and E [Pa]
and each method it reports, over sessions, the bias (mean relative error), the median |relative
error|, the RMS relative error and the 95 %-interval coverage of the truth. Methods:

* ``closed-form (calibrated k_s)``: k_s from ``calibrate_ks`` on one manometer session per curve
  (independent noise draws), delta-method intervals;
* ``closed-form (k_s = 0.64)``: the paper's default;
* ``fit``: ``fit_session`` through the axisymmetric engine (``wrinkle_law`` from ``--wrinkle-law``);
* ``bayes``: ``sample_posterior`` (same forward model, through its checked Chebyshev surrogate) on
  the first ``--bayes-realisations`` realisations of every curve at the depth-noise levels
  ``--bayes-noise`` [mm], ``--walkers``, ``--bayes-steps``.

Per-session results are appended to ``<out>.jsonl`` as they finish (a rerun skips finished ones);
the summary table is printed and written to ``--out`` (JSON).

Usage: python experiments/compare_estimators.py [--out compare_estimators.json] [--bayes-noise 1.0] [--only-bayes]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from shelljax.paper import PAPER_FORCES as FORCES
from shelljax.virtual import (
    CURVES_PATH,
    QUANTITIES,
    draw_calibration_sessions,
    draw_sessions,
    load_curves,
    noise_free_session,
    summarise,
)


def _record(est, truth: float) -> dict:
    lo, hi = est.ci95
    return {
        "value": est.value,
        "std": est.std,
        "ci95": [lo, hi],
        "rel_error": est.value / truth - 1.0,
        "covered": bool(lo <= truth <= hi),
    }


NOISE_FREE_DEPTH_NOISE = 1e-3  # [m]: σ_w assumed by the noise-free fits; it only scales their Laplace errors


def _noise_free_bias(curves, model, fit_session, out: Path):
    """Fit every curve's noise-free session: the relative P_g and E errors are the forward model's
    bias; the Laplace standard deviations and P_g–E correlation (at σ_w = 1 mm, 3 trials) show how
    a session's noise reaches P_g."""
    rows = []
    print(f"\n{'set':>4}{'tau':>6}{'P_g err':>9}{'E err':>9}{'sd(P_g)':>9}{'sd(E)':>8}{'corr':>7}")
    for c in sorted(curves, key=lambda c: c["tau"]):
        fit = fit_session(
            noise_free_session(c, name=f"set{c.get('set')}_noise_free"), model, depth_noise=NOISE_FREE_DEPTH_NOISE
        )
        sd = np.sqrt(np.diag(fit.covariance))  # relative (log-parametrised unknowns)
        row = {
            "set": c.get("set"),
            "tau": c["tau"],
            "rel_error": {q: fit.estimates[q].value / c[q] - 1.0 for q in QUANTITIES},
            "rel_std": {q: float(sd[i]) for i, q in enumerate(QUANTITIES)},
            "correlation": float(fit.covariance[0, 1] / (sd[0] * sd[1])),
        }
        rows.append(row)
        print(
            f"{row['set']:>4}{row['tau']:>6.0f}{row['rel_error']['gauge_pressure']:>+9.4f}"
            f"{row['rel_error']['young_modulus']:>+9.4f}{sd[0]:>9.3f}{sd[1]:>8.3f}{row['correlation']:>7.2f}"
        )
    out.write_text(
        json.dumps(
            {
                "machine": f"{platform.platform()}, {os.cpu_count()} CPUs",
                "depth_noise_m": NOISE_FREE_DEPTH_NOISE,
                "rows": rows,
            },
            indent=2,
        )
    )
    print(f"wrote {out}")


def _parse(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--curves", type=Path, default=CURVES_PATH)
    ap.add_argument("--realisations", type=int, default=4, help="noise draws per curve and noise level")
    ap.add_argument("--wrinkle-law", default="scaling", choices=["scaling", "mechanics"])
    ap.add_argument(
        "--no-relax",
        action="store_true",
        help="forward model without the wrinkling relaxation of the hoop stress (docs/estimators.md)",
    )
    ap.add_argument(
        "--hoop-capacity",
        type=float,
        default=None,
        help="hoop compression of the wrinkled wall in classical buckling resultants "
        "(default: the engine's calibrated value; 0: tension field)",
    )
    ap.add_argument("--fit-label", default="fit", help="method name of this fit variant in the table")
    ap.add_argument(
        "--bayes-noise",
        type=float,
        nargs="*",
        default=[1.0],
        help="depth-noise levels [mm] whose first realisation gets bayes (none: skip bayes)",
    )
    ap.add_argument(
        "--bayes-realisations",
        type=int,
        default=1,
        help="how many realisations per curve and noise level get bayes (from the first)",
    )
    ap.add_argument(
        "--bayes-nuisance",
        nargs="*",
        default=[],
        choices=["depth_offset", "force_gain"],
        help="nuisance parameters of bayes (force_gain: a 5 %% prior on the force scale, which "
        "also absorbs a proportional model discrepancy)",
    )
    ap.add_argument("--bayes-label", default="bayes", help="method name of this bayes variant in the table")
    ap.add_argument("--walkers", type=int, default=32)
    ap.add_argument("--bayes-steps", type=int, default=20_000)
    ap.add_argument("--skip-fit", action="store_true")
    ap.add_argument("--only-bayes", action="store_true", help="skip closed form and fit (a parallel bayes job)")
    ap.add_argument(
        "--also",
        type=Path,
        nargs="*",
        default=[],
        help="per-session .jsonl files of other runs whose method results join the table",
    )
    ap.add_argument(
        "--noise-free",
        action="store_true",
        help="only fit each curve's noise-free session (the forward model's bias per ball) and exit",
    )
    ap.add_argument("--out", type=Path, default=Path("compare_estimators.json"))
    ap.add_argument(
        "--write-rows",
        type=Path,
        default=None,
        help="also write the final per-session rows (closed form recomputed, --also merged) as JSON lines",
    )
    args = ap.parse_args(argv)
    return args


def main(argv=None):
    args = _parse(argv)
    import jax

    import shelljax  # noqa: F401  (float64)

    # Synchronous dispatch: XLA:CPU wedged long runs (docs/shell3d.md, *XLA:CPU hangs*).
    jax.config.update("jax_cpu_enable_async_dispatch", False)
    from shelljax.estimate import calibrate_ks, fit_session

    curves = load_curves(args.curves)
    sessions = draw_sessions(curves, realisations=args.realisations)
    calib = calibrate_ks(draw_calibration_sessions(curves))
    print(
        f"{len(curves)} curves, {len(sessions)} sessions; calibrated k_s = {calib.k_s.value:.4f} ± {calib.k_s.std:.4f}",
        flush=True,
    )
    model = _forward_model(curves, args)
    if args.noise_free:
        _noise_free_bias(curves, model, fit_session, args.out)
        return
    log_path = args.out.with_suffix(".jsonl")
    t_start = time.perf_counter()
    done = _run_sessions(sessions, model, calib, args, log_path)
    for extra in args.also:
        for line in extra.read_text().splitlines():
            r = json.loads(line)
            if r["name"] in done:
                done[r["name"]].update({m: v for m, v in r.items() if isinstance(v, dict) and m not in done[r["name"]]})
    rows = [done[t["name"]] for t, _ in sessions if t["name"] in done]
    if args.write_rows is not None:
        args.write_rows.write_text("".join(json.dumps(r) + "\n" for r in rows))
    _report(rows, curves, calib, args, time.perf_counter() - t_start)
    print(f"wrote {args.out} (per-session rows: {log_path})")


def _forward_model(curves, args):
    """One axisymmetric forward model for every session: the grid brackets the recorded (noisy)
    forces, so the compiled program is shared; w0 between grid points is linearly interpolated
    (docs/fit-and-bayes.md)."""
    from shelljax.estimate import AxisymForwardModel

    radius = curves[0]["radius"]
    if any(c["radius"] != radius for c in curves):
        raise SystemExit("all curves must share one radius (one compiled forward model)")
    return AxisymForwardModel.for_forces(
        radius,
        [FORCES[0] - 0.3, FORCES[-1] + 0.3],
        poisson_ratio=curves[0]["poisson_ratio"],
        wrinkle_law=args.wrinkle_law,
        relax=not args.no_relax,
        **({} if args.hoop_capacity is None else {"hoop_capacity": args.hoop_capacity}),
    )


def _closed_forms(row, session, true, calib, args) -> None:
    """The closed form with the calibrated and the paper's k_s (instant: always recomputed)."""
    from shelljax.estimate import estimate_session

    for label, ks in () if args.only_bayes else (("closed_form_calibrated", calib.k_s), ("closed_form_paper", None)):
        t0 = time.perf_counter()
        cf = (
            estimate_session(session, k_s=ks, bootstrap_samples=0)
            if ks is not None
            else estimate_session(session, bootstrap_samples=0)
        )
        row[label] = {
            "gauge_pressure": _record(cf.gauge_pressure, true["gauge_pressure"]),
            "young_modulus": _record(cf.young_modulus, true["young_modulus"]),
            "seconds": time.perf_counter() - t0,
        }


def _fit(row, session, true, model, args) -> None:
    """``fit_session`` through the axisymmetric engine, unless skipped or already in ``row``."""
    from shelljax import InvalidInputError, NoConvergenceError
    from shelljax.estimate import fit_session

    fit_label = args.fit_label
    if args.skip_fit or args.only_bayes or fit_label in row:
        return
    t0 = time.perf_counter()
    try:
        fit = fit_session(session, model)
        row[fit_label] = {q: _record(fit.estimates[q], true[q]) for q in QUANTITIES}
        row[fit_label]["chi2"] = fit.chi2
        row[fit_label]["dof"] = fit.dof
    except (NoConvergenceError, InvalidInputError) as err:
        row[fit_label] = {"error": str(err)[:300]}
    row[fit_label]["seconds"] = time.perf_counter() - t0


def _bayes(row, session, truth, true, model, args, seed: int) -> None:
    """``sample_posterior`` on the sessions ``--bayes-noise`` and ``--bayes-realisations`` select."""
    from shelljax import InvalidInputError, NoConvergenceError
    from shelljax.estimate import ConvergenceWarning, fit_session, sample_posterior

    selected = truth["realisation"] < args.bayes_realisations and any(
        abs(truth["depth_noise"] * 1e3 - b) < 1e-9 for b in args.bayes_noise
    )
    if args.bayes_label in row or not selected:
        return
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        try:
            fit = fit_session(session, model, nuisance=tuple(args.bayes_nuisance), raise_on_failure=False)
            post = sample_posterior(
                fit,
                n_walkers=args.walkers,
                max_steps=args.bayes_steps,
                min_steps=min(1000, args.bayes_steps),
                seed=seed,
                progress=False,
            )
            row[args.bayes_label] = {q: _record(post.estimates[q], true[q]) for q in QUANTITIES}
            row[args.bayes_label].update(
                effective_samples=post.effective_samples,
                n_steps=post.n_steps,
                converged=post.converged,
                failed_forward=post.failed_forward,
                surrogate=post.surrogate,
            )
        except (NoConvergenceError, InvalidInputError) as err:
            row[args.bayes_label] = {"error": str(err)[:300]}
    row[args.bayes_label]["seconds"] = time.perf_counter() - t0


def _run_sessions(sessions, model, calib, args, log_path: Path) -> dict:
    """Every session's row by name; fit and bayes results are reused from the ``log_path`` lines
    of an earlier run, new rows are appended to it."""
    from tqdm import tqdm

    done = {}
    if log_path.exists():
        for line in log_path.read_text().splitlines():
            r = json.loads(line)
            done[r["name"]] = r
    with log_path.open("a") as log:
        for k, (truth, session) in enumerate(tqdm(sessions, desc="sessions", file=sys.stdout, mininterval=5)):
            previous = done.get(truth["name"], {})
            row = dict(truth)
            # the closed form is recomputed, so a k_s calibrated on a grown set of curves applies to every session
            row.update({m: v for m, v in previous.items() if isinstance(v, dict) and not m.startswith("closed_form")})
            true = {q: truth[q] for q in QUANTITIES}
            _closed_forms(row, session, true, calib, args)
            _fit(row, session, true, model, args)
            _bayes(row, session, truth, true, model, args, seed=k)
            if row.keys() - previous.keys():
                log.write(json.dumps(row) + "\n")
                log.flush()
            done[truth["name"]] = row
    return done


def _per_set(rows, methods) -> dict:
    """Median relative errors per parameter set and method (with the fit's χ²/dof and coverage)."""
    per_set = {}
    for k in sorted({r["set"] for r in rows}):
        mine = [r for r in rows if r["set"] == k]
        per_set[k] = {
            m: {q: float(np.median([r[m][q]["rel_error"] for r in mine if q in r.get(m, {})])) for q in QUANTITIES}
            for m in methods
            if any(QUANTITIES[0] in r.get(m, {}) for r in mine)
        }
        fits = [r["fit"] for r in mine if "chi2" in r.get("fit", {})]
        if fits:
            per_set[k]["fit"]["chi2_per_dof"] = float(np.median([f["chi2"] / f["dof"] for f in fits]))
            per_set[k]["fit"]["coverage95_gauge_pressure"] = float(
                np.mean([f["gauge_pressure"]["covered"] for f in fits])
            )
    return per_set


def _report(rows, curves, calib, args, wall: float) -> None:
    """Print the summary and per-set tables and write them to ``args.out``."""
    methods = ("closed_form_calibrated", "closed_form_paper")
    for family in ("fit", "bayes"):
        methods += tuple(sorted({m for r in rows for m in r if m.startswith(family) and isinstance(r[m], dict)}))
    summary = {m: summarise(rows, m) for m in methods}
    print(
        f"\nmachine: {platform.platform()}, {os.cpu_count()} CPUs; {len(rows)} sessions; "
        f"wrinkle law {args.wrinkle_law}; wall {wall:.0f} s"
    )
    print(f"{'method':<26}{'qty':<5}{'n':>4}{'bias':>9}{'med|err|':>10}{'RMS':>9}{'cover95':>9}")
    for m in methods:
        for q in QUANTITIES:
            s = summary[m].get(q)
            if s:
                print(
                    f"{m:<26}{'P_g' if q == 'gauge_pressure' else 'E':<5}{s['n']:>4}{s['bias']:>+9.3f}"
                    f"{s['median_abs']:>10.3f}{s['rms']:>9.3f}{s['coverage95']:>9.2f}"
                )
        if summary[m].get("failed"):
            print(f"{m:<26}failed: {summary[m]['failed']}")
    per_set = _per_set(rows, methods)
    print("\nmedian relative error per parameter set (P_g / E):")
    for k, v in per_set.items():
        print(
            f"set {k}: " + "  ".join(f"{m} {e['gauge_pressure']:+.3f}/{e['young_modulus']:+.3f}" for m, e in v.items())
        )
    timing = {
        m: float(np.median([r[m]["seconds"] for r in rows if m in r])) for m in methods if any(m in r for r in rows)
    }
    result = {
        "machine": f"{platform.platform()}, {os.cpu_count()} CPUs",
        "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
        "n_sessions": len(rows),
        "wrinkle_law": args.wrinkle_law,
        "k_s_calibrated": calib.k_s.to_dict(),
        "bayes": {
            "walkers": args.walkers,
            "max_steps": args.bayes_steps,
            "noise_levels_mm": args.bayes_noise,
            "realisations": args.bayes_realisations,
        },
        "median_seconds_per_session": timing,
        "summary": summary,
        "median_rel_error_per_set": per_set,
        "curves": [
            {k: c[k] for k in ("gauge_pressure", "young_modulus", "thickness", "tau", "n_faces", "pole_edge")}
            for c in curves
        ],
    }
    args.out.write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
