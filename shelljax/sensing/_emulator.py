"""A software force sensor that speaks the line protocol, for tests and demos without hardware.

:class:`EmulatedDevice` simulates a finger poking a pressurized ball through a piezoresistive film
(non-linear: conductance ∝ force**β, read through a voltage divider), an optional depth gauge on
the second channel, sensor noise, baseline drift, saturation, garbage bytes, corrupted lines and
unplugs. It runs on a virtual clock, so a whole recording takes a fraction of a second.

Two ways to talk to it, both through the same :class:`~shelljax.sensing.SerialSensor` code path:

* :meth:`EmulatedDevice.open_port` returns an in-process pyserial-like port (``read``,
  ``in_waiting``, ``write``, ``close``); pass it as ``SerialSensor(opener=device.open_port, ...)``.
* :class:`PtyLink` (POSIX) serves the device on a pseudo-terminal behind a stable symlink, which
  any program opens like real hardware (``shelljax acquire --port <link>``). Unplugs close the
  pty, so readers see the same I/O error as a pulled USB cable.
"""

from __future__ import annotations

import dataclasses
import math
import os
import tempfile
import threading
import time
from collections.abc import Callable

import numpy as np
import serial

from ..paper import DEFAULT_POISSON_RATIO, PAPER_KS, scaling_wrinkle_count
from ._protocol import HELLO_REQUEST, Hello, RawSample, format_hello, format_sample


@dataclasses.dataclass(frozen=True)
class FilmSensor:
    """Piezoresistive film in a voltage divider, read by an ``adc_bits`` ADC.

    The film's conductance G, scaled by the divider resistor R_m, is ``c = R_m G``
    (dimensionless). Under force F [N] it follows a power law on top of a zero-load value::

        c(F, t) = preload + drift * t + g * sensitivity * F_eff**exponent
        F_eff   = F / (1 + (F / saturation_force)**8)**(1/8)      (the film saturates)
        counts  = round(adc_max * c / (1 + c) + noise)            (divider, clipped to the ADC)

    ``g`` is lognormal with ``placement_scatter``, redrawn at every new contact (a weight lands a
    little off the active area's centre, a finger presses at another angle): the repeatability
    limit of real films, which calibration must report as uncertainty.
    """

    sensitivity: float = 0.12  # [N**-exponent]
    exponent: float = 1.15  # [-]
    preload: float = 0.04  # [-] c at zero force: the film is bent around the fingertip
    drift: float = 0.0  # [1/s] baseline drift of c
    saturation_force: float = 60.0  # [N]
    adc_bits: int = 10
    noise_counts: float = 1.0  # [counts] standard deviation of the ADC noise
    placement_scatter: float = 0.02  # [-] relative sensitivity change per new contact (std)

    @property
    def adc_max(self) -> int:
        return 2**self.adc_bits - 1

    def conductance(self, force: float, t: float, gain: float = 1.0) -> float:
        """Dimensionless conductance proxy c at force [N] and emulator time t [s]."""
        f = max(force, 0.0)
        f_eff = f / (1.0 + (f / self.saturation_force) ** 8) ** 0.125
        return self.preload + self.drift * t + gain * self.sensitivity * f_eff**self.exponent

    def counts(self, force: float, t: float, rng: np.random.Generator, gain: float = 1.0) -> int:
        """One ADC reading [counts] at force [N] and time t [s]."""
        c = self.conductance(force, t, gain)
        value = self.adc_max * c / (1.0 + c) + self.noise_counts * rng.standard_normal()
        return int(min(max(round(value), 0), self.adc_max))


@dataclasses.dataclass(frozen=True)
class PokedBall:
    """The object under the finger: F = π k_s R P_g w (the paper's Eq. for the inverted cap). Its
    fields are ``physics.ShellProperties``' (same names and units), kept loose: the data layer stays
    free of JAX, which ShellProperties (an equinox module) brings."""

    radius: float = 0.13  # [m]
    gauge_pressure: float = 3000.0  # [Pa]
    k_s: float = PAPER_KS  # [-]
    thickness: float = 0.9e-3  # [m]
    young_modulus: float = 2.34e6  # [Pa]
    poisson_ratio: float = DEFAULT_POISSON_RATIO  # [-]

    def depth(self, force: float) -> float:
        """Indentation depth [m] at force [N]."""
        return max(force, 0.0) / (math.pi * self.k_s * self.radius * self.gauge_pressure)

    def wrinkles(self) -> int:
        """Radial wrinkle count [-]: Vella's n ≈ 1.33 τ^½ (the paper's Eq. 8), rounded."""
        n = scaling_wrinkle_count(
            self.gauge_pressure, self.radius, self.young_modulus, self.thickness, self.poisson_ratio
        )
        return round(float(n))


@dataclasses.dataclass(frozen=True)
class DepthGauge:
    """Linear displacement sensor on channel 2: counts = offset + depth * counts_per_m + noise."""

    counts_per_m: float = 20000.0  # [counts/m] (0.05 mm per count)
    offset_counts: float = 100.0  # [counts]
    noise_counts: float = 0.7  # [counts]

    def counts(self, depth: float, rng: np.random.Generator, adc_max: int) -> int:
        value = self.offset_counts + depth * self.counts_per_m + self.noise_counts * rng.standard_normal()
        return int(min(max(round(value), 0), adc_max))


@dataclasses.dataclass(frozen=True)
class Faults:
    """Transport faults. Rates are probabilities per line; times are emulator seconds."""

    garbage_rate: float = 0.0  # random bytes (ending in a newline) before a line
    corrupt_rate: float = 0.0  # one byte of the line replaced
    split_rate: float = 0.0  # a line delivered in two writes (a partial line in between)
    disconnects: tuple[float, ...] = ()  # unplug times [s]; the cable is cut mid-line
    downtime: float = 0.5  # [s] until the device is back (it reboots: clock restarts at 0)


class EmulatedDevice:
    """Finger + film sensor + optional depth gauge + faults, on a virtual clock.

    ``press(F)`` makes the simulated finger approach ``F`` [N] (first order, time constant
    ``finger_tau`` [s], plus tremor of standard deviation ``tremor`` [N]); ``place_weight(F)``
    applies a dead weight (no tremor, immediate); ``release()`` lifts the finger. ``sent`` records
    every sample line the device emitted as ``(connection, RawSample, intact)``.
    """

    def __init__(
        self,
        sensor: FilmSensor = FilmSensor(),
        ball: PokedBall = PokedBall(),
        depth_gauge: DepthGauge | None = DepthGauge(),
        faults: Faults = Faults(),
        *,
        rate_hz: float = 100.0,
        seed: int = 0,
        finger_tau: float = 0.2,
        tremor: float = 0.08,
        realtime: bool = False,
    ):
        self.sensor, self.ball, self.depth_gauge, self.faults = sensor, ball, depth_gauge, faults
        self.rate_hz = rate_hz
        self.finger_tau, self.tremor_std = finger_tau, tremor
        self.realtime = realtime
        self.hello = Hello("shelljax-emu", "1.0.0", rate_hz, sensor.adc_bits, 2 if depth_gauge else 1)
        self._rng = np.random.default_rng(seed)
        self._lock = threading.RLock()
        self._time = 0.0  # [s] since the emulator started
        self._last_step = 0.0  # [s] time of the last sample
        self._wall_start = time.monotonic()
        self._boot_time = 0.0  # [s] emulator time of the last (re)boot
        self._force = 0.0  # [N] applied force now: the smooth approach plus tremor
        self._base = 0.0
        self._gain = 1.0  # see FilmSensor.placement_scatter
        self._target = 0.0
        self._tremor = 0.0
        self._dead_weight = False
        self._pending_unplugs = sorted(faults.disconnects)
        self._down_until: float | None = None
        self._hello_due = True
        self._sink: Callable[[bytes], None] | None = None
        self._on_unplug: list[Callable[[], None]] = []
        self.connection = 0
        self.sent: list[tuple[int, RawSample, bool]] = []

    # -- the finger ---------------------------------------------------------------------------
    def press(self, force: float) -> None:
        """Let the finger approach ``force`` [N]."""
        with self._lock:
            if self._target == 0.0 or self._dead_weight:
                self._new_contact()
            self._target, self._dead_weight = float(force), False

    def _new_contact(self) -> None:
        scatter = self.sensor.placement_scatter
        self._gain = math.exp(scatter * self._rng.standard_normal()) if scatter else 1.0

    def place_weight(self, force: float) -> None:
        """Put a dead weight of ``force`` [N] on the sensor (instant, no tremor)."""
        with self._lock:
            self._new_contact()
            self._target = self._base = self._force = float(force)
            self._dead_weight, self._tremor = True, 0.0

    def hold(self) -> None:
        """Stop pushing: the finger stays at the force it has now (tremor goes on)."""
        with self._lock:
            self._target = self._base

    def release(self) -> None:
        with self._lock:
            self._target, self._dead_weight = 0.0, False

    @property
    def force(self) -> float:
        """Force [N] applied right now."""
        return self._force

    @property
    def depth(self) -> float:
        """True indentation depth [m] right now."""
        return self.ball.depth(self._force)

    # -- the clock ----------------------------------------------------------------------------
    def clock(self) -> float:
        """Emulator time [s]."""
        return self._time

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` of emulator time pass (samples go to whoever is connected)."""
        self.run_until(self._time + seconds)

    def run_until(self, t: float) -> None:
        period = 1.0 / self.rate_hz
        while True:
            with self._lock:
                t_next = self._next_step_time(period)
                if t_next > t + 1e-12:
                    self._time = max(self._time, t)
                    return
            if self.realtime:
                delay = self._wall_start + t_next - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            with self._lock:
                self._step(t_next)

    def _next_step_time(self, period: float) -> float:
        k = math.floor(self._time / period + 1e-9) + 1
        return k * period

    # -- the wire -----------------------------------------------------------------------------
    @property
    def plugged(self) -> bool:
        return self._down_until is None

    def attach(self, sink: Callable[[bytes], None] | None) -> None:
        """Connect a host (``sink`` receives the bytes) or disconnect it (``None``)."""
        with self._lock:
            self._sink = sink

    def on_unplug(self, callback: Callable[[], None]) -> None:
        self._on_unplug.append(callback)

    def receive(self, data: bytes) -> None:
        """Bytes from the host: ``?`` asks for a hello line."""
        if HELLO_REQUEST.strip() in data:
            self._hello_due = True

    def unplug(self) -> None:
        """Cut the cable now (mid-line); the device is back after ``faults.downtime``."""
        with self._lock:
            self._cut(self._time)

    def _emit(self, data: bytes) -> None:
        if self._sink is not None and data:
            self._sink(data)

    def _cut(self, t: float) -> None:
        if self._down_until is not None:
            return
        t_ms = round((t - self._boot_time) * 1000) % 2**32
        half = format_sample(t_ms, self._read_channels(t))
        self._emit(half[: len(half) // 2])  # the cable goes mid-line
        self._down_until = t + self.faults.downtime
        self._sink = None
        for callback in self._on_unplug:
            callback()

    def _read_channels(self, t: float) -> tuple[int, ...]:
        raw = [self.sensor.counts(self._force, t, self._rng, self._gain)]
        if self.depth_gauge is not None:
            raw.append(self.depth_gauge.counts(self.depth, self._rng, self.sensor.adc_max))
        return tuple(raw)

    def _step(self, t: float) -> None:
        dt = t - self._last_step  # not t - self._time: the clock also advances between steps
        self._time = self._last_step = t
        if self._pending_unplugs and t >= self._pending_unplugs[0]:
            self._pending_unplugs.pop(0)
            self._cut(t)
        if self._down_until is not None:
            if t < self._down_until:
                return
            self._down_until = None  # back: the device reboots
            self._boot_time = t
            self._hello_due = True
            self.connection += 1
        self._move_finger(dt)
        if self._hello_due:
            self._hello_due = False
            self._emit(format_hello(self.hello))
        t_ms = round((t - self._boot_time) * 1000) % 2**32
        sample = RawSample(t_ms, self._read_channels(t))
        line = format_sample(sample.t_ms, sample.raw)
        faults, rng = self.faults, self._rng
        intact = True
        if faults.garbage_rate and rng.random() < faults.garbage_rate:
            junk = rng.integers(0, 256, size=int(rng.integers(1, 40)), dtype=np.uint8).tobytes()
            self._emit(junk.replace(b"\n", b"") + b"\n")
        if faults.corrupt_rate and rng.random() < faults.corrupt_rate:
            i = int(rng.integers(0, len(line) - 1))
            new = (line[i] + int(rng.integers(1, 256))) % 256
            if new != ord("\n"):  # a byte turned into a newline just splits the line
                line = line[:i] + bytes([new]) + line[i + 1 :]
                intact = False
        self.sent.append((self.connection, sample, intact))
        if faults.split_rate and rng.random() < faults.split_rate:
            cut = int(rng.integers(1, len(line)))
            self._emit(line[:cut])
            self._emit(line[cut:])
        else:
            self._emit(line)

    def _move_finger(self, dt: float) -> None:
        if self._dead_weight:
            return
        self._base = self._target + (self._base - self._target) * math.exp(-dt / self.finger_tau)
        if self._target > 0 and self.tremor_std > 0:
            rho = math.exp(-dt / 0.1)  # tremor correlated over ~0.1 s
            kick = math.sqrt(1 - rho**2) * self.tremor_std * self._rng.standard_normal()
            self._tremor = rho * self._tremor + kick
        else:
            self._tremor = 0.0
            if self._base < 1e-3:
                self._base = 0.0
        self._force = max(self._base + self._tremor, 0.0)

    # -- in-process port ----------------------------------------------------------------------
    def open_port(self, timeout: float = 0.02) -> "EmulatedPort":
        """Open an in-process port to the device (what ``serial.Serial(port)`` would return).

        Raises ``serial.SerialException`` while the device is unplugged, as opening a missing
        ``/dev/ttyACM0`` does.
        """
        with self._lock:
            if not self.plugged:
                raise serial.SerialException("could not open port emulated://: device unplugged")
            return EmulatedPort(self, timeout)


class EmulatedPort:
    """The host side of an in-process connection: the subset of ``serial.Serial`` the driver uses."""

    def __init__(self, device: EmulatedDevice, timeout: float):
        self._device = device
        self.timeout = timeout
        self._buffer = bytearray()
        self._dead = False
        self.is_open = True
        device.attach(self._buffer.extend)
        device.on_unplug(self._unplugged)

    def _unplugged(self) -> None:
        self._dead = True

    @property
    def in_waiting(self) -> int:
        if self._dead and not self._buffer:
            raise serial.SerialException("device disconnected")
        return len(self._buffer)

    def read(self, size: int = 1) -> bytes:
        if not self.is_open:
            raise serial.PortNotOpenError()
        device = self._device
        deadline = device.clock() + self.timeout
        while not self._buffer:
            if self._dead:
                raise serial.SerialException("read failed: [Errno 5] Input/output error (emulated unplug)")
            if device.clock() >= deadline - 1e-12:
                return b""
            device.run_until(min(deadline, device.clock() + 1.0 / device.rate_hz))
        data = bytes(self._buffer[:size])
        del self._buffer[:size]
        return data

    def write(self, data: bytes) -> int:
        if self._dead:
            raise serial.SerialException("write failed: device disconnected")
        self._device.receive(data)
        return len(data)

    def close(self) -> None:
        if self.is_open and not self._dead:
            self._device.attach(None)
        self.is_open = False


class PtyLink:
    """Serve an :class:`EmulatedDevice` on a POSIX pseudo-terminal behind a stable symlink.

    A background thread runs the device in real time and writes its bytes to the pty master.
    An unplug closes the pty (readers get EIO, like a pulled USB cable) and removes the link;
    after the downtime a fresh pty appears behind the same link path. Use as a context manager.
    """

    def __init__(self, device: EmulatedDevice, link: str | os.PathLike | None = None):
        import tty  # POSIX only; imported here so the module imports everywhere

        self._tty = tty
        self.device = device
        device.realtime = True
        device._wall_start = time.monotonic() - device.clock()
        if link is None:
            self._tmpdir = tempfile.mkdtemp(prefix="shelljax-emu-")
            link = os.path.join(self._tmpdir, "ttyEMU0")
        self.port = str(link)
        self._master: int | None = None
        self._slave: int | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="shelljax-pty-emulator", daemon=True)
        device.on_unplug(self._close_pty)

    def __enter__(self) -> "PtyLink":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self) -> None:
        self._open_pty()
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self._close_pty()

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        self._tty.setraw(slave)  # no echo, no line editing: bytes pass unchanged
        os.set_blocking(master, False)
        tmp = self.port + ".tmp"
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.port)
        self._master, self._slave = master, slave
        self.device.attach(self._write)

    def _close_pty(self) -> None:
        master, slave = self._master, self._slave
        self._master = self._slave = None
        if os.path.lexists(self.port):
            os.unlink(self.port)
        for fd in (master, slave):
            if fd is not None:
                os.close(fd)

    def _write(self, data: bytes) -> None:
        if self._master is None:
            return
        try:
            os.write(self._master, data)
        except (BlockingIOError, OSError):
            pass  # nobody reading and the pty buffer is full: the bytes are lost, as on hardware

    def _run(self) -> None:
        period = 1.0 / self.device.rate_hz
        while not self._stop.is_set():
            self.device.run_until(time.monotonic() - self.device._wall_start)
            if self._master is None and self.device.plugged:
                self._open_pty()
            if self._master is not None:
                try:
                    data = os.read(self._master, 256)
                    self.device.receive(data)
                except (BlockingIOError, OSError):
                    pass
            time.sleep(period / 2)


class EmulatedOperator:
    """The emulator's hands and eyes: moves the simulated finger, reads a ruler, counts wrinkles.

    ``suggest_depth`` is the true depth rounded to the ruler's resolution [m], what a person
    would read off a ruler held beside the finger.
    """

    def __init__(self, device: EmulatedDevice, ruler_resolution: float = 0.5e-3, feedback_gain: float = 0.15):
        self.device = device
        self.ruler_resolution = ruler_resolution
        self.feedback_gain = feedback_gain  # [-] per displayed reading (~20 per second)
        self._goal: float | None = None
        self._aim = 0.0

    def press(self, force: float) -> None:
        self._goal = self._aim = force
        self.device.press(force)

    def see(self, force: float) -> None:
        # A person pushes until the display shows the level, not until the (unknown) true
        # force does: integral feedback on the displayed value, as slow as a hand.
        if self._goal is None or not math.isfinite(force) or force <= 0:
            return
        self._aim += self.feedback_gain * (self._goal - force)
        self.device.press(self._aim)

    def hold(self) -> None:
        self._goal = None
        self.device.hold()

    def place_weight(self, force: float) -> None:
        self.device.place_weight(force)

    def release(self) -> None:
        self._goal = None
        self.device.release()

    def suggest_depth(self) -> float | None:
        return round(self.device.depth / self.ruler_resolution) * self.ruler_resolution

    def suggest_wrinkles(self) -> int | None:
        return self.device.ball.wrinkles()
