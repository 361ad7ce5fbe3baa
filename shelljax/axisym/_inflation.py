"""Rest shape from the pressurized-radius convention: a ball's radius is its inflated one.

The given radius R [m] is the *inflated* radius at gauge pressure P_g [Pa]. For a sphere of rest
radius R0 under uniform stretch λ the energy is 4πR0² W(λ; R0) − P_g (4/3)πR0³λ³, with W the
shared membrane density (C = λ² I; Neo-Hookean, Gent-stiffened by ``stiffening`` s [-], 0 by
default) plus the bending density (M = (λ − 1)/R0 · I).
Equilibrium ∂W/∂λ = P_g R0 λ² = P_g R λ is solved for λ by a fixed number of Newton steps
(smooth, monotone; differentiable by unrolling), and R0 = R / λ.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..physics import bending_density_invariants, gent_membrane_invariants, lame_constants_2d


def uniform_stretch_density(
    stretch, rest_radius, thickness, young_modulus, poisson_ratio, bending_scale=1.0, stiffening=0.0
):
    """Energy per rest area [J/m²] of a sphere of rest radius R0 [m] under uniform stretch λ [-]
    (Gent ``stiffening`` s [-], 0: Neo-Hookean)."""
    lam2 = stretch**2
    membrane = gent_membrane_invariants(2.0 * lam2, lam2**2, thickness, young_modulus, poisson_ratio, stiffening)
    m = (stretch - 1.0) / rest_radius
    bending = bending_density_invariants(2.0 * m, 2.0 * m**2, thickness, young_modulus, poisson_ratio)
    return membrane + bending_scale * bending


def inflation_stretch(
    gauge_pressure,
    radius,
    young_modulus,
    thickness,
    poisson_ratio,
    bending_scale=1.0,
    iterations: int = 30,
    stiffening=0.0,
):
    """Uniform stretch λ = R / R0 [-] of a Neo-Hookean sphere of E [Pa], h [m], ν [-] inflated to
    radius R [m] by P_g [Pa] (Gent-stiffened by ``stiffening`` s [-]; 0: Neo-Hookean). The shell's
    parameters come in the one order of ``physics.ShellProperties``: P_g, R, E, h, ν."""

    def residual(lam):
        r0 = radius / lam
        dw = jax.grad(uniform_stretch_density)(
            lam, r0, thickness, young_modulus, poisson_ratio, bending_scale, stiffening
        )
        return dw - gauge_pressure * radius * lam

    # Small-strain start: λ − 1 ≈ P R (1 − ν) / (2 E h).
    lam0 = 1.0 + gauge_pressure * radius * (1.0 - poisson_ratio) / (2.0 * young_modulus * thickness)

    def step(_, lam):
        f, df = jax.jvp(residual, (lam,), (jnp.ones_like(lam),))
        return jnp.clip(lam - f / df, 0.5 * lam, 2.0 * lam)

    return jax.lax.fori_loop(0, iterations, step, lam0)


def neo_hookean_sphere_pressure(stretch, rest_radius, young_modulus, thickness, poisson_ratio):
    """Closed-form membrane inflation law P_g(λ) [Pa] of the compressible Neo-Hookean sphere.

    P = h [2β(λ − 1/λ) + α(λ³ − 1/λ)] / (R0 λ²), α = Eν/(1−ν²), β = E/(2(1+ν)) (hand-derived;
    used as an independent check of the numerical inflation).
    """
    alpha = young_modulus * poisson_ratio / (1.0 - poisson_ratio**2)
    beta = young_modulus / (2.0 * (1.0 + poisson_ratio))
    lam = stretch
    return thickness * (2.0 * beta * (lam - 1.0 / lam) + alpha * (lam**3 - 1.0 / lam)) / (rest_radius * lam**2)


def gent_sphere_pressure(stretch, rest_radius, young_modulus, thickness, poisson_ratio, stiffening):
    """Closed-form membrane inflation law P_g(λ) [Pa] of the Gent-stiffened compressible sphere.

    P = h [2β(λ − 1/λ)/(1 − s I) + α(λ³ − 1/λ)] / (R0 λ²), I = 2λ² − 2 − 4 ln λ: the Neo-Hookean
    law with β → β/(1 − s I) (hand-derived from ``physics.gent_membrane_invariants`` with
    C = λ² I; an independent check of the numerical inflation). ``stiffening`` s [-], λ [-],
    R0 [m], E [Pa], h [m], ν [-] (the order of every shell law: P_g, R, E, h, ν).
    """
    alpha, beta = lame_constants_2d(young_modulus, poisson_ratio)
    lam = stretch
    invariant = 2.0 * lam**2 - 2.0 - 4.0 * jnp.log(lam)
    return (
        thickness
        * (2.0 * beta * (lam - 1.0 / lam) / (1.0 - stiffening * invariant) + alpha * (lam**3 - 1.0 / lam))
        / (rest_radius * lam**2)
    )
