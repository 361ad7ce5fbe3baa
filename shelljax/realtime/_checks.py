"""Argument checks of the real-time runtime (SI units)."""

from __future__ import annotations

import math

from .._errors import InvalidInputError


def _check(name: str, value, *, positive=True, allow_none=False) -> float:
    if value is None and allow_none:
        return None
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name}: expected a number; got {value!r}.") from None
    if not math.isfinite(v) or (v <= 0.0 if positive else v < 0.0):
        raise InvalidInputError(f"{name}: must be finite and {'> 0' if positive else '≥ 0'}; got {value!r}.")
    return v
