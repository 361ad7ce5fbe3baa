"""The paper's constants and measurement protocol (Zhang et al., Sections 3.4 and 4.1), SI units.

Everything a module needs to reproduce the paper's set-up lives here, once: the calibrated k_s,
the force levels of the poke protocol, the finger radius, the assumed Poisson ratio, and the two
laws the estimators read E by: τ (with the flexural rigidity B it is built on) and the wrinkle
law n ≈ 1.33 τ^½. They are plain arithmetic, so
they take numbers, NumPy and JAX arrays alike, and this module imports only ``math``: the data
layer's sensor emulator uses them without JAX. The other results of shell theory are in
:mod:`shelljax.physics`, which re-exports these three.
"""

from __future__ import annotations

import math

PAPER_KS = 0.64  # [-], calibrated on a Pezzi and a yoga ball (Section 4.1)
# The paper quotes no error bar on k_s; its held-out pressures came out with 3.5 % mean relative
# error, which is taken as k_s's relative standard deviation when the paper's value is used.
PAPER_KS_STD = 0.035 * PAPER_KS  # [-]
PAPER_FORCES = (5.0, 7.5, 10.0, 12.5, 15.0, 17.5, 20.0)  # [N], the poke protocol's force levels
PAPER_INDENTER_RADIUS = 8e-3  # [m], the finger pad of the estimators' forward model
DEFAULT_POISSON_RATIO = 0.4  # [-], the paper's assumption (Section 3.4): rubbers sit at 0.3-0.4
WRINKLE_PREFACTOR = 1.33  # [-], n ≈ 1.33 τ^½ (Vella et al. 2011; the paper's Eq. modulus-estimation-2)


def bending_stiffness(young_modulus, thickness, poisson_ratio):
    """Flexural rigidity B = E h³ / (12 (1 − ν²)) [N·m] from E [Pa], h [m], ν [-] (τ reads it; every
    other module through ``physics.bending_stiffness``)."""
    return young_modulus * thickness**3 / (12.0 * (1.0 - poisson_ratio**2))


def tau(gauge_pressure, radius, young_modulus, thickness, poisson_ratio):
    """Dimensionless pressure τ = P_g R² / √(E h B) [-] from P_g [Pa], R [m], E [Pa], h [m], ν [-],
    with the flexural rigidity B [N·m] (:func:`bending_stiffness`)."""
    bending = bending_stiffness(young_modulus, thickness, poisson_ratio)
    return gauge_pressure * radius**2 / _sqrt(young_modulus * thickness * bending)


def scaling_wrinkle_count(gauge_pressure, radius, young_modulus, thickness, poisson_ratio):
    """Vella's radial wrinkle count n = 1.33 τ^½ [-] (continuous)."""
    return WRINKLE_PREFACTOR * _sqrt(tau(gauge_pressure, radius, young_modulus, thickness, poisson_ratio))


def _sqrt(x):
    # the array's own sqrt (NumPy's, or JAX's when traced), else math's: each is IEEE's correctly
    # rounded square root, where x ** 0.5 is a pow that may round otherwise
    namespace = getattr(x, "__array_namespace__", None)
    return namespace().sqrt(x) if namespace is not None else math.sqrt(x)
