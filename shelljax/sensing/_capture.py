"""Pulling samples off the driver: the durable sample log, force conversion, stable windows.

Durability guarantee of :class:`SampleLog`: every batch the driver returns is written, flushed
and ``fsync``-ed before anything else happens with it (display, capture, prompts). A sample is
therefore on disk before the recording acts on it; a crash, kill or unplug loses at most samples
still inside the OS serial buffer, which the program never received. A batch spans at most
``batch_s`` (default 0.05 s) of data.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

import numpy as np

from ._calibration import OK, SensorCalibration
from ._console import Console
from ._driver import Sample, SerialSensor

LOG_COLUMNS = (
    "row",
    "host_time_s",
    "device_time_s",
    "connection",
    "raw0",
    "raw1",
    "force_N",
    "force_std_N",
    "flags",
    "phase",
    "trial",
)


class SampleLog:
    """Append-only CSV of every received sample (columns :data:`LOG_COLUMNS`).

    Reopening an existing log continues its row numbering; a torn last line (power loss in the
    middle of a write) is terminated so later rows stay parseable, and readers skip it.
    """

    def __init__(self, path: str | Path, *, durable: bool = True):
        self.path = Path(path)
        self.durable = durable
        exists = self.path.exists() and self.path.stat().st_size > 0
        self.n_rows = 0
        if exists:
            data = self.path.read_bytes()
            self.n_rows = max(data.count(b"\n") - 1, 0)
        self._file = open(self.path, "ab", buffering=0)
        if not exists:
            self._write((",".join(LOG_COLUMNS) + "\n").encode())
        elif not data.endswith(b"\n"):
            self._write(b"\n")
            self.n_rows += 1  # the torn line counts as a (malformed) row

    def _write(self, data: bytes) -> None:
        self._file.write(data)
        if self.durable:
            os.fsync(self._file.fileno())

    def append(self, rows: list[tuple]) -> None:
        """Write rows (tuples in :data:`LOG_COLUMNS` order, without ``row``) durably."""
        if not rows:
            return
        lines = []
        for values in rows:
            lines.append(",".join([str(self.n_rows)] + [_fmt(v) for v in values]))
            self.n_rows += 1
        self._write(("\n".join(lines) + "\n").encode())

    def close(self) -> None:
        self._file.close()


def _fmt(value) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return "nan" if math.isnan(value) else repr(value)
    return str(value)


def read_sample_log(path: str | Path) -> dict[str, np.ndarray]:
    """Read a sample log into columns (rows that do not parse, e.g. a torn line, are skipped)."""
    rows = []
    with open(path) as handle:
        header = handle.readline().strip().split(",")
        for line in handle:
            parts = line.rstrip("\n").split(",")
            if len(parts) == len(header):
                rows.append(parts)
    columns: dict[str, np.ndarray] = {}
    for i, name in enumerate(header):
        values = [r[i] for r in rows]
        if name in ("phase",):
            columns[name] = np.array(values, dtype=object)
        else:
            columns[name] = np.array([float(v) if v not in ("",) else np.nan for v in values])
    return columns


class Operator(Protocol):
    """The hands: a person with real hardware (no-ops) or the emulator's simulated finger."""

    def press(self, force: float) -> None: ...  # target force [N]
    def hold(self) -> None: ...  # the level was captured: stop pushing, keep still
    def see(self, force: float) -> None: ...  # the displayed force [N], to close the loop
    def place_weight(self, force: float) -> None: ...  # a known dead weight [N]
    def release(self) -> None: ...
    def suggest_depth(self) -> float | None: ...  # [m]
    def suggest_wrinkles(self) -> int | None: ...


class HumanOperator:
    """Real hardware: the person follows the display; nothing to suggest."""

    def press(self, force: float) -> None:
        pass

    def hold(self) -> None:
        pass

    def see(self, force: float) -> None:
        pass

    def place_weight(self, force: float) -> None:
        pass

    def release(self) -> None:
        pass

    def suggest_depth(self) -> float | None:
        return None

    def suggest_wrinkles(self) -> int | None:
        return None


@dataclasses.dataclass(frozen=True)
class Reading:
    """One received sample converted: device time [s], c [-], force and its std [N], flags."""

    device_time: float
    connection: int
    raw: tuple[int, ...]
    c: float
    force: float
    force_std: float
    flags: int


class Pump:
    """Reads batches from the driver, logs them durably, converts them and redraws the display."""

    def __init__(
        self,
        driver: SerialSensor,
        calibration: SensorCalibration | None,
        log: SampleLog,
        console: Console,
        *,
        batch_s: float = 0.05,
        on_batch: Callable[["Pump", list[Reading]], None] | None = None,
    ):
        self.driver, self.calibration, self.log, self.console = driver, calibration, log, console
        self.batch_s = batch_s
        self.on_batch = on_batch
        self.zero = calibration.zero if calibration is not None else 0.0
        self.phase = "idle"
        self.trial = 0
        self.headline = ""
        self.last: Reading | None = None
        self.received = 0

    def pull(self) -> list[Reading]:
        batch: list[Sample] = self.driver.read(self.batch_s)
        readings = self._convert(batch)
        self.log.append(
            [
                (
                    s.host_time,
                    s.device_time,
                    s.connection,
                    s.raw[0],
                    s.raw[1] if len(s.raw) > 1 else None,
                    r.force,
                    r.force_std,
                    r.flags,
                    self.phase,
                    self.trial,
                )
                for s, r in zip(batch, readings, strict=True)
            ]
        )
        self.received += len(batch)
        if readings:
            self.last = readings[-1]
        self._display()
        if self.on_batch is not None:
            self.on_batch(self, readings)
        return readings

    def _convert(self, batch: list[Sample]) -> list[Reading]:
        if not batch:
            return []
        raw0 = np.array([s.raw[0] for s in batch], dtype=np.float64)
        if self.calibration is None:  # calibrating: counts only
            return [Reading(s.device_time, s.connection, s.raw, math.nan, math.nan, math.nan, OK) for s in batch]
        c = self.calibration.conductance(raw0)
        reading = self.calibration.force(raw0, zero=self.zero)
        return [
            Reading(
                s.device_time,
                s.connection,
                s.raw,
                float(c[i]),
                float(reading.force[i]),
                float(reading.std[i]),
                int(reading.flags[i]),
            )
            for i, s in enumerate(batch)
        ]

    def _display(self) -> None:
        r = self.last
        if r is None:
            force = "   --   "
        elif self.calibration is None:
            force = f"raw {r.raw[0]:5d}"
        elif r.flags & 4:
            force = "SATURATED"
        else:
            force = f"{r.force:6.2f} ± {r.force_std:4.2f} N"
            if r.flags & 2:
                force += " ABOVE CALIBRATED RANGE"
        stats = self.driver.stats
        extra = f" bad {stats.n_malformed}" if stats.n_malformed else ""
        extra += f" reconnects {stats.n_reconnects}" if stats.n_reconnects else ""
        self.console.status(f"{self.headline} | {force} | samples {self.received}{extra}")

    def collect(self, duration: float) -> list[Reading]:
        """All readings of the next ``duration`` [s] (driver clock)."""
        readings: list[Reading] = []
        start = self.driver.clock()
        while self.driver.clock() - start < duration:
            readings.extend(self.pull())
        return readings

    def wait_stable(
        self,
        accept: Callable[[Reading], bool],
        duration: float,
        timeout: float,
        watch: Callable[[Reading], None] | None = None,
    ) -> list[Reading] | None:
        """The first window of ``duration`` [s] of consecutive readings all accepted, or ``None``
        after ``timeout`` [s] (driver clock). A rejected reading or a reconnect restarts the
        window; windows need at least 3 readings. ``watch`` sees the newest reading of every
        batch (the emulated operator closes its loop on it)."""
        window: deque[Reading] = deque()
        start = self.driver.clock()
        while self.driver.clock() - start < timeout:
            readings = self.pull()
            if watch is not None and readings:
                watch(readings[-1])
            for r in readings:
                if window and (r.connection != window[0].connection or r.device_time < window[-1].device_time):
                    window.clear()
                if not accept(r):
                    window.clear()
                    continue
                window.append(r)
                period = (window[-1].device_time - window[0].device_time) / max(len(window) - 1, 1)
                if len(window) >= 3 and window[-1].device_time - window[0].device_time >= duration - period:
                    return list(window)
        return None


def accept_force(target: float, tolerance: float) -> Callable[[Reading], bool]:
    """Accepts in-range readings within ``tolerance`` [N] of ``target`` [N]."""
    return lambda r: r.flags == OK and abs(r.force - target) <= tolerance
