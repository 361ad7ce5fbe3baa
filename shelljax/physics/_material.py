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

Gent-type stiffening (``gent_membrane_invariants``): the shear part β/2 · I, I = tr C − 2 − ln det C
(≥ 0, zero only at C = I), becomes −β/(2s) ln(1 − s I) with ``stiffening`` s = 1/J_m [-] (J_m the
Gent locking value of I): the stress grows without bound as I → 1/s. It tends to the Neo-Hookean
β/2 · I as s → 0 (the difference is β s I²/4 + O(s²)); s < 0 softens. The volumetric part is
unchanged.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax.custom_derivatives import SymbolicZero
from jaxtyping import Array, Float

Scalar = Float[Array, ""]
Matrix2 = Float[Array, "2 2"]

# ψ(x) = −ln(1 − x)/x = Σ xⁿ/(n + 1) and ψ'(x) = Σ n xⁿ⁻¹/(n + 1) by their Taylor series near x = 0,
# where the closed forms cancel. The value needs 5 terms for |x| < 1e-3 (remainder x⁵/6 < 2e-16,
# and −log1p(−x)/x is exact to round-off beyond). ψ', needed only for derivatives in s, keeps 15
# terms up to |x| < 0.05 (remainder < 1e-18); its closed form (x/(1 − x) + log1p(−x))/x² loses
# ≈ 2 eps/|x| ≤ 1e-14 beyond.
_GENT_VALUE_LIMIT = 1e-3
_GENT_VALUE_COEFFICIENTS = tuple(1.0 / (n + 1) for n in range(5))
_GENT_SLOPE_LIMIT = 0.05
_GENT_SLOPE_COEFFICIENTS = tuple(n / (n + 1) for n in range(1, 16))


def lame_constants_2d(young_modulus, poisson_ratio) -> tuple[Scalar, Scalar]:
    """Plane-stress Lamé constants (α, β) [Pa] from Young's modulus [Pa] and Poisson ratio [-]."""
    alpha = young_modulus * poisson_ratio / (1.0 - poisson_ratio**2)
    beta = young_modulus / (2.0 * (1.0 + poisson_ratio))
    return alpha, beta


def _inv2(m: Matrix2) -> Matrix2:
    det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    return jnp.array([[m[1, 1], -m[0, 1]], [-m[1, 0], m[0, 0]]]) / det


def neo_hookean_membrane_invariants(trace_c, det_c, thickness, young_modulus, poisson_ratio):
    """Membrane energy per rest area [J/m²] from the invariants tr C [-] and det C [-] of C = ā⁻¹a.

    The axisymmetric engine calls this with C = diag(λ_s², λ_θ²) (principal stretches).
    """
    alpha, beta = lame_constants_2d(young_modulus, poisson_ratio)
    log_det = jnp.log(det_c)
    return thickness * (0.5 * beta * (trace_c - 2.0 - log_det) + 0.25 * alpha * (det_c - 1.0 - log_det))


def _horner(coefficients, x):
    out = jnp.zeros_like(x)
    for c in reversed(coefficients):
        out = out * x + c
    return out


def _gent_log_slope(x):
    """ψ'(x) [-] for x < 1, ψ(x) = −ln(1 − x)/x: the series near 0, the closed form beyond."""
    small = jnp.abs(x) < _GENT_SLOPE_LIMIT
    x_series = jnp.where(small, x, 0.0)
    x_closed = jnp.where(small, 0.5, x)
    closed = (x_closed / (1.0 - x_closed) + jnp.log1p(-x_closed)) / x_closed**2
    return jnp.where(small, _horner(_GENT_SLOPE_COEFFICIENTS, x_series), closed)


@functools.partial(jax.custom_jvp)
def _gent_shear(invariant, stiffening):
    x = stiffening * invariant
    small = jnp.abs(x) < _GENT_VALUE_LIMIT
    finite = x < 1.0
    x_series = jnp.where(small, x, 0.0)
    closed = ~small & finite
    x_closed = jnp.where(closed, x, 0.5)
    s_closed = jnp.where(closed, stiffening, 1.0)
    return jnp.where(
        small,
        invariant * _horner(_GENT_VALUE_COEFFICIENTS, x_series),
        jnp.where(finite, -jnp.log1p(-x_closed) / s_closed, jnp.inf),
    )


def _gent_shear_jvp(primals, tangents):
    # Closed-form partial derivatives: ∂/∂I = 1/(1 − s I) exactly (no series, no cancellation),
    # ∂/∂s = I² ψ'(s I). The tangent in s is a symbolic zero wherever s is not differentiated
    # (every Newton gradient and Hessian), so ψ' is only traced for derivatives in s.
    invariant, stiffening = primals
    d_invariant, d_stiffening = tangents
    value = _gent_shear(invariant, stiffening)
    x = stiffening * invariant
    finite = x < 1.0
    x_safe = jnp.where(finite, x, 0.0)
    terms = []
    if not isinstance(d_invariant, SymbolicZero):
        terms.append(jnp.where(finite, 1.0 / (1.0 - x_safe), 0.0) * d_invariant)
    if not isinstance(d_stiffening, SymbolicZero):
        terms.append(jnp.where(finite, invariant**2 * _gent_log_slope(x_safe), 0.0) * d_stiffening)
    return value, sum(terms[1:], terms[0]) if terms else jnp.zeros_like(value)


_gent_shear.defjvp(_gent_shear_jvp, symbolic_zeros=True)


def gent_shear_energy(invariant, stiffening):
    """−ln(1 − s I)/s [-] for the shear invariant I ≥ 0 [-] and ``stiffening`` s [-] (I at s = 0).

    +inf where s I ≥ 1 (past the locking stretch: a line search rejects such a state; the
    derivatives there are set to 0, never NaN). Smooth, with derivatives of every order in I and s
    through s = 0: ∂/∂I = 1/(1 − s I), ∂/∂s = I² ψ'(s I) with ψ(x) = −ln(1 − x)/x (ψ'(0) = 1/2).
    """
    invariant = jnp.asarray(invariant)
    stiffening = jnp.asarray(stiffening, dtype=invariant.dtype)
    invariant, stiffening = jnp.broadcast_arrays(invariant, stiffening)
    return _gent_shear(invariant, stiffening)


def gent_membrane_invariants(trace_c, det_c, thickness, young_modulus, poisson_ratio, stiffening):
    """Gent-stiffened compressible membrane energy per rest area [J/m²] from tr C [-], det C [-].

    h [−β/(2s) ln(1 − s I) + α/4 (det C − 1 − ln det C)], I = tr C − 2 − ln det C; ``thickness``
    h [m], ``young_modulus`` E [Pa], ``poisson_ratio`` ν [-], ``stiffening`` s = 1/J_m [-]
    (0: exactly ``neo_hookean_membrane_invariants``, derivatives included; may be traced, and
    slightly negative). +inf where s I ≥ 1.
    """
    alpha, beta = lame_constants_2d(young_modulus, poisson_ratio)
    log_det = jnp.log(det_c)
    shear = gent_shear_energy(trace_c - 2.0 - log_det, stiffening)
    return thickness * (0.5 * beta * shear + 0.25 * alpha * (det_c - 1.0 - log_det))


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
    rest_metric: Matrix2, rest_curvature: Matrix2, curvature: Matrix2, thickness, young_modulus, poisson_ratio
) -> Scalar:
    """Bending energy per rest area [J/m²] relative to the rest curvature.

    ``rest_metric`` ā, ``rest_curvature`` b̄ and ``curvature`` b: 2x2 fundamental forms in one
    parametrisation; ``thickness`` h [m]; ``young_modulus`` E [Pa]; ``poisson_ratio`` ν [-].
    """
    m = _inv2(rest_metric) @ (curvature - rest_curvature)
    trace_m = m[0, 0] + m[1, 1]
    trace_m2 = jnp.sum(m * m.T)
    return bending_density_invariants(trace_m, trace_m2, thickness, young_modulus, poisson_ratio)
