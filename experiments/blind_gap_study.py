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

**Withheld forms** (``--withheld``): effects whose form the library does not share, each study one
ball at two pressures with shape data. A power-law sensor about a reference force other than the
diagnosis's (F_true = F_r (F_rec/F_r)^p, F_r 3 N or 30 N: a gain and an exponent at once); a
saturating sensor (F_rec = F_s tanh(F_true/F_s)); a pad compressing as c F^(2/3) (Hertzian); two
library effects at once. Each is scored by the models that count as its attribution (``right``),
and is *identifiable* when, on its noise-free data under the noisy study's noise model, the best of
those models beats the baseline by ≥ 4 nats. Output adds, per study: E inside the robust range,
the truth among the models not excluded, the refits that failed, E's error after the diagnosis.

Run:  python experiments/blind_gap_study.py --studies 48 --out docs/bench/blind-gap-study.json
      python experiments/blind_gap_study.py --withheld --studies 20 --out docs/bench/withheld-form-study.json
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
SENSOR_EXPONENT = lambda r: r.choice([r.uniform(0.7, 0.82), r.uniform(1.18, 1.3)])  # noqa: E731
# withheld form: (sampler of the truth, the models that count as its attribution (a verdict holding every
# effect of one of them; the first ones, in the library's form, also decide whether it is identifiable))
WITHHELD = {
    "none": (lambda r: {}, ()),
    "sensor_reference": (
        lambda r: {"force_exponent": SENSOR_EXPONENT(r), "force_reference": float(r.choice([3.0, 30.0]))},
        ("force_sensor_gain+force_sensor_nonlinearity", "force_sensor_nonlinearity"),
    ),
    "sensor_saturation": (
        lambda r: {"saturation_force": r.uniform(24.0, 40.0)},
        ("force_sensor_nonlinearity", "force_sensor_gain+force_sensor_nonlinearity", "force_sensor_gain"),
    ),
    "pad_two_thirds": (
        lambda r: {"pad_two_thirds": r.uniform(0.8e-3, 2.5e-3)},  # [m/N^(2/3)]: 6-18 mm at 20 N
        ("finger_compliance", "finger_compliance+depth_offset"),
    ),
    "gain_and_pad": (
        lambda r: {
            "force_gain": float(EFFECTS["force_sensor_gain"][1](r)),
            "finger_compliance": r.uniform(0.3e-3, 1e-3),
        },
        ("finger_compliance+force_sensor_gain",),
    ),
    "offset_and_stiffening": (
        lambda r: {"depth_offset": r.choice([-1, 1]) * r.uniform(3e-3, 8e-3), "stiffening": r.uniform(30.0, 60.0)},
        ("depth_offset+material_stiffening",),
    ),
}


def draw_object(rng, n_pressures=None):
    """A random ball: R [m], h [m], E [Pa], base pressure [Pa], pressures [Pa], mass [kg]."""
    radius = rng.uniform(0.1, 0.3)
    thickness = rng.uniform(0.6e-3, 2.0e-3)
    young = math.exp(rng.uniform(math.log(1.0e6), math.log(5.0e6)))
    low = max(700.0, 16.0 / radius**2)
    n_pressures = int(rng.choice([3, 4])) if n_pressures is None else n_pressures
    steps = np.array([1.0, 1.3, 1.65, 2.0])[:n_pressures] if n_pressures > 2 else np.array([1.0, 2.0])
    pressures = low * rng.uniform(1.0, 1.3) * steps
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


def true_force(recorded, truth):
    """The force [N] the sensor's reading ``recorded`` [N] stands for under ``truth``'s sensor."""
    force_ref = truth.get("force_reference", math.sqrt(FORCE_LEVELS[0] * FORCE_LEVELS[-1]))
    gain, exponent = truth.get("force_gain", 1.0), truth.get("force_exponent", 1.0)
    force = gain * force_ref * (np.asarray(recorded) / force_ref) ** exponent
    if "saturation_force" in truth:  # F_rec = F_s tanh(F_true / F_s)
        force = truth["saturation_force"] * np.arctanh(force / truth["saturation_force"])
    return force


def draw_truth(rng, effect: str, obj: dict) -> dict:
    """The effect's true parameters (a library effect's, or a withheld form's)."""
    if effect in WITHHELD:
        return {k: float(v) for k, v in WITHHELD[effect][0](rng).items()}
    parameter, sampler = EFFECTS[effect]
    return {} if parameter is None else {parameter: float(sampler(rng)) if sampler else obj["mass"]}


def _noise(rng, size: int, noisy: bool, std: float):
    return rng.normal(0.0, std, size) if noisy else np.zeros(size)


def make_study(rng, effect: str, directory: Path, with_shape: bool, n_pressures=None, noisy=True, drawn=None):
    """Write the study's sessions into ``directory``; return (paths, truth). ``n_pressures``: how many
    (None: 3 or 4 at random); ``noisy`` False: the same study without noise (forces at their levels,
    exact readings), for ``drawn`` = (object, truth) of the noisy one."""
    from shelljax.session import write_session

    obj = draw_object(rng, n_pressures) if drawn is None else drawn[0]
    truth = draw_truth(rng, effect, obj) if drawn is None else drawn[1]
    thickness = obj["thickness"] * truth.get("thickness_factor", 1.0)
    paths = []
    for k, pressure in enumerate(obj["pressures"]):
        trial, force, depth, counts, shape_rows = [], [], [], [], []
        for t in range(1, N_TRIALS + 1):
            recorded = np.round(FORCE_LEVELS + _noise(rng, FORCE_LEVELS.size, noisy, 0.05), 2)
            true = true_force(recorded, truth)
            points = np.concatenate([true, true_force(SHAPE_FORCES, truth)])
            unique, inverse = np.unique(points, return_inverse=True)
            at = {key: v[inverse] for key, v in reality_curves(obj, truth, pressure, unique).items()}
            w0 = at["w0"][: recorded.size]
            pad = truth.get("finger_compliance", 0.0) * true + truth.get("pad_two_thirds", 0.0) * true ** (2 / 3)
            measured = (w0 + truth.get("depth_offset", 0.0) + pad) * (
                1 + _noise(rng, recorded.size, noisy, 0.02)
            ) + _noise(rng, 1, noisy, 0.5e-3)
            trial += [t] * recorded.size
            force += recorded.tolist()
            depth += (np.round(measured * 2e3) / 2e3 if noisy else measured).tolist()
            mean_count = scaling_wrinkle_count(pressure, obj["radius"], obj["young_modulus"], thickness, POISSON)
            counts.append(int(round(float(mean_count) + _noise(rng, 1, noisy, 0.5)[0])))
            if with_shape:
                for j, f in enumerate(SHAPE_FORCES):
                    row = {
                        key: float(np.round((at[key][recorded.size + j] + _noise(rng, 1, noisy, 1e-3)[0]) * 2e3) / 2e3)
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
            mass=round(obj["mass"] * (1 + _noise(rng, 1, noisy, 0.02)[0]), 3),
            manometer_gauge_pressure=float(pressure * (1 + _noise(rng, 1, noisy, 0.01)[0])),
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

    if effect == "none" or effect not in EFFECTS or report["verdict"] != effect:
        return None
    entry = next(e for e in report["ranking"] if e["effect"] == effect)
    est = entry["parameters"][LIBRARY[effect].parameters[0]]
    return dict(
        covered=bool(est["ci95"][0] <= true_value <= est["ci95"][1]),
        value=est["value"],
        ci95=est["ci95"],
        truth=true_value,
    )


def best_library_gain(clean_paths, noisy_study, models) -> float | None:
    """The largest Δ elpd [nats] over the baseline of ``models`` (library names) on the noise-free
    sessions ``clean_paths``, under ``noisy_study``'s noise model (None: no model to try)."""
    from shelljax.diagnose import build_study, candidate_data, fit_candidate, loo_score, study_arrays
    from shelljax.diagnose.internal import object_unknowns
    from shelljax.session import load_session

    if not models:
        return None
    noise = (noisy_study.trial_offset_std, noisy_study.depth_noise)
    study = build_study([load_session(p) for p in clean_paths], noise)
    base, free = study_arrays(study), object_unknowns(study)
    baseline = fit_candidate(candidate_data(base, None, free), "scaling", np.zeros(base.free.shape[0]))
    gains = []
    for name in models:
        fit = fit_candidate(candidate_data(base, name, free), "scaling", baseline.u)
        if fit.converged and baseline.converged:
            gains.append(float(np.sum(loo_score(fit).elpd - loo_score(baseline).elpd)))
    return max(gains) if gains else None


def right_attribution(effect: str, verdict: str) -> bool:
    """Whether ``verdict`` attributes the study's ``effect``: the same name, or, for a withheld form,
    a verdict holding every effect of one of the models that count as its attribution."""
    if effect not in WITHHELD or effect == "none":
        return verdict == effect
    held = set(verdict.split("+"))
    return any(set(model.split("+")) <= held for model in WITHHELD[effect][1])


def _true_value(effect: str, label: dict):
    parameter = EFFECTS[effect][0] if effect in EFFECTS else None
    true_value = label["truth"].get(parameter)
    if parameter == "thickness_factor":  # the diagnosis reports h itself
        true_value *= label["object"]["thickness"]
    return true_value


def _robust_record(report: dict, effect: str, true_e: float) -> dict:
    """E inside the robust range, the truth among the models not excluded, the refits that failed."""
    robust = report["robust"]["young_modulus"]["range95"]
    kept = [k["effect"] for k in report["not_excluded"]]
    truth_models = ("baseline",) if effect == "none" else WITHHELD[effect][1] if effect in WITHHELD else (effect,)
    return dict(
        modulus_covered=bool(robust[0] <= true_e <= robust[1]),
        robust_modulus_range=robust,
        truth_not_excluded=any(set(m.split("+")) in [set(k.split("+")) for k in kept] for m in truth_models),
        failed_refits=[e["effect"] for e in report["ranking"] if e["status"] != "ok"],
        search=report.get("search"),
        warning=report["robust"].get("warning"),
    )


def diagnose_study(index, effect, paths, label, clean_paths=None) -> dict:
    """One study's work item: the diagnosis of its files, scored against the label it never sees
    (and, with ``clean_paths``, whether its effect is identifiable on the noise-free data)."""
    from shelljax import NoConvergenceError
    from shelljax.diagnose import diagnose

    start = time.perf_counter()
    try:
        diag = diagnose(paths, progress=False)  # the diagnosis sees the files only
    except NoConvergenceError as err:
        return dict(study=index, effect=effect, truth=label["truth"], verdict="failed", error=str(err))
    seconds = time.perf_counter() - start
    report = diag.report
    true_value = _true_value(effect, label)
    gain = None
    if clean_paths is not None and effect in WITHHELD:
        gain = best_library_gain(clean_paths, diag.study, WITHHELD[effect][1])
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
        right=right_attribution(effect, report["verdict"]),
        noise_free_gain=gain,
        identifiable=None if gain is None else gain >= 4.0,
        n_pressures=len(label["object"]["pressures"]),
        **_robust_record(report, effect, label["object"]["young_modulus"]),
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


def withheld_study(index: int, effect: str, seed: int, log: str | None) -> dict:
    """One withheld-form study's work item: drawn from its own stream (seed, index), so any number of
    workers gives the same studies; two pressures, shape data, and its noise-free twin. Its row is
    appended to ``log`` (JSON lines) as soon as it is done."""
    from shelljax import NoConvergenceError

    rng = np.random.default_rng([seed, index])
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(MAX_REDRAWS):
            try:
                paths, label = make_study(rng, effect, Path(tmp), with_shape=True, n_pressures=2)
                break
            except NoConvergenceError as err:  # reality has no ball state there: draw another object
                print(f"    redrawn: {str(err).splitlines()[0][:100]}", flush=True)
        clean = Path(tmp) / "noise_free"
        clean.mkdir()
        drawn = ({**label["object"], "pressures": np.asarray(label["object"]["pressures"])}, label["truth"])
        clean_paths, _ = make_study(rng, effect, clean, with_shape=True, noisy=False, drawn=drawn)
        row = diagnose_study(index, effect, [str(p) for p in paths], label, [str(p) for p in clean_paths])
    if log is not None:
        with open(log, "a") as f:
            f.write(json.dumps(row, default=float) + "\n")
    return row


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--studies", type=int, default=48)
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--effects", nargs="+", default=None, help="default: every effect (or withheld form)")
    parser.add_argument("--withheld", action="store_true", help="withheld forms at two pressures (module docstring)")
    parser.add_argument("--log", default=None, help="JSON lines, one per finished withheld-form study")
    parser.add_argument("--from-log", default=None, help="summarize this --log's studies into --out, run nothing")
    add_executor_arguments(parser, resume=False)
    parser.add_argument(
        "--out", default=str(Path(__file__).resolve().parents[1] / "docs" / "bench" / "blind-gap-study.json")
    )
    args = parser.parse_args()
    effects = args.effects or list(WITHHELD if args.withheld else EFFECTS)
    names = [effects[i % len(effects)] for i in range(args.studies)]
    if args.from_log:
        rows = [json.loads(line) for line in Path(args.from_log).read_text().splitlines() if line.strip()]
        return write_results(sorted(rows, key=lambda r: r["study"]), Path(args.out))
    if args.withheld:
        items = [WorkItem(f"study{i}", withheld_study, (i, e, args.seed, args.log)) for i, e in enumerate(names)]
        done = run_items(items, options=executor_options(args), progress=True, desc="studies")
        return write_results(_rows(done, names), Path(args.out))
    from shelljax import NoConvergenceError

    rng = np.random.default_rng(args.seed)
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
    write_results(_rows(done, names), out)


def _rows(done, names) -> list[dict]:
    return [
        r.value if r.status == "done" else dict(study=i, effect=names[i], verdict="failed", error=r.error)
        for i, r in enumerate(done)
    ]


def write_results(results: list[dict], out: Path) -> None:
    """Print one line per study and the summary table; write the JSON to ``out``."""
    n = len(results)
    for row in results:
        if row["verdict"] == "failed":
            print(f"[{row['study'] + 1}/{n}] {row['effect']:>26s} -> FAILED: {row['error'][:120]}", flush=True)
        else:
            print(
                f"[{row['study'] + 1}/{n}] {row['effect']:>26s} -> {row['verdict']:<26s} "
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
        attribution_accuracy=float(np.mean([_right(r) for r in results])),
        attribution_accuracy_with_effect=float(np.mean([_right(r) for r in with_effect])) if with_effect else None,
        **_withheld_summary(results),
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


def _right(row) -> bool:
    return row.get("right", row["verdict"] == row["effect"])


def _withheld_summary(results) -> dict:
    """Coverage of E by the robust range, attribution where identifiable, refits that failed, |E error|
    after the diagnosis: the withheld-form study's targets (docs/sim-to-real.md)."""
    ok = [r for r in results if r["verdict"] != "failed" and "modulus_covered" in r]
    if not ok:
        return {}
    identifiable = [r for r in ok if r.get("identifiable")]
    with_effect = [r for r in ok if r["effect"] != "none"]
    return dict(
        modulus_coverage_by_robust_range=float(np.mean([r["modulus_covered"] for r in ok])),
        modulus_covered_count=f"{sum(r['modulus_covered'] for r in ok)}/{len(ok)}",
        truth_not_excluded=float(np.mean([r["truth_not_excluded"] for r in ok])),
        identifiable_count=len(identifiable),
        attribution_where_identifiable=float(np.mean([r["right"] for r in identifiable])) if identifiable else None,
        studies_with_failed_refits=sum(bool(r["failed_refits"]) for r in ok),
        failed_refits=sum(len(r["failed_refits"]) for r in ok),
        median_abs_modulus_error_percent_before=float(np.median([abs(r["modulus_error_before"]) for r in with_effect]))
        if with_effect
        else None,
        median_abs_modulus_error_percent_after=float(np.median([abs(r["modulus_error_after"]) for r in with_effect]))
        if with_effect
        else None,
        median_seconds_two_pressures=float(np.median([r["seconds"] for r in ok if r.get("n_pressures") == 2]))
        if any(r.get("n_pressures") == 2 for r in ok)
        else None,
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
