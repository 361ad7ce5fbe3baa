"""The record every estimator returns for one physical quantity."""

from __future__ import annotations

import dataclasses
import math


@dataclasses.dataclass(frozen=True)
class Estimate:
    """A positive physical quantity with its uncertainty.

    Attributes:
        value: best estimate, in ``unit``.
        std: standard deviation, in ``unit``.
        ci95: (low, high) 95 % interval, in ``unit``.
        unit: SI unit symbol ("Pa", "m", "1" for dimensionless).
        method: how value and uncertainty were obtained.
        note: caveats a reader must see (e.g. "unreliable: ..."), empty when none.
    """

    value: float
    std: float
    ci95: tuple[float, float]
    unit: str
    method: str
    note: str = ""

    @classmethod
    def lognormal(cls, value: float, relative_std: float, unit: str, method: str, note: str = ""):
        """From a value and a relative standard deviation of a positive quantity.

        The 95 % interval is taken in log space (value · exp(±1.96 σ_rel)), which stays positive
        and matches the delta method for small σ_rel.
        """
        half = 1.959963984540054 * relative_std
        return cls(
            value=float(value),
            std=float(abs(value) * relative_std),
            ci95=(float(value * math.exp(-half)), float(value * math.exp(half))),
            unit=unit,
            method=method,
            note=note,
        )

    @classmethod
    def from_dict(cls, record: dict) -> "Estimate":
        """The estimate :meth:`to_dict` wrote (JSON numbers read back exactly)."""
        return cls(
            float(record["value"]),
            float(record["std"]),
            tuple(float(v) for v in record["ci95"]),
            record["unit"],
            record["method"],
            record.get("note", ""),
        )

    def to_dict(self) -> dict:
        """JSON-ready dict: value, std, ci95 and unit, method (and note when present)."""
        out = {"value": self.value, "std": self.std, "ci95": list(self.ci95), "unit": self.unit, "method": self.method}
        if self.note:
            out["note"] = self.note
        return out
