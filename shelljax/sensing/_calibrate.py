"""Calibrating the force film with known weights: the walk-through behind `shelljax sensor-calibrate`.

For every cycle the user puts the weights on the sensor one at a time (the unloaded reading
first); each reading is the mean over ``hold`` seconds after ``settle`` seconds of creep. Cycles
after the first go down the weights again, so hysteresis shows up in the fit's scatter and thus
in the stated uncertainty rather than being hidden.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .._errors import InvalidInputError
from ._calibration import LoadPoint, SensorCalibration, fit_calibration, load_point
from ._capture import HumanOperator, Operator, Pump, SampleLog
from ._console import Console
from ._driver import SerialSensor

DEFAULT_MASSES = (0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 2.5)  # [kg]: 2.5 kg ≈ 24.5 N covers 20 N levels
MAX_MASS = 20.0  # [kg]: 196 N, about what the force range of a finger's session allows (shelljax.session)


def calibrate_sensor(
    driver: SerialSensor,
    console: Console,
    *,
    masses: Sequence[float] = DEFAULT_MASSES,
    cycles: int = 2,
    hold: float = 1.0,
    settle: float = 0.5,
    model: str = "power",
    sensor: str = "",
    gravity: float = 9.80665,
    operator: Operator | None = None,
    log_path: str | Path | None = None,
    durable: bool = True,
) -> SensorCalibration:
    """Walk through loading the sensor with ``masses`` [kg] and fit a :class:`SensorCalibration`.

    ``masses`` must include 0 (the unloaded reading). ``gravity`` [m/s²] turns masses into
    forces. Every sample is logged to ``log_path`` (CSV, durable) if given.
    """
    masses = sorted(float(m) for m in masses)
    if not masses or masses[0] != 0.0 or any(not 0 <= m <= MAX_MASS for m in masses) or len(set(masses)) < 3:
        raise InvalidInputError(
            f"--masses {masses}: not a set of calibration weights. Fix: give 0 (unloaded) and at "
            f"least two other masses in kg, up to {MAX_MASS:g} kg, e.g. 0,0.5,1,2.5"
        )
    operator = operator or HumanOperator()
    if not driver.is_open:
        driver.open()
    log = SampleLog(log_path, durable=durable) if log_path is not None else None
    pump = Pump(driver, None, log if log is not None else _NullLog(), console)
    points: list[LoadPoint] = []
    try:
        pump.collect(0.2)  # the hello line tells the ADC range
        adc_max = 2**driver.hello.adc_bits - 1 if driver.hello is not None else 1023
        for cycle in range(1, cycles + 1):
            order = masses if cycle % 2 else masses[::-1]
            for mass in order:
                force = mass * gravity
                operator.place_weight(force)
                what = "Remove every weight (sensor unloaded)" if mass == 0 else f"Place {mass:g} kg ({force:.2f} N)"
                console.ask(f"Cycle {cycle}/{cycles}: {what}, keep still, then press Enter ")
                pump.phase, pump.headline = "calibrate", f"cycle {cycle}: {mass:g} kg"
                pump.collect(settle)
                raw = [r.raw[0] for r in pump.collect(hold)]
                if len(raw) < 3:
                    raise InvalidInputError(
                        f"calibration: only {len(raw)} samples in {hold:g} s. Fix: check the sensor "
                        "connection and the firmware's sample rate, or raise --hold"
                    )
                point = load_point(force, np.asarray(raw), adc_max=adc_max)
                points.append(point)
                console.say(f"  {mass:g} kg: mean {np.mean(raw):.1f} counts (std {np.std(raw):.1f}, n={len(raw)})")
        operator.release()
        calibration = fit_calibration(points, model=model, adc_max=adc_max, sensor=sensor, gravity=gravity)
    finally:
        if log is not None:
            log.close()
    console.say(
        f"Fit: c - c0 = {np.exp(calibration.log_sensitivity):.4g} F^{calibration.exponent:.3f}, "
        f"scatter {100 * calibration.residual_std:.1f} % in conductance, "
        f"range {calibration.force_min:.3g}–{calibration.force_max:.3g} N"
    )
    return calibration


class _NullLog:
    n_rows = 0

    def append(self, rows: list[tuple]) -> None:
        self.n_rows += len(rows)


def emulated_calibration(seed: int = 0) -> SensorCalibration:
    """Calibrate the default emulated film (virtual clock, no prompts): how the bundled
    ``shelljax/data/calibration/emulated-film.toml`` was made."""
    from ._console import AutoConsole
    from ._emulator import EmulatedDevice, EmulatedOperator

    device = EmulatedDevice(seed=seed)
    driver = SerialSensor(opener=device.open_port, clock=device.clock, sleep=device.sleep, wallclock=device.clock)
    with driver:
        return calibrate_sensor(
            driver,
            AutoConsole(),
            operator=EmulatedOperator(device),
            sensor="emulated film (shelljax.sensing.FilmSensor defaults)",
        )
