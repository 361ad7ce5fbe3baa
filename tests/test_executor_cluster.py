"""The executor's other users: `shelljax diagnose --study` over many studies, bulk virtual sessions
and scenario sweeps; where a result could depend on where it ran, a 2-process cluster gives the
serial values."""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

import cloudpickle
import jax
import numpy as np
import pytest
from distributed import LocalCluster
from test_dynamics_shell import TINY

import shelljax.diagnose
import shelljax.report
from shelljax import InvalidInputError, NoConvergenceError, virtual
from shelljax.cli import main
from shelljax.executor import ExecutorOptions, WorkItem, item_path, run_items
from shelljax.runner import study_groups
from shelljax.scenario import load_scenario, run_sweep
from shelljax.session import load_session

# the workers cannot import this test module: its functions travel by value
cloudpickle.register_pickle_by_value(sys.modules[__name__])

# test_dynamics_shell.py's tiny ball, shorter, without figures, at two pressures
TINY_SWEEP = (
    TINY.replace("duration_s = 0.08", "duration_s = 0.05")
    .replace("figures = true", "figures = false")
    .replace("max_frames = 3", "max_frames = 2")
    .replace("preview_gif = true", "preview_gif = false")
    + '[sweep]\nparameter = "object.gauge_pressure_Pa"\nvalues = [4000.0, 6000.0]\n'
)


@pytest.fixture(scope="module")
def cluster():
    """A 2-process LocalCluster, reached by address as a user's own scheduler would be."""
    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=logging.CRITICAL
    ) as local:
        yield ExecutorOptions(cluster=local.scheduler_address)


def _without_wall_times(tree):
    if isinstance(tree, dict):
        return {
            k: _without_wall_times(v)
            for k, v in tree.items()
            if k not in ("seconds", "wall_seconds", "worker", "executor", "compilation", "directory", "resumed")
        }
    if isinstance(tree, list):
        return [_without_wall_times(v) for v in tree]
    return tree


def cache_settings() -> dict:
    """Where a worker's JAX keeps compiled programs, and from which compile time [s] on."""
    return {
        "directory": jax.config.jax_compilation_cache_dir,
        "min_seconds": jax.config.jax_persistent_cache_min_compile_time_secs,
    }


def test_the_workers_keep_every_program_they_compile_in_the_shared_cache(cluster):
    (result,) = run_items([WorkItem("cache", cache_settings)], options=cluster)
    # the directory this process uses, and no program too quick to keep: a fresh worker loads what another compiled
    assert result.value == {"directory": jax.config.jax_compilation_cache_dir, "min_seconds": 0.0}


# --- scenario sweeps ----------------------------------------------------------------------------
@pytest.mark.slow  # two tiny drops in this process, then on two workers that compile them again
def test_a_sweep_runs_one_scenario_per_value_and_the_cluster_gives_the_serial_values(tmp_path, cluster):
    config = tmp_path / "tiny.toml"
    config.write_text(TINY_SWEEP)
    scenario = load_scenario(config)
    assert scenario.sweep.parameter == "object.gauge_pressure_Pa" and scenario.sweep.values == (4000.0, 6000.0)
    assert main(["simulate", str(config), "--out", str(tmp_path / "serial"), "--quiet"]) == 0
    remote = run_sweep(scenario, tmp_path / "cluster", executor=cluster, progress=False)
    serial = json.loads((tmp_path / "serial" / "sweep.json").read_text())
    assert serial["unit"] == "Pa" and [v["status"] for v in serial["values"]] == ["done", "done"]
    assert [v["parameters"]["gauge_pressure_Pa"] for v in serial["values"]] == [4000.0, 6000.0]
    assert all(v["worker"].startswith("tcp://") for v in remote["values"]), "the values ran on the workers"
    assert _without_wall_times(remote["values"]) == _without_wall_times(serial["values"])
    for name in ("gauge_pressure_Pa_4000", "gauge_pressure_Pa_6000"):  # each value's trajectory, bit for bit
        a, b = (
            json.loads((tmp_path / run / name / "h0.00m" / "results.json").read_text()) for run in ("serial", "cluster")
        )
        assert a["steps"] == b["steps"]
        assert (
            json.loads(item_path(tmp_path / "serial", f"value00{name.endswith('6000'):d}-{name}").read_text())["status"]
            == "done"
        )
    # resuming a finished sweep runs nothing again; resuming it after the config changed is refused
    assert main(["simulate", str(config), "--resume", str(tmp_path / "serial"), "--quiet"]) == 0
    resumed = json.loads((tmp_path / "serial" / "sweep.json").read_text())["values"]
    assert [v["resumed"] for v in resumed] == [True, True] and _without_wall_times(resumed) == _without_wall_times(
        serial["values"]
    )
    config.write_text(TINY_SWEEP.replace("dt_s = 2e-3", "dt_s = 1e-3"))
    with pytest.raises(InvalidInputError, match=r"started with other config_sha256.*Fix"):
        run_sweep(load_scenario(config), tmp_path / "serial", progress=False, resume=True)


@pytest.mark.parametrize(
    ("table", "pattern"),
    [
        ('parameter = "object.radius"\nvalues = [1.0, 2.0]', r"sweep\.parameter.*unknown sweep parameter"),
        ('parameter = "initial.drop_heights_m"\nvalues = 0.5', r"sweep\.values.*non-empty list"),
        ('parameter = "initial.drop_heights_m"\nvalues = [0.5, 0.5]', r"sweep\.values.*repeated"),
        ('parameter = "object.gauge_pressure_Pa"\nvalues = [4000.0, -1.0]', r"object\.gauge_pressure_Pa"),
        ('parameter = "dissipation.cor"\nvalues = [0.5, 1.5]', r"dissipation\.cor.*at most 1"),
    ],
)
def test_the_sweep_table_is_checked_value_by_value(tmp_path, table, pattern):
    config = tmp_path / "bad.toml"
    config.write_text(TINY_SWEEP.partition("[sweep]")[0] + f"[sweep]\n{table}\n")
    with pytest.raises(InvalidInputError, match=pattern) as err:
        load_scenario(config)
    assert str(config) in str(err.value) and "Fix" in str(err.value)


def test_a_sweep_value_is_its_own_scenario_and_workers_need_a_sweep(tmp_path, capsys):
    config = tmp_path / "tiny.toml"
    config.write_text(
        TINY_SWEEP.replace('"object.gauge_pressure_Pa"', '"dissipation.cor"').replace("[4000.0, 6000.0]", "[0.5, 0.7]")
    )
    one = load_scenario(config, value=0.7)
    # the swept COR replaces the config's damping (calibrated to it), and the value's scenario sweeps nothing
    assert one.cor == 0.7 and one.contact_damping is None and one.sweep is None
    assert load_scenario(config).contact_damping == 1.0
    plain = tmp_path / "plain.toml"
    plain.write_text(TINY_SWEEP.partition("[sweep]")[0])
    assert load_scenario(plain).sweep is None
    assert main(["simulate", str(plain), "--workers", "2", "--out", str(tmp_path / "out"), "--quiet"]) == 2
    assert "has none" in capsys.readouterr().err and not (tmp_path / "out").exists()


# --- virtual sessions ---------------------------------------------------------------------------
def test_virtual_sessions_written_on_the_cluster_are_the_serial_draws(tmp_path, cluster):
    curves = virtual.load_curves()[:2]
    serial = virtual.write_sessions(curves, tmp_path / "serial", realisations=1)
    remote = virtual.write_sessions(curves, tmp_path / "cluster", realisations=1, executor=cluster)
    drawn = virtual.draw_sessions(curves, realisations=1)
    assert len(serial) == len(drawn) == 2 * len(virtual.NOISE_LEVELS) and all(e["status"] == "done" for e in remote)
    for (truth, session), a, b in zip(drawn, serial, remote):
        assert {k: a[k] for k in truth} == truth and a["name"] == b["name"] and a["seed"] == b["seed"]
        assert Path(a["path"]).read_bytes() == Path(b["path"]).read_bytes(), "the same file wherever it was drawn"
        written = load_session(a["path"])  # the drawn session, value for value
        for field in ("force", "depth", "wrinkle_counts", "trial"):
            np.testing.assert_array_equal(getattr(written, field), getattr(session, field))
    index = json.loads((tmp_path / "cluster" / "sessions.json").read_text())["sessions"]
    assert [e["seed"] for e in index] == [t["seed"] for t, _ in drawn]


@pytest.mark.slow
def test_curve_sets_are_work_items_merged_in_order_and_a_rerun_skips_the_solved(tmp_path):
    import subprocess

    # one set on a 150-face sphere: about 50 s of 3D solves, the cheapest that runs the real tool
    out = tmp_path / "curves.json"
    command = [
        sys.executable,
        str(Path(__file__).resolve().parents[1] / "tools" / "make_virtual_sessions.py"),
        "--curves",
        "--sets",
        "0",
        "--n-triangles",
        "150",
        "--out",
        str(out),
    ]
    first = subprocess.run(command, capture_output=True, text=True, check=True)
    assert "set0: solved" in first.stdout
    curves = json.loads(out.read_text())["curves"]
    assert [c["set"] for c in curves] == [0] and curves[0]["gauge_pressure"] == virtual.PARAMETER_SETS[0][0]
    assert json.loads(item_path(Path(f"{out}.parts"), "set0").read_text())["status"] == "done"
    again = subprocess.run(command, capture_output=True, text=True, check=True)  # resumed from the record: no solve
    assert "set0: solved" in again.stdout and json.loads(out.read_text())["curves"] == curves


# --- diagnose over many studies -----------------------------------------------------------------
FAILING, CALLS = ["yoga"], []  # which studies the fake diagnosis fails; which it was called on


def _fake_diagnosis(paths, **options):
    """Stands in for the joint fits (their programs are test_diagnose's): a report shaped as diagnose's."""
    CALLS.append(Path(paths[0]).parent.name if "rig" in str(paths[0]) else Path(paths[0]).stem)
    if any(name in str(paths[0]) for name in FAILING):
        raise NoConvergenceError("the baseline fit stopped short", [1.0])
    estimate = {"value": 2.3e6, "ci95": [2.1e6, 2.5e6], "unit": "Pa"}
    report = {
        "verdict": "none",
        "shrink": 1.0,
        "gap_before": {"rms_standardized": 1.1},
        "gap_after": {"rms_standardized": 1.1},
        "winner": None,
        "baseline": {"estimates": {"young_modulus": estimate}},
        "misfit_p_value": 0.4,
        "ranking": [
            {"effect": "baseline", "status": "ok"},
            {"effect": options["effects"][0], "status": "ok", "delta": -0.5, "delta_se": 0.2},
        ],
    }
    return type("Diagnosis", (), {"report": report, "sessions": list(paths)})()


def _fake_write(diagnosis, out_dir):
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "diagnosis.json").write_text(json.dumps({**diagnosis.report, "sessions": diagnosis.sessions}))
    return [out / "diagnosis.json"]


def test_diagnose_over_studies_writes_each_one_and_records_a_failure(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(shelljax.diagnose, "diagnose", _fake_diagnosis)
    monkeypatch.setattr(shelljax.report, "write_diagnosis", _fake_write)
    studies = ["bundled:sessions/calib_pezzi_*.toml", "bundled:sessions/calib_yoga_*.toml", "bundled:sessions/rig"]
    assert [(name, len(files)) for name, files in study_groups(studies)] == [
        ("calib_pezzi", 6),
        ("calib_yoga", 4),
        ("rig", 8),
    ]
    out = tmp_path / "diag"
    argv = [
        "diagnose",
        *[a for s in studies for a in ("--study", s)],
        "--effects",
        "depth_offset",
        "--out",
        str(out),
        "--quiet",
    ]
    assert main(argv) == 0
    table = capsys.readouterr().out
    assert "calib_pezzi" in table and "FAILED: NoConvergenceError: the baseline fit stopped short" in table
    summary = json.loads((out / "diagnoses.json").read_text())
    assert [s["status"] for s in summary["studies"]] == ["done", "failed", "done"]
    done = summary["studies"][0]
    assert done["young_modulus"]["unit"] == "Pa" and done["best_candidate"]["effect"] == "depth_offset"
    assert json.loads((out / "calib_pezzi" / "diagnosis.json").read_text())["sessions"][0].endswith(
        "calib_pezzi_0900Pa.toml"
    )
    assert json.loads(item_path(out, "study001-calib_yoga").read_text())["status"] == "failed"
    assert summary["options"]["effects"] == ["depth_offset"] and summary["executor"] == {"backend": "in-process"}
    # resumed once the cause is fixed: only the failed study runs again
    CALLS.clear()
    monkeypatch.setattr(sys.modules[__name__], "FAILING", [])
    assert main([*argv[:-3], "--resume", str(out), "--quiet"]) == 0
    assert CALLS == ["calib_yoga_0800Pa"]
    summary = json.loads((out / "diagnoses.json").read_text())
    assert [s["status"] for s in summary["studies"]] == ["done"] * 3 and [s["resumed"] for s in summary["studies"]] == [
        True,
        False,
        True,
    ]
    capsys.readouterr()
    assert main([*argv[:-3], "--effects", "gas", "--resume", str(out), "--quiet"]) == 2  # other options: refused
    assert "was started with other options" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["a.toml", "--study", "bundled:sessions/calib_yoga_*.toml", "--out", "x"], "both given"),
        (["--study", "bundled:sessions/calib_yoga_*.toml"], "--study needs --out"),
        (["--study", "no/such/dir", "--out", "x"], "no session file there"),
        (["--study", "bundled:sessions/calib_yoga_*.toml", "--out", "x", "--effects", "finger_size"], "unknown effect"),
        (["bundled.toml", "--workers", "2"], "--workers/--cluster/--resume run many studies"),
        (
            ["--study", "bundled:sessions/calib_yoga_*.toml", "--resume", "x"],
            "not a diagnosis of many studies shelljax can resume",
        ),
        ([], "no sessions given"),
    ],
)
def test_diagnose_over_studies_refuses_bad_input_before_running(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    assert main(["diagnose", *argv, "--quiet"]) == 2
    err = capsys.readouterr().err
    assert message in err and "Fix" in err and err.count("\n") == 1
    assert not (tmp_path / "x").exists()
