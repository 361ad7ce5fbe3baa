"""Plausible values of what a session records: a value outside its range is a unit mistake or a
typo, refused before any work with the value and unit as the user wrote them.

The ranges are those of an inflated object poked by a finger (docs/session-format.md#validation):
a wall of 0.05–10 mm, a radius of curvature of 1 cm–2 m, 10 Pa–100 kPa of gauge pressure (the
fit's prior), 0.01–200 N of finger force, depths of 0.05 mm–0.5 m. The session loader and
``shelljax acquire`` both read them here, so a file and a command line are held to the same limits;
the loader's checks with them (``check_plausible``, and a spread or a depth that contradicts the
other samples) raise through the file's reader, naming the file, the field and the fix.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .._arguments import shown
from .._toml import TomlReader
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
    fitting = [
        (abs(math.log(value * f / middle)), u)
        for u, f in QUANTITY_UNITS[limits.quantity].items()
        if value > 0 and limits.low <= value * f <= limits.high
    ]
    return min(fitting)[1] if fitting else None


def convert_unit(value: float, quantity: str, from_unit: str, to_unit: str) -> float:
    """``value`` in ``from_unit`` expressed in ``to_unit`` (both units of ``quantity``)."""
    units = QUANTITY_UNITS[quantity]
    return value * units[from_unit] / units[to_unit]


# Within a trial the depth follows the force; a step against it beyond this fraction of the
# deeper of the two depths is not reading noise (a ruler read to ~5 %) but a wrong sample.
BACKWARDS_TOLERANCE = 0.1


def check_plausible(
    reader: TomlReader, name: str, field: str, written: float, unit: str, unit_key: str, where: str = ""
) -> None:
    """Refuse ``written`` (in ``unit``, set by ``unit_key``) outside the plausible range of ``name``
    (``_ranges.RANGES``), naming the value as written and the unit that would make it plausible."""
    problem = implausible(name, written, unit)
    if problem is None:
        return
    likely = likely_unit(name, written)
    if likely is not None and likely != unit:
        quantity = RANGES[name].quantity
        fix = (
            f'if {written:g} is in {likely}, set {unit_key} = "{likely}" (or write '
            f"{convert_unit(written, quantity, likely, unit):g} {unit}); else re-measure it"
        )
    else:
        fix = f"check the value and {unit_key}, then re-measure it"
    raise reader.fail(field, where + problem, fix, value=written)


def check_plausible_samples(
    reader: TomlReader, name: str, field: str, written: np.ndarray, unit: str, unit_key: str, where: list[str]
) -> None:
    """``check_plausible`` on every sample, naming the first one outside the range (NaN: not
    measured, skipped)."""
    for i, value in enumerate(written):
        if math.isfinite(value) and implausible(name, float(value), unit) is not None:
            check_plausible(reader, name, f"{field}[{i}]", float(value), unit, unit_key, where[i])


def check_spread(reader: TomlReader, field: str, std: float, value: float, unit: str, of: str, unit_key: str) -> None:
    """A standard deviation as large as its value is a unit or digit mistake: refuse it."""
    if std >= value:
        raise reader.fail(
            field,
            f"{std:g} {unit} is not smaller than the {of} {value:g} {unit}",
            f"write the standard deviation in the same unit ({unit_key} applies to both), e.g. 5 % of the {of}",
            value=std,
        )


def check_forwards(
    reader: TomlReader, trial: np.ndarray, force: np.ndarray, written: np.ndarray, unit: str, where: list[str]
) -> None:
    """Within a trial the depth (``written``, in ``unit``) follows the force [N] from sample to
    sample, as written: a step against it by more than ``BACKWARDS_TOLERANCE`` of the deeper depth
    is refused, naming both samples. Where the force falls and the depth with it (a new sweep in
    the same trial), nothing is wrong."""
    for t in np.unique(trial):
        samples = np.flatnonzero(trial == t)
        for before, i in zip(samples[:-1], samples[1:]):
            rise, deepen = force[i] - force[before], written[i] - written[before]
            if rise * deepen < 0 and abs(deepen) > BACKWARDS_TOLERANCE * max(written[i], written[before]):
                raise reader.fail(
                    f"indentation.depth[{i}]",
                    f"{where[i]}trial {t} runs backwards: {written[i]:g} {unit} at {force[i]:g} N after "
                    f"{written[before]:g} {unit} at {force[before]:g} N (sample {before}); the depth "
                    "follows the force within a trial",
                    "re-measure or delete that sample (the whole row); if the trial holds several sweeps, give "
                    "each its own trial id",
                    value=float(written[i]),
                )
