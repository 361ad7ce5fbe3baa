"""The serial driver against the emulator: garbage, clock wrap, unplugs, a real pseudo-terminal."""

import logging
import os
import time

import pytest
import serial

from shelljax import DeviceError
from shelljax.sensing import EmulatedDevice, Faults, PtyLink, SerialSensor, format_sample


def virtual_driver(device: EmulatedDevice, **kwargs) -> SerialSensor:
    return SerialSensor(
        opener=device.open_port, clock=device.clock, sleep=device.sleep, wallclock=device.clock, **kwargs
    )


def read_for(driver: SerialSensor, seconds: float):
    out = []
    start = driver.clock()
    while driver.clock() - start < seconds:
        out += driver.read(0.05)
    return out


def test_every_intact_line_arrives_despite_garbage(caplog):
    faults = Faults(garbage_rate=0.05, corrupt_rate=0.05, split_rate=0.2)
    device = EmulatedDevice(faults=faults, seed=1)
    with caplog.at_level(logging.WARNING, logger="shelljax.sensing"), virtual_driver(device) as driver:
        device.press(10.0)
        received = read_for(driver, 5.0)
    sent_intact = [s for _, s, intact in device.sent if intact]
    n_corrupted = sum(not intact for *_, intact in device.sent)
    assert n_corrupted > 10  # the faults did happen
    # The only intact lines not received are the ones still in flight when reading stopped.
    assert [s.raw for s in received] == [s.raw for s in sent_intact[: len(received)]]
    assert len(sent_intact) - len(received) <= 2
    # Every corrupted line and every garbage line was counted, none crashed the reader.
    assert driver.stats.n_malformed >= n_corrupted
    assert any("malformed" in r.getMessage() for r in caplog.records)


class ScriptedPort:
    """A port that returns fixed byte chunks, then nothing."""

    def __init__(self, chunks):
        self.chunks = list(chunks)
        self.timeout = 0.0

    @property
    def in_waiting(self):
        return len(self.chunks[0]) if self.chunks else 0

    def read(self, size=1):
        return self.chunks.pop(0) if self.chunks else b""

    def write(self, data):
        return len(data)

    def close(self):
        pass


def test_device_clock_wrap_is_unwrapped():
    top = 2**32
    times = [top - 20, top - 10, 0, 10, 20]
    port = ScriptedPort([b"".join(format_sample(t, (5,)) for t in times)])
    clock = iter(range(1000))
    driver = SerialSensor(opener=lambda: port, clock=lambda: next(clock), sleep=lambda s: None)
    got = driver.read(max_wait=3)
    assert [round(s.device_time * 1000) for s in got] == [top - 20, top - 10, top, top + 10, top + 20]
    assert {s.connection for s in got} == {1}


def test_device_reset_starts_a_new_epoch():
    port = ScriptedPort([b"".join(format_sample(t, (5,)) for t in (5000, 5010, 3, 13))])
    clock = iter(range(1000))
    driver = SerialSensor(opener=lambda: port, clock=lambda: next(clock), sleep=lambda s: None)
    got = driver.read(max_wait=3)
    assert [s.connection for s in got] == [1, 1, 2, 2]
    assert [s.device_time for s in got] == [5.0, 5.01, 0.003, 0.013]


def test_reconnects_after_unplug_and_counts_the_cut_line():
    device = EmulatedDevice(faults=Faults(disconnects=(1.0,), downtime=0.6), seed=2)
    with virtual_driver(device, reconnect_interval=0.1) as driver:
        received = read_for(driver, 3.0)
    assert driver.stats.n_reconnects == 1
    assert driver.stats.n_malformed == 1  # the line cut in half by the unplug
    before = [s for s in received if s.connection == 1]
    after = [s for s in received if s.connection == 2]
    assert before[-1].device_time == pytest.approx(0.99, abs=0.011)
    assert after and after[0].device_time < 0.15  # the device rebooted: its clock restarted
    # Nothing the device sent while connected before the unplug was lost.
    assert [s.raw for s in before] == [s.raw for c, s, _ in device.sent if c == 0]


def test_device_that_stays_away_raises_device_error():
    device = EmulatedDevice(faults=Faults(disconnects=(0.5,), downtime=100.0))
    with virtual_driver(device, reconnect_timeout=2.0) as driver:
        with pytest.raises(DeviceError, match="did not come back within 2 s"):
            read_for(driver, 5.0)


def test_missing_port_raises_device_error_naming_it(tmp_path):
    driver = SerialSensor(str(tmp_path / "ttyNOPE"), 115200)
    with pytest.raises(DeviceError, match="ttyNOPE"):
        driver.open()


@pytest.mark.skipif(os.name != "posix", reason="pseudo-terminals are POSIX")
def test_pseudo_terminal_unplug_and_reconnect():
    """Real pyserial on a real pty: the unplug shows up as an I/O error, and the link comes back."""
    device = EmulatedDevice(faults=Faults(disconnects=(0.6,), downtime=0.3), seed=3)
    with PtyLink(device) as link:
        driver = SerialSensor(link.port, 115200, reconnect_interval=0.05, reconnect_timeout=5.0)
        with driver:
            assert isinstance(driver._port, serial.Serial)
            received = []
            deadline = time.monotonic() + 1.6
            while time.monotonic() < deadline:
                received += driver.read(0.05)
    assert driver.stats.n_reconnects == 1
    assert driver.hello is not None and driver.hello.firmware == "shelljax-emu"
    connections = [s.connection for s in received]
    assert connections == sorted(connections) and set(connections) == {1, 2}
    # Samples before the unplug arrive in order and without gaps (10 ms apart).
    first = [round(s.device_time * 1000) for s in received if s.connection == 1]
    assert len(first) > 20
    assert all(b - a == 10 for a, b in zip(first, first[1:]))
