"""Compressible Neo-Hookean shell material: membrane and bending energy densities.

Both engines (the 3D triangle shell and the axisymmetric meridian shell) call these functions;
they only differ in how they build the 2x2 tensors. Conventions follow libshell:

* ``rest_metric`` ``ā`` and ``metric`` ``a`` are first fundamental forms (2x2, symmetric positive
  definite) in any common parametrisation; only ``ā⁻¹a`` enters, so the parametrisation cancels.
* ``rest_curvature`` ``b̄`` and ``curvature`` ``b`` are second fundamental forms in the same
  parametrisation (units of metric / length).
* Energies are **per unit rest area** [J/m²]; multiply by the rest area [m²] of an element.

Plane-stress 2D Lamé constants (libshell's convention): α = Eν/(1−ν²), β = E/(2(1+ν)).
The membrane density is W_m = h [β/2 (tr C − 2 − ln det C) + α/4 (det C − 1 − ln det C)] with
C = ā⁻¹a; for small strain ε (C = I + 2ε) it reduces to h [β ε:ε + α/2 (tr ε)²], the linear
plane-stress energy. The bending density is W_b = h³/12 [α/2 (tr M)² + β tr(M²)] with
M = ā⁻¹(b − b̄); for a pure curvature change κ in both directions it equals B (1+ν) κ², the
Kirchhoff plate energy with B = E h³ / (12 (1 − ν²)).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

Scalar = Float[Array, ""]
Matrix2 = Float[Array, "2 2"]


def lame_constants_2d(young_modulus, poisson_ratio) -> tuple[Scalar, Scalar]:
    """Plane-stress Lamé constants (α, β) [Pa] from Young's modulus [Pa] and Poisson ratio [-]."""
    alpha = young_modulus * poisson_ratio / (1.0 - poisson_ratio**2)
    beta = young_modulus / (2.0 * (1.0 + poisson_ratio))
    return alpha, beta


def bending_stiffness(young_modulus, thickness, poisson_ratio) -> Scalar:
    """Flexural rigidity B = E h³ / (12 (1 − ν²)) [N·m] from E [Pa], h [m], ν [-]."""
    return young_modulus * thickness**3 / (12.0 * (1.0 - poisson_ratio**2))


def _inv2(m: Matrix2) -> Matrix2:
    det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    return jnp.array([[m[1, 1], -m[0, 1]], [-m[1, 0], m[0, 0]]]) / det


def neo_hookean_membrane_invariants(trace_c, det_c, thickness, young_modulus, poisson_ratio):
    """Membrane energy per rest area [J/m²] from the invariants tr C [-] and det C [-] of C = ā⁻¹a.

    The axisymmetric engine calls this with C = diag(λ_s², λ_θ²) (principal stretches).
    """
    alpha, beta = lame_constants_2d(young_modulus, poisson_ratio)
    log_det = jnp.log(det_c)
    return thickness * (
        0.5 * beta * (trace_c - 2.0 - log_det) + 0.25 * alpha * (det_c - 1.0 - log_det)
    )


def neo_hookean_membrane_density(
    rest_metric: Matrix2, metric: Matrix2, thickness, young_modulus, poisson_ratio
) -> Scalar:
    """Compressible Neo-Hookean plane-stress membrane energy per rest area [J/m²].

    ``rest_metric``, ``metric``: 2x2 first fundamental forms (any units, same parametrisation);
    ``thickness`` h [m]; ``young_modulus`` E [Pa]; ``poisson_ratio`` ν [-].
    """
    c = _inv2(rest_metric) @ metric
    trace_c = c[0, 0] + c[1, 1]
    det_c = c[0, 0] * c[1, 1] - c[0, 1] * c[1, 0]
    return neo_hookean_membrane_invariants(trace_c, det_c, thickness, young_modulus, poisson_ratio)


def bending_density_invariants(trace_m, trace_m2, thickness, young_modulus, poisson_ratio):
    """Bending energy per rest area [J/m²] from tr M [1/m] and tr(M²) [1/m²], M = ā⁻¹(b − b̄).

    The axisymmetric engine calls this with M = diag(Δκ_s, Δκ_θ) (changes of principal curvature).
    """
    alpha, beta = lame_constants_2d(young_modulus, poisson_ratio)
    return thickness**3 / 12.0 * (0.5 * alpha * trace_m**2 + beta * trace_m2)


def bending_density(
    rest_metric: Matrix2,
    rest_curvature: Matrix2,
    curvature: Matrix2,
    thickness,
    young_modulus,
    poisson_ratio,
) -> Scalar:
    """Bending energy per rest area [J/m²] relative to the rest curvature.

    ``rest_metric`` ā, ``rest_curvature`` b̄ and ``curvature`` b: 2x2 fundamental forms in one
    parametrisation; ``thickness`` h [m]; ``young_modulus`` E [Pa]; ``poisson_ratio`` ν [-].
    """
    m = _inv2(rest_metric) @ (curvature - rest_curvature)
    trace_m = m[0, 0] + m[1, 1]
    trace_m2 = jnp.sum(m * m.T)
    return bending_density_invariants(trace_m, trace_m2, thickness, young_modulus, poisson_ratio)
