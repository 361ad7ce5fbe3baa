"""Force-film calibration: recovery of a known response curve, honest uncertainty, range flags."""

import math

import numpy as np
import pytest

from shelljax import InvalidInputError
from shelljax.sensing import (
    ABOVE_RANGE,
    ADC_SATURATED,
    BELOW_RANGE,
    OK,
    AutoConsole,
    EmulatedDevice,
    EmulatedOperator,
    FilmSensor,
    LoadPoint,
    SensorCalibration,
    SerialSensor,
    calibrate_sensor,
    fit_calibration,
)
from shelljax.sensing._cli import emulated_calibration_path

A_TRUE, BETA_TRUE, C0_TRUE = 0.12, 1.15, 0.04
FORCES = np.array([2.5, 5.0, 10.0, 15.0, 20.0, 25.0])


def synthetic_loads(rng, scatter=0.03, cycles=3, beta=BETA_TRUE):
    """Load points drawn from c = c0 + a F^β with lognormal scatter (repeatability), plus tares."""
    points = [LoadPoint(0.0, C0_TRUE + 1e-4 * rng.standard_normal(), 1e-3, 100) for _ in range(cycles)]
    for _ in range(cycles):
        for f in FORCES:
            c = C0_TRUE + A_TRUE * f**beta * math.exp(scatter * rng.standard_normal())
            points.append(LoadPoint(float(f), c, 0.01, 100))
    return points


def test_fit_recovers_known_power_law_with_calibrated_uncertainty():
    # Over 300 independent calibrations, the stated 2σ intervals must contain the truth about
    # 95 % of the time (binomial sd at n=300 is 1.3 %: accept 90–99 %). This checks the
    # uncertainty itself, not only the point estimate.
    rng = np.random.default_rng(0)
    inside_beta = inside_a = inside_f = 0
    n = 300
    for _ in range(n):
        cal = fit_calibration(synthetic_loads(rng))
        cov = np.asarray(cal.covariance)
        inside_a += abs(cal.log_sensitivity - math.log(A_TRUE)) < 2 * math.sqrt(cov[0, 0])
        inside_beta += abs(cal.exponent - BETA_TRUE) < 2 * math.sqrt(cov[1, 1])
        # A fresh single reading at 12 N (with its own placement scatter): is 12 N within 2σ?
        c_new = C0_TRUE + A_TRUE * 12.0**BETA_TRUE * math.exp(0.03 * rng.standard_normal())
        reading = cal.force_from_conductance(c_new)
        inside_f += abs(reading.force[0] - 12.0) < 2 * reading.std[0]
    for inside in (inside_a, inside_beta, inside_f):
        assert 0.90 <= inside / n <= 0.99


def test_linear_conductance_model():
    rng = np.random.default_rng(1)
    cal = fit_calibration(synthetic_loads(rng, beta=1.0, scatter=0.01), model="linear_conductance")
    assert cal.exponent == 1.0
    # 18 points at 1 % scatter: σ(ln a) ≈ 0.01/sqrt(18) ≈ 0.0024; 4σ ≈ 0.01.
    assert cal.log_sensitivity == pytest.approx(math.log(A_TRUE), abs=0.01)


def test_calibration_walk_on_the_emulator_recovers_its_film():
    device = EmulatedDevice(seed=5)
    driver = SerialSensor(opener=device.open_port, clock=device.clock, sleep=device.sleep, wallclock=device.clock)
    cal = calibrate_sensor(driver, AutoConsole(), operator=EmulatedOperator(device), cycles=2)
    film = device.sensor
    assert cal.zero == pytest.approx(film.preload, abs=2e-3)  # ADC noise 1 count ≈ 1e-3 in c, averaged
    z = []
    for f in (3.0, 5.0, 8.0, 12.5, 17.5, 22.0):
        # The emulator's true response, evaluated independently of the calibration code.
        reading = cal.force_from_conductance(film.conductance(f, t=0.0))
        z.append((reading.force[0] - f) / reading.std[0])
        assert reading.flags[0] == OK
    assert max(abs(v) for v in z) < 3.0


def test_bundled_emulator_calibration_matches_the_emulator():
    cal = SensorCalibration.load(emulated_calibration_path())
    film = FilmSensor()
    for f in (5.0, 10.0, 20.0):
        reading = cal.force_from_conductance(film.conductance(f, t=0.0))
        assert abs(reading.force[0] - f) < 3 * reading.std[0]


def test_out_of_range_is_flagged_never_silent():
    cal = SensorCalibration.load(emulated_calibration_path())
    a, beta = math.exp(cal.log_sensitivity), cal.exponent
    c_above = cal.zero + a * (1.3 * cal.force_max) ** beta
    c_below = cal.zero + a * (0.5 * cal.force_min) ** beta
    c_inside = cal.zero + a * 10.0**beta
    reading = cal.force_from_conductance(np.array([c_above, c_below, c_inside, cal.zero - 0.01]))
    assert list(reading.flags) == [ABOVE_RANGE, BELOW_RANGE, OK, BELOW_RANGE]
    assert reading.force[0] == pytest.approx(1.3 * cal.force_max)  # value kept, but flagged
    assert reading.force[2] == pytest.approx(10.0)
    assert reading.force[3] == 0.0  # unloaded: nothing to extrapolate
    full = cal.force([cal.adc_max, cal.adc_max - 1])
    assert full.flags[0] & ADC_SATURATED and math.isnan(full.force[0])
    assert not full.flags[1] & ADC_SATURATED


def test_tare_removes_baseline_drift():
    # A film whose zero drifts by 0.002/s: after 60 s a stale zero misreads 5 N badly; a fresh
    # tare (the recorder takes one before every trial) brings the reading back.
    cal = SensorCalibration.load(emulated_calibration_path())
    drifting = FilmSensor(drift=0.002)
    t = 60.0
    c_5n = drifting.conductance(5.0, t)
    stale = cal.force_from_conductance(c_5n).force[0]
    fresh_zero = drifting.conductance(0.0, t)
    fresh = cal.with_zero(fresh_zero).force_from_conductance(c_5n)
    assert stale - 5.0 > 5 * fresh.std[0]
    assert abs(fresh.force[0] - 5.0) < 3 * fresh.std[0]
    # The recorder's drift report uses the fitted model, the stale reading the true film: they
    # agree to within the calibration's uncertainty at 5 N.
    assert abs(cal.zero_shift_force(fresh_zero, 5.0) - (stale - 5.0)) < 3 * fresh.std[0]


def test_save_load_round_trip(tmp_path):
    cal = fit_calibration(synthetic_loads(np.random.default_rng(2)), sensor="left index")
    path = tmp_path / "cal.toml"
    cal.save(path)
    assert SensorCalibration.load(path) == cal


@pytest.mark.parametrize(
    "field, value, match",
    [
        ("kind", "something-else", "field 'kind'"),
        ("exponent", -1.0, "exponent"),
        ("model", "cubic", "field 'model'"),
        ("covariance", [[1.0]], "field 'covariance'"),
    ],
)
def test_bad_calibration_files_name_the_field(tmp_path, field, value, match):
    data = fit_calibration(synthetic_loads(np.random.default_rng(3))).to_dict()
    data[field] = value
    with pytest.raises(InvalidInputError, match=match):
        SensorCalibration.from_dict(data, source="cal.toml")


def test_fit_refuses_underdetermined_data():
    with pytest.raises(InvalidInputError, match="unloaded"):
        fit_calibration([LoadPoint(5.0, 1.0, 0.0, 1), LoadPoint(10.0, 2.0, 0.0, 1), LoadPoint(15.0, 3.0, 0.0, 1)])
    with pytest.raises(InvalidInputError, match="distinct loads"):
        fit_calibration([LoadPoint(0.0, 0.1, 0.0, 1), LoadPoint(5.0, 1.0, 0.0, 1), LoadPoint(5.0, 1.1, 0.0, 1)])
    with pytest.raises(InvalidInputError, match="not above the unloaded"):
        fit_calibration(
            [
                LoadPoint(0.0, 1.0, 0.0, 1),
                LoadPoint(5.0, 0.9, 0.0, 1),
                LoadPoint(10.0, 2.0, 0.0, 1),
                LoadPoint(15.0, 3.0, 0.0, 1),
            ]
        )
