"""Wrinkle count from the axisymmetric state (documented local model).

Where the (unrelaxed) hoop stress of the axisymmetric indented state is compressive, a real
shell wrinkles radially. The wrinkle wavelength is set by bending against the curvature-induced
elastic foundation of the shell, K = E h / R² [Pa/m] (Cerda & Mahadevan 2003; Vella et al. 2011):
a compressed strip on a foundation buckles at λ = 2π (B / K)^{1/4} = 2π ℓ_w with
ℓ_w = (B R² / (E h))^{1/4} [m]. Counting wavelengths around the mid-circle of the compressive
annulus r_w = (r_in + r_out)/2 [m] gives the continuous count

    n = 2π r_w / λ = r_w / ℓ_w,

which is differentiable through the implicit derivative of the state (r_in, r_out are linear
interpolations of the sign changes of N_θ). Because r_w ≈ l_p · O(1) in the membrane regime,
n ≈ c τ^{1/2}; the paper quotes c ≈ 1.33 (Vella et al. 2011), compared in docs/axisym.md.
Limitations: this is a local (WKB-type) wavelength estimate, not a Fourier-mode bifurcation
analysis of the full state; radial tension and the dimple's own curvature are neglected.
"""

from __future__ import annotations

import jax.numpy as jnp

from ..physics import bending_stiffness


def wrinkle_length(young_modulus, thickness, poisson_ratio, radius):
    """ℓ_w = (B R² / (E h))^{1/4} [m]; B from E [Pa], h [m], ν [-]; R [m] the curvature radius."""
    b = bending_stiffness(young_modulus, thickness, poisson_ratio)
    return (b * radius**2 / (young_modulus * thickness)) ** 0.25


def wrinkle_count(r_inner, r_outer, young_modulus, thickness, poisson_ratio, radius):
    """Continuous wrinkle count n = (r_in + r_out) / (2 ℓ_w) [-]; 0 without a compressive annulus."""
    mid = 0.5 * (r_inner + r_outer)
    return mid / wrinkle_length(young_modulus, thickness, poisson_ratio, radius)


def vella_wrinkle_count(gauge_pressure, young_modulus, thickness, poisson_ratio, radius):
    """The paper's n ≈ 1.33 τ^{1/2}, τ = P_g R² / sqrt(E h B) [-] (for comparison only)."""
    return 1.33 * jnp.sqrt(tau(gauge_pressure, young_modulus, thickness, poisson_ratio, radius))


def tau(gauge_pressure, young_modulus, thickness, poisson_ratio, radius):
    """Dimensionless pressure τ = P_g R² / sqrt(E h B) [-]."""
    b = bending_stiffness(young_modulus, thickness, poisson_ratio)
    return gauge_pressure * radius**2 / jnp.sqrt(young_modulus * thickness * b)
