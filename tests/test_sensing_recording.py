"""Recording: emulated acquisition → session file → estimate; unplugs, crashes and resume."""

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from shelljax import InvalidInputError
from shelljax.estimate import estimate_session
from shelljax.sensing import (
    AcquisitionPlan,
    AutoConsole,
    EmulatedDevice,
    EmulatedOperator,
    Faults,
    FilmSensor,
    PtyLink,
    RecordingPaths,
    ScriptedConsole,
    SensorCalibration,
    SerialSensor,
    acquire,
    read_sample_log,
)
from shelljax.sensing import _cli as sensing_cli
from shelljax.session import load_session

CAL = SensorCalibration.load(sensing_cli.emulated_calibration_path())
META = {
    "object": "emulated-ball",
    "geometry": {"radius": 0.13, "length_unit": "m"},
    "wall": {"thickness": 0.9, "thickness_std": 0.05, "thickness_unit": "mm"},
}


def fast_driver(device):
    return SerialSensor(
        opener=device.open_port, clock=device.clock, sleep=device.sleep, wallclock=device.clock, reconnect_interval=0.1
    )


def test_emulated_acquisition_to_estimate(tmp_path):
    faults = Faults(garbage_rate=0.01, corrupt_rate=0.01, split_rate=0.05)
    device = EmulatedDevice(faults=faults, seed=11)
    out = tmp_path / "ball.toml"
    result = acquire(
        fast_driver(device),
        out,
        AutoConsole(),
        calibration=CAL,
        plan=AcquisitionPlan(),
        meta=META,
        operator=EmulatedOperator(device),
    )
    assert result.completed_trials == 3 and result.levels == 21 and result.malformed > 0
    session = load_session(out)
    ball = device.ball
    assert session.force.size == 21
    assert list(session.wrinkle_counts) == [ball.wrinkles()] * 3
    # Stored forces are the calibrated means of the holding windows, within tolerance of the levels.
    levels = np.tile(np.arange(5.0, 20.1, 2.5), 3)
    assert np.all(np.abs(np.sort(session.force.reshape(3, 7), axis=1).ravel() - levels) <= 0.5)
    # Depths are ruler readings (0.5 mm resolution: ±0.25 mm) of the true depth. The stored force
    # is off by the film's repeatability (2 % per contact, the calibration's stated σ ≈ 2 %), and
    # the true depth at the stored force with it: 3σ = 6 %.
    true_depth = np.array([ball.depth(f) for f in session.force])
    assert np.all(np.abs(session.depth - true_depth) < 0.25e-3 + 0.06 * true_depth)
    estimate = estimate_session(session, bootstrap_samples=0)
    # The emulated ball obeys F = π k_s R P_g w exactly with the paper's k_s = 0.64, so P_g is
    # recovered up to the force calibration (≈ 2 %) and the ruler rounding: 5 % is ~2.5σ.
    assert estimate.gauge_pressure.value == pytest.approx(ball.gauge_pressure, rel=0.05)
    # E ∝ P_g / n²: the integer wrinkle count (12 for a true 12.26) shifts E by ≈ +4 %.
    assert estimate.young_modulus.value == pytest.approx(ball.young_modulus, rel=0.12)


def test_baseline_drift_is_tared_away_and_reported(tmp_path):
    # The film's zero drifts by 0.004/s (in c): by trial 3 a stale zero reads ≈ 0.8 N high. The
    # tare before every trial removes it, and the recorder reports the shift. Truth: the depth
    # channel gives the true force F = π k_s R P_g w (the emulated ball); no placement scatter,
    # so drift is the only error source beyond the calibration's own bias.
    device = EmulatedDevice(sensor=FilmSensor(drift=0.004, placement_scatter=0.0), seed=19)
    console = AutoConsole()
    out = tmp_path / "drift.toml"
    plan = AcquisitionPlan(
        depth_source="channel", depth_scale=1 / device.depth_gauge.counts_per_m, ask_level_wrinkles=False
    )
    acquire(fast_driver(device), out, console, calibration=CAL, plan=plan, meta=META, operator=EmulatedOperator(device))
    events = [json.loads(line) for line in RecordingPaths.for_session(out).events.read_text().splitlines()]
    shifts = [e["shift_N_at_min_force"] for e in events if e["event"] == "tare"]
    assert shifts[0] < 0.2 and shifts[-1] > 0.5  # what an untared trial 3 would be off by
    assert any("since the last tare" in text for _, text in console.transcript)
    session = load_session(out)
    ball = device.ball
    true_force = session.depth * math.pi * ball.k_s * ball.radius * ball.gauge_pressure
    error_trial3 = (session.force - true_force)[session.trial == 3]
    # Left after the tare: drift within one trial (~11 s × 0.004 ≈ 0.3 N at 5 N, less higher up)
    # plus the bundled calibration's bias (~0.1 N): mean below 0.4 N, well under the 0.5 N shift.
    assert abs(error_trial3.mean()) < 0.4


def test_unplug_and_crash_lose_no_received_sample_and_resume_completes(tmp_path):
    device = EmulatedDevice(faults=Faults(disconnects=(8.0,), downtime=0.4), seed=12)
    driver = fast_driver(device)
    out = tmp_path / "s.toml"
    paths = RecordingPaths.for_session(out)
    checks = []

    def on_batch(pump, readings):
        # Durability: whatever the driver handed over is already on disk, line for line.
        on_disk = paths.samples.read_bytes().count(b"\n") - 1
        checks.append(on_disk == pump.log.n_rows == pump.received)

    prompts = iter(range(10_000))

    def answer_then_crash(prompt):
        if next(prompts) >= 20:  # 1st trial: 7 levels × 2 prompts + 1; crash inside trial 2
            raise KeyboardInterrupt
        return ""

    console = ScriptedConsole([answer_then_crash] * 100)
    with pytest.raises(KeyboardInterrupt):
        acquire(
            driver,
            out,
            console,
            calibration=CAL,
            plan=AcquisitionPlan(),
            meta=META,
            operator=EmulatedOperator(device),
            on_batch=on_batch,
        )
    assert len(checks) > 100 and all(checks)
    assert driver.stats.n_reconnects == 1
    log = read_sample_log(paths.samples)
    assert log["row"].size == driver.stats.n_samples
    # Every sample the device sent before the unplug is in the log, in order: nothing received
    # was lost, and (the device having been read continuously) nothing was missed either.
    before = [s for c, s, _ in device.sent if c == 0]
    first = log["connection"] == 1
    assert np.array_equal(log["raw0"][first], [s.raw[0] for s in before])
    assert np.array_equal(np.round(log["device_time_s"][first] * 1000), [s.t_ms for s in before])
    # The crash left one complete trial, already a valid session.
    assert len(load_session(out).wrinkle_counts) == 1
    rows_before = log["row"].size

    result = acquire(
        fast_driver(device), out, ScriptedConsole([""] * 100), resume=True, operator=EmulatedOperator(device)
    )
    assert result.completed_trials == 3
    session = load_session(out)
    assert session.force.size == 21 and len(session.wrinkle_counts) == 3
    log = read_sample_log(paths.samples)
    assert np.array_equal(log["row"], np.arange(log["row"].size)) and log["row"].size > rows_before
    events = [json.loads(line) for line in paths.events.read_text().splitlines()]
    assert [e["event"] for e in events].count("resume") == 1
    levels_trial2 = [e["target"] for e in events if e["event"] == "level" and e["trial"] == 2]
    assert sorted(levels_trial2) == list(np.arange(5.0, 20.1, 2.5))  # no level recorded twice


def test_typed_answers_are_validated_and_stored(tmp_path):
    device = EmulatedDevice(seed=13)
    out = tmp_path / "typed.toml"
    answers = ["abc", "4.5", "-1", "6.25", "8", "many", "11"]
    console = ScriptedConsole(answers)
    plan = AcquisitionPlan(forces=(5.0, 7.5, 10.0), trials=1, ask_level_wrinkles=False, depth_unit="mm")
    acquire(fast_driver(device), out, console, calibration=CAL, plan=plan, meta=META, operator=EmulatedOperator(device))
    session = load_session(out)
    np.testing.assert_allclose(session.depth, [4.5e-3, 6.25e-3, 8e-3])
    assert list(session.wrinkle_counts) == [11]
    said = [text for kind, text in console.transcript if kind == "say"]
    assert any("'abc' is not a number" in s for s in said)
    assert any("non-negative" in s for s in said)
    assert any("'many' is not a non-negative whole number" in s for s in said)


def test_depth_from_second_channel(tmp_path):
    device = EmulatedDevice(seed=14)
    out = tmp_path / "ch2.toml"
    plan = AcquisitionPlan(
        forces=(5.0, 10.0, 15.0, 20.0),
        trials=1,
        depth_source="channel",
        depth_scale=1 / device.depth_gauge.counts_per_m,
        ask_level_wrinkles=False,
    )
    console = ScriptedConsole(["12"])  # only the trial's wrinkle count is asked
    acquire(fast_driver(device), out, console, calibration=CAL, plan=plan, meta=META, operator=EmulatedOperator(device))
    session = load_session(out)
    true_depth = np.array([device.ball.depth(f) for f in session.force])
    # The gauge is exact up to 0.7-count noise (35 µm, averaged); the stored force carries the
    # calibration error (≈ 2 %), which maps one-to-one onto the depth at that force.
    np.testing.assert_allclose(session.depth, true_depth, rtol=0.06)
    assert [k for k, _ in console.transcript].count("ask") == 1


def test_level_that_cannot_be_reached_can_be_skipped(tmp_path):
    device = EmulatedDevice(seed=15)

    class WeakFinger(EmulatedOperator):
        def press(self, force):
            super().press(min(force, 8.0))  # never reaches 10 N

    plan = AcquisitionPlan(forces=(5.0, 7.5, 10.0), trials=1, level_timeout=2.0, ask_level_wrinkles=False)
    console = ScriptedConsole(["", "", "r", "s", ""])  # depth, depth, retry, skip, wrinkles
    out = tmp_path / "weak.toml"
    acquire(fast_driver(device), out, console, calibration=CAL, plan=plan, meta=META, operator=WeakFinger(device))
    events = [json.loads(line) for line in RecordingPaths.for_session(out).events.read_text().splitlines()]
    assert [e["target"] for e in events if e["event"] == "skip"] == [10.0]
    assert sum("No steady 10 N" in text for _, text in console.transcript) == 2


def test_refusals(tmp_path):
    device = EmulatedDevice(seed=16)
    with pytest.raises(InvalidInputError, match="calibrated range"):
        acquire(
            fast_driver(device),
            tmp_path / "a.toml",
            AutoConsole(),
            calibration=CAL,
            plan=AcquisitionPlan(forces=(5.0, 15.0, 30.0)),
            meta=META,
        )
    with pytest.raises(InvalidInputError, match="--resume"):
        acquire(fast_driver(device), tmp_path / "b.toml", AutoConsole(), resume=True)
    (tmp_path / "c.samples.csv").write_text("row\n")
    with pytest.raises(InvalidInputError, match="already exist"):
        acquire(
            fast_driver(device), tmp_path / "c.toml", AutoConsole(), calibration=CAL, plan=AcquisitionPlan(), meta=META
        )


def cli(argv):
    parser = argparse.ArgumentParser()
    sensing_cli.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def test_cli_calibrate_then_acquire_emulated(tmp_path):
    cal = tmp_path / "film.toml"
    assert cli(["sensor-calibrate", "--emulate-fast", "--yes", "--out", str(cal), "--cycles", "1"]) == 0
    assert SensorCalibration.load(cal).force_max == pytest.approx(2.5 * 9.80665)
    out = tmp_path / "demo.toml"
    code = cli(
        [
            "acquire",
            "--emulate-fast",
            "--yes",
            "--emulate-faults",
            "--out",
            str(out),
            "--calibration",
            str(cal),
            "--trials",
            "2",
            "--forces",
            "5:15:2.5",
            "--no-level-wrinkles",
        ]
    )
    assert code == 0
    session = load_session(out)
    assert session.force.size == 10 and session.object_name == "emulated-ball"
    assert session.radius == pytest.approx(0.13) and session.thickness == pytest.approx(0.9e-3)


def test_killed_process_keeps_every_received_sample(tmp_path):
    """A real crash: SIGKILL to a `shelljax acquire` reading a pseudo-terminal like hardware."""
    device = EmulatedDevice(seed=17)
    out = tmp_path / "killed.toml"
    paths = RecordingPaths.for_session(out)
    with PtyLink(device) as link:
        argv = [
            "acquire",
            "--port",
            link.port,
            "--out",
            str(out),
            "--calibration",
            str(sensing_cli.emulated_calibration_path()),
            "--object",
            "ball",
            "--radius",
            "0.13",
            "--thickness",
            "0.9",
            "--thickness-std",
            "0.05",
            "--trials",
            "1",
            "--forces",
            "5:10:2.5",
            "--depth-from-channel",
            "--depth-scale",
            "5e-5",
            "--no-level-wrinkles",
            "--yes",
        ]
        code = (
            "import sys; from shelljax.sensing._cli import register; import argparse; "
            "p = argparse.ArgumentParser(); register(p.add_subparsers()); a = p.parse_args(sys.argv[1:]); "
            "sys.exit(a.func(a))"
        )
        proc = subprocess.Popen(
            [sys.executable, "-c", code, *argv],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:
                if paths.samples.exists() and paths.samples.read_bytes().count(b"\n") > 150:
                    break
                time.sleep(0.05)
            device.press(5.0)
            time.sleep(0.3)
            t_kill = device.clock()
            os.kill(proc.pid, signal.SIGKILL)
        finally:
            proc.wait(timeout=10)
    assert proc.returncode == -signal.SIGKILL
    log = read_sample_log(paths.samples)
    t_log = np.round(log["device_time_s"] * 1000).astype(int)
    sent = {s.t_ms: s.raw for c, s, _ in device.sent}
    # Every logged row is a sample the device sent, exactly once, in order.
    assert all(sent[t][0] == r for t, r in zip(t_log, log["raw0"], strict=True))
    assert np.all(np.diff(t_log) > 0)
    # Every sample sent between the first logged one and 0.25 s before the kill (time enough to
    # be read, at 100 Hz, by a reader that polls every 50 ms) is on disk: none was lost.
    expected = [t for t in sorted(sent) if t_log[0] <= t <= (t_kill - 0.25) * 1000]
    assert len(expected) > 100
    assert set(expected) <= set(t_log)
    # The killed recording resumes (here on an in-process emulator) and completes.
    fast = EmulatedDevice(seed=18)
    result = acquire(fast_driver(fast), out, AutoConsole(), resume=True, operator=EmulatedOperator(fast))
    assert result.completed_trials == 1
    assert load_session(out).force.size == 3
    assert not np.isnan(load_session(out).depth).any()
