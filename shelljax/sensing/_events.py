"""The recording's event log: an append-only JSON-lines file, fsync-ed per event (start, tare,
level, skip, trial, resume, done), and the state an interrupted recording resumes from.

The log is appended event by event while the user records, so it streams to disk rather than
being rewritten whole: a crash or a power cut loses no event that was acted on.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

from .._errors import InvalidInputError

EVENTS_VERSION = 1


class EventLog:
    """Append-only JSON-lines file, fsync-ed per event. A torn last line is ignored on reading."""

    def __init__(self, path: Path):
        self.path = path
        self._file = open(path, "ab", buffering=0)
        if path.stat().st_size and not path.read_bytes().endswith(b"\n"):
            self._file.write(b"\n")

    def append(self, event: dict) -> None:
        self._file.write((json.dumps(event, sort_keys=True) + "\n").encode())
        os.fsync(self._file.fileno())

    def close(self) -> None:
        self._file.close()

    @staticmethod
    def read(path: Path) -> list[dict]:
        events = []
        for line in path.read_text().splitlines():
            if not line.strip():
                continue
            try:
                events.append(json.loads(line))
            except json.JSONDecodeError:
                continue  # torn by a crash in mid-write; the event after it was never acted on
        return events


@dataclasses.dataclass
class RecordingState:
    """What the event log says has been recorded."""

    start: dict
    levels: dict[int, list[dict]] = dataclasses.field(default_factory=dict)
    skipped: dict[int, set[float]] = dataclasses.field(default_factory=dict)
    wrinkles: dict[int, int] = dataclasses.field(default_factory=dict)

    @classmethod
    def from_events(cls, events: list[dict], path: Path) -> "RecordingState":
        if not events or events[0].get("event") != "start":
            raise InvalidInputError(
                f"{path}: no start event, so there is nothing to resume. Fix: start a new recording "
                "without --resume (delete or move the old files first)"
            )
        if events[0].get("version") != EVENTS_VERSION:
            raise InvalidInputError(f"{path}: event log version {events[0].get('version')!r} unknown")
        state = cls(events[0])
        for event in events[1:]:
            kind, trial = event.get("event"), event.get("trial")
            if kind == "level":
                state.levels.setdefault(trial, []).append(event)
            elif kind == "skip":
                state.skipped.setdefault(trial, set()).add(event["target"])
            elif kind == "trial":
                state.wrinkles[trial] = event["wrinkles"]
        return state

    def done_targets(self, trial: int) -> set[float]:
        return {e["target"] for e in self.levels.get(trial, [])} | self.skipped.get(trial, set())

    def next_trial(self) -> int:
        trial = 1
        while trial in self.wrinkles:
            trial += 1
        return trial
