"""The estimator's defaults are defined once (``shelljax.estimate.DEFAULT_OPTIONS``), every command
reads them there, and they are right: with no options, ``shelljax estimate SESSION --method fit``
holds the truth of every bundled session in its 95 % interval."""

from __future__ import annotations

import dataclasses
import json
import re

import pytest

from shelljax.cli import build_parser, main
from shelljax.config import load_config
from shelljax.estimate import DEFAULT_OPTIONS, EstimatorOptions
from shelljax.session import bundled_sessions, load_session

SHARED_PROGRAMS = "bundled-session fits"  # one xdist worker for the files that fit alike (conftest.py)
# How the bundled sessions' notes state their truth (tools/make_bundled_data.py)
TRUTH = re.compile(r"true P_g = (?P<gauge_pressure>[0-9.e+]+) Pa, E = (?P<young_modulus>[0-9.e+]+) Pa")


def test_the_defaults_are_the_sealed_gas_and_the_scaling_law():
    assert (DEFAULT_OPTIONS.forward_model, DEFAULT_OPTIONS.gas, DEFAULT_OPTIONS.wrinkle_law) == (
        "axisym",
        "isothermal",
        "scaling",
    )
    assert DEFAULT_OPTIONS == EstimatorOptions()


def test_estimate_with_no_options_runs_the_defaults(monkeypatch, capsys):
    import shelljax.estimate as estimate

    seen = {}

    def record(method, session, options, **_):
        seen["options"] = options
        raise KeyboardInterrupt  # stop before any work

    monkeypatch.setattr(estimate, "run_estimator", record)
    with pytest.raises(KeyboardInterrupt):
        main(["estimate", str(bundled_sessions("pezzi.toml")[0]), "--method", "fit", "--quiet"])
    assert dataclasses.replace(seen["options"], k_s=None) == DEFAULT_OPTIONS


def test_every_command_reads_the_one_set_of_defaults(tmp_path):
    parser = build_parser()
    estimate = vars(parser.parse_args(["estimate", "s.toml"]))
    options = dataclasses.asdict(DEFAULT_OPTIONS)
    for flag, field in (
        ("bootstrap", "bootstrap_samples"),
        ("seed", "seed"),
        ("model", "forward_model"),
        ("walkers", "walkers"),
        ("max_steps", "max_steps"),
    ):
        assert estimate[flag] == options[field], flag
    calibrate = parser.parse_args(["rig", "calibrate", "s.toml", "--out", "rig.toml"])
    assert (calibrate.gas, calibrate.wrinkle_law) == (DEFAULT_OPTIONS.gas, DEFAULT_OPTIONS.wrinkle_law)
    config = tmp_path / "c.toml"
    config.write_text('[estimators]\nmethods = ["fit"]\n[sessions]\npaths = ["bundled:sessions/pezzi.toml"]\n')
    assert load_config(config).estimator_options == DEFAULT_OPTIONS


def _sessions_with_truth():
    for path in bundled_sessions("*.toml"):
        match = TRUTH.search(load_session(path).notes)
        if match:
            yield path, {k: float(v) for k, v in match.groupdict().items()}


@pytest.mark.slow  # 18 fits through the engine: one compiled program, then about a second each
def test_the_default_fit_holds_the_truth_of_every_bundled_session(capsys):
    cases = list(_sessions_with_truth())
    assert len(cases) == 18
    missed = []
    for path, truth in cases:
        assert main(["estimate", str(path), "--method", "fit", "--json", "--quiet"]) == 0
        estimates = json.loads(capsys.readouterr().out)["estimates"]
        for name, value in truth.items():
            low, high = estimates[name]["ci95"]
            if not low <= value <= high:
                missed.append(f"{path.name}: {name} {value:g} outside [{low:.4g}, {high:.4g}]")
    assert not missed, "\n".join(missed)
