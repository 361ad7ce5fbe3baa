"""The rig: calibrated once where the pressure is known, carried to a held-out session.

The bundled Pezzi sessions are virtual (the engine at 201 elements, an ideal measuring chain,
shelljax/data/README.md); a linear finger pad of known compliance is planted in their depths. The
calibration must switch the pad on, recover its compliance, and the held-out session's P_g through
the rig must be right where the fit without the rig is not. The file format, its checks, the weights,
PSIS and the command line are tested on their own.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from shelljax import InvalidInputError
from shelljax.cli import main
from shelljax.config import bundled_data_dir, load_config
from shelljax.rig import (
    calibrate_rig,
    estimate_with_rig,
    load_rig,
    physical_parameter,
    psis,
    pseudo_bma_plus,
    write_rig,
)
from shelljax.session import load_session, write_session

# one xdist worker for the files that fit alike (conftest.py): the calibration's joint fit of four
# sessions is test_diagnose's, and it, the one-session estimate through the rig and the plain fit
# are the rig_calibration notebook's programs

PAD = 0.3e-3  # [m/N] planted pad compliance: 6 mm at 20 N, about a fifth of the Pezzi ball's depths
TERMS = ("pad_linear", "depth_offset", "sensor_gain")  # candidates: enough to choose among, few to fit
SESSIONS = bundled_data_dir() / "sessions"


def _padded(path):
    session = load_session(path)
    return dataclasses.replace(session, depth=session.depth + PAD * session.force)


def _write_padded(path, directory, manometer=True):
    """``path``'s session with the pad planted, written into ``directory``; without its manometer
    reading when ``manometer`` is False (a session to estimate, whose P_g nobody measured)."""
    s = _padded(path)
    out = directory / path.name
    write_session(
        out,
        object_name=s.object_name,
        radius=s.radius,
        radius_std=s.radius_std,
        thickness=s.thickness,
        thickness_std=s.thickness_std,
        trial=s.trial,
        force=s.force,
        depth=s.depth,
        wrinkle_counts=s.wrinkle_counts,
        manometer_gauge_pressure=s.manometer_gauge_pressure if manometer else None,
        poisson_ratio=s.poisson_ratio,
    )
    return out


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    directory = tmp_path_factory.mktemp("rig")
    paths = [_write_padded(SESSIONS / f"calib_pezzi_{p:04d}Pa.toml", directory) for p in (900, 1200, 1500, 1650)]
    rig = calibrate_rig(paths, terms=TERMS, progress=False)
    return rig, write_rig(rig, directory / "rig.toml"), directory


@pytest.mark.slow  # calibrates the rig (the module's fixture)
def test_calibration_switches_the_pad_on_and_recovers_its_compliance(calibrated):
    rig, _, _ = calibrated
    assert rig.inclusion["pad_linear"] > 0.9, rig.models
    best = rig.models[0]
    assert "pad_linear" in best.terms
    i = best.parameters.index("finger_compliance")
    value, std = physical_parameter(
        "finger_compliance", best.mean[i], math.sqrt(best.covariance[i, i]), rig.indenter_radius
    )
    # within 3 std (a Laplace interval of 4 sessions' worth of data), and never off by 30 %
    assert abs(value - PAD) < 3 * std and abs(value / PAD - 1) < 0.3, (value, std)
    assert abs(sum(m.weight for m in rig.models) - 1) < 1e-9
    assert all(m.delta <= 0 for m in rig.models)


@pytest.mark.slow  # calibrates the rig (the module's fixture)
def test_held_out_pressure_through_the_rig_is_right_and_the_fit_without_it_is_not(calibrated):
    from shelljax.estimate import EstimatorOptions, run_estimator

    rig, path, directory = calibrated
    held_out = _write_padded(SESSIONS / "heldout_pezzi_1100Pa.toml", directory)
    truth = 1100.0  # [Pa] the virtual session's gauge pressure
    through = estimate_with_rig(held_out, load_rig(path)).estimates["gauge_pressure"]
    plain = run_estimator("fit", load_session(held_out), EstimatorOptions(gas="isothermal", wrinkle_law="scaling"))
    plain = plain.estimates["gauge_pressure"]
    assert through.ci95[0] <= truth <= through.ci95[1], through
    # the pad makes every depth deeper: without the rig the ball reads softer, P_g low
    assert abs(through.value / truth - 1) < 0.04
    assert abs(plain.value / truth - 1) > 2 * abs(through.value / truth - 1), (plain.value, through.value)


@pytest.mark.slow  # calibrates the rig (the module's fixture)
def test_rig_file_round_trip_keeps_every_model(calibrated):
    rig, path, _ = calibrated
    again = load_rig(path)
    assert [m.terms for m in again.models] == [m.terms for m in rig.models]
    for a, b in zip(again.models, rig.models):
        np.testing.assert_allclose(a.mean, b.mean, rtol=1e-12)
        np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-12)
        assert a.weight == pytest.approx(b.weight, rel=1e-12)
    assert again.noise[0] == pytest.approx(rig.noise[0]) and again.noise[1] == pytest.approx(rig.noise[1])
    assert len(again.calibration) == 4 and all(len(c["sha256"]) == 64 for c in again.calibration)


@pytest.mark.parametrize(
    "edit, field",
    [
        (lambda t: t.replace("format = 1", "format = 7"), "format"),
        (lambda t: t.replace('shelljax_version = "0.1.0"', 'shelljax_version = "9.0.0"'), "shelljax_version"),
        (lambda t: t.replace("weight = ", "weight = -", 1), "weight"),
        (lambda t: t.replace('gas = "isothermal"', 'gas = "helium"'), "forward_model"),
        (
            lambda t: t.replace('[[model]]\nterms = [\n    "pad_linear"', '[[model]]\nterms = [\n    "pad_tofu"', 1),
            "terms",
        ),
        (lambda t: t.replace("force_ref = ", "force_ref = -", 1), "reference.force_ref"),
    ],
)
@pytest.mark.slow  # calibrates the rig (the module's fixture)
def test_a_rig_file_edited_into_nonsense_is_refused_naming_the_field(calibrated, tmp_path, edit, field):
    _, path, _ = calibrated
    text = path.read_text()
    edited = edit(text)
    assert edited != text, "the edit must change the file"
    bad = tmp_path / "bad.toml"
    bad.write_text(edited)
    with pytest.raises(InvalidInputError, match=field.split(".")[0]):
        load_rig(bad)


@pytest.mark.slow  # calibrates the rig (the module's fixture)
def test_a_rig_of_other_forward_model_options_is_refused(calibrated):
    _, path, _ = calibrated
    held_out = SESSIONS / "heldout_pezzi_1100Pa.toml"
    with pytest.raises(InvalidInputError, match="calibrated with gas = 'isothermal'"):
        estimate_with_rig(held_out, load_rig(path), gas="prescribed")
    with pytest.raises(InvalidInputError, match="wrinkle_law"):
        estimate_with_rig(held_out, load_rig(path), wrinkle_law="mechanics")


def test_calibration_sessions_without_a_manometer_are_refused():
    with pytest.raises(InvalidInputError, match="manometer_gauge_pressure.*missing"):
        calibrate_rig([SESSIONS / "calib_pezzi_0900Pa.toml", SESSIONS / "pezzi.toml"], progress=False)
    with pytest.raises(InvalidInputError, match="unknown rig term"):
        calibrate_rig([SESSIONS / "calib_pezzi_0900Pa.toml"], terms=("pad_tofu",), progress=False)


def test_a_calibration_object_of_loosely_stated_radius_is_warned_about():
    # on one object the rig's force gain and the object's R are one product: R's error becomes the gain's
    import warnings

    from shelljax.rig import RigWarning
    from shelljax.rig._calibrate import _hint_radius

    taped = [load_session(p) for p in sorted((SESSIONS / "rig").glob("calib_ball_*.toml"))]
    assert taped and all(s.radius_std <= 0.01 * s.radius for s in taped)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _hint_radius(taped)
    with pytest.warns(
        RigWarning, match=r"toy_2200Pa\.toml: field 'radius_std'.*±2\.0 %.*Fix: measure its circumference"
    ):
        _hint_radius([load_session(SESSIONS / "rig" / "toy_2200Pa.toml")])


def test_pseudo_bma_plus_weights():
    rng = np.random.default_rng(0)
    same = rng.normal(size=20)
    np.testing.assert_allclose(pseudo_bma_plus(np.stack([same, same])), [0.5, 0.5], atol=1e-12)
    # a model better by 1 nat in each of 20 units takes (nearly) all the weight
    w = pseudo_bma_plus(np.stack([same + 1.0, same]))
    assert w[0] > 0.99 and w.sum() == pytest.approx(1.0)


def test_psis_recovers_a_known_posterior_mean():
    # target N(1, 0.5²) sampled from a proposal t₅(0, 1): the weighted mean is the target's
    from scipy import stats

    rng = np.random.default_rng(1)
    x = stats.t(df=5).rvs(size=4000, random_state=rng)
    log_w = stats.norm(1.0, 0.5).logpdf(x) - stats.t(df=5).logpdf(x)
    w, k_hat = psis(log_w)
    assert k_hat < 0.7
    assert np.sum(w * x) == pytest.approx(1.0, abs=0.03)  # a few Monte Carlo standard errors (≈ 0.01)


@pytest.mark.slow  # calibrates the rig (the module's fixture)
def test_cli_rig_calibrate_and_estimate(calibrated, tmp_path, capsys):
    rig, path, directory = calibrated
    held_out = _write_padded(SESSIONS / "heldout_pezzi_1450Pa.toml", directory)
    assert main(["estimate", str(held_out), "--method", "fit", "--rig", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    p = out["estimates"]["gauge_pressure"]
    assert p["unit"] == "Pa" and p["ci95"][0] <= 1450.0 <= p["ci95"][1]
    assert sum(m["weight"] for m in out["rig_models"]) == pytest.approx(1.0)
    assert main(["estimate", str(held_out), "--method", "fit", "--rig", str(path), "--gas", "prescribed"]) == 2
    assert "calibrated with gas" in capsys.readouterr().err
    assert main(["estimate", str(held_out), "--rig", str(path)]) == 2  # closed form has no rig
    assert "--method fit" in capsys.readouterr().err


@pytest.mark.slow  # calibrates the rig (the module's fixture)
def test_config_rig_table_names_the_rig_and_refuses_contradictions(calibrated, tmp_path):
    _, path, _ = calibrated
    config = tmp_path / "exp.toml"
    config.write_text(
        f'[estimators]\nmethods = ["fit"]\n[rig]\npath = "{path}"\n[sessions]\n'
        'paths = ["bundled:sessions/heldout_pezzi_1100Pa.toml"]\n'
    )
    loaded = load_config(config)
    options = loaded.estimator_options
    assert loaded.rig == path and options.gas == "isothermal" and options.wrinkle_law == "scaling"
    config.write_text(
        f'[estimators]\nmethods = ["fit"]\ngas = "prescribed"\n[rig]\npath = "{path}"\n[sessions]\n'
        'paths = ["bundled:sessions/heldout_pezzi_1100Pa.toml"]\n'
    )
    with pytest.raises(InvalidInputError, match="estimators.gas"):
        load_config(config)


@pytest.mark.slow  # calibrates the rig (the module's fixture)
def test_replica_and_scenario_take_the_rig(calibrated, tmp_path):
    from shelljax.replica import export_replica
    from shelljax.scenario import load_scenario

    _, path, directory = calibrated
    s = _padded(SESSIONS / "heldout_pezzi_1100Pa.toml")
    session = tmp_path / "ball.toml"
    write_session(
        session,
        object_name=s.object_name,
        radius=s.radius,
        radius_std=s.radius_std,
        thickness=s.thickness,
        thickness_std=s.thickness_std,
        trial=s.trial,
        force=s.force,
        depth=s.depth,
        wrinkle_counts=s.wrinkle_counts,
        mass=0.4,
    )
    export_replica(session, tmp_path / "replica", rig=path, mesh_faces=200)
    replica = json.loads((tmp_path / "replica" / "replica.json").read_text())
    direct = estimate_with_rig(session, load_rig(path)).estimates["gauge_pressure"].value
    assert replica["gauge_pressure_Pa"]["value"] == pytest.approx(direct, rel=1e-9)
    assert replica["source"]["rig"] == str(path)
    drop = (bundled_data_dir().parents[1] / "configs" / "drop.toml").read_text()
    config = tmp_path / "drop.toml"
    config.write_text(drop.replace("[integrator]", f'[rig]\npath = "{path}"\n\n[integrator]'))
    assert load_scenario(config).rig == path
    config.write_text(
        drop.replace('wrinkle_law = "scaling"', 'wrinkle_law = "mechanics"').replace(
            "[integrator]", f'[rig]\npath = "{path}"\n\n[integrator]'
        )
    )
    with pytest.raises(InvalidInputError, match="estimators.wrinkle_law"):
        load_scenario(config)


def _press(directory, rng, compliance=PAD, offset=0.0):
    from shelljax.session import write_rigid_press

    trial = np.repeat([1, 2, 3], 7)
    force = np.tile(np.arange(5.0, 20.1, 2.5), 3) + rng.normal(0, 0.05, 21)
    depth = compliance * force + offset + np.repeat(rng.normal(0, 0.1e-3, 3), 7) + rng.normal(0, 0.05e-3, 21)
    return write_rigid_press(
        directory / "press.toml", object_name="table", trial=trial, force=np.round(force, 2), depth=depth
    )


def test_a_press_alone_measures_the_pad_and_the_depth_zero(tmp_path):
    from shelljax.rig._press import fit_press, press_data

    press = _press(tmp_path, np.random.default_rng(5), offset=1e-3)
    data = press_data([press])
    fit = fit_press(data, ("pad_linear", "depth_offset"), 10.0)
    c, delta = (
        physical_parameter(n, u, math.sqrt(fit.covariance[i, i]), 0.008)
        for i, (n, u) in enumerate(zip(fit.parameters, fit.mean))
    )
    # within 3 std of the planted values (a linear least-squares problem: the Laplace std is exact)
    assert abs(c[0] - PAD) < 3 * c[1] and abs(delta[0] - 1e-3) < 3 * delta[1]
    # a press with a pad is badly predicted by a rig without one: its trials lose density
    assert fit.elpd.sum() > fit_press(data, (), 10.0).elpd.sum() + 20


@pytest.mark.slow  # calibrates the rig (the module's fixture)
def test_calibration_with_a_press_pins_the_pad_down(calibrated, tmp_path):
    rig, _, directory = calibrated
    press = _press(tmp_path, np.random.default_rng(6))
    calibration = sorted(directory.glob("calib_pezzi_*.toml"))
    with_press = calibrate_rig(calibration, terms=("pad_linear",), presses=[press.source], progress=False)
    without = next(m for m in rig.models if m.terms == ("pad_linear",))
    pressed = next(m for m in with_press.models if m.terms == ("pad_linear",))
    # the press's 21 samples at 0.1 mm measure c far better than four balls whose E absorbs part of it
    assert math.sqrt(pressed.covariance[0, 0]) < 0.5 * math.sqrt(without.covariance[0, 0])
    value = physical_parameter("finger_compliance", pressed.mean[0], 0.0, 0.008)[0]
    assert abs(value / PAD - 1) < 0.1
    assert any(c.get("kind") == "rigid_press" for c in with_press.calibration)


@pytest.mark.slow  # calibrates the rig (the module's fixture)
def test_cli_rig_calibrate_writes_the_rig_or_nothing(calibrated, tmp_path, capsys):
    _, _, directory = calibrated
    press = _press(tmp_path, np.random.default_rng(7))
    calibration = [str(p) for p in sorted(directory.glob("calib_pezzi_*.toml"))]
    out = tmp_path / "rig.toml"
    assert (
        main(
            ["rig", "calibrate", *calibration, str(press.source), "--terms", "pad_linear", "--out", str(out), "--quiet"]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "pad_linear" in printed and f"written: {out}" in printed
    assert load_rig(out).models[0].terms == ("pad_linear",)
    assert main(["validate", str(press.source)]) == 0
    assert "rigid-surface press" in capsys.readouterr().out
    refused = tmp_path / "refused.toml"
    assert (
        main(["rig", "calibrate", calibration[0], str(SESSIONS / "pezzi.toml"), "--out", str(refused), "--quiet"]) == 2
    )
    assert "manometer_gauge_pressure" in capsys.readouterr().err and not refused.exists()


@pytest.mark.slow  # calibrates the rig (the module's fixture)
def test_mixed_rigs_are_refused_in_a_calibration_and_in_an_estimate(calibrated, tmp_path):
    rig, _, _ = calibrated
    paths = []
    for k, p in enumerate((900, 1200)):
        s = load_session(SESSIONS / f"calib_pezzi_{p:04d}Pa.toml")
        paths.append(tmp_path / f"s{k}.toml")
        write_session(
            paths[-1],
            object_name=s.object_name,
            radius=s.radius,
            radius_std=s.radius_std,
            thickness=s.thickness,
            thickness_std=s.thickness_std,
            trial=s.trial,
            force=s.force,
            depth=s.depth,
            wrinkle_counts=s.wrinkle_counts,
            manometer_gauge_pressure=s.manometer_gauge_pressure,
            rig_name=("alice-index", "bob-thumb")[k],
        )
    with pytest.raises(InvalidInputError, match="different rigs.*alice-index.*bob-thumb"):
        calibrate_rig(paths, progress=False)
    named = write_rig(dataclasses.replace(rig, name="alice-index"), tmp_path / "alice.toml")
    assert load_rig(named).name == "alice-index"
    with pytest.raises(InvalidInputError, match="field 'rig'.*bob-thumb"):
        estimate_with_rig(paths[1], load_rig(named))


@pytest.mark.slow  # calibrates the rig (the module's fixture)
def test_an_estimate_says_what_would_separate_the_terms_not_identified(calibrated, tmp_path):
    from shelljax.rig._estimate import RigEstimate

    rig, _, _ = calibrated
    held_out = SESSIONS / "heldout_pezzi_1100Pa.toml"
    unsure = dataclasses.replace(rig, not_identified=("pad_linear", "sensor_gain"))
    result = estimate_with_rig(held_out, unsure)
    assert isinstance(result, RigEstimate)
    rows = {s["term"]: s for s in result.to_dict()["separating"]}
    assert (
        "rigid-surface press" in rows["pad_linear"]["measurement"] and "weights" in rows["sensor_gain"]["measurement"]
    )
    # one model: the mixture is that model, and settling the terms would change nothing
    assert rows["pad_linear"]["young_modulus_interval_shrink"] == pytest.approx(1.0, rel=1e-3)


@pytest.mark.slow  # calibrates the rig (the module's fixture)
def test_diagnose_with_the_rig_as_baseline(calibrated, tmp_path, capsys):
    _, path, directory = calibrated
    calibration = [str(p) for p in sorted(directory.glob("calib_pezzi_*.toml"))]
    assert (
        main(
            [
                "diagnose",
                *calibration,
                "--rig",
                str(path),
                "--effects",
                "finger_compliance",
                "depth_offset",
                "--json",
                "--quiet",
            ]
        )
        == 0
    )
    report = json.loads(capsys.readouterr().out)
    # the rig's pad is the baseline: its own candidate is left out, and the rest find nothing more
    assert report["baseline"]["measurement"] == "pad_linear"
    assert report["baseline"]["effects_in_measurement"] == ["finger_compliance"]
    assert {e["effect"] for e in report["ranking"]} == {"baseline", "depth_offset"} and report["verdict"] == "none"
    assert {"not_excluded", "robust", "separating"} <= set(report)
    assert main(["diagnose", *calibration, "--rig", str(path), "--wrinkle-law", "mechanics"]) == 2
    assert "wrinkle_law" in capsys.readouterr().err


@pytest.mark.slow  # calibrates the rig (the module's fixture)
def test_a_model_whose_fit_fails_is_reported_not_dropped(calibrated, tmp_path, monkeypatch):
    import shelljax.rig._calibrate as calibrate

    _, _, directory = calibrated
    real = calibrate.fit_model

    def failing_gain(base, study, terms, *args, **kwargs):
        fit = real(base, study, terms, *args, **kwargs)
        return dataclasses.replace(fit, converged=False, message="forced") if "sensor_gain" in terms else fit

    monkeypatch.setattr(calibrate, "fit_model", failing_gain)
    rig = calibrate_rig(
        sorted(directory.glob("calib_pezzi_*.toml")), terms=("pad_linear", "sensor_gain"), progress=False
    )
    # the gain alone, then the pad with the gain: each reported with its reason
    assert [f["terms"] for f in rig.failed] == [["sensor_gain"], ["pad_linear", "sensor_gain"]]
    assert all("forced" in f["message"] for f in rig.failed)
    assert all("sensor_gain" not in m.terms for m in rig.models)
    assert load_rig(write_rig(rig, tmp_path / "rig.toml")).failed == rig.failed


@pytest.mark.slow  # calibrates the rig (the module's fixture)
def test_cli_estimates_the_sessions_of_one_object_at_once_through_the_rig(calibrated, tmp_path, capsys):
    _, path, _ = calibrated
    # Four sessions of the Pezzi ball the rig never saw: the two held-out ones and the two bundled
    # calibration sessions this rig was not calibrated on, without their manometer readings (a
    # reading would be P_g's prior). Four, as the calibration: the same joint problem's shapes, so
    # its compiled fit serves this estimate too (two sessions compiled one of their own, ~45 s)
    truths = (1100.0, 1450.0, 1050.0, 1350.0)  # [Pa] the virtual sessions' gauge pressures
    names = ["heldout_pezzi_1100Pa", "heldout_pezzi_1450Pa", "calib_pezzi_1050Pa", "calib_pezzi_1350Pa"]
    sessions = [str(_write_padded(SESSIONS / f"{name}.toml", tmp_path, manometer=False)) for name in names]
    assert main(["estimate", *sessions, "--method", "fit", "--rig", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["session"] == sessions
    for k, truth in enumerate(truths):
        p = out["estimates"][f"gauge_pressure[{k}]"]
        assert p["ci95"][0] <= truth <= p["ci95"][1]
    e = out["estimates"]["young_modulus"]
    assert e["ci95"][0] <= 2.34e6 <= e["ci95"][1]  # the bundled Pezzi ball's E (shelljax/data/README.md)
    assert main(["estimate", *sessions, "--method", "fit"]) == 2
    assert "without --rig" in capsys.readouterr().err
