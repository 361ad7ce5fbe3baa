"""What a study cannot exclude: the candidates the best one does not beat, the range of P_g and E
over them, and which extra measurement would tell them apart.

A candidate is excluded when the best model beats it by the decision margin (Δ elpd ≥ 4 nats and
≥ 2 SE, as a winner must beat the baseline). Over the rest (``not_excluded``), ``robust`` spans
every one's 95 % interval of P_g (per session) and E; a verdict — `none` included — is only as sure
as that range. The range also covers the chosen model's expansions (the search's next models, one
effect more) that the margin did not let in (``expansion_widening``): all of them when the chosen
model's held-out residuals still show structure (its χ² p-value or a misfit group of its
where-table), and any one that moves E beyond the chosen model's 95 % interval; a decisive
verdict's best expansion is always covered, so the range never contradicts it. ``separating`` names, for each candidate not excluded besides the chosen model, the
measurement that would tell it from the chosen one, and the factor by which E's 95 % interval
would shrink once it did (from the robust range to the chosen model's own interval).
"""

from __future__ import annotations

import math

import numpy as np

# the measurement that separates a candidate from the rest, by the observable it moves most
SEPARATING_MEASUREMENT = {
    "baseline": "none needed beyond the other candidates' measurements",
    "finger_compliance": "a rigid-surface press (the pad's compression alone)",
    "depth_offset": "a rigid-surface press (the depth gauge's zero)",
    "force_sensor_gain": "a second pressure with a manometer, or the sensor checked against weights",
    "force_sensor_nonlinearity": "the sensor checked against weights across 5-20 N",
    "indenter_size": "a second finger size (or a rigid sphere of known radius)",
    "gas": "shape observables (H, D_u, D_l, d at 10 and 20 N)",
    "material_stiffening": "deeper indentation (forces above 20 N)",
    "wall_thickness": "a calliper reading of h on a squeezed fold",
    "self_weight": "the object's mass",
    "ground_friction": "shape observables (the contact diameter D_l)",
}
SPREAD_WARNING = 1.5  # the robust E range this many times the chosen model's interval deserves a warning


def not_excluded(ranking: list[dict], scores: dict, win_nats: float, win_se: float) -> list[dict]:
    """Every converged model the best one does not beat by the margin: {effect, delta_to_best, se}."""
    ok = [e for e in ranking if e["status"] == "ok"]
    best = scores[ok[0]["effect"]].elpd
    out = []
    for entry in ok:
        diff = best - scores[entry["effect"]].elpd
        delta, se = float(diff.sum()), float(math.sqrt(diff.size * np.var(diff)))
        if not (delta >= win_nats and delta >= win_se * se):
            out.append({"effect": entry["effect"], "delta_to_best": -delta, "delta_to_best_se": se, "unit": "nats"})
    return out


def expansion_widening(
    expansions: list[str], estimates: dict, chosen: str, structure: list[str], decisive: bool
) -> list[dict]:
    """The chosen model's ``expansions`` (best score first) the robust range must cover, each
    {effect, reason, young_modulus_shift_percent}: all when ``structure`` (why the chosen model's
    residuals still misfit) is not empty; else those whose E lies outside the chosen model's 95 %
    interval, and the best one of a ``decisive`` verdict (no reason then: it only may not be contradicted)."""
    own = estimates[chosen]["young_modulus"]
    out = []
    for rank, name in enumerate(expansions):
        value = estimates[name]["young_modulus"]["value"]
        shift = 100.0 * (value / own["value"] - 1.0)
        added = "+".join(e for e in name.split("+") if e not in chosen.split("+"))
        if structure:
            reason = f"the chosen model still misfits ({', '.join(structure[:3])}): the range covers what it may lack"
        elif not own["ci95"][0] <= value <= own["ci95"][1]:
            reason = f"adding {added} moves E by {shift:+.0f} %, beyond the chosen model's 95 % interval"
        elif decisive and rank == 0:
            reason = None
        else:
            continue
        out.append({"effect": name, "reason": reason, "young_modulus_shift_percent": shift})
    return out


def robust_range(kept: list[dict], estimates: dict, chosen: str, widening: list[dict] = ()) -> dict:
    """Range of P_g [Pa] (per session) and E [Pa] over the 95 % intervals of the kept models and the
    ``widening`` expansions (:func:`expansion_widening`), with the spread of their point values [%]
    and the chosen model's own interval for comparison; ``widened_by`` and ``warning`` say why."""
    names = list(dict.fromkeys([k["effect"] for k in kept] + [w["effect"] for w in widening]))

    def span(get):
        values = [get(estimates[n]) for n in names]
        lo, hi = min(v["ci95"][0] for v in values), max(v["ci95"][1] for v in values)
        points = [v["value"] for v in values]
        own = get(estimates[chosen])
        return {
            "range95": [lo, hi],
            "values": dict(zip(names, points)),
            "spread_percent": 100.0 * (max(points) / min(points) - 1.0),
            "chosen_ci95": own["ci95"],
            "unit": "Pa",
        }

    n_sessions = len(estimates[chosen]["gauge_pressure"])
    out = {
        "gauge_pressure": [span(lambda e, i=i: e["gauge_pressure"][i]) for i in range(n_sessions)],
        "young_modulus": span(lambda e: e["young_modulus"]),
    }
    e = out["young_modulus"]
    width = math.log(e["range95"][1] / e["range95"][0])
    own = math.log(e["chosen_ci95"][1] / e["chosen_ci95"][0])
    out["young_modulus"]["width_ratio"] = width / own if own > 0 else math.inf
    by_reason: dict[str, list[str]] = {}
    for w in widening:
        if w["reason"]:
            by_reason.setdefault(w["reason"], []).append(w["effect"])
    warnings = [reason if "moves E" in reason else f"{reason}, {', '.join(n)}" for reason, n in by_reason.items()]
    if width > SPREAD_WARNING * own:
        warnings.insert(
            0,
            f"E is not pinned down by this study: over the {len(names)} models it cannot exclude or must cover, "
            f"E's 95 % range is {e['range95'][0]:.4g}-{e['range95'][1]:.4g} Pa ({width / own:.1f}x the chosen "
            f"model's interval; point values spread {e['spread_percent']:.0f} %)",
        )
    out["widened_by"] = list(widening)
    out["warning"] = "; ".join(warnings) if warnings else None
    return out


def _measurement_of(model: str, chosen: str) -> str:
    """What separates ``model`` from ``chosen``: the measurements of the effects one holds and the other
    does not (a combination is told apart by what it adds)."""
    effects = lambda name: [] if name == "baseline" else name.split("+")  # noqa: E731
    ours, theirs = effects(chosen), effects(model)
    differ = [e for e in theirs if e not in ours] or [e for e in ours if e not in theirs] or ["baseline"]
    return "; ".join(SEPARATING_MEASUREMENT.get(e, "a measurement it moves") for e in differ)


def separating(kept: list[dict], chosen: str, robust: dict) -> list[dict]:
    """For each kept model besides the chosen: the measurement that separates it, and the factor E's
    95 % interval would shrink by once the study could exclude every model but the chosen one."""
    ratio = robust["young_modulus"]["width_ratio"]
    return [
        {
            "effect": k["effect"],
            "measurement": _measurement_of(k["effect"], chosen),
            "young_modulus_interval_shrink": ratio,
        }
        for k in kept
        if k["effect"] != chosen
    ]
