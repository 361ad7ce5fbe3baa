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


def _barrier(plane) -> tuple[float, float]:
    """(ĝ [m], κ [J/m²]) of a plane's IPC log barrier (a ``dynamics.BarrierContact`` law or a scenario
    PlaneSpec's), or (0, 0) for a plane without one (the runtime's penalty spring from g = 0)."""
    law = getattr(plane, "law", None)
    if law is not None and hasattr(law, "activation_distance") and hasattr(law, "stiffness"):
        return float(np.asarray(law.activation_distance)), float(np.asarray(law.stiffness))
    if hasattr(plane, "activation_distance") and hasattr(plane, "barrier_stiffness"):
        return float(plane.activation_distance), float(plane.barrier_stiffness)
    return 0.0, 0.0


def _planes_array(planes, slip_velocity: float) -> tuple[np.ndarray, tuple[str, ...]]:
    """(P, 11) rows point, normal, μ, v_ε, c, barrier ĝ [m], κ [J/m²] (0, 0: none) from physics.Plane
    objects or scenario PlaneSpecs."""
    rows, names = [], []
    for i, p in enumerate(planes):
        point = np.asarray(p.point, dtype=float).reshape(-1)
        normal = np.asarray(p.normal, dtype=float).reshape(-1)
        name = str(getattr(p, "name", f"plane{i}"))
        if (
            point.shape != (3,)
            or normal.shape != (3,)
            or not np.all(np.isfinite(point))
            or not np.linalg.norm(normal) > 0
        ):
            raise InvalidInputError(
                f"planes[{i}] ({name!r}): point and normal must be finite 3-vectors, normal nonzero; "
                f"got point {point.tolist()}, normal {normal.tolist()}."
            )
        mu = _check(f"planes[{i}] ({name!r}).friction", np.asarray(getattr(p, "friction", 0.0)), positive=False)
        damping = _check(
            f"planes[{i}] ({name!r}).damping [N·s/m]", np.asarray(getattr(p, "damping", 0.0)), positive=False
        )
        reach, kappa = _barrier(p)
        _check(f"planes[{i}] ({name!r}) barrier activation distance ĝ [m]", reach, positive=False)
        _check(f"planes[{i}] ({name!r}) barrier stiffness κ [J/m²]", kappa, positive=reach > 0.0)
        rows.append([*point, *(normal / np.linalg.norm(normal)), mu, slip_velocity, damping, reach, kappa])
        names.append(name)
    return np.asarray(rows, dtype=float).reshape(-1, 11), tuple(names)
