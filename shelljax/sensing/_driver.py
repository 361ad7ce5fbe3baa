"""Serial driver for the force sensor: reads protocol lines, survives garbage and unplugs.

Only pyserial and the standard library: no JAX here.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from typing import Any

import serial

from .._errors import DeviceError
from ._protocol import HELLO_REQUEST, MAX_T_MS, Hello, RawSample, StreamParser

logger = logging.getLogger("shelljax.sensing")

DEFAULT_BAUD = 115200
_WARN_FIRST = 20  # malformed lines warned about one by one, then every _WARN_EVERY-th
_WARN_EVERY = 500
_WRAP_WINDOW_MS = 60_000  # a clock that falls back by ~2**32 ms wrapped; by less, the device reset


@dataclasses.dataclass(frozen=True)
class Sample:
    """One sample as received by the host.

    ``host_time`` [s] is the host clock when the batch was read (Unix time by default);
    ``device_time`` [s] is the device clock unwrapped past the 2**32 ms rollover, counted from
    the device's last reset; ``connection`` increments at every (re)connect or device reset, so
    ``(connection, device_time)`` orders samples; ``raw`` holds the ADC counts per channel.
    """

    host_time: float
    device_time: float
    connection: int
    raw: tuple[int, ...]


@dataclasses.dataclass
class DriverStats:
    """Counters since the driver was created."""

    n_samples: int = 0
    n_malformed: int = 0
    n_unknown: int = 0
    n_reconnects: int = 0
    n_bytes: int = 0
    n_out_of_range: int = 0  # samples with counts above the ADC range the hello announced


class SerialSensor:
    """Reads :class:`Sample` batches from a force sensor on a serial port.

    Args:
        port: a device path (``/dev/ttyACM0``, ``COM3``) or any pyserial URL
            (``socket://host:port``, ``rfc2217://...``, ``loop://``), opened with
            ``serial.serial_for_url``.
        baudrate: [bit/s], must match the firmware (default 115200).
        opener: instead of ``port``, a callable returning an open pyserial-like object
            (used for the in-process emulator); it raises ``serial.SerialException`` when the
            device is absent.
        read_timeout: [s] blocking time of one port read.
        reconnect_timeout: [s] how long to keep trying after a disconnect before raising
            :class:`~shelljax.DeviceError`.
        reconnect_interval: [s] pause between reconnection attempts.
        clock, sleep, wallclock: time sources (monotonic [s], sleep [s], host timestamp [s]);
            the emulator passes its virtual clock so tests do not wait.

    Malformed or partial lines are counted in :attr:`stats` and skipped with a warning on the
    ``shelljax.sensing`` logger; they never raise.
    """

    def __init__(
        self,
        port: str | None = None,
        baudrate: int = DEFAULT_BAUD,
        *,
        opener: Callable[[], Any] | None = None,
        read_timeout: float = 0.02,
        reconnect_timeout: float = 10.0,
        reconnect_interval: float = 0.25,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        wallclock: Callable[[], float] = time.time,
    ):
        if (port is None) == (opener is None):
            raise ValueError("give exactly one of port= or opener=")
        self.port_name = port if port is not None else "<emulated>"
        self.baudrate = baudrate
        self._opener = opener or (lambda: serial.serial_for_url(port, baudrate=baudrate, timeout=read_timeout))
        self.read_timeout = read_timeout
        self.reconnect_timeout = reconnect_timeout
        self.reconnect_interval = reconnect_interval
        self.clock, self.sleep, self.wallclock = clock, sleep, wallclock
        self.stats = DriverStats()
        self.hello: Hello | None = None
        self.connection = 0
        self._port: Any = None
        self._parser = StreamParser()
        self._last_t_ms: int | None = None
        self._wrap_ms = 0
        self._malformed_seen = 0

    # -- connection ---------------------------------------------------------------------------
    def __enter__(self) -> "SerialSensor":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def is_open(self) -> bool:
        return self._port is not None

    def open(self) -> None:
        """Open the port. Raises :class:`~shelljax.DeviceError` if it cannot be opened."""
        try:
            self._connect()
        except (serial.SerialException, OSError, ValueError) as error:
            raise DeviceError(
                f"could not open serial port {self.port_name!r} at {self.baudrate} baud: {error}. "
                "Fix: check the cable and the port name (list ports with "
                "`python -m serial.tools.list_ports`), close other programs using the port "
                "(e.g. the Arduino serial monitor), or use `--emulate` to try without hardware"
            ) from error

    def close(self) -> None:
        if self._port is not None:
            try:
                self._port.close()
            except (serial.SerialException, OSError):
                pass
            self._port = None
        if self.stats.n_malformed > self._malformed_seen:
            self._report_malformed(final=True)

    def _connect(self) -> None:
        self._port = self._opener()
        self.connection += 1
        self._parser.drop_partial()
        self._last_t_ms = None
        self._wrap_ms = 0
        try:
            self._port.write(HELLO_REQUEST)
        except (serial.SerialException, OSError):
            pass  # read-only links (some URL handlers) still deliver samples

    def _reconnect(self, error: Exception) -> None:
        logger.warning("sensor on %s disconnected (%s); reconnecting", self.port_name, error)
        if self._port is not None:
            try:
                self._port.close()
            except (serial.SerialException, OSError):
                pass
            self._port = None
        partial = self._parser.drop_partial()
        if partial is not None:
            self.stats.n_malformed += 1
        start = self.clock()
        while True:
            try:
                self._connect()
            except (serial.SerialException, OSError) as again:
                if self.clock() - start > self.reconnect_timeout:
                    raise DeviceError(
                        f"sensor on {self.port_name!r} disconnected ({error}) and did not come back "
                        f"within {self.reconnect_timeout:g} s (last error: {again}). Fix: reconnect "
                        "the cable and resume the recording with `--resume`"
                    ) from again
                self.sleep(self.reconnect_interval)
            else:
                self.stats.n_reconnects += 1
                logger.warning("sensor on %s reconnected", self.port_name)
                return

    # -- reading ------------------------------------------------------------------------------
    def read(self, max_wait: float = 0.05) -> list[Sample]:
        """Samples that arrive within about ``max_wait`` [s] (at least one port read).

        Reconnects transparently after a disconnect; raises :class:`~shelljax.DeviceError` only
        if the device stays away longer than ``reconnect_timeout``.
        """
        if self._port is None:
            self.open()
        samples: list[Sample] = []
        start = self.clock()
        while True:
            try:
                waiting = self._port.in_waiting
                data = self._port.read(waiting if waiting else 1)
            except (serial.SerialException, OSError) as error:
                self._reconnect(error)
                data = b""
            if data:
                self._ingest(data, samples)
            if self.clock() - start >= max_wait:
                return samples

    def _ingest(self, data: bytes, samples: list[Sample]) -> None:
        self.stats.n_bytes += len(data)
        frames, errors = self._parser.feed(data)
        self.stats.n_malformed += len(errors)
        if errors:
            self._report_malformed()
        self.stats.n_unknown = self._parser.n_unknown
        now = self.wallclock()
        for frame in frames:
            if isinstance(frame, Hello):
                # Not an epoch marker: hellos also answer `?` mid-stream. Resets show as the
                # device clock going back (see _unwrap).
                self.hello = frame
                logger.info(
                    "sensor: %s %s, %g Hz, %d-bit, %d channel(s)",
                    frame.firmware,
                    frame.version,
                    frame.rate_hz,
                    frame.adc_bits,
                    frame.n_channels,
                )
                continue
            assert isinstance(frame, RawSample)
            if self.hello is not None and max(frame.raw) >= 2**self.hello.adc_bits:
                self.stats.n_out_of_range += 1
                self.stats.n_malformed += 1
                self._report_malformed(reason="counts above the announced ADC range")
                continue
            samples.append(Sample(now, self._unwrap(frame.t_ms) / 1000.0, self.connection, frame.raw))
            self.stats.n_samples += 1

    def _new_epoch(self) -> None:
        """The device reset without the port closing: its clock restarts."""
        self.connection += 1
        self._last_t_ms = None
        self._wrap_ms = 0

    def _unwrap(self, t_ms: int) -> int:
        last = self._last_t_ms
        if last is not None and t_ms < last:
            if last - t_ms > MAX_T_MS - _WRAP_WINDOW_MS:
                self._wrap_ms += MAX_T_MS + 1
            else:
                logger.warning("sensor clock went back from %d ms to %d ms: device reset", last, t_ms)
                self._new_epoch()
        self._last_t_ms = t_ms
        return t_ms + self._wrap_ms

    def _report_malformed(self, final: bool = False, reason: str | None = None) -> None:
        n = self.stats.n_malformed
        error = self._parser.last_error
        why = reason or (error.reason if error is not None else "malformed")
        if final:
            logger.warning("sensor on %s: %d malformed line(s) skipped in total", self.port_name, n)
        elif n <= _WARN_FIRST or n % _WARN_EVERY == 0:
            detail = f": {error.line[:40]!r}" if error is not None and reason is None else ""
            logger.warning("skipped a malformed line from %s (%s)%s; %d so far", self.port_name, why, detail, n)
        self._malformed_seen = n
