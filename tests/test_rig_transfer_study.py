"""experiments/rig_transfer_study.py's summary on synthetic rig records (no engine solves): the
model of the true families, and the bootstrap interval of a median over rigs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _scripts import load_script


def _model(terms, p_ratio, e_ratio, weight, truth_p, truth_e, std=0.05):
    return {
        "terms": terms,
        "weight": weight,
        "status": "ok",
        "estimates": {
            "gauge_pressure": {"value": truth_p * p_ratio, "relative_std": std, "unit": "Pa"},
            "young_modulus": {"value": truth_e * e_ratio, "relative_std": std, "unit": "Pa"},
        },
    }


def _rig(index, families, sessions):
    return {
        "rig": index,
        "truth": {family: {} for family in families},
        "families": sorted(families),
        "calibration_seconds": 1.0,
        "selected": [],
        "not_identified": [],
        "sessions": sessions,
    }


def _session(p_error, models, truth_p=1000.0, truth_e=2e6):
    fit = {"p_error": p_error, "p_covered": True, "e_error": 0.0, "e_covered": True, "seconds": 1.0}
    return {
        "radius": 0.1,
        "pressure": truth_p,
        "young_modulus": truth_e,
        "results": {"fit": fit, "fit+rig": fit, "rig_models": models},
    }


def test_model_of_the_true_families_is_picked_by_family_not_by_weight():
    """A rig with a pad and a depth zero error: of the models the calibration kept, the one whose
    terms' families are exactly {pad, depth} (pad_power + depth_offset) gives the row, whatever its
    weight; its interval is value × exp(±1.96 σ), so a 12 % error with σ = 5 % is not covered."""
    study = load_script("experiments", "rig_transfer_study")
    models = [
        _model(["sensor_gain"], 1.30, 1.0, 0.7, 1000.0, 2e6),
        _model(["pad_power", "depth_offset"], 1.12, 0.95, 0.2, 1000.0, 2e6),
        _model(["pad_hertz"], 0.5, 1.0, 0.1, 1000.0, 2e6),
    ]
    rig = study._with_true_families(_rig(0, ["pad", "depth"], [_session(3.0, models)]))
    row = rig["sessions"][0]["results"][study.TRUE_FAMILIES]
    assert row["p_error"] == pytest.approx(12.0) and row["e_error"] == pytest.approx(-5.0)
    assert row["p_covered"] is False and row["e_covered"] is True  # |ln 1.12| = 0.113 > 1.96 × 0.05; |ln 0.95| < it
    clean = study._with_true_families(_rig(1, [], [_session(1.0, models)]))
    assert study.TRUE_FAMILIES not in clean["sessions"][0]["results"]  # no ideal model kept: no row


def test_median_interval_resamples_rigs():
    """Rigs whose sessions all share one error: the median's bootstrap interval over rigs spans the
    rigs' errors (a resampling of sessions would not see that the eight sessions of a rig move
    together), and a single rig gives a point."""
    study = load_script("experiments", "rig_transfer_study")
    errors = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    rigs = [_rig(i, [], [_session(e, []) for _ in range(8)]) for i, e in enumerate(errors)]
    lo, hi = study._median_interval(rigs, "fit+rig", "p")
    assert lo <= np.median(errors) <= hi
    assert lo <= 2.0 and hi >= 5.0  # resampling six rigs reaches well past the middle two
    assert study._median_interval(rigs[:1], "fit+rig", "p") == [1.0, 1.0]
    summary = study.summarize(rigs, ["fit", "fit+rig"])
    assert summary["all"]["fit+rig"]["median_abs_p_error_ci95"] == [lo, hi]
    assert math.isclose(summary["all"]["fit+rig"]["median_abs_p_error"], 3.5)
