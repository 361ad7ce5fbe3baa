"""The executor layer: in-process and Dask runs agree, a killed worker's item reruns, a resumed run
skips finished items, failures are recorded, and a missing scheduler is one clear error."""

import json
import os
import sys

import cloudpickle
import pytest
from distributed import LocalCluster

from shelljax import InvalidInputError
from shelljax.executor import ExecutorOptions, ItemResult, WorkItem, item_path, read_item, run_items, write_item

# the workers cannot import this test module: its functions travel by value
cloudpickle.register_pickle_by_value(sys.modules[__name__])


def polynomial(x, seed=None):
    """A value that depends on the item's input and its own seed."""
    return {"x": x, "value": x**3 - 2.0 * x + 0.1 * (seed or 0), "seed": seed}


def fails(x):
    raise ValueError(f"input {x} is bad")


def dies_once(marker):
    """Kill the worker process the first time; return on the rerun."""
    if not os.path.exists(marker):
        open(marker, "w").close()
        os._exit(1)
    return {"rerun": True}


def counted(x, log):
    with open(log, "a") as out:
        out.write(f"{x}\n")
    return {"x": x}


@pytest.fixture(scope="module")
def scheduler():
    """A 2-process LocalCluster, reached by address as a user's own scheduler would be."""
    import logging

    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=logging.CRITICAL
    ) as cluster:
        yield cluster.scheduler_address


def _items(n=6):
    return [WorkItem(f"poly/{i}", polynomial, (float(i),), seed=100 + i) for i in range(n)]


def test_cluster_results_equal_serial_and_keep_order(tmp_path, scheduler):
    serial = run_items(_items(), run_dir=tmp_path / "serial")
    remote = run_items(_items(), run_dir=tmp_path / "remote", options=ExecutorOptions(cluster=scheduler))
    assert [r.key for r in remote] == [f"poly/{i}" for i in range(6)]
    assert [r.value for r in remote] == [r.value for r in serial]
    assert all(r.status == "done" for r in remote)
    assert {r.worker for r in remote} - {"local"}, "the items ran on the cluster's workers"
    # each item's seed reached its function
    assert [r.value["seed"] for r in remote] == [100 + i for i in range(6)]
    record = json.loads(item_path(tmp_path / "remote", "poly/3").read_text())
    assert record["status"] == "done" and record["value"] == serial[3].value and record["seconds_unit"] == "s"


def test_a_killed_workers_item_reruns_elsewhere(tmp_path, scheduler):
    marker = tmp_path / "died"
    items = [WorkItem("dies", dies_once, (str(marker),)), *_items(3)]
    results = run_items(items, run_dir=tmp_path / "run", options=ExecutorOptions(cluster=scheduler))
    assert marker.exists(), "the first attempt killed its worker"
    assert results[0].status == "done" and results[0].value == {"rerun": True}
    assert all(r.status == "done" for r in results)


def test_failed_item_is_recorded_with_its_error_not_dropped(tmp_path, scheduler):
    items = [*_items(2), WorkItem("bad", fails, (7,))]
    for options in (ExecutorOptions(), ExecutorOptions(cluster=scheduler)):
        results = run_items(items, run_dir=tmp_path / str(options.distributed), options=options)
        assert [r.status for r in results] == ["done", "done", "failed"]
        assert results[2].error == "ValueError: input 7 is bad" and results[2].value is None
        record = json.loads(item_path(tmp_path / str(options.distributed), "bad").read_text())
        assert record["status"] == "failed" and "input 7 is bad" in record["error"]


def test_resume_skips_finished_items_and_reruns_failed_ones(tmp_path):
    log = tmp_path / "calls.txt"
    run_dir = tmp_path / "run"
    items = [WorkItem(f"c{i}", counted, (i, str(log))) for i in range(4)]
    run_items(items[:2], run_dir=run_dir)  # an interrupted run: two of four items finished
    write_item(run_dir, ItemResult("c2", "failed", error="RuntimeError: was interrupted"))
    results = run_items(items, run_dir=run_dir, resume=True)
    assert log.read_text().split() == ["0", "1", "2", "3"], "items 0 and 1 ran once; the failed one ran again"
    assert [r.resumed for r in results] == [True, True, False, False]
    assert [r.value for r in results] == [{"x": i} for i in range(4)]


def test_records_are_whole_and_a_damaged_one_is_named(tmp_path):
    write_item(tmp_path, ItemResult("a/b", "done", value={"v": 1.5}))
    assert not [p for p in (tmp_path / "items").iterdir() if p.name.endswith(".tmp")], "no temporary file left"
    assert read_item(tmp_path, "a/b").value == {"v": 1.5}
    item_path(tmp_path, "a/b").write_text("{not json")
    with pytest.raises(InvalidInputError, match=r"items/a_b\.json: not a readable item record.*Fix: delete it"):
        read_item(tmp_path, "a/b")


def test_bad_options_and_an_unreachable_scheduler_are_one_line_errors():
    with pytest.raises(InvalidInputError, match=r"--workers = 0: must be a whole number"):
        ExecutorOptions(workers=0)
    with pytest.raises(InvalidInputError, match="both given"):
        ExecutorOptions(workers=2, cluster="tcp://127.0.0.1:8786")
    with pytest.raises(InvalidInputError, match="not a scheduler address"):
        ExecutorOptions(cluster="localhost")
    with pytest.raises(InvalidInputError) as err:
        run_items(_items(1), options=ExecutorOptions(cluster="tcp://127.0.0.1:9", connect_timeout_s=2.0))
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith("--cluster tcp://127.0.0.1:9: no Dask scheduler answered") and "Fix:" in message
    with pytest.raises(InvalidInputError, match="share the key"):
        run_items([WorkItem("same", polynomial, (1.0,)), WorkItem("same", polynomial, (2.0,))])
