"""Argument checks of the real-time runtime: numbers and planes (SI units)."""

from __future__ import annotations

import math

import numpy as np

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


def _planes_array(planes, slip_velocity: float) -> tuple[np.ndarray, tuple[str, ...]]:
    """(P, 9) rows point, normal, μ, v_ε, c from physics.Plane objects or scenario PlaneSpecs."""
    rows, names = [], []
    for i, p in enumerate(planes):
        point = np.asarray(p.point, dtype=float).reshape(-1)
        normal = np.asarray(p.normal, dtype=float).reshape(-1)
        name = str(getattr(p, "name", f"plane{i}"))
        if point.shape != (3,) or normal.shape != (3,) or not np.all(np.isfinite(point)) or not np.linalg.norm(normal) > 0:
            raise InvalidInputError(f"planes[{i}] ({name!r}): point and normal must be finite 3-vectors, normal nonzero; "
                                    f"got point {point.tolist()}, normal {normal.tolist()}.")
        mu = _check(f"planes[{i}] ({name!r}).friction", np.asarray(getattr(p, "friction", 0.0)), positive=False)
        damping = _check(f"planes[{i}] ({name!r}).damping [N·s/m]", np.asarray(getattr(p, "damping", 0.0)), positive=False)
        rows.append([*point, *(normal / np.linalg.norm(normal)), mu, slip_velocity, damping])
        names.append(name)
    return np.asarray(rows, dtype=float).reshape(-1, 9), tuple(names)
