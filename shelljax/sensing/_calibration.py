"""Raw ADC counts → force [N], for piezoresistive force films, with uncertainty and range flags.

Model (documented in docs/sensing.md):

1. Counts → conductance proxy ``c`` (dimensionless). With the film on the high side of a voltage
   divider of resistor R_m read by an ADC of full scale ``adc_max``, ``x = counts / adc_max`` and
   ``c = R_m G = x / (1 - x)`` (``transform = "divider"``). For an amplifier whose output is
   already proportional to conductance, ``c = counts`` (``transform = "linear"``).
2. Conductance → force: ``c - c0 = a F**β`` (``model = "power"``), or with β fixed to 1
   (``model = "linear_conductance"``, the datasheet's "conductance linear in force"). ``c0`` is
   the zero-load reading (tare); it moves when the film is re-mounted or drifts, and is
   re-measured by :meth:`SensorCalibration.with_zero` (the recorder tares before every trial).
3. Fit: least squares of ``ln(c - c0) = ln a + β ln F`` over the loaded readings. The
   residual scatter ``s`` (in ln c: noise, hysteresis, creep, model error) and the covariance of
   ``(ln a, β)`` give a per-reading standard uncertainty of the force (delta method)::

       var(ln F) = J Σ Jᵀ + s²/β² + (σ_c0 / (β (c - c0)))²,   J = (-1/β, -ln F/β)

Readings outside ``[force_min, force_max]`` (the lightest and heaviest calibration loads) are
flagged (:data:`BELOW_RANGE`, :data:`ABOVE_RANGE`), as are ADC readings at full scale
(:data:`ADC_SATURATED`, force NaN). Unloaded readings (``c <= c0``) read 0 N, flagged below range.
Nothing outside the calibrated range is returned unflagged.
"""

from __future__ import annotations

import dataclasses
import datetime
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import tomli_w

from .._errors import InvalidInputError
from .._files import atomic_write_text
from .._toml import REQUIRED, TomlReader, read_toml

SCHEMA_KIND = "shelljax-force-sensor-calibration"
SCHEMA_VERSION = 1
MODELS = ("power", "linear_conductance")
TRANSFORMS = ("divider", "linear")

OK = 0
BELOW_RANGE = 1
ABOVE_RANGE = 2
ADC_SATURATED = 4


@dataclasses.dataclass(frozen=True)
class LoadPoint:
    """The readings taken under one known load: force [N], mean/std conductance proxy c, count."""

    force: float
    c_mean: float
    c_std: float
    n: int


@dataclasses.dataclass(frozen=True)
class ForceReading:
    """Forces [N], their standard uncertainties [N] and flag bitmasks, one per raw reading."""

    force: np.ndarray
    std: np.ndarray
    flags: np.ndarray


@dataclasses.dataclass(frozen=True)
class SensorCalibration:
    """A fitted force-film calibration. See the module docstring for the model.

    Attributes:
        log_sensitivity: ln a, with a in [N**-β].
        exponent: β [-].
        covariance: 2×2 covariance of (ln a, β).
        residual_std: s, scatter of ln(c - c0) about the fit [-].
        zero, zero_std: c0 and its standard uncertainty [-].
        force_min, force_max: calibrated range [N].
        adc_max: full-scale ADC reading [counts].
    """

    model: str
    transform: str
    adc_max: int
    log_sensitivity: float
    exponent: float
    covariance: tuple[tuple[float, float], tuple[float, float]]
    residual_std: float
    zero: float
    zero_std: float
    force_min: float
    force_max: float
    sensor: str = ""
    created: str = ""
    gravity: float = 9.80665  # [m/s^2] used to turn calibration masses into forces
    loads: tuple[LoadPoint, ...] = ()

    # -- evaluation ---------------------------------------------------------------------------
    def conductance(self, raw: np.ndarray | Sequence[float] | float) -> np.ndarray:
        """Conductance proxy c [-] of raw counts (NaN at ADC full scale)."""
        counts = np.asarray(raw, dtype=np.float64)
        if self.transform == "linear":
            return counts
        x = counts / self.adc_max
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(x < 1.0, x / (1.0 - x), np.nan)

    def force_from_conductance(self, c: np.ndarray | float, zero: float | None = None) -> ForceReading:
        """Force reading for conductance proxy values ``c`` with zero-load value ``zero``."""
        c = np.atleast_1d(np.asarray(c, dtype=np.float64))
        c0 = self.zero if zero is None else zero
        beta = self.exponent
        excess = c - c0
        loaded = excess > 0
        safe = np.where(loaded, excess, 1.0)
        log_f = (np.log(safe) - self.log_sensitivity) / beta
        force = np.where(loaded, np.exp(log_f), 0.0)
        cov = np.asarray(self.covariance)
        j0, j1 = -1.0 / beta, -log_f / beta
        var_log = (
            j0 * j0 * cov[0, 0]
            + 2 * j0 * j1 * cov[0, 1]
            + j1 * j1 * cov[1, 1]
            + (self.residual_std / beta) ** 2
            + (self.zero_std / (beta * safe)) ** 2
        )
        std = np.where(loaded, force * np.sqrt(var_log), 0.0)
        flags = np.zeros(c.shape, dtype=np.int64)
        flags |= np.where(~loaded | (force < self.force_min), BELOW_RANGE, OK)
        flags |= np.where(loaded & (force > self.force_max), ABOVE_RANGE, OK)
        saturated = ~np.isfinite(c)
        flags |= np.where(saturated, ADC_SATURATED, OK)
        force = np.where(saturated, np.nan, force)
        std = np.where(saturated, np.nan, std)
        return ForceReading(force, std, flags)

    def force(self, raw: np.ndarray | Sequence[float] | float, zero: float | None = None) -> ForceReading:
        """Force [N] with standard uncertainty [N] and flags for raw counts.

        ``zero`` overrides the calibration's zero-load conductance (a fresh tare).
        """
        counts = np.atleast_1d(np.asarray(raw, dtype=np.float64))
        reading = self.force_from_conductance(self.conductance(counts), zero)
        if self.transform == "divider":
            at_full_scale = counts >= self.adc_max
            flags = reading.flags | np.where(at_full_scale, ADC_SATURATED, OK)
            reading = ForceReading(reading.force, reading.std, flags)
        return reading

    def conductance_at(self, force: float, zero: float | None = None) -> float:
        """Model conductance proxy c [-] at force [N] (the forward model)."""
        c0 = self.zero if zero is None else zero
        return c0 + math.exp(self.log_sensitivity) * force**self.exponent

    def with_zero(self, zero: float, zero_std: float | None = None) -> "SensorCalibration":
        """The same calibration re-tared: zero-load conductance proxy ``zero`` [-]."""
        return dataclasses.replace(
            self, zero=float(zero), zero_std=self.zero_std if zero_std is None else float(zero_std)
        )

    def zero_shift_force(self, zero: float, at_force: float) -> float:
        """How far a reading at ``at_force`` [N] would be off [N] if the zero moved to ``zero``
        and nobody re-tared: the drift made visible in newtons."""
        c = self.conductance_at(at_force, zero=zero)
        return float(self.force_from_conductance(c).force[0]) - at_force

    # -- file I/O -----------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "kind": SCHEMA_KIND,
            "schema_version": SCHEMA_VERSION,
            "sensor": self.sensor,
            "created": self.created,
            "model": self.model,
            "transform": self.transform,
            "adc_max": self.adc_max,
            "log_sensitivity": self.log_sensitivity,
            "exponent": self.exponent,
            "covariance": [list(row) for row in self.covariance],
            "residual_std": self.residual_std,
            "zero": self.zero,
            "zero_std": self.zero_std,
            "force_min": self.force_min,
            "force_max": self.force_max,
            "force_unit": "N",
            "gravity": self.gravity,
            "loads": {
                "force": [p.force for p in self.loads],
                "c_mean": [p.c_mean for p in self.loads],
                "c_std": [p.c_std for p in self.loads],
                "n": [p.n for p in self.loads],
            },
        }

    def save(self, path: str | Path) -> None:
        """Write the calibration as TOML (SI: forces in N; c dimensionless)."""
        atomic_write_text(path, _HEADER + tomli_w.dumps(self.to_dict()))

    @classmethod
    def from_dict(cls, data: dict, source: str = "<dict>") -> "SensorCalibration":
        # a calibration is written by a program, so every field's fix is to write it again
        reader = TomlReader(
            source,
            fix="use a file written by `shelljax.sensing.SensorCalibration.save` (see docs/sensing.md), "
            "or re-calibrate",
        )
        fail = reader.fail
        if data.get("kind") != SCHEMA_KIND:
            raise fail("kind", f"expected {SCHEMA_KIND!r}, got {data.get('kind')!r}")
        if data.get("schema_version") != SCHEMA_VERSION:
            raise fail("schema_version", f"expected {SCHEMA_VERSION}, got {data.get('schema_version')!r}")
        for key, allowed in (("model", MODELS), ("transform", TRANSFORMS)):
            reader.choice(data, key, "", allowed, REQUIRED, what=key)
        numbers = {
            key: reader.number(data, key)
            for key in (
                "adc_max",
                "log_sensitivity",
                "exponent",
                "residual_std",
                "zero",
                "zero_std",
                "force_min",
                "force_max",
                "gravity",
            )
        }
        if numbers["exponent"] <= 0 or numbers["force_max"] <= numbers["force_min"] or numbers["force_min"] <= 0:
            raise fail("exponent/force_min/force_max", "need exponent > 0 and 0 < force_min < force_max")
        cov = np.asarray(data.get("covariance"), dtype=np.float64)
        if cov.shape != (2, 2) or not np.all(np.isfinite(cov)):
            raise fail("covariance", "expected a 2×2 array of finite numbers")
        loads_table = data.get("loads", {})
        loads = tuple(
            LoadPoint(float(f), float(m), float(s), int(n))
            for f, m, s, n in zip(
                loads_table.get("force", []),
                loads_table.get("c_mean", []),
                loads_table.get("c_std", []),
                loads_table.get("n", []),
                strict=True,
            )
        )
        return cls(
            model=data["model"],
            transform=data["transform"],
            adc_max=int(numbers["adc_max"]),
            log_sensitivity=float(numbers["log_sensitivity"]),
            exponent=float(numbers["exponent"]),
            covariance=((float(cov[0, 0]), float(cov[0, 1])), (float(cov[1, 0]), float(cov[1, 1]))),
            residual_std=float(numbers["residual_std"]),
            zero=float(numbers["zero"]),
            zero_std=float(numbers["zero_std"]),
            force_min=float(numbers["force_min"]),
            force_max=float(numbers["force_max"]),
            sensor=str(data.get("sensor", "")),
            created=str(data.get("created", "")),
            gravity=float(numbers["gravity"]),
            loads=loads,
        )

    @classmethod
    def load(cls, path: str | Path) -> "SensorCalibration":
        """Read a calibration TOML; raises :class:`~shelljax.InvalidInputError` naming the field."""
        path = Path(path)
        data = read_toml(
            path,
            "calibration file",
            fix_syntax="re-save the calibration",
            fix_missing="pass --calibration with an existing file, or create one with `shelljax sensor-calibrate`",
        )
        return cls.from_dict(data, source=str(path))


_HEADER = (
    "# shelljax force-sensor calibration (docs/sensing.md).\n"
    "# c = x/(1-x), x = counts/adc_max (transform 'divider');  c - zero = exp(log_sensitivity) * F**exponent.\n"
    "# Forces in N; c is dimensionless; covariance is of (log_sensitivity, exponent).\n"
)


def fit_calibration(
    loads: Sequence[LoadPoint],
    *,
    model: str = "power",
    transform: str = "divider",
    adc_max: int = 1023,
    sensor: str = "",
    gravity: float = 9.80665,
) -> SensorCalibration:
    """Fit the calibration model to readings under known loads.

    Args:
        loads: at least one unloaded point (force 0: gives the zero c0) and at least three
            distinct non-zero forces [N] (two for ``model="linear_conductance"``); repeats of a
            load (e.g. loading and unloading cycles) are welcome and enter the scatter ``s``.
        model: ``"power"`` (β fitted) or ``"linear_conductance"`` (β = 1).
        transform, adc_max: how counts became ``c`` (recorded for later conversions).

    Raises :class:`~shelljax.InvalidInputError` when the data cannot determine the model.
    """
    if model not in MODELS:
        raise InvalidInputError(f"calibration model {model!r} unknown. Fix: use one of {MODELS}")
    if transform not in TRANSFORMS:
        raise InvalidInputError(f"calibration transform {transform!r} unknown. Fix: use one of {TRANSFORMS}")
    zeros = [p for p in loads if p.force == 0]
    loaded = [p for p in loads if p.force > 0]
    if not zeros:
        raise InvalidInputError("calibration: no unloaded (0 kg) reading. Fix: start with the sensor unloaded")
    n_needed = 3 if model == "power" else 2
    if len({p.force for p in loaded}) < n_needed:
        raise InvalidInputError(
            f"calibration: {len({p.force for p in loaded})} distinct loads, need at least {n_needed} "
            f"for model {model!r}. Fix: add more known weights spanning the working range (e.g. 0.5–2.5 kg)"
        )
    zero_values = np.array([p.c_mean for p in zeros])
    zero_weights = np.array([max(p.n, 1) for p in zeros], dtype=np.float64)
    c0 = float(np.average(zero_values, weights=zero_weights))
    # Spread of repeated tares if there are several, else the noise of the mean of one.
    if len(zeros) > 1:
        zero_std = float(np.std(zero_values, ddof=1))
    else:
        zero_std = float(zeros[0].c_std / math.sqrt(max(zeros[0].n, 1)))
    force = np.array([p.force for p in loaded])
    excess = np.array([p.c_mean for p in loaded]) - c0
    if np.any(excess <= 0):
        bad = force[excess <= 0][0]
        raise InvalidInputError(
            f"calibration: the reading under {bad:.3g} N is not above the unloaded reading (c={c0:.4g}). "
            "Fix: check that the weight rests on the sensor's active area and the sensor is wired"
        )
    x, y = np.log(force), np.log(excess)
    if model == "power":
        design = np.stack([np.ones_like(x), x], axis=1)
        coef, *_ = np.linalg.lstsq(design, y, rcond=None)
        dof = len(y) - 2
        resid = y - design @ coef
        s2 = float(resid @ resid / dof) if dof > 0 else 0.0
        cov = s2 * np.linalg.inv(design.T @ design)
        log_a, beta = float(coef[0]), float(coef[1])
    else:
        log_a, beta = float(np.mean(y - x)), 1.0
        resid = y - x - log_a
        dof = len(y) - 1
        s2 = float(resid @ resid / dof) if dof > 0 else 0.0
        cov = np.array([[s2 / len(y), 0.0], [0.0, 0.0]])
    if not beta > 0:
        raise InvalidInputError(
            f"calibration: fitted exponent β={beta:.3g} is not positive (the reading falls with load). "
            "Fix: check the wiring and that the loads were entered in the right order"
        )
    return SensorCalibration(
        model=model,
        transform=transform,
        adc_max=int(adc_max),
        log_sensitivity=log_a,
        exponent=beta,
        covariance=((float(cov[0, 0]), float(cov[0, 1])), (float(cov[1, 0]), float(cov[1, 1]))),
        residual_std=math.sqrt(s2),
        zero=c0,
        zero_std=zero_std,
        force_min=float(force.min()),
        force_max=float(force.max()),
        sensor=sensor,
        created=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        gravity=gravity,
        loads=tuple(loads),
    )


def load_point(
    force: float, raw: Sequence[int] | np.ndarray, *, transform: str = "divider", adc_max: int = 1023
) -> LoadPoint:
    """Summarize raw counts taken under a known ``force`` [N] as a :class:`LoadPoint`."""
    probe = SensorCalibration(
        model="power",
        transform=transform,
        adc_max=adc_max,
        log_sensitivity=0.0,
        exponent=1.0,
        covariance=((0.0, 0.0), (0.0, 0.0)),
        residual_std=0.0,
        zero=0.0,
        zero_std=0.0,
        force_min=1.0,
        force_max=2.0,
    )
    c = probe.conductance(np.asarray(raw))
    if not np.all(np.isfinite(c)):
        raise InvalidInputError(
            f"calibration: the ADC is at full scale under {force:.3g} N. Fix: use a smaller "
            "divider resistor or lighter weights; the sensor cannot resolve this load"
        )
    return LoadPoint(float(force), float(np.mean(c)), float(np.std(c, ddof=1)) if len(c) > 1 else 0.0, len(c))
