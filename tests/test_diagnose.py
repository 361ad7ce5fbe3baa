"""The diagnosis end to end on studies made by its own forward model (an effect planted or not).

The studies are generated through the diagnosis's joint model at known parameters, with the
bundled sessions' noise (2 % proportional scatter, 0.5 mm per-trial offsets): the test checks the
decision logic, the magnitude's interval, the gap, the JSON contract and the CLI. Blind studies on
a finer "reality" are experiments/blind_gap_study.py's job (docs/sim-to-real.md).
"""

from __future__ import annotations

import json

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from shelljax.cli import main
from shelljax.diagnose import diagnose
from shelljax.diagnose._effects import GLOBAL_PARAMETERS
from shelljax.diagnose._loo import fit_candidate
from shelljax.diagnose._model import study_arrays
from shelljax.diagnose._study import build_study
from shelljax.session import load_session, write_session

pytestmark = pytest.mark.slow  # diagnoses whole studies: joint fits of every candidate effect
SHARED_PROGRAMS = (
    "joint diagnosis"  # the sim_to_real notebook's diagnosis is this file's joint fit: one xdist worker (conftest.py)
)

LEVELS = np.arange(5.0, 20.0 + 1e-9, 2.5)
PRESSURES = (900.0, 1200.0, 1500.0, 1800.0)  # [Pa]
EFFECTS = ("depth_offset", "finger_compliance", "gas")
OFFSET = 3e-3  # [m] planted depth offset


def _write(directory, depths, counts, name="ball"):
    paths = []
    for k, (p, d, n) in enumerate(zip(PRESSURES, depths, counts)):
        trial = np.repeat([1, 2, 3], LEVELS.size)
        force = np.tile(LEVELS, 3) + np.random.default_rng(k).normal(0, 0.05, trial.size)
        path = directory / f"s{k}.toml"
        write_session(
            path,
            object_name=name,
            radius=0.13,
            radius_std=0.0026,
            thickness=0.9e-3,
            thickness_std=0.045e-3,
            trial=trial,
            force=np.round(force, 2),
            depth=d,
            wrinkle_counts=n,
            manometer_gauge_pressure=p,
            mass=0.4,
        )
        paths.append(path)
    return paths


def _study(directory, planted: dict[str, float], seed: int):
    """Sessions whose depths are the joint model's at P_g = manometer, E = 2.34 MPa and the
    ``planted`` parameters (scaled values u by name), plus noise."""
    template = _write(directory, [np.full(3 * LEVELS.size, 0.02)] * 4, [[7, 7, 7]] * 4)
    study = build_study([load_session(p) for p in template])
    data = study_arrays(study)
    n_s = len(PRESSURES)
    u = np.zeros(data.free.shape[0])
    u[n_s + GLOBAL_PARAMETERS.index("young_modulus")] = np.log(2.34e6 / float(data.start_modulus))
    for name, value in planted.items():
        u[n_s + GLOBAL_PARAMETERS.index(name)] = value
    # The joint model's prediction at u, through the diagnosis's own compiled fit with every entry
    # fixed at u (free mask all False, u_base = u): Levenberg-Marquardt has nothing to move and
    # returns the prediction at u, the same arithmetic as JointProblem.residuals_and_prediction(u)
    # run op by op, which compiled about 150 small programs and the engine's curves of its own
    fixed = eqx.tree_at(lambda d: (d.free, d.u_base), data, (jnp.zeros_like(data.free), jnp.asarray(u)))
    at_u = fit_candidate(fixed, "scaling", np.zeros(u.size))
    assert at_u.converged and np.array_equal(at_u.u, np.zeros(u.size))
    pred = at_u.prediction
    rng = np.random.default_rng(seed)
    depth = np.asarray(pred["depth"]) * (1 + rng.normal(0, 0.02, study.depth.size))
    depth += np.repeat(rng.normal(0, 0.5e-3, 3 * n_s), LEVELS.size)  # one offset per trial
    counts = np.round(np.asarray(pred["count"]) + rng.normal(0, 0.5, study.count.size))
    return _write(directory, np.split(np.round(depth * 2e3) / 2e3, n_s), np.split(counts.astype(int), n_s))


@pytest.fixture(scope="module")
def studies(tmp_path_factory):
    planted = _study(tmp_path_factory.mktemp("offset"), {"depth_offset": OFFSET / 1e-3}, seed=3)
    clean = _study(tmp_path_factory.mktemp("clean"), {}, seed=4)
    return (
        planted,
        diagnose(planted, effects=EFFECTS, progress=False),
        clean,
        diagnose(clean, effects=EFFECTS, progress=False),
    )


def test_a_planted_depth_offset_is_found_and_measured(studies):
    _, found, _, _ = studies
    report = found.report
    assert report["verdict"] == "depth_offset" and report["search"] == ["baseline", "depth_offset"]
    best = next(e for e in report["ranking"] if e["effect"] == "depth_offset")
    assert best["delta"] >= max(4.0, 2 * best["delta_se"])
    interval = best["parameters"]["depth_offset"]["ci95"]
    assert interval[0] <= OFFSET <= interval[1]
    # the baseline misfits the depths (an offset weighs most at the lowest force, where the depth is
    # smallest); the winner leaves no misfit group and brings the held-out gap to the noise (rms ≈ 1)
    assert any(g.startswith(("observable:depth", "force:")) for g in report["where"]["misfit_groups"])
    assert report["where_after"]["misfit_groups"] == []
    # (the baseline absorbs part of an offset into P_g, E, h and R within their priors: the gap it
    # leaves is modest, and the winner's is the noise's)
    assert report["gap_after"]["rms_standardized"] < 1.3
    assert report["gap_before"]["rms_standardized"] > report["gap_after"]["rms_standardized"]
    assert report["shrink"] == pytest.approx(
        report["gap_before"]["rms_standardized"] / report["gap_after"]["rms_standardized"]
    )
    for shift in report["winner"]["gauge_pressure_shift_percent"]:
        assert np.isfinite(shift)


def test_an_effect_free_study_gets_no_effect(studies):
    _, _, _, clean = studies
    report = clean.report
    assert report["verdict"] == "none"
    assert report["misfit_p_value"] > 1e-3
    assert report["winner"] is None and report["shrink"] == pytest.approx(1.0)
    # every candidate is scored, none by the 4-nat / 2-SE margin
    assert {e["effect"] for e in report["ranking"]} == {"baseline", *EFFECTS}
    assert all(e["delta"] < max(4.0, 2 * e["delta_se"]) for e in report["ranking"] if e["effect"] != "baseline")


def test_the_json_contract(studies):
    _, found, _, _ = studies
    report = json.loads(json.dumps(found.report, default=lambda v: v.item() if hasattr(v, "item") else str(v)))
    assert {"verdict", "ranking", "gap_before", "gap_after", "shrink", "where", "baseline", "sessions"} <= set(report)
    for entry in report["ranking"]:
        assert {"effect", "score", "score_se", "status"} <= set(entry)
        for value in entry.get("parameters", {}).values():
            assert {"value", "ci95", "unit"} <= set(value)
    where = report["where"]
    assert {
        "by_observable",
        "by_regime",
        "by_force_level",
        "by_session",
        "structure_along_force",
        "misfit_groups",
    } <= set(where)
    assert len(where["by_force_level"]) == LEVELS.size and len(where["by_session"]) == len(PRESSURES)
    # a planted positive offset leaves a positive offset term in the baseline's held-out depth
    # residuals, and a smaller one once the winner models it
    before = where["structure_along_force"]["pooled"]["offset"]
    after = report["where_after"]["structure_along_force"]["pooled"]["offset"]
    assert before["value"] > 0 and abs(after["z"]) < abs(before["z"])


def test_cli_writes_the_diagnosis_and_refuses_bad_input(studies, tmp_path, capsys):
    planted, _, clean, _ = studies
    out = tmp_path / "diag"
    assert main(["diagnose", *map(str, planted), "--effects", "depth_offset", "--out", str(out), "--quiet"]) == 0
    assert "verdict: depth_offset" in capsys.readouterr().out
    assert json.loads((out / "diagnosis.json").read_text())["verdict"] == "depth_offset"
    assert (out / "diagnosis.png").stat().st_size > 10_000
    assert main(["diagnose", *map(str, planted), "--effects", "finger_size", "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err
    assert "unknown effect(s) 'finger_size'" in err and "finger_compliance" in err
    other = _write(tmp_path, [np.full(3 * LEVELS.size, 0.02)] * 4, [[7, 7, 7]] * 4, name="another-ball")
    assert main(["diagnose", str(planted[0]), str(other[1]), "--out", str(tmp_path / "mixed")]) == 2
    assert "different objects" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists() and not (tmp_path / "mixed").exists()


def test_the_winner_is_expanded_and_its_range_never_contradicts_its_best_expansion(studies):
    _, found, _, clean = studies
    report = found.report
    ranked = {e["effect"]: e for e in report["ranking"]}
    # the search fitted the winner's pairs, named in library order, and neither beat it by the margin
    pairs = {"finger_compliance+depth_offset", "depth_offset+gas"}
    assert pairs <= set(ranked) and all(ranked[p]["status"] == "ok" for p in pairs)
    offset_elpd = found.scores["depth_offset"].elpd
    for p in pairs:
        diff = found.scores[p].elpd - offset_elpd
        assert not (diff.sum() >= 4.0 and diff.sum() >= 2 * np.sqrt(diff.size * np.var(diff)))
    # the best pair (the verdict's next-best expansion) is covered by the robust E range
    best_pair = max(pairs, key=lambda p: ranked[p]["score"])
    e = report["robust"]["young_modulus"]
    assert best_pair in e["values"] and e["range95"][0] <= e["values"][best_pair] <= e["range95"][1]
    assert best_pair in {w["effect"] for w in report["robust"]["widened_by"]}
    # the kept models' pseudo-BMA+ weights sum to one; an effect-free study is not expanded at all
    assert sum(k["weight"] for k in report["not_excluded"]) == pytest.approx(1.0)
    assert clean.report["search"] == ["baseline"] and not any("+" in e["effect"] for e in clean.report["ranking"])


def test_what_the_study_cannot_exclude(studies):
    _, found, _, clean = studies
    # with the offset planted, the models that ignore it are excluded: the offset is in, the baseline out
    kept = {k["effect"] for k in found.report["not_excluded"]}
    assert "depth_offset" in kept and "baseline" not in kept
    # the effect-free study cannot exclude the candidates that add nothing: the robust range spans
    # every one's interval, and so contains the chosen model's
    report = clean.report
    kept = {k["effect"] for k in report["not_excluded"]}
    assert "baseline" in kept and len(kept) >= 2
    e = report["robust"]["young_modulus"]
    assert e["range95"][0] <= e["chosen_ci95"][0] and e["range95"][1] >= e["chosen_ci95"][1]
    assert e["unit"] == "Pa" and e["width_ratio"] >= 1.0
    assert len(report["robust"]["gauge_pressure"]) == len(PRESSURES)
    separating = {s["effect"]: s["measurement"] for s in report["separating"]}
    assert set(separating) == kept - {"baseline"}
    if "depth_offset" in separating:
        assert "rigid-surface press" in separating["depth_offset"]


def test_two_sensor_effects_at_once_are_found_as_a_combination(tmp_path):
    # a sensor whose gain and exponent are both off (a power law about another reference force):
    # gain 1.35 and exponent 1.25 move the force by +35 % at F_ref and by 35 % more across 5-20 N
    planted = {"force_gain": np.log(1.35), "force_exponent": 2.5}
    found = diagnose(
        _study(tmp_path, planted, seed=5),
        effects=("force_sensor_gain", "force_sensor_nonlinearity", "depth_offset"),
        progress=False,
    ).report
    assert found["verdict"] == "force_sensor_gain+force_sensor_nonlinearity"
    assert found["search"][0] == "baseline" and found["search"][-1] == found["verdict"]
    gain = found["winner"]["parameters"]["force_gain"]
    assert found["winner"]["effects"] == ["force_sensor_gain", "force_sensor_nonlinearity"]
    assert gain["ci95"][0] <= 1.35 <= gain["ci95"][1]
    e = found["robust"]["young_modulus"]["range95"]
    assert e[0] <= 2.34e6 <= e[1]
