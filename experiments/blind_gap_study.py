"""Blind withheld-effect studies: does ``shelljax diagnose`` find the effect that made the data?

Each study is one random inflated ball (R, h, E, mass), measured at 3–4 pressures with manometer
readings under the paper's protocol (5–20 N in 2.5 N steps, three trials, one wrinkle count a
trial; three studies in four also measure the deformed shape at 10 and 20 N), with realistic noise, and
with one effect of the library at a random magnitude, or none. "Reality" is a finer model than the
diagnosis's: the axisymmetric engine at 201 meridian elements (the diagnosis uses 101), reached by
similarity from its own reference radius (0.15 m; the diagnosis's is 0.2 m).

The diagnosis sees only the session files, under neutral names; the labels stay in this script
until it scores the answers. Output: JSON (per study: truth, verdict, ranking head, gap, recovered
magnitude, P_g and E errors before and after) and a summary table (confusion matrix, attribution
accuracy, false alarms, median shrink, magnitude coverage).

Noise (as the bundled sessions, shelljax/data/README.md): recorded force = level + N(0, 0.05 N),
0.01 N resolution; depth = w0 (1 + N(0, 2 %)) + N(0, 0.5 mm) per trial, 0.5 mm resolution;
count = round(1.33 τ^½ + N(0, 0.5)); manometer = P_g (1 + N(0, 1 %)); shape observables
+ N(0, 1 mm), 0.5 mm resolution.

The studies are drawn first, one after the other from one stream; each diagnosis is then one work
item (``shelljax.executor``), so ``--workers N`` or ``--cluster`` give the same results as a serial run.

Run:  python experiments/blind_gap_study.py --studies 48 --out docs/bench/blind-gap-study.json
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from shelljax.executor import WorkItem, add_executor_arguments, executor_options, run_items
from shelljax.paper import DEFAULT_POISSON_RATIO, PAPER_FORCES, PAPER_INDENTER_RADIUS
from shelljax.physics import PolytropicGas, ShellProperties, scaling_wrinkle_count

FORCE_LEVELS = np.asarray(PAPER_FORCES)  # [N]
SHAPE_FORCES = (10.0, 20.0)  # [N]
N_TRIALS = 3
REALITY_RADIUS = 0.15  # [m] the generator's engine radius (similarity to every R)
REALITY_ELEMENTS = 201
POISSON = DEFAULT_POISSON_RATIO
MAX_REDRAWS = 5
# effect: (parameter, sampler of its true value). Magnitudes are plausible and large enough to
# move some observable by several noise std at the protocol's noise (docs/sim-to-real.md lists
# the ranges); below that no method can attribute them, and "none" is the right answer.
EFFECTS = {
    "none": (None, None),
    "finger_compliance": ("finger_compliance", lambda r: r.uniform(0.3e-3, 1.0e-3)),
    "depth_offset": ("depth_offset", lambda r: r.choice([-1, 1]) * r.uniform(3e-3, 8e-3)),
    "force_sensor_gain": ("force_gain", lambda r: r.choice([r.uniform(0.6, 0.8), r.uniform(1.25, 1.6)])),
    "force_sensor_nonlinearity": ("force_exponent", lambda r: r.choice([r.uniform(0.7, 0.82), r.uniform(1.18, 1.3)])),
    "indenter_size": ("indenter_radius", lambda r: r.uniform(25e-3, 45e-3)),
    "gas": ("gas_exponent", lambda r: r.uniform(0.0, 0.2)),
    "material_stiffening": ("stiffening", lambda r: r.uniform(30.0, 60.0)),
    "wall_thickness": ("thickness_factor", lambda r: r.choice([r.uniform(0.45, 0.6), r.uniform(1.7, 2.3)])),
    "self_weight": ("body_mass", None),  # the object's own mass, as the session states it
    "ground_friction": ("friction_coefficient", lambda r: r.uniform(0.3, 1.0)),
}


def draw_object(rng):
    """A random ball: R [m], h [m], E [Pa], base pressure [Pa], pressures [Pa], mass [kg]."""
    radius = rng.uniform(0.1, 0.3)
    thickness = rng.uniform(0.6e-3, 2.0e-3)
    young = math.exp(rng.uniform(math.log(1.0e6), math.log(5.0e6)))
    low = max(700.0, 16.0 / radius**2)
    n_pressures = int(rng.choice([3, 4]))
    pressures = low * rng.uniform(1.0, 1.3) * np.array([1.0, 1.3, 1.65, 2.0])[:n_pressures]
    mass = rng.uniform(0.3, 1.2)  # [kg] wall, valve and print: the bundled balls weigh 0.1–1.1 kg
    return dict(radius=radius, thickness=thickness, young_modulus=young, pressures=pressures, mass=mass)


def reality_curves(obj, truth, pressure, true_forces):
    """Noise-free reality at increasing true forces [N]: w0 [m] and shape observables [m]."""
    from shelljax.axisym import CurvePhysics, indentation_curves, inflation_stretch
    from shelljax.physics import STANDARD_GRAVITY

    scale = obj["radius"] / REALITY_RADIUS
    thickness = obj["thickness"] * truth.get("thickness_factor", 1.0)
    stretch = float(inflation_stretch(pressure, obj["radius"], obj["young_modulus"], thickness, POISSON))
    mass = truth.get("body_mass", 0.0)
    areal_weight = mass * STANDARD_GRAVITY / (4 * math.pi * (obj["radius"] / stretch) ** 2)
    physics = CurvePhysics(
        indenter_radius=np.array([truth.get("indenter_radius", PAPER_INDENTER_RADIUS) / scale]),
        gas_volume_ratio=np.ones(1),
        gas_exponent=np.array([truth.get("gas_exponent", 1.0)]),
        stiffening=np.array([truth.get("stiffening", 0.0)]),
        areal_weight=np.array([areal_weight]),
        friction_coefficient=np.array([truth.get("friction_coefficient", 0.0)]),
    )
    shell = ShellProperties(
        gauge_pressure=pressure,
        young_modulus=obj["young_modulus"],
        thickness=thickness / scale,
        poisson_ratio=POISSON,
        radius=REALITY_RADIUS,
    )
    curve = indentation_curves(
        shell,
        np.asarray(true_forces) / scale**2,
        n_elements=REALITY_ELEMENTS,
        gas=PolytropicGas(),
        physics=physics,
        workers=1,
    )
    return {
        k: scale * np.asarray(getattr(curve, k)[0])
        for k in ("w0", "height", "upper_diameter", "contact_diameter", "sunken_depth")
    }


def make_study(rng, effect: str, directory: Path, with_shape: bool):
    """Write the study's sessions into ``directory``; return (paths, truth)."""
    from shelljax.session import write_session

    obj = draw_object(rng)
    parameter, sampler = EFFECTS[effect]
    truth = {} if parameter is None else {parameter: float(sampler(rng)) if sampler else obj["mass"]}
    force_ref = math.sqrt(FORCE_LEVELS[0] * FORCE_LEVELS[-1])
    gain, exponent = truth.get("force_gain", 1.0), truth.get("force_exponent", 1.0)
    thickness = obj["thickness"] * truth.get("thickness_factor", 1.0)
    paths = []
    for k, pressure in enumerate(obj["pressures"]):
        trial, force, depth, counts, shape_rows = [], [], [], [], []
        for t in range(1, N_TRIALS + 1):
            recorded = np.round(FORCE_LEVELS + rng.normal(0.0, 0.05, FORCE_LEVELS.size), 2)
            true = gain * force_ref * (recorded / force_ref) ** exponent
            points = np.concatenate([true, gain * force_ref * (np.array(SHAPE_FORCES) / force_ref) ** exponent])
            unique, inverse = np.unique(points, return_inverse=True)
            at = {key: v[inverse] for key, v in reality_curves(obj, truth, pressure, unique).items()}
            w0 = at["w0"][: recorded.size]
            measured = (w0 + truth.get("depth_offset", 0.0) + truth.get("finger_compliance", 0.0) * true) * (
                1 + rng.normal(0.0, 0.02, recorded.size)
            ) + rng.normal(0.0, 0.5e-3)
            trial += [t] * recorded.size
            force += recorded.tolist()
            depth += (np.round(measured * 2e3) / 2e3).tolist()
            mean_count = scaling_wrinkle_count(pressure, obj["radius"], obj["young_modulus"], thickness, POISSON)
            counts.append(int(round(float(mean_count) + rng.normal(0.0, 0.5))))
            if with_shape:
                for j, f in enumerate(SHAPE_FORCES):
                    row = {
                        key: float(np.round((at[key][recorded.size + j] + rng.normal(0, 1e-3)) * 2e3) / 2e3)
                        for key in ("height", "upper_diameter", "contact_diameter", "sunken_depth")
                    }
                    row["sunken_depth"] = max(row["sunken_depth"], 0.0)
                    shape_rows.append((t, f, row))
        shape = None
        if shape_rows:
            shape = {"trial": [r[0] for r in shape_rows], "force": [r[1] for r in shape_rows]}
            for key in ("height", "upper_diameter", "contact_diameter"):
                shape[key] = [r[2][key] for r in shape_rows]
        path = directory / f"session_{k}.toml"
        write_session(
            path,
            object_name="ball",
            radius=obj["radius"],
            radius_std=0.02 * obj["radius"],
            thickness=obj["thickness"],
            thickness_std=0.05 * obj["thickness"],
            trial=trial,
            force=force,
            depth=depth,
            wrinkle_counts=counts,
            mass=round(obj["mass"] * (1 + rng.normal(0.0, 0.02)), 3),
            manometer_gauge_pressure=float(pressure * (1 + rng.normal(0.0, 0.01))),
            poisson_ratio=POISSON,
            shape=shape,
        )
        paths.append(path)
    return paths, dict(
        effect=effect,
        truth=truth,
        object={k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in obj.items()},
        shape=with_shape,
    )


def recovered_magnitude(report, effect, true_value):
    """(covered, value, ci95, truth) of the winning effect's parameter (None unless it won)."""
    from shelljax.diagnose import EFFECTS as LIBRARY

    if effect == "none" or report["verdict"] != effect:
        return None
    entry = next(e for e in report["ranking"] if e["effect"] == effect)
    est = entry["parameters"][LIBRARY[effect].parameters[0]]
    return dict(
        covered=bool(est["ci95"][0] <= true_value <= est["ci95"][1]),
        value=est["value"],
        ci95=est["ci95"],
        truth=true_value,
    )


def diagnose_study(index, effect, paths, label) -> dict:
    """One study's work item: the diagnosis of its files, scored against the label it never sees."""
    from shelljax import NoConvergenceError
    from shelljax.diagnose import diagnose

    start = time.perf_counter()
    try:
        diag = diagnose(paths, progress=False)  # the diagnosis sees the files only
    except NoConvergenceError as err:
        return dict(study=index, effect=effect, truth=label["truth"], verdict="failed", error=str(err))
    seconds = time.perf_counter() - start
    report = diag.report
    parameter = EFFECTS[effect][0]
    true_value = label["truth"].get(parameter)
    if parameter == "thickness_factor":  # the diagnosis reports h itself
        true_value *= label["object"]["thickness"]
    truth_p = np.asarray(label["object"]["pressures"])
    before = report["baseline"]["estimates"]
    after = report["winner"]["estimates_after"] if report["winner"] else before
    true_e = label["object"]["young_modulus"]
    return dict(
        study=index,
        effect=effect,
        truth=label["truth"],
        shape=label["shape"],
        verdict=report["verdict"],
        seconds=seconds,
        shrink=report["shrink"],
        gap_before=report["gap_before"]["rms_standardized"],
        gap_after=report["gap_after"]["rms_standardized"],
        ranking=[(e["effect"], e["delta"], e["delta_se"]) for e in report["ranking"][:4]],
        magnitude=recovered_magnitude(report, effect, true_value),
        pressure_error_before=[100 * (b["value"] / t - 1) for b, t in zip(before["gauge_pressure"], truth_p)],
        pressure_error_after=[100 * (a["value"] / t - 1) for a, t in zip(after["gauge_pressure"], truth_p)],
        modulus_error_before=100 * (before["young_modulus"]["value"] / true_e - 1),
        modulus_error_after=100 * (after["young_modulus"]["value"] / true_e - 1),
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--studies", type=int, default=48)
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--effects", nargs="+", default=list(EFFECTS))
    add_executor_arguments(parser, resume=False)
    parser.add_argument(
        "--out", default=str(Path(__file__).resolve().parents[1] / "docs" / "bench" / "blind-gap-study.json")
    )
    args = parser.parse_args()
    from shelljax import NoConvergenceError

    rng = np.random.default_rng(args.seed)
    names = [args.effects[i % len(args.effects)] for i in range(args.studies)]
    rng.shuffle(names)
    out = Path(args.out)
    with tempfile.TemporaryDirectory() as tmp:
        # the studies are drawn here, one after the other from one stream, so that they are the
        # same draws however many workers diagnose them
        items = []
        for i, effect in enumerate(names):
            directory = Path(tmp) / f"study{i}"
            directory.mkdir()
            for _ in range(MAX_REDRAWS):
                try:
                    paths, label = make_study(rng, effect, directory, with_shape=i % 4 != 0)
                    break
                except NoConvergenceError as err:  # reality has no ball state there: draw another object
                    print(f"    redrawn: {str(err).splitlines()[0][:100]}", flush=True)
            items.append(WorkItem(f"study{i}", diagnose_study, (i, effect, [str(p) for p in paths], label)))
        done = run_items(items, options=executor_options(args), progress=True, desc="studies")
    results = [
        r.value if r.status == "done" else dict(study=i, effect=names[i], verdict="failed", error=r.error)
        for i, r in enumerate(done)
    ]
    for row in results:
        if row["verdict"] == "failed":
            print(f"[{row['study'] + 1}/{len(names)}] {row['effect']:>26s} -> FAILED: {row['error'][:120]}", flush=True)
        else:
            print(
                f"[{row['study'] + 1}/{len(names)}] {row['effect']:>26s} -> {row['verdict']:<26s} "
                f"shrink {row['shrink']:.2f}  {row['seconds']:.0f} s",
                flush=True,
            )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"summary": summarize(results), "studies": results}, indent=1, default=float))
    print(table(summarize(results)))


def summarize(results):
    labels = sorted({r["effect"] for r in results} | {r["verdict"] for r in results})
    confusion = {
        t: {p: sum(1 for r in results if r["effect"] == t and r["verdict"] == p) for p in labels}
        for t in sorted({r["effect"] for r in results})
    }
    with_effect = [r for r in results if r["effect"] != "none"]
    none = [r for r in results if r["effect"] == "none"]
    mags = [r["magnitude"] for r in with_effect if r.get("magnitude") is not None]
    ok = [r for r in results if r["verdict"] != "failed"]
    rms = lambda xs: float(np.sqrt(np.mean(np.square(xs)))) if len(xs) else None  # noqa: E731
    return dict(
        studies=len(results),
        effects=len({r["effect"] for r in results}) - (1 if none else 0),
        attribution_accuracy=float(np.mean([r["verdict"] == r["effect"] for r in results])),
        attribution_accuracy_with_effect=float(np.mean([r["verdict"] == r["effect"] for r in with_effect]))
        if with_effect
        else None,
        false_alarm_rate=float(np.mean([r["verdict"] not in ("none",) for r in none])) if none else None,
        median_shrink_with_effect=float(np.median([r.get("shrink", 1.0) for r in with_effect]))
        if with_effect
        else None,
        failed=sum(r["verdict"] == "failed" for r in results),
        magnitude_coverage=float(np.mean([m["covered"] for m in mags])) if mags else None,
        magnitude_count=len(mags),
        pressure_rms_error_percent_before=rms([e for r in ok for e in r["pressure_error_before"]]),
        pressure_rms_error_percent_after=rms([e for r in ok for e in r["pressure_error_after"]]),
        modulus_rms_error_percent_before=rms([r["modulus_error_before"] for r in ok]),
        modulus_rms_error_percent_after=rms([r["modulus_error_after"] for r in ok]),
        median_seconds=float(np.median([r["seconds"] for r in ok])) if ok else None,
        confusion=confusion,
    )


def table(summary):
    lines = [f"{k}: {v}" for k, v in summary.items() if k != "confusion"]
    labels = sorted({p for row in summary["confusion"].values() for p in row})
    lines.append("confusion (rows: truth, columns: verdict)")
    lines.append(" " * 26 + " ".join(f"{p[:6]:>6s}" for p in labels))
    for t, row in summary["confusion"].items():
        lines.append(f"{t:>26s}" + " ".join(f"{row.get(p, 0):6d}" for p in labels))
    return "\n".join(lines)


if __name__ == "__main__":
    main()
