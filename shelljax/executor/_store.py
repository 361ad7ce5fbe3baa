"""A run directory's item records: one JSON file per finished work item, written atomically.

``<run_dir>/items/<key>.json`` holds :class:`ItemResult`'s fields. A file is written to a
temporary name and renamed into place, so a run killed at any moment leaves whole records or none,
and ``--resume`` trusts every file it finds.
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

from .._errors import InvalidInputError
from .._files import atomic_write_text

ITEMS_DIR = "items"
INPUTS = "inputs.json"  # what a run's items were made of, so that a resumed run can be checked against it
STATUSES = ("done", "failed")


@dataclasses.dataclass(frozen=True)
class ItemResult:
    """What one work item gave: ``key``; ``status`` "done" or "failed"; ``value`` (the item
    function's JSON-ready return, None when failed); ``error`` ("Type: message", None when done);
    ``seconds`` [s] of wall time on its worker; ``worker`` (its address, "local" in-process);
    ``seed`` (the item's own, or None); ``resumed`` (read back from an earlier run)."""

    key: str
    status: str
    value: object = None
    error: str | None = None
    seconds: float = 0.0
    worker: str = "local"
    seed: int | None = None
    resumed: bool = False

    def to_dict(self) -> dict:
        """JSON-ready: every field but ``resumed``, ``seconds`` with its unit."""
        return {
            "key": self.key,
            "status": self.status,
            "value": self.value,
            "error": self.error,
            "seconds": self.seconds,
            "seconds_unit": "s",
            "worker": self.worker,
            "seed": self.seed,
        }


def item_path(run_dir: Path, key: str) -> Path:
    """The record file of ``key`` under ``run_dir`` (the key made a safe file name)."""
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", key).strip("._") or "item"
    return Path(run_dir) / ITEMS_DIR / f"{safe}.json"


def write_item(run_dir: Path, result: ItemResult) -> Path:
    """Write ``result``'s record atomically (temporary file, then rename); return its path."""
    path = item_path(run_dir, result.key)
    path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write_text(path, json.dumps(result.to_dict(), indent=1, allow_nan=True))


def read_item(run_dir: Path, key: str) -> ItemResult | None:
    """The finished record of ``key`` in ``run_dir``, or None when there is none (or it failed:
    a failed item is run again on resume)."""
    path = item_path(run_dir, key)
    if not path.exists():
        return None
    try:
        record = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise InvalidInputError(
            f"{path}: not a readable item record ({err}). Fix: delete it; --resume then reruns the item"
        )
    if record.get("key") != key or record.get("status") not in STATUSES:
        raise InvalidInputError(
            f"{path}: field 'key' = {record.get('key')!r} / 'status' = {record.get('status')!r} "
            f"is not a record of item {key!r}. Fix: delete it; --resume then reruns the item"
        )
    if record["status"] != "done":
        return None
    return ItemResult(
        key=key,
        status="done",
        value=record.get("value"),
        seconds=float(record.get("seconds", 0.0)),
        worker=str(record.get("worker", "local")),
        seed=record.get("seed"),
        resumed=True,
    )


def check_inputs(run_dir: Path, inputs: dict, *, resume: bool, what: str) -> None:
    """Record ``inputs`` (JSON: what the items are made of) in ``run_dir``; on ``resume``, refuse a
    run directory whose recorded inputs differ, since its finished items answer those.

    Raises:
        InvalidInputError: resuming a directory without a record, or one made of other inputs.
    """
    path = Path(run_dir) / INPUTS
    inputs = json.loads(json.dumps(inputs))  # as it reads back: lists, not tuples
    if not resume:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps(inputs, indent=1))
        return
    if not path.exists():
        raise InvalidInputError(
            f"--resume {run_dir}: no {INPUTS} there, so it is not a {what} shelljax can resume. "
            f"Fix: give the --out directory of the interrupted {what}, or start a fresh one"
        )
    recorded = json.loads(path.read_text())
    changed = sorted(k for k in set(recorded) | set(inputs) if recorded.get(k) != inputs.get(k))
    if changed:
        raise InvalidInputError(
            f"--resume {run_dir}: that {what} was started with other {', '.join(changed)}, so its "
            f"finished items answer those. Fix: resume it as it was started, or start a fresh one "
            "in another --out"
        )
