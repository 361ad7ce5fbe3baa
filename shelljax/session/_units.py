"""Unit conversion for user-facing files: every value is stored in SI once it is read."""

from __future__ import annotations

LENGTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6}
FORCE_UNITS = {"N": 1.0, "mN": 1e-3, "kN": 1e3}
PRESSURE_UNITS = {"Pa": 1.0, "hPa": 1e2, "kPa": 1e3, "mbar": 1e2, "bar": 1e5, "psi": 6894.757293168}
MASS_UNITS = {"kg": 1.0, "g": 1e-3}

QUANTITY_UNITS = {"length": LENGTH_UNITS, "force": FORCE_UNITS, "pressure": PRESSURE_UNITS, "mass": MASS_UNITS}
