"""Self-weight of a shell wall as a potential energy (uniform gravity along −z).

A wall of density ρ [kg/m³] and rest thickness h [m] weighs q = ρ h g per unit rest area [Pa]
(its mass is conserved, so the rest area carries it whatever the stretch). A patch of rest area
A [m²] at height z [m] has potential q A z [J]; the potential is linear in the heights, so it
adds a constant load q A to the gradient and nothing to the Hessian.
"""

from __future__ import annotations

STANDARD_GRAVITY = 9.80665  # [m/s²]


def areal_weight_from_density(density, thickness, gravity=STANDARD_GRAVITY):
    """Weight per unit rest area q = ρ h g [Pa] from ρ [kg/m³], h [m] and g [m/s²]."""
    return density * thickness * gravity


def self_weight_energy(height, rest_area, areal_weight):
    """Potential q A z [J] of patches of rest area A [m²] at heights z [m], weight q [Pa]."""
    return areal_weight * rest_area * height
