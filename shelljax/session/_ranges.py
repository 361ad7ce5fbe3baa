"""Plausible values of what a session records: a value outside its range is a unit mistake or a
typo, refused before any work with the value and unit as the user wrote them.

The ranges are those of an inflated object poked by a finger (docs/session-format.md#validation):
a wall of 0.05–10 mm, a radius of curvature of 1 cm–2 m, 10 Pa–100 kPa of gauge pressure (the
fit's prior), 0.01–200 N of finger force, depths of 0.05 mm–0.5 m. The session loader and
``shelljax acquire`` both read them here, so a file and a command line are held to the same limits.
"""

from __future__ import annotations

import dataclasses
import math

from .._arguments import shown
from ._units import QUANTITY_UNITS


@dataclasses.dataclass(frozen=True)
class PlausibleRange:
    """``low``–``high`` [SI] of ``what`` (a ``quantity`` of ``QUANTITY_UNITS``), shown in ``shown_in``."""

    what: str
    quantity: str
    low: float
    high: float
    shown_in: str

    def text(self) -> str:
        scale = QUANTITY_UNITS[self.quantity][self.shown_in]
        return f"{self.low / scale:g}–{self.high / scale:g} {self.shown_in}"


RANGES = {
    "thickness": PlausibleRange("a wall thickness", "length", 0.05e-3, 10e-3, "mm"),
    "radius": PlausibleRange("a radius of curvature", "length", 0.01, 2.0, "m"),
    "fit_radius": PlausibleRange("a sphere fit's neighbourhood", "length", 1e-3, 2.0, "m"),
    "depth": PlausibleRange("an indentation depth", "length", 0.05e-3, 0.5, "mm"),
    "shape_length": PlausibleRange("a length of the deformed shape", "length", 0.05e-3, 5.0, "m"),
    "force": PlausibleRange("a finger's force", "force", 0.01, 200.0, "N"),
    "pressure": PlausibleRange("an inflated object's gauge pressure", "pressure", 10.0, 1e5, "Pa"),
    "mass": PlausibleRange("an inflated object's mass", "mass", 1e-4, 100.0, "kg"),
}


def implausible(name: str, value: float, unit: str) -> str | None:
    """Why ``value`` in ``unit`` is not a plausible ``name`` (a key of ``RANGES``), or None when it is."""
    limits = RANGES[name]
    si = value * QUANTITY_UNITS[limits.quantity][unit]
    if limits.low <= si <= limits.high:
        return None
    size = "small" if si < limits.low else "large"
    return f"{shown(value)} {unit} is implausibly {size} for {limits.what} ({limits.text()})"


def likely_unit(name: str, value: float) -> str | None:
    """The unit in which ``value`` would be the most typical ``name`` (nearest the middle of its
    range, on a log scale), or None when no unit makes it plausible."""
    limits = RANGES[name]
    middle = math.sqrt(limits.low * limits.high)
    fitting = [(abs(math.log(value * f / middle)), u) for u, f in QUANTITY_UNITS[limits.quantity].items()
               if value > 0 and limits.low <= value * f <= limits.high]
    return min(fitting)[1] if fitting else None


def convert_unit(value: float, quantity: str, from_unit: str, to_unit: str) -> float:
    """``value`` in ``from_unit`` expressed in ``to_unit`` (both units of ``quantity``)."""
    units = QUANTITY_UNITS[quantity]
    return value * units[from_unit] / units[to_unit]
