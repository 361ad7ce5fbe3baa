"""The shell's material and loading properties, one object for every engine and estimator."""

from __future__ import annotations

import equinox as eqx
from jaxtyping import ArrayLike, Float

__all__ = ["ShellProperties"]


class ShellProperties(eqx.Module):
    """Gauge pressure, Young's modulus, thickness, Poisson ratio and (where it applies) radius of a
    pressurized shell: what the estimators infer and the engines take, in one order everywhere.

    Keyword-only, so that no call can swap two moduli or a pressure and a modulus by position:
    ``gauge_pressure`` P_g [Pa] (of the inflated, scanned state), ``young_modulus`` E [Pa],
    ``thickness`` h [m], ``poisson_ratio`` ν [-] and ``radius`` R [m] (the inflated radius; None
    where the engine takes its geometry from elsewhere, a mesh or a ``Setup``). Each field is a
    scalar, or an array of shape (batch,) for a batch of curves (``axisym.indentation_curves``);
    the fields are stored as given, so the object is a pytree that ``jit``, ``vmap`` and ``grad``
    pass through.
    """

    gauge_pressure: Float[ArrayLike, "*batch"]
    young_modulus: Float[ArrayLike, "*batch"]
    thickness: Float[ArrayLike, "*batch"]
    poisson_ratio: Float[ArrayLike, "*batch"]
    radius: Float[ArrayLike, "*batch"] | None

    def __init__(self, *, gauge_pressure, young_modulus, thickness, poisson_ratio, radius=None):
        self.gauge_pressure = gauge_pressure
        self.young_modulus = young_modulus
        self.thickness = thickness
        self.poisson_ratio = poisson_ratio
        self.radius = radius
