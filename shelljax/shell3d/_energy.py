"""Per-element discrete shell energy on a 6-vertex flap stencil (pure JAX, float64, SI units).

Membrane: the first fundamental form of the flat triangle, a = [eᵢ·eⱼ] with e₁ = x₁−x₀,
e₂ = x₂−x₀. Bending: the second fundamental form of the quadratic surface interpolating the six
flap vertices (the face and the three vertices across its edges), taken as the height field over
the face plane — the curvature of the rotation-free "basic shell triangle" family (Oñate & Zárate
2000, Int. J. Numer. Meth. Eng. 47, 557). It reproduces the curvature of any quadratic surface
exactly, hence is consistent on irregular meshes. The midedge-average operator of libshell
(Grinspun et al. 2006) was tried first and rejected: on our sphere meshes its rest curvature
ā⁻¹b̄ deviates from −I/R by up to ±16 % (icosphere) and ±75 % (graded ring mesh), which would bias
the bending stiffness by as much. Outward normals give b ≈ −a/R on a sphere of radius R.

Energy densities come from :mod:`shelljax.physics` (shared with the axisymmetric engine); each face
contributes ``rest_area · (W_membrane + W_bending)``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..physics import bending_density, neo_hookean_membrane_density

Stencil = Float[Array, "6 3"]
Matrix2 = Float[Array, "2 2"]


def _unit(v):
    return v / jnp.linalg.norm(v)


def fundamental_forms(p: Stencil) -> tuple[Matrix2, Matrix2]:
    """First (a [m²]) and second (b [m]) fundamental forms of a flap stencil (6, 3) [m].

    Both are expressed in the face parametrisation x = x₀ + u e₁ + v e₂. The curvature is the
    Hessian in (u, v) of the quadratic height field w(u, v) over the face plane interpolating all
    six stencil vertices. The three corners have w = 0, so w lies in the span of the products of
    the face's barycentric coordinates φ₀ = 1 − u − v, φ₁ = u, φ₂ = v,

        w = γ₀₁ φ₀φ₁ + γ₁₂ φ₁φ₂ + γ₂₀ φ₂φ₀,

    and the three flap vertices fix γ by a 3×3 system solved by Cramer's rule. Pure arithmetic
    (no LAPACK call): XLA fuses it, which makes the vmapped element Hessians several times faster
    than a batched 6×6 solve, and the result equals the 6-point interpolant (tested against a
    Vandermonde solve in tests/test_shell3d_energy.py).
    """
    x0, x1, x2 = p[0], p[1], p[2]
    e1, e2 = x1 - x0, x2 - x0
    a = jnp.array([[e1 @ e1, e1 @ e2], [e1 @ e2, e2 @ e2]])
    normal = _unit(jnp.cross(e1, e2))
    d = p[3:] - x0  # (3, 3): flap vertices relative to x₀
    # In-plane coordinates (u, v) of the flap vertices' projections: a [u, v]ᵀ = [e₁·d, e₂·d]ᵀ.
    r1, r2 = d @ e1, d @ e2
    det_a = a[0, 0] * a[1, 1] - a[0, 1] ** 2
    u = (a[1, 1] * r1 - a[0, 1] * r2) / det_a
    v = (a[0, 0] * r2 - a[0, 1] * r1) / det_a
    height = d @ normal
    phi0 = 1.0 - u - v
    m = jnp.stack([phi0 * u, u * v, v * phi0], axis=1)  # (3 flaps, 3 products)
    gamma = _solve3(m, height)
    # Hessian of w: ∂uu = −2γ₀₁, ∂vv = −2γ₂₀, ∂uv = −γ₀₁ + γ₁₂ − γ₂₀.
    b_uv = -gamma[0] + gamma[1] - gamma[2]
    b = jnp.array([[-2.0 * gamma[0], b_uv], [b_uv, -2.0 * gamma[2]]])
    return a, b


def _solve3(m: Float[Array, "3 3"], rhs: Float[Array, " 3"]) -> Float[Array, " 3"]:
    """Solution of m x = rhs for a 3×3 matrix by Cramer's rule (adjugate over determinant)."""
    c0 = jnp.cross(m[1], m[2])
    c1 = jnp.cross(m[2], m[0])
    c2 = jnp.cross(m[0], m[1])
    det = m[0] @ c0
    return (rhs[0] * c0 + rhs[1] * c1 + rhs[2] * c2) / det


def face_volume(p) -> Float[Array, ""]:
    """Signed volume [m³] of the tetrahedron (origin, x₀, x₁, x₂); sums to the enclosed volume."""
    return p[0] @ jnp.cross(p[1], p[2]) / 6.0


def membrane_energy(p: Stencil, rest_metric, rest_area, thickness, young_modulus, poisson_ratio):
    """Neo-Hookean membrane energy [J] of one face: rest_area [m²] × W_m [J/m²]."""
    a, _ = fundamental_forms(p)
    return rest_area * neo_hookean_membrane_density(rest_metric, a, thickness, young_modulus, poisson_ratio)


def bending_energy(p: Stencil, rest_metric, rest_curvature, rest_area, thickness, young_modulus, poisson_ratio):
    """Midedge bending energy [J] of one face relative to its rest curvature."""
    _, b = fundamental_forms(p)
    return rest_area * bending_density(rest_metric, rest_curvature, b, thickness, young_modulus, poisson_ratio)


def face_energy(p: Stencil, rest_metric, rest_curvature, rest_area, thickness, young_modulus, poisson_ratio, gauge_pressure):
    """Membrane + bending energy [J] of one face minus gauge_pressure [Pa] × its volume share [m³].

    The pressure term makes the per-face Hessian include P ∂²V; for a sealed gas the current
    pressure is passed (the rank-one Π''(V) ∇V∇Vᵀ part is added separately).
    """
    a, b = fundamental_forms(p)
    w = neo_hookean_membrane_density(rest_metric, a, thickness, young_modulus, poisson_ratio)
    w = w + bending_density(rest_metric, rest_curvature, b, thickness, young_modulus, poisson_ratio)
    return rest_area * w - gauge_pressure * face_volume(p)


def rest_geometry(rest_stencils: Float[Array, "F 6 3"]):
    """Per-face rest metric ā (F, 2, 2) [m²], rest curvature b̄ (F, 2, 2) [m], rest area (F,) [m²]."""
    a, b = jax.vmap(fundamental_forms)(rest_stencils)
    area = 0.5 * jnp.sqrt(a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] ** 2)
    return a, b, area
