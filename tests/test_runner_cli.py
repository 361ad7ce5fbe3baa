"""The runner and the CLI, end to end on the bundled data."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from shelljax import InvalidInputError
from shelljax.cli import main
from shelljax.config import bundled_data_dir, load_config
from shelljax.runner import run_experiment

REPO = Path(__file__).resolve().parents[1]
PAPER_CONFIG = REPO / "configs" / "paper.toml"


@pytest.fixture(scope="module")
def paper_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs")
    run_dir = run_experiment(PAPER_CONFIG, output_dir=out, progress=False)
    return run_dir, json.loads((run_dir / "results.json").read_text())


def test_default_experiment_reports_pressure_and_modulus_for_every_session(paper_run):
    run_dir, results = paper_run
    config = load_config(PAPER_CONFIG)
    assert len(results["sessions"]) == len(config.sessions)
    for entry in results["sessions"]:
        block = entry["estimates"]["closed-form"]
        for quantity in ("gauge_pressure", "young_modulus"):
            est = block[quantity]
            assert est["unit"] == "Pa" and est["std"] > 0
            assert est["ci95"][0] < est["value"] < est["ci95"][1]
        assert all(len(h) == 64 for h in entry["input_files"].values())  # sha256 of each input
        for fig in entry["figures"]:
            assert (run_dir / fig).stat().st_size > 10_000
    assert (run_dir / "figures" / "calibration.png").is_file()
    assert (run_dir / "figures" / "estimates.png").is_file()


def test_held_out_pressures_are_recovered(paper_run):
    _, results = paper_run
    errors = [e["estimates"]["closed-form"]["gauge_pressure_relative_error_vs_manometer"] for e in results["sessions"]
              if "gauge_pressure_relative_error_vs_manometer" in e["estimates"]["closed-form"]]  # fmt: skip
    assert len(errors) == 4
    # the bundled data carry 4 % depth noise and object-specific k_s within ±3 % of the
    # calibrated one: held-out pressures must come back within 10 %
    assert max(abs(e) for e in errors) < 0.10
    k = results["calibration"]["k_s"]
    assert 0.60 < k["value"] < 0.68 and len(results["calibration"]["points"]) == 10


def test_run_directories_are_fresh(tmp_path):
    first = run_experiment(PAPER_CONFIG, output_dir=tmp_path, progress=False)
    second = run_experiment(PAPER_CONFIG, output_dir=tmp_path, progress=False)
    assert first != second and (first / "results.json").is_file() and (second / "results.json").is_file()


def test_estimate_json_on_stdout(capsys):
    code = main(["estimate", str(bundled_data_dir() / "sessions" / "pezzi.toml"), "--method", "closed-form", "--json"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    p_g = out["estimates"]["gauge_pressure"]
    assert p_g["unit"] == "Pa" and math.isfinite(p_g["value"]) and p_g["std"] > 0


def test_cli_reports_bad_input_without_traceback(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('object = "x"\n')
    assert main(["estimate", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.toml" in err and "Traceback" not in err and "Fix:" in err


@pytest.mark.parametrize(
    "text, pattern",
    [
        ('[sessions]\npaths = ["nope/*.toml"]\n', r"sessions.paths'.*matches no file"),
        ('[sessions]\npaths = ["bundled:sessions/pezzi.toml"]\n[estimators]\nmethods = ["magic"]\n', r"unknown method 'magic'"),
        ('colour = 1\n[sessions]\npaths = []\n', r"field 'colour': unknown key"),
        ('[estimators]\nbootstrap_samples = -1\n[sessions]\npaths = ["bundled:sessions/pezzi.toml"]\n', r"bootstrap_samples"),
        ('name = "x"\n', r"sessions.paths'.*missing"),
        ('[estimators]\nwrinkle_law = "folklore"\n[sessions]\npaths = ["bundled:sessions/pezzi.toml"]\n',
         r"estimators.wrinkle_law'.*unknown wrinkle law 'folklore'"),
        ('[estimators]\nbayes_surrogate = "yes"\n[sessions]\npaths = ["bundled:sessions/pezzi.toml"]\n',
         r"estimators.bayes_surrogate'.*not true/false"),
    ],
)
def test_bad_config_is_named(tmp_path, text, pattern):
    path = tmp_path / "c.toml"
    path.write_text(text)
    with pytest.raises(InvalidInputError, match=pattern):
        load_config(path)


def test_console_script_entry_point_runs():
    proc = subprocess.run([sys.executable, "-m", "shelljax.cli", "validate",
                           str(bundled_data_dir() / "sessions" / "hammer.toml")],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "inflatable-hammer" in proc.stdout


def test_config_carries_the_forward_model_options(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text('[estimators]\nmethods = ["fit"]\ngas = "isothermal"\nwrinkle_law = "scaling"\nbayes_surrogate = false\n'
                    '[sessions]\npaths = ["bundled:sessions/pezzi.toml"]\n')  # fmt: skip
    config = load_config(path)
    assert (config.gas, config.wrinkle_law, config.bayes_surrogate) == ("isothermal", "scaling", False)
    assert load_config(PAPER_CONFIG).wrinkle_law == "mechanics"  # the default
