"""The force-sensor line protocol (version 1): formatting, parsing and stream splitting.

Device → host, one ASCII record per line, terminated by ``\\n`` (a preceding ``\\r`` is tolerated)::

    H,<firmware>,<version>,<rate_hz>,<adc_bits>,<n_channels>*<CS>   hello: at boot and on request
    S,<t_ms>,<raw0>[,<raw1>]*<CS>                                  one sample

* ``<CS>`` is the XOR of every byte before ``*`` (as in NMEA 0183), two *uppercase* hex digits.
  Any single corrupted byte of a line therefore fails the check.
* ``t_ms`` is the device clock in milliseconds, an unsigned 32-bit integer (Arduino ``millis()``):
  it wraps after 2**32 ms ≈ 49.7 days and restarts at 0 when the device resets.
* ``raw0`` is the force channel, ``raw1`` an optional second channel (e.g. a depth sensor); both
  are non-negative integer ADC counts below ``2**adc_bits`` (at most 16 bits).
* ``firmware`` is ``[A-Za-z0-9_.-]{1,24}``, ``version`` likewise, ``rate_hz`` a positive decimal.
* A line is at most :data:`MAX_LINE_BYTES` bytes long, terminator included.
* Records with a valid checksum but another leading letter are reserved for later versions:
  hosts ignore them (counted, not warned about).

Host → device: ``?\\n`` asks for a hello line. Nothing else is sent.

The parser never raises on bad input inside a stream: :class:`StreamParser` counts and skips
malformed or partial lines. :func:`parse_line` raises :class:`MalformedLine` for a single line.
"""

from __future__ import annotations

import dataclasses
import re

PROTOCOL_VERSION = 1
MAX_LINE_BYTES = 80
MAX_RAW = 2**16 - 1
MAX_T_MS = 2**32 - 1
HELLO_REQUEST = b"?\n"

_NAME = re.compile(rb"[A-Za-z0-9_.\-]{1,24}\Z")
_UINT = re.compile(rb"(0|[1-9][0-9]{0,9})\Z")
_RATE = re.compile(rb"[0-9]{1,5}(\.[0-9]{1,6})?\Z")
_HEX2 = re.compile(rb"[0-9A-F]{2}\Z")


class MalformedLine(ValueError):
    """One line that does not follow the protocol; ``reason`` says why (for logs and counters)."""

    def __init__(self, reason: str, line: bytes):
        self.reason = reason
        self.line = line
        super().__init__(f"{reason}: {line[:MAX_LINE_BYTES]!r}")


@dataclasses.dataclass(frozen=True)
class Hello:
    """Device identification, sent at boot: sample rate [Hz], ADC resolution [bits], channels."""

    firmware: str
    version: str
    rate_hz: float
    adc_bits: int
    n_channels: int


@dataclasses.dataclass(frozen=True)
class RawSample:
    """One sample as sent: device clock [ms, uint32] and raw ADC counts per channel."""

    t_ms: int
    raw: tuple[int, ...]


@dataclasses.dataclass(frozen=True)
class UnknownRecord:
    """A checksum-valid record of a type this host does not know (reserved for later versions)."""

    kind: str


Frame = Hello | RawSample | UnknownRecord


def checksum(body: bytes) -> int:
    """XOR of all bytes of ``body`` (the part of a line before ``*``)."""
    value = 0
    for byte in body:
        value ^= byte
    return value


def _seal(body: str) -> bytes:
    raw = body.encode("ascii")
    return raw + b"*" + f"{checksum(raw):02X}".encode("ascii") + b"\n"


def format_sample(t_ms: int, raw: tuple[int, ...] | list[int]) -> bytes:
    """One sample line, terminator included. ``t_ms`` in [0, 2**32), 1 or 2 channels of counts."""
    if not 0 <= t_ms <= MAX_T_MS:
        raise ValueError(f"t_ms={t_ms} outside the uint32 range")
    if not 1 <= len(raw) <= 2 or any(not 0 <= r <= MAX_RAW for r in raw):
        raise ValueError(f"raw={raw!r}: need 1 or 2 channels of counts in [0, {MAX_RAW}]")
    return _seal(",".join(["S", str(int(t_ms)), *(str(int(r)) for r in raw)]))


def format_hello(hello: Hello) -> bytes:
    """The hello line for ``hello``, terminator included."""
    rate = f"{hello.rate_hz:g}"
    return _seal(f"H,{hello.firmware},{hello.version},{rate},{hello.adc_bits},{hello.n_channels}")


def parse_line(line: bytes) -> Frame:
    """Parse one line (with or without its terminator). Raises :class:`MalformedLine`."""
    stripped = line.rstrip(b"\n")
    if len(stripped) + 1 > MAX_LINE_BYTES:
        raise MalformedLine("line too long", line)
    if stripped.endswith(b"\r"):
        stripped = stripped[:-1]
    body, star, cs = stripped.rpartition(b"*")
    if not star:
        raise MalformedLine("no checksum", line)
    if not _HEX2.match(cs):
        raise MalformedLine("checksum is not two uppercase hex digits", line)
    if int(cs, 16) != checksum(body):
        raise MalformedLine("checksum mismatch", line)
    fields = body.split(b",")
    kind = fields[0]
    if kind == b"S":
        if not 3 <= len(fields) <= 4 or not all(_UINT.match(f) for f in fields[1:]):
            raise MalformedLine("bad sample fields", line)
        t_ms, *raw = (int(f) for f in fields[1:])
        if t_ms > MAX_T_MS or any(r > MAX_RAW for r in raw):
            raise MalformedLine("sample value out of range", line)
        return RawSample(t_ms, tuple(raw))
    if kind == b"H":
        if len(fields) != 6:
            raise MalformedLine("bad hello fields", line)
        _, firmware, version, rate, bits, channels = fields
        if not (
            _NAME.match(firmware)
            and _NAME.match(version)
            and _RATE.match(rate)
            and _UINT.match(bits)
            and _UINT.match(channels)
        ):
            raise MalformedLine("bad hello fields", line)
        rate_hz, adc_bits, n_channels = float(rate), int(bits), int(channels)
        if rate_hz <= 0 or not 1 <= adc_bits <= 16 or not 1 <= n_channels <= 2:
            raise MalformedLine("hello value out of range", line)
        return Hello(firmware.decode(), version.decode(), rate_hz, adc_bits, n_channels)
    if len(kind) == 1 and kind.isalpha():
        return UnknownRecord(kind.decode())
    raise MalformedLine("unknown record type", line)


class StreamParser:
    """Splits a byte stream into frames; counts and skips malformed or partial lines.

    Feed it whatever the port returned (any chunking); it keeps the unterminated tail for the
    next call. A line longer than :data:`MAX_LINE_BYTES` is discarded up to its terminator
    without buffering it, so garbage without newlines cannot grow memory.
    """

    def __init__(self) -> None:
        self._buffer = bytearray()
        self._overflow = False
        self.n_frames = 0
        self.n_malformed = 0
        self.n_unknown = 0
        self.last_error: MalformedLine | None = None

    def feed(self, data: bytes) -> tuple[list[Frame], list[MalformedLine]]:
        """Frames completed by ``data``, and the malformed lines met (already counted)."""
        frames: list[Frame] = []
        errors: list[MalformedLine] = []
        start = 0
        while True:
            end = data.find(b"\n", start)
            if end < 0:
                break
            piece = data[start : end + 1]
            start = end + 1
            if self._overflow:
                self._overflow = False
                self._fail(MalformedLine("line too long", bytes(self._buffer) + piece), errors)
                self._buffer.clear()
                continue
            self._buffer += piece
            line = bytes(self._buffer)
            self._buffer.clear()
            try:
                frame = parse_line(line)
            except MalformedLine as error:
                self._fail(error, errors)
                continue
            if isinstance(frame, UnknownRecord):
                self.n_unknown += 1
                continue
            self.n_frames += 1
            frames.append(frame)
        if not self._overflow:
            self._buffer += data[start:]
            if len(self._buffer) >= MAX_LINE_BYTES:
                self._overflow = True
                del self._buffer[16:]  # keep a prefix for the error message only
        return frames, errors

    def drop_partial(self) -> MalformedLine | None:
        """Discard an unterminated line (the port was lost mid-line); counts it if non-empty."""
        pending = bytes(self._buffer)
        self._buffer.clear()
        was_overflow, self._overflow = self._overflow, False
        if pending or was_overflow:
            error = MalformedLine("partial line at disconnect", pending)
            self._fail(error, [])
            return error
        return None

    def _fail(self, error: MalformedLine, errors: list[MalformedLine]) -> None:
        self.n_malformed += 1
        self.last_error = error
        errors.append(error)
