"""Per-element discrete shell energy on a 6-vertex flap stencil (pure JAX, float64, SI units).

Membrane: the first fundamental form of the flat triangle, a = [eᵢ·eⱼ] with e₁ = x₁−x₀,
e₂ = x₂−x₀. Bending: the second fundamental form of the quadratic surface interpolating the six
flap vertices (the face and the three vertices across its edges), taken as the height field over
the face plane — the curvature of the rotation-free "basic shell triangle" family (Oñate & Zárate
2000, Int. J. Numer. Meth. Eng. 47, 557). It reproduces the curvature of any quadratic surface
exactly, hence is consistent on irregular meshes. The midedge-average operator of libshell
(Grinspun et al. 2006) is not used: on our sphere meshes its rest curvature ā⁻¹b̄ deviates from
−I/R by up to ±16 % (icosphere) and ±75 % (graded ring mesh), which would bias the bending
stiffness by as much. Outward normals give b ≈ −a/R on a sphere of radius R.

Energy densities come from :mod:`shelljax.physics` (shared with the axisymmetric engine); each face
contributes ``rest_area · (W_membrane + W_bending)``.

The total potential energy of the model (:func:`total_energy`) adds the gas, the contacts, the
ground friction, the indenter force, nodal forces and the weight to the faces' energies (the
formula is in :mod:`shelljax.shell3d._model`).
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ..physics import STANDARD_GRAVITY, bending_density, neo_hookean_membrane_density
from ._config import ModelConfig, split_dofs
from ._contact import friction_potential, min_gap, plane_contact_energy, sphere_contact_energy
from ._mesh import ShellMesh

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


def face_energy(
    p: Stencil, rest_metric, rest_curvature, rest_area, thickness, young_modulus, poisson_ratio, gauge_pressure
):
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


class ShellGeometry(eqx.Module):
    """Per-face rest data and per-vertex weights (arrays; not part of the jit key)."""

    stencil: Int[Array, "F 6"]
    rest_metric: Float[Array, "F 2 2"]
    rest_curvature: Float[Array, "F 2 2"]
    rest_area: Float[Array, " F"]
    vertex_area: Float[Array, " V"]


def make_geometry(mesh: ShellMesh, rest_vertices) -> ShellGeometry:
    """Rest fundamental forms of ``mesh``'s topology at ``rest_vertices`` (V, 3) [m]."""
    stencil = jnp.asarray(mesh.stencil)
    rest = jnp.asarray(rest_vertices, dtype=jnp.float64)
    metric, curvature, area = rest_geometry(rest[stencil])
    vertex_area = jnp.zeros(mesh.n_vertices).at[stencil[:, :3]].add(area[:, None] / 3.0)
    return ShellGeometry(stencil, metric, curvature, area, vertex_area)


def volume(x: Float[Array, "V 3"], stencil) -> Float[Array, ""]:
    """Enclosed volume [m³] of the closed mesh at vertex positions x (V, 3) [m]."""
    return jnp.sum(jax.vmap(face_volume)(x[stencil[:, :3]]))


def gas_energy(vol, params, config: ModelConfig):
    """Gas potential Π(V) [J] of ``config.gas`` (a ``physics.AbstractGasLaw``)."""
    if not config.gas.sealed:  # a held gauge pressure has no reference volume
        return config.gas.energy(vol, None, params.gauge_pressure)
    return config.gas.energy(vol, params.reference_volume, params.gauge_pressure, params.outside_pressure)


def gauge_pressure(q, params, geometry: ShellGeometry, config: ModelConfig):
    """Current gauge pressure −dΠ/dV [Pa] of the gas."""
    x, _ = split_dofs(q, config)
    vol = volume(x, geometry.stencil)
    return -jax.grad(gas_energy)(vol, params, config)


def elastic_energy(x, params, geometry):
    """Membrane + bending energy [J] of the whole shell."""
    p = x[geometry.stencil]
    e = jax.vmap(face_energy, in_axes=(0, 0, 0, 0, None, None, None, None))(
        p,
        geometry.rest_metric,
        geometry.rest_curvature,
        geometry.rest_area,
        params.thickness,
        params.young_modulus,
        params.poisson_ratio,
        0.0,
    )
    return jnp.sum(e)


def total_energy(q, params, geometry: ShellGeometry, config: ModelConfig):
    """Total potential energy E(q) [J] (formula: :mod:`shelljax.shell3d._model`)."""
    x, c = split_dofs(q, config)
    e = elastic_energy(x, params, geometry)
    e = e + gas_energy(volume(x, geometry.stencil), params, config)
    if config.contact.indenter_radius is not None:
        e = e + sphere_contact_energy(x, c, geometry, config)
    for plane in config.contact.planes:
        e = e + plane_contact_energy(x, plane, geometry, config)
    if config.contact.has_friction:
        e = e + friction_potential(x, params, config)
    if config.force_control:
        e = e + params.indenter_force * c[2]
    if params.nodal_forces is not None:
        e = e - jnp.sum(params.nodal_forces * x)
    if params.mass is not None:
        weights = geometry.vertex_area / jnp.sum(geometry.vertex_area)
        e = e + params.mass * STANDARD_GRAVITY * jnp.sum(weights * x[:, 2])
    return e


@functools.partial(jax.jit, static_argnames=("config",))
def search_energy(q, params, geometry, config):
    """Total energy [J] for Newton's line search: +inf where a barrier is crossed or not finite."""
    e = total_energy(q, params, geometry, config)
    if config.contact.kind == "barrier":
        e = jnp.where(min_gap(q, geometry, config) > 0.0, e, jnp.inf)
    return jnp.where(jnp.isfinite(e), e, jnp.inf)


#: ∇E(q) [N], jitted.
energy_gradient = jax.jit(jax.grad(total_energy), static_argnames=("config",))
