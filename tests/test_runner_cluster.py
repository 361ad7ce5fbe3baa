"""`shelljax run` on Dask workers and resumed: the serial run's results, sessions never lost."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from test_runner_cli import paper_variant

import shelljax.runner._run as run_module
from shelljax import InvalidInputError
from shelljax.cli import main
from shelljax.config import load_config
from shelljax.runner import run_experiment, summary_table


HELD_OUT = ["bundled:sessions/heldout_pezzi_1100Pa.toml", "bundled:sessions/heldout_pezzi_1450Pa.toml"]
THREE = HELD_OUT + ["bundled:sessions/pezzi.toml"]


def _values(tree, prefix=""):
    """Every leaf of a results tree by its path, except what differs by design (wall times, workers)."""
    if isinstance(tree, dict):
        out = {}
        for key, value in tree.items():
            if key not in ("seconds", "wall_seconds", "compilation", "worker"):
                out.update(_values(value, f"{prefix}/{key}"))
        return out
    if isinstance(tree, list):
        return {k: v for i, value in enumerate(tree) for k, v in _values(value, f"{prefix}/{i}").items()}
    return {prefix: tree}


def _results(run_dir: Path) -> dict:
    return json.loads((run_dir / "results.json").read_text())


@pytest.mark.slow  # a 2-process cluster: each worker imports shelljax and loads the fit and bayes programs
def test_a_run_on_two_workers_gives_the_serial_results_bit_for_bit(tmp_path):
    # Without figures: they are drawn from the numbers compared here (a posterior's corner and trace
    # plots took about a sixth of its session's bayes stage in a profile, and every process imports
    # matplotlib for them; the test took 144 s instead of 165 s), and the runner's figures are checked
    # by tests/test_runner_cli.py and tests/test_outputs_report.py. What each worker writes into the
    # run directory is still compared: the chain files below.
    config = paper_variant(tmp_path, ["closed-form", "fit", "bayes"], HELD_OUT)
    config.write_text(config.read_text().replace("[outputs]\nfigures = true", "[outputs]\nfigures = false"))
    assert "figures = false" in config.read_text()
    serial = run_experiment(config, output_dir=tmp_path / "serial", progress=False)
    assert main(["run", str(config), "--out", str(tmp_path / "cluster"), "--workers", "2", "--quiet"]) == 0
    (cluster,) = (tmp_path / "cluster").iterdir()
    a, b = _results(serial), _results(cluster)
    assert b["executor"] == {"backend": "dask", "local_cluster_workers": 2}
    assert all(item["worker"].startswith("tcp://") for item in b["items"]), "the sessions ran on the workers"
    values = _values(a["sessions"])
    assert len(values) > 300 and values == _values(b["sessions"])
    for name in ("heldout_pezzi_1100Pa.h5", "heldout_pezzi_1450Pa.h5"):  # the same chains, sample for sample
        with h5py.File(serial / "chains" / name) as x, h5py.File(cluster / "chains" / name) as y:
            (group,) = x.keys()
            assert x[group]["chain"].shape[0] > 10 and np.array_equal(x[group]["chain"][...], y[group]["chain"][...])


def test_an_interrupted_run_resumes_keeping_the_finished_sessions(tmp_path, monkeypatch, capsys):
    config = paper_variant(tmp_path, ["closed-form"], THREE)
    calls, interrupts = [], [True]  # Ctrl-C once, at the second session
    original = run_module.estimate_session_item

    def interrupted_at_the_second(*args, **kwargs):
        calls.append(args[0])
        if len(calls) == 2 and interrupts:
            interrupts.pop()
            raise KeyboardInterrupt
        return original(*args, **kwargs)

    monkeypatch.setattr(run_module, "estimate_session_item", interrupted_at_the_second)
    assert main(["run", str(config), "--out", str(tmp_path / "runs"), "--quiet"]) == 130
    (run_dir,) = (tmp_path / "runs").iterdir()
    assert f"shelljax run --resume {run_dir}" in capsys.readouterr().err
    assert not (run_dir / "results.json").exists() and len(list((run_dir / "items").glob("*.json"))) == 1
    calls.clear()
    assert main(["run", "--resume", str(run_dir), "--quiet"]) == 0
    assert len(calls) == 2, "only the two unfinished sessions ran again"
    resumed = _results(run_dir)
    assert [item["resumed"] for item in resumed["items"]] == [True, False, False]
    fresh = run_experiment(config, output_dir=tmp_path / "fresh", progress=False)
    assert _values(resumed["sessions"]) == _values(_results(fresh)["sessions"])


def test_a_failed_session_is_recorded_with_its_error_and_the_others_kept(tmp_path, monkeypatch):
    config = paper_variant(tmp_path, ["closed-form"], HELD_OUT)
    original = run_module.estimate_session_item

    def fails_on_1450(path, *args, **kwargs):
        if "1450" in path:
            raise RuntimeError("the sensor's cable came loose")
        return original(path, *args, **kwargs)

    monkeypatch.setattr(run_module, "estimate_session_item", fails_on_1450)
    with pytest.warns(UserWarning, match="cable came loose"):
        run_dir = run_experiment(config, output_dir=tmp_path, progress=False)
    results = _results(run_dir)
    failed = results["sessions"][1]
    assert (
        failed["error"] == "RuntimeError: the sensor's cable came loose" and failed["inputs"]["radius"]["unit"] == "m"
    )
    assert "gauge_pressure" in results["sessions"][0]["estimates"]["closed-form"]
    assert [i["status"] for i in results["items"]] == ["done", "failed"]
    assert "failed" in summary_table(results).splitlines()[3]


def test_resume_refuses_what_it_cannot_resume(tmp_path):
    config = paper_variant(tmp_path, ["closed-form"], HELD_OUT[:1])
    run_dir = run_experiment(config, output_dir=tmp_path / "runs", progress=False)
    with pytest.raises(InvalidInputError, match=r"no run\.json there.*Fix"):
        run_experiment(resume=tmp_path)
    config.write_text(config.read_text().replace("seed = 0", "seed = 1"))
    with pytest.raises(InvalidInputError, match="has changed since the run started.*Fix: start a fresh run"):
        run_experiment(resume=run_dir)
    with pytest.raises(InvalidInputError, match="no experiment config given"):
        run_experiment()


@pytest.mark.parametrize(
    ("table", "pattern"),
    [
        ("workers = 0", r"executor\.workers.*integer >= 1"),
        ('workers = 2\ncluster = "tcp://h:8786"', "both workers and cluster"),
        ('cluster = "h:8786"', r"executor\.cluster.*not a scheduler address"),
        ("threads = 2", "threads"),
    ],
)
def test_the_executor_table_is_checked(tmp_path, table, pattern):
    config = paper_variant(tmp_path, ["closed-form"], HELD_OUT[:1])
    config.write_text(config.read_text() + f"\n[executor]\n{table}\n")
    with pytest.raises(InvalidInputError, match=pattern):
        load_config(config)


def test_an_unreachable_scheduler_is_one_line_naming_the_option(tmp_path, capsys):
    config = paper_variant(tmp_path, ["closed-form"], HELD_OUT[:1])
    code = main(["run", str(config), "--out", str(tmp_path), "--cluster", "tcp://127.0.0.1:9", "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.count("\n") == 0
    assert err.startswith("shelljax: error: --cluster tcp://127.0.0.1:9: no Dask scheduler answered") and "Fix:" in err
