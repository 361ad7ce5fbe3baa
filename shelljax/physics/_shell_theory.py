"""Closed-form results of pressurized thin-shell theory (SI units).

* τ = P_g R² / √(E h B), the dimensionless pressure (Vella et al. 2011), and Vella's wrinkle law
  n ≈ 1.33 τ^½: defined in :mod:`shelljax.paper` (the laws the paper's estimator reads E by),
  re-exported here;
* the wrinkling onset W(0) = −2.52;
* the point-load stiffness of an unpressurized sphere (Reissner) and of a pressurized one (Vella
  et al. 2012), the references of the engines' shallow-shell checks.

Every function takes the shell's parameters in one order: gauge pressure P_g [Pa], radius R [m],
Young's modulus E [Pa], thickness h [m], Poisson ratio ν [-]. ``tau`` and
``scaling_wrinkle_count`` accept numbers and JAX arrays alike.
"""

from __future__ import annotations

import numpy as np

from ..paper import WRINKLE_PREFACTOR, bending_stiffness, scaling_wrinkle_count, tau

__all__ = [
    "CRITICAL_W",
    "WRINKLE_PREFACTOR",
    "bending_stiffness",
    "reissner_stiffness",
    "scaling_wrinkle_count",
    "tau",
    "vella_linear_stiffness",
]

CRITICAL_W = 2.52  # [-], wrinkling onset at the dimensionless depth W(0) = −2.52 (Vella et al. 2011)


def reissner_stiffness(radius, young_modulus, thickness, poisson_ratio):
    """k = 4 E h² / (R √(3(1 − ν²))) [N/m]: an unpressurized spherical shell under a point load."""
    return 4.0 * young_modulus * thickness**2 / (radius * np.sqrt(3.0 * (1.0 - poisson_ratio**2)))


def vella_linear_stiffness(gauge_pressure, radius, young_modulus, thickness, poisson_ratio, bending_scale=1.0):
    """Linear point-load stiffness [N/m] of a pressurized spherical shell (Vella et al. 2012; numpy).

    k = 2π √(T² − 4BK) / artanh(√(1 − 4BK/T²)) with pre-tension T = P_g R / 2 and foundation
    K = E h / R², continued analytically for T² < 4BK; it tends to Reissner's k as P_g → 0 and to
    π P_g R / ln(τ/2) as τ → ∞. ``bending_scale`` multiplies B (checks of the bending term).
    """
    b = bending_scale * bending_stiffness(young_modulus, thickness, poisson_ratio)
    t = gauge_pressure * radius / 2.0
    k = young_modulus * thickness / radius**2
    disc = t**2 - 4.0 * b * k
    if disc > 0:
        s = np.sqrt(disc)
        return 2.0 * np.pi * s / np.arctanh(s / t)
    s = np.sqrt(-disc)
    # ∫₀^∞ du / (B u² + T u + K) = (2/s)(π/2 − arctan(T/s)) for T² < 4BK
    integral = (2.0 / s) * (0.5 * np.pi - np.arctan(t / s))
    return 4.0 * np.pi / integral
