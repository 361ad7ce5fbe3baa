"""Rig transfer study: calibrate a rig once on one object with a manometer, measure others without.

Each rig has 0–3 imperfections of its measuring chain, drawn from families **wider than the rig
model's** (shelljax.rig fits linear, Hertzian or power-law pads and power-law sensors; here pads
also saturate exponentially and sensors also bend quadratically):

| family | drawn | truth |
|---|---|---|
| pad | linear, Hertzian or saturating | compression 2–5 mm at 20 N: c F, c' F^(2/3), or d (1 − e^(−F/F₀)) with F₀ 5–12 N |
| finger | a wider finger | radius 10–25 mm (the estimators assume 8 mm) |
| sensor | gain, power law, or quadratic | F_t = g F (g 0.8–1.25), F_ref (F/F_ref)^p (p 0.8–1.2), or F (1 + β (F/F_ref − 1)) (β ±0.1–0.2) |
| depth | zero error | δ ±1–3 mm |

Per rig: a calibration object (R 0.12–0.2 m) at 4 pressures with manometer readings (1 % noise),
and ``--objects`` test objects of other R (0.08–0.30 m, log-uniform), h (0.6–2 mm) and E (1–5 MPa,
log-uniform) at 2 pressures each, without manometer. Each object's R and h are measured once, with
the errors their sessions state (2 % and 5 %; ``--exact-geometry`` records the truth instead). The paper's protocol (5–20 N in 2.5 N steps,
3 trials, one wrinkle count a trial) with the bundled sessions' noise (as
``experiments/blind_gap_study.py``). "Reality" is a finer engine than the estimators': the
axisymmetric engine at 201 meridian elements from its own reference radius (0.15 m), sealed
isothermal gas. The estimators see only the session files.

Methods, on every test session:
* ``fit``: the fitted estimator without a rig (sealed isothermal gas, n = 1.33 τ^½);
* ``fit+rig`` and ``bayes+rig``: the same forward model through the rig calibrated on the
  calibration object (``shelljax.rig``);
* ``closed-form k_s``: the paper's closed form with k_s calibrated on the calibration object.

The rigs' worlds are drawn first, one after the other from one stream; each rig's calibration and
estimates are then one work item (``shelljax.executor``), so ``--workers N`` or ``--cluster`` give
the same numbers as a serial run. ``--calibration-radius-std`` sets how well the calibration ball's
R is measured (and stated): its mesh's 2 % by default, a tape's 0.3 % in docs/rig.md's second table.

Run:  python experiments/rig_transfer_study.py --rigs 12 --out docs/bench/rig-transfer-study.json
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from shelljax.executor import WorkItem, add_executor_arguments, executor_options, run_items
from shelljax.paper import DEFAULT_POISSON_RATIO, PAPER_FORCES, PAPER_INDENTER_RADIUS
from shelljax.physics import ShellProperties, scaling_wrinkle_count
from shelljax.physics import PolytropicGas

FORCE_LEVELS = np.asarray(PAPER_FORCES)  # [N]
N_TRIALS = 3
REALITY_RADIUS = 0.15  # [m]
REALITY_ELEMENTS = 201
POISSON = DEFAULT_POISSON_RATIO
RADIUS_STD, THICKNESS_STD = 0.02, 0.05  # relative std of the mesh's R and the caliper's h, as the sessions state
F_REF = math.sqrt(FORCE_LEVELS[0] * FORCE_LEVELS[-1])  # [N]
FAMILIES = ("pad", "finger", "sensor", "depth")
METHODS = ("fit", "fit+rig", "bayes+rig", "closed-form k_s", "fit+rig, object")
CALIBRATION_WEIGHTS = "fit+rig, calibration weights"  # the same fits, mixed by the rig's weights alone
TRUE_FAMILIES = "fit+rig, model of the true families"  # the rig model whose families are the truth's, where selected
TERM_FAMILY = {
    "pad_linear": "pad",
    "pad_hertz": "pad",
    "pad_power": "pad",
    "finger_radius": "finger",
    "depth_offset": "depth",
    "sensor_gain": "sensor",
    "sensor_power": "sensor",
}


def draw_rig(rng, n_imperfections: int) -> dict:
    """The true measuring chain: a dict of the imperfections present (family → kind and values)."""
    rig = {}
    for family in rng.choice(FAMILIES, size=n_imperfections, replace=False):
        if family == "pad":
            kind = str(rng.choice(["linear", "hertz", "saturating"]))
            at_20 = rng.uniform(2e-3, 5e-3)  # [m] compression at 20 N
            rig["pad"] = {"kind": kind, "compression_at_20N": at_20, "f0": rng.uniform(5.0, 12.0)}
        elif family == "finger":
            rig["finger"] = {"radius": rng.uniform(10e-3, 25e-3)}
        elif family == "sensor":
            kind = str(rng.choice(["gain", "power", "quadratic"]))
            rig["sensor"] = {
                "kind": kind,
                "gain": rng.uniform(0.8, 1.25),
                "exponent": rng.uniform(0.8, 1.2),
                "beta": rng.choice([-1, 1]) * rng.uniform(0.1, 0.2),
            }
        else:
            rig["depth"] = {"offset": rng.choice([-1, 1]) * rng.uniform(1e-3, 3e-3)}
    return rig


def true_force(rig, recorded):
    s = rig.get("sensor")
    if s is None:
        return recorded
    if s["kind"] == "gain":
        return s["gain"] * recorded
    if s["kind"] == "power":
        return F_REF * (recorded / F_REF) ** s["exponent"]
    return recorded * (1 + s["beta"] * (recorded / F_REF - 1))


def pad_compression(rig, force):
    p = rig.get("pad")
    if p is None:
        return np.zeros_like(force)
    if p["kind"] == "linear":
        return p["compression_at_20N"] * force / 20.0
    if p["kind"] == "hertz":
        return p["compression_at_20N"] * (force / 20.0) ** (2.0 / 3.0)
    return p["compression_at_20N"] * (1 - np.exp(-force / p["f0"])) / (1 - math.exp(-20.0 / p["f0"]))


def draw_object(rng, radius_range, log_radius=False):
    lo, hi = radius_range
    radius = math.exp(rng.uniform(math.log(lo), math.log(hi))) if log_radius else rng.uniform(lo, hi)
    thickness = rng.uniform(0.6e-3, 2.0e-3)
    young = math.exp(rng.uniform(math.log(1.0e6), math.log(5.0e6)))
    low = max(700.0, 16.0 / radius**2)
    return dict(radius=radius, thickness=thickness, young_modulus=young, low_pressure=low * rng.uniform(1.0, 1.3))


def reality_w0(obj, rig, pressure, forces):
    """Noise-free w0 [m] of reality at increasing true forces [N]."""
    from shelljax.axisym import CurvePhysics, indentation_curves

    scale = obj["radius"] / REALITY_RADIUS
    radius = rig.get("finger", {}).get("radius", PAPER_INDENTER_RADIUS)
    physics = CurvePhysics(
        indenter_radius=np.array([radius / scale]),
        gas_volume_ratio=np.ones(1),
        gas_exponent=np.ones(1),
        stiffening=np.zeros(1),
        areal_weight=np.zeros(1),
        friction_coefficient=np.zeros(1),
    )
    shell = ShellProperties(
        gauge_pressure=pressure,
        young_modulus=obj["young_modulus"],
        thickness=obj["thickness"] / scale,
        poisson_ratio=POISSON,
        radius=REALITY_RADIUS,
    )
    curve = indentation_curves(
        shell,
        np.asarray(forces) / scale**2,
        n_elements=REALITY_ELEMENTS,
        gas=PolytropicGas(),
        physics=physics,
        workers=1,
    )
    return scale * np.asarray(curve.w0[0])


def write_object(rng, obj, rig, pressures, directory: Path, name: str, manometer: bool):
    from shelljax.session import write_session

    paths = []
    for k, pressure in enumerate(pressures):
        trial, force, depth, counts = [], [], [], []
        for t in range(1, N_TRIALS + 1):
            recorded = np.round(FORCE_LEVELS + rng.normal(0.0, 0.05, FORCE_LEVELS.size), 2)
            true = true_force(rig, recorded)
            order = np.argsort(true)
            w0 = np.empty_like(true)
            w0[order] = reality_w0(obj, rig, pressure, true[order])
            offset = rig.get("depth", {}).get("offset", 0.0)
            measured = (w0 + pad_compression(rig, true) + offset) * (1 + rng.normal(0.0, 0.02, true.size)) + rng.normal(
                0.0, 0.5e-3
            )
            trial += [t] * recorded.size
            force += recorded.tolist()
            depth += (np.round(measured * 2e3) / 2e3).tolist()
            mean = scaling_wrinkle_count(pressure, obj["radius"], obj["young_modulus"], obj["thickness"], POISSON)
            counts.append(int(round(float(mean) + rng.normal(0.0, 0.5))))
        path = directory / f"{name}_{k}.toml"
        radius, thickness = obj.get("measured_radius", obj["radius"]), obj.get("measured_thickness", obj["thickness"])
        write_session(
            path,
            object_name=name,
            radius=radius,
            radius_std=obj.get("radius_std", RADIUS_STD) * radius,
            thickness=thickness,
            thickness_std=THICKNESS_STD * thickness,
            trial=trial,
            force=force,
            depth=depth,
            wrinkle_counts=counts,
            poisson_ratio=POISSON,
            manometer_gauge_pressure=float(pressure * (1 + rng.normal(0.0, 0.01))) if manometer else None,
        )
        paths.append(path)
    return paths


def measured_geometry(obj, geometry_rng, radius_std: float = RADIUS_STD) -> dict:
    """``obj`` with the R and h its sessions record: the truth times (1 + their stated relative std × N(0, 1)).

    ``radius_std`` [-]: the relative std of R, as measured and as stated. ``geometry_rng`` None
    records the truth itself, which an interval that carries the stated std of R and h is bound
    to over-cover.
    """
    obj = {**obj, "radius_std": radius_std}
    if geometry_rng is None:
        return obj
    radius_error, thickness_error = geometry_rng.standard_normal(2) * (radius_std, THICKNESS_STD)
    return {
        **obj,
        "measured_radius": obj["radius"] * (1 + radius_error),
        "measured_thickness": obj["thickness"] * (1 + thickness_error),
    }


def make_rig_world(
    rng,
    n_imperfections: int,
    n_objects: int,
    directory: Path,
    geometry_rng=None,
    calibration_radius_std: float = RADIUS_STD,
):
    """Write one rig's calibration and test sessions; return (rig truth, calibration paths, tests).

    Each object's R and h are measured once (``measured_geometry``) and recorded in all its sessions.
    """
    from shelljax import NoConvergenceError

    directory.mkdir(parents=True, exist_ok=True)
    rig = draw_rig(rng, n_imperfections)
    for _ in range(5):
        try:
            obj = measured_geometry(draw_object(rng, (0.12, 0.2)), geometry_rng, calibration_radius_std)
            pressures = obj["low_pressure"] * np.array([1.0, 1.3, 1.65, 2.0])
            calibration = write_object(rng, obj, rig, pressures, directory, "calibration", manometer=True)
            break
        except NoConvergenceError:
            continue
    tests = []
    while len(tests) < n_objects:
        obj = measured_geometry(draw_object(rng, (0.08, 0.30), log_radius=True), geometry_rng)
        pressures = obj["low_pressure"] * np.array([1.0, rng.uniform(1.4, 2.0)])
        try:
            paths = write_object(rng, obj, rig, pressures, directory, f"object{len(tests)}", manometer=False)
        except NoConvergenceError:
            continue
        tests.append(dict(paths=paths, object=obj, pressures=pressures.tolist()))
    return rig, calibration, {"radius": obj["radius"]}, tests


def _errors(estimates, truth_p, truth_e):
    """Relative errors [%] and 95 % coverage of P_g and E, from (value, (low, high)) by name."""
    row = {}
    for key, name, truth in (("p", "gauge_pressure", truth_p), ("e", "young_modulus", truth_e)):
        if estimates.get(name) is not None:
            value, (lo, hi) = estimates[name]
            row.update({f"{key}_error": 100 * (value / truth - 1), f"{key}_covered": bool(lo <= truth <= hi)})
    return row


def _calibration_weighted(result):
    """The rig fit's per-model estimates mixed by the rig's weights alone (no update by the session)."""
    from shelljax.rig import normal_mixture

    ok = [m for m in result.models if m["status"] == "ok"]
    out = {}
    for name in ("gauge_pressure", "young_modulus"):
        center, lo, hi, _ = normal_mixture(
            [math.log(m["estimates"][name]["value"]) for m in ok],
            [m["estimates"][name]["relative_std"] for m in ok],
            [m["weight"] for m in ok],
        )
        out[name] = (math.exp(center), (math.exp(lo), math.exp(hi)))
    return out


def evaluate_session(path, truth_p, truth_e, rig_model, k_s, methods):
    """Every method's errors on one test session (a failure is recorded, not raised)."""
    from shelljax import ShelljaxError
    from shelljax.estimate import EstimatorOptions, estimate_session, run_estimator
    from shelljax.rig import estimate_with_rig
    from shelljax.session import load_session

    session = load_session(path)
    out = {}
    for method in methods:
        start = time.perf_counter()
        try:
            if method == "fit":
                est = run_estimator("fit", session, EstimatorOptions(gas="isothermal", wrinkle_law="scaling")).estimates
            elif method == "closed-form k_s":
                est = estimate_session(session, k_s=k_s, bootstrap_samples=0).estimates
            elif method == "fit+rig, object":
                continue  # estimated per object in run_rig
            else:
                result = estimate_with_rig(session, rig_model, method=method.split("+")[0])
                est = result.estimates
                if method == "fit+rig":
                    out[CALIBRATION_WEIGHTS] = {
                        **_errors(_calibration_weighted(result), truth_p, truth_e),
                        "seconds": 0.0,
                    }
                    out["rig_models"] = list(result.models)  # per model: weights, evidence, its own estimates
            pairs = {k: (v.value, v.ci95) for k, v in est.items() if k in ("gauge_pressure", "young_modulus")}
            out[method] = {**_errors(pairs, truth_p, truth_e), "seconds": time.perf_counter() - start}
        except ShelljaxError as err:
            out[method] = {"failed": str(err)[:300]}
    return out


def _object_estimate(test, rig) -> list[dict]:
    """Both sessions of a test object through the rig at once (shared E, h, R and rig terms): per session."""
    from shelljax import ShelljaxError
    from shelljax.rig import estimate_with_rig

    start = time.perf_counter()
    try:
        est = estimate_with_rig(test["paths"], rig).estimates
    except ShelljaxError as err:
        return [{"failed": str(err)[:300]}] * len(test["paths"])
    seconds = time.perf_counter() - start
    e = est["young_modulus"]
    return [
        {
            **_errors(
                {
                    "gauge_pressure": (est[f"gauge_pressure[{k}]"].value, est[f"gauge_pressure[{k}]"].ci95),
                    "young_modulus": (e.value, e.ci95),
                },
                p,
                test["object"]["young_modulus"],
            ),
            "seconds": seconds,
        }
        for k, p in enumerate(test["pressures"])
    ]


def evaluate_rig(index, world, methods, bayes_every: int, manometer_std: float) -> dict:
    """One rig's work item: calibrate it on its calibration files, then every method on its tests."""
    from shelljax.estimate import calibrate_ks
    from shelljax.rig import calibrate_rig
    from shelljax.session import load_session

    truth, calibration, tests = world["truth"], world["calibration"], world["tests"]
    start = time.perf_counter()
    rig = calibrate_rig(calibration, manometer_std=manometer_std, progress=False)
    seconds = time.perf_counter() - start
    k_s = calibrate_ks([load_session(p) for p in calibration]).k_s
    rows = []
    for test in tests:
        joint = _object_estimate(test, rig) if "fit+rig, object" in methods else {}
        for k, (path, pressure) in enumerate(zip(test["paths"], test["pressures"])):
            use = [m for m in methods if m != "bayes+rig" or k % bayes_every == 0]
            row = evaluate_session(path, pressure, test["object"]["young_modulus"], rig, k_s, use)
            if joint:
                row["fit+rig, object"] = joint[k]
            rows.append(
                dict(
                    radius=test["object"]["radius"],
                    pressure=pressure,
                    young_modulus=test["object"]["young_modulus"],
                    results=row,
                )
            )
    return dict(
        rig=index,
        truth=truth,
        families=sorted(truth),
        calibration_seconds=seconds,
        selected=[dict(terms=list(m.terms), weight=m.weight) for m in rig.models],
        not_identified=list(rig.not_identified),
        sessions=rows,
    )


def _with_true_families(rig) -> dict:
    """``rig`` with each session's results gaining ``TRUE_FAMILIES``: the estimates of the selected rig
    model whose term families are exactly the rig's true ones (none where selection kept no such
    model). Its 95 % interval is the model's own, value × exp(±1.96 × relative std)."""
    truth = set(rig["families"])
    sessions = []
    for row in rig["sessions"]:
        models = [
            m
            for m in row["results"].get("rig_models", [])
            if m.get("status") == "ok" and {TERM_FAMILY[t] for t in m["terms"]} == truth
        ]
        results = dict(row["results"])
        if models:
            est = models[0]["estimates"]
            pairs = {
                name: (
                    est[name]["value"],
                    (
                        est[name]["value"] * math.exp(-1.96 * est[name]["relative_std"]),
                        est[name]["value"] * math.exp(1.96 * est[name]["relative_std"]),
                    ),
                )
                for name in ("gauge_pressure", "young_modulus")
            }
            results[TRUE_FAMILIES] = {**_errors(pairs, row["pressure"], row["young_modulus"]), "seconds": 0.0}
        sessions.append({**row, "results": results})
    return {**rig, "sessions": sessions}


def _median_interval(rigs, method, key, draws: int = 2000) -> list[float]:
    """95 % bootstrap interval [%] of the median |error| of ``method`` over rigs: a rig's sessions share
    its calibration (and an object's sessions its R and h), so rigs are the independent draws."""
    per_rig = [
        np.array(
            [
                abs(r["results"][method][f"{key}_error"])
                for r in rig["sessions"]
                if method in r["results"] and f"{key}_error" in r["results"][method]
            ]
        )
        for rig in rigs
    ]
    per_rig = [errors for errors in per_rig if errors.size]
    rng = np.random.default_rng(0)
    samples = [
        np.median(np.concatenate([per_rig[i] for i in rng.integers(0, len(per_rig), len(per_rig))]))
        for _ in range(draws)
    ]
    return [float(np.percentile(samples, 2.5)), float(np.percentile(samples, 97.5))]


def summarize(rigs, methods):
    rigs = [_with_true_families(rig) for rig in rigs]

    def stats(group):
        rows = [r for rig in group for r in rig["sessions"]]
        out = {}
        for m in [*methods, CALIBRATION_WEIGHTS, TRUE_FAMILIES]:
            ok = [r["results"][m] for r in rows if m in r["results"] and "failed" not in r["results"][m]]
            failed = sum(1 for r in rows if m in r["results"] and "failed" in r["results"][m])
            if not ok:
                continue
            entry = dict(
                n=len(ok),
                failed=failed,
                median_abs_p_error=float(np.median([abs(o["p_error"]) for o in ok])),
                median_abs_p_error_ci95=_median_interval(group, m, "p"),
                p_coverage=float(np.mean([o["p_covered"] for o in ok])),
                p_coverage_ci95=_coverage_interval([o["p_covered"] for o in ok]),
            )
            with_e = [o for o in ok if "e_error" in o]
            if with_e:
                entry.update(
                    median_abs_e_error=float(np.median([abs(o["e_error"]) for o in with_e])),
                    median_abs_e_error_ci95=_median_interval(group, m, "e"),
                    e_coverage=float(np.mean([o["e_covered"] for o in with_e])),
                    e_coverage_ci95=_coverage_interval([o["e_covered"] for o in with_e]),
                )
            entry["median_seconds"] = float(np.median([o["seconds"] for o in ok]))
            out[m] = entry
        return out

    summary = {
        "rigs": len(rigs),
        "test_sessions": sum(len(rig["sessions"]) for rig in rigs),
        "all": stats(rigs),
        "clean": stats([rig for rig in rigs if not rig["families"]]),
    }
    for family in FAMILIES:
        summary[f"with_{family}"] = stats([rig for rig in rigs if family in rig["families"]])
    clean = [rig for rig in rigs if not rig["families"]]
    if {"fit", "fit+rig"} <= set(methods) and clean:
        summary["clean_fit+rig_minus_fit"] = _median_difference(clean, "fit+rig", "fit")
    summary["median_calibration_seconds"] = float(np.median([r["calibration_seconds"] for r in rigs]))
    return summary


def _coverage_interval(covered) -> list[float]:
    """Clopper-Pearson 95 % interval [-] of a coverage from its sessions' covered flags."""
    from scipy.stats import binomtest

    interval = binomtest(int(sum(covered)), len(covered)).proportion_ci(0.95)
    return [float(interval.low), float(interval.high)]


def _median_difference(rigs, method, baseline, draws: int = 2000) -> dict:
    """Median |error| of ``method`` minus ``baseline``'s [percentage points], P_g and E, with a 95 %
    bootstrap interval over test objects (an object's sessions share its R and h errors, so
    objects, not sessions, are the independent draws)."""
    objects = {}
    for rig in rigs:
        for row in rig["sessions"]:
            objects.setdefault((str(rig["rig"]), row["radius"]), []).append(row["results"])
    groups = [
        rows
        for rows in objects.values()
        if all(m in r and "failed" not in r[m] for r in rows for m in (method, baseline))
    ]
    rng = np.random.default_rng(0)
    out = {"objects": len(groups), "unit": "percentage points"}
    for key in ("p", "e"):

        def difference(picked):
            rows = [r for g in picked for r in g]
            return float(
                np.median([abs(r[method][f"{key}_error"]) for r in rows])
                - np.median([abs(r[baseline][f"{key}_error"]) for r in rows])
            )

        samples = [difference([groups[i] for i in rng.integers(0, len(groups), len(groups))]) for _ in range(draws)]
        out[key] = {
            "difference": difference(groups),
            "ci95": [float(np.percentile(samples, 2.5)), float(np.percentile(samples, 97.5))],
        }
    return out


def table(summary, methods) -> str:
    lines = [
        f"{summary['rigs']} rigs, {summary['test_sessions']} test sessions; median calibration "
        f"{summary['median_calibration_seconds']:.0f} s",
        f"{'group':>14s} {'method':>36s} {'n':>4s} {'|P_g err| med (95 % over rigs)':>30s} {'P cov95':>8s} "
        f"{'|E err| med (95 % over rigs)':>28s} {'E cov95':>8s}",
    ]
    for group in ("all", "clean") + tuple(f"with_{f}" for f in FAMILIES):
        for m, s in summary.get(group, {}).items():
            p_lo, p_hi = s["median_abs_p_error_ci95"]
            e_lo, e_hi = s.get("median_abs_e_error_ci95", (float("nan"),) * 2)
            lines.append(
                f"{group:>14s} {m:>36s} {s['n']:4d} {s['median_abs_p_error']:10.1f}% ({p_lo:4.1f} … {p_hi:4.1f} %) "
                f"{100 * s['p_coverage']:7.0f}% {s.get('median_abs_e_error', float('nan')):8.1f}% "
                f"({e_lo:4.1f} … {e_hi:4.1f} %) {100 * s.get('e_coverage', float('nan')):7.0f}%"
            )
    if "clean_fit+rig_minus_fit" in summary:
        d = summary["clean_fit+rig_minus_fit"]
        lines.append(
            f"clean rigs, fit+rig minus fit ({d['objects']} objects, bootstrap 95 %): "
            + ", ".join(
                f"{name} {d[k]['difference']:+.1f} ({d[k]['ci95'][0]:+.1f} … {d[k]['ci95'][1]:+.1f}) points"
                for k, name in (("p", "|P_g err|"), ("e", "|E err|"))
            )
        )
    return "\n".join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rigs", type=int, default=12)
    parser.add_argument("--objects", type=int, default=4, help="test objects per rig (2 pressures each)")
    parser.add_argument("--seed", type=int, default=46)
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    parser.add_argument("--bayes-every", type=int, default=2, help="bayes+rig on every n-th session of an object")
    parser.add_argument(
        "--manometer-std",
        type=float,
        default=0.01,
        help="the calibration's manometer accuracy, as the generator's noise (1 %%)",
    )
    parser.add_argument(
        "--exact-geometry",
        action="store_true",
        help="record each object's true R and h in its sessions (with the stated std all the same)",
    )
    parser.add_argument(
        "--calibration-radius-std",
        type=float,
        default=RADIUS_STD,
        help="relative std of the calibration ball's R, as measured and as its sessions state "
        "(default: the mesh's 2 %%; a tape round the equator: about 0.3 %%)",
    )
    add_executor_arguments(parser, resume=False)
    parser.add_argument(
        "--run-dir",
        default=None,
        help="write each finished rig's record here and skip the rigs already recorded (a killed "
        "study resumes where it stopped)",
    )
    parser.add_argument(
        "--combine",
        nargs="+",
        default=None,
        metavar="JSON",
        help="summarise the rigs of earlier studies' JSON outputs together (other seeds) into --out; runs nothing",
    )
    parser.add_argument(
        "--out", default=str(Path(__file__).resolve().parents[1] / "docs" / "bench" / "rig-transfer-study.json")
    )
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    if args.combine:
        return combine(args.combine, Path(args.out), args.methods)
    rng = np.random.default_rng(args.seed)
    # a stream of its own, so the rigs, objects and noise are the same draws with or without it
    geometry_rng = None if args.exact_geometry else np.random.default_rng([args.seed, 1])
    # imperfections per rig: 0, 1, 2, 3 in turn (every fourth rig is clean)
    counts = [i % 4 for i in range(args.rigs)]
    out = Path(args.out)
    with tempfile.TemporaryDirectory() as tmp:
        # the worlds are drawn here, one after the other from one stream, so that the rigs are the
        # same draws however many workers evaluate them
        worlds = []
        for i, n in enumerate(counts):
            truth, calibration, _, tests = make_rig_world(
                rng, n, args.objects, Path(tmp) / f"rig{i}", geometry_rng, args.calibration_radius_std
            )
            worlds.append(dict(truth=truth, calibration=[str(p) for p in calibration], tests=tests))
        items = [
            WorkItem(f"rig{i}", evaluate_rig, (i, world, args.methods, args.bayes_every, args.manometer_std))
            for i, world in enumerate(worlds)
        ]
        results = run_items(
            items,
            run_dir=args.run_dir,
            resume=args.run_dir is not None,
            options=executor_options(args),
            progress=True,
            desc="rigs",
        )
    failed = [r for r in results if r.status != "done"]
    for r in failed:
        print(f"{r.key} failed: {r.error}", flush=True)
    rigs = [r.value for r in results if r.status == "done"]
    for rig in rigs:
        print(f"rig {rig['rig']} {rig['truth']} -> {[m['terms'] for m in rig['selected'][:3]]}", flush=True)
    summary = summarize(rigs, args.methods)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        json.dumps(
            {"summary": summary, "seed": args.seed, "rigs": rigs, "failed": [r.to_dict() for r in failed]},
            indent=1,
            default=float,
        )
    )
    print(table(summary, args.methods))
    return 0


def combine(paths, out: Path, methods) -> int:
    """One summary over the rigs of several studies' JSON outputs (each rig keyed by its study's file
    name); ``out`` holds the summary and the studies' paths, not their rigs again."""
    rigs = []
    for path in paths:
        study = json.loads(Path(path).read_text())
        rigs += [{**rig, "rig": f"{Path(path).stem}/{rig['rig']}"} for rig in study["rigs"]]
    present = [m for m in methods if any(m in r["results"] for rig in rigs for r in rig["sessions"])]
    summary = summarize(rigs, present)
    out.write_text(json.dumps({"summary": summary, "studies": [str(p) for p in paths]}, indent=1, default=float))
    print(table(summary, present))
    return 0


if __name__ == "__main__":
    sys.exit(main())
