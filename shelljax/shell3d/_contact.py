"""Contact of the shell with rigid bodies: the indenter sphere and planes (ground, walls).

Per-vertex potentials φ(gap) (IPC barrier or quadratic penalty) with stiffness scaled by the lumped
rest area, the lagged smoothed Coulomb friction on the planes, and the host-side gap geometry that
Newton's feasibility projection and warm starts use. SI units: m, N, J.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._errors import InvalidInputError
from ..physics import barrier_energy, friction_energy, penalty_energy, sphere_gap
from ._config import ContactConfig, ModelConfig, split_dofs

# Barrier calibration: the IPC barrier's force at g = ĝ/10 is κ ĝ · 12.2 (φ(s) = 2(s−1)ln s +
# (s−1)²/s at s = 0.1), so κ = p_ref A_v / (12.2 ĝ) makes a vertex pressed with p_ref sit at ĝ/10.
_BARRIER_FORCE_AT_TENTH = 2.0 * 0.9 * np.log(10.0) + 0.81 / 0.1


def contact_potential(gap, stiffness, contact: ContactConfig):
    if contact.kind == "barrier":
        return barrier_energy(gap, contact.activation_distance, stiffness)
    return penalty_energy(gap, stiffness)


def contact_stiffness(geometry, contact: ContactConfig):
    """Per-vertex barrier κ [J/m²] or penalty k [N/m], scaled by lumped rest area."""
    force = contact.reference_pressure * geometry.vertex_area
    if contact.kind == "barrier":
        return force / (_BARRIER_FORCE_AT_TENTH * contact.activation_distance)
    return force / contact.activation_distance


def sphere_contact_energy(x, c, geometry, config):
    """Indenter contact energy [J] summed over vertices."""
    k = contact_stiffness(geometry, config.contact)
    gap = sphere_gap(x, c, config.contact.indenter_radius)
    return jnp.sum(contact_potential(gap, k, config.contact))


def plane_contact_energy(x, plane, geometry, config):
    """Contact energy [J] of all vertices against one :class:`shelljax.physics.Plane`."""
    k = contact_stiffness(geometry, config.contact)
    gap = plane.gap(x)
    return jnp.sum(contact_potential(gap, k, config.contact))


def plane_normal_forces(x, plane, geometry, config) -> Float[Array, " V"]:
    """Normal contact force magnitude λ = −dφ/dgap [N] (≥ 0) of every vertex on one plane."""
    k = contact_stiffness(geometry, config.contact)
    gap = plane.gap(x)
    dphi = jax.vmap(jax.grad(contact_potential), in_axes=(0, 0, None))(gap, k, config.contact)
    return -dphi


def friction_data(params, config):
    """(lagged anchors (V, 3) [m], lagged normal forces (n_planes, V) [N]) of ``params``."""
    missing = [key for key in ("friction_anchor", "friction_normal_force") if getattr(params, key) is None]
    if missing:
        raise InvalidInputError(
            f"params: friction μ = {config.contact.friction} needs {missing} (lagged vertex positions "
            "(V, 3) [m] and normal forces (n_planes, V) [N]); Indentation sets them, or use μ = 0."
        )
    return params.friction_anchor, params.friction_normal_force


def vertex_friction(y, anchor, lam, normal, mu, contact: ContactConfig):
    """Friction potential [J] of vertex positions y (…, 3) on a plane of unit ``normal``."""
    d = y - anchor
    slip = d - (d @ normal)[..., None] * normal
    return friction_energy(slip, lam, mu, contact.friction_slip_tolerance)


def friction_coefficient(params, config):
    """Coulomb μ [-]: the traced one of ``params`` if set, else the config's."""
    return config.contact.friction if params.friction_coefficient is None else params.friction_coefficient


def friction_potential(x, params, config) -> Float[Array, ""]:
    """Lagged smoothed Coulomb friction energy [J] of all vertices on all planes (0 if μ = 0)."""
    if not config.contact.has_friction:
        return jnp.zeros(())
    anchor, lam = friction_data(params, config)
    mu = friction_coefficient(params, config)
    e = jnp.zeros(())
    for i, plane in enumerate(config.contact.planes):
        e = e + jnp.sum(vertex_friction(x, anchor, lam[i], plane.normal, mu, config.contact))
    return e


def min_gap(q, geometry, config):
    """Smallest contact gap [m] over all vertices and rigid bodies (+inf without contacts)."""
    x, c = split_dofs(q, config)
    g = jnp.inf
    if config.contact.indenter_radius is not None:
        g = jnp.minimum(g, jnp.min(sphere_gap(x, c, config.contact.indenter_radius)))
    for plane in config.contact.planes:
        g = jnp.minimum(g, jnp.min(plane.gap(x)))
    return g


@functools.partial(jax.jit, static_argnames=("config",))
def stacked_plane_normal_forces(q, geometry, config):
    """(n_planes, V) normal contact force magnitudes λ [N] of every vertex on every plane."""
    x, _ = split_dofs(q, config)
    forces = [plane_normal_forces(x, plane, geometry, config) for plane in config.contact.planes]
    return jnp.stack(forces) if forces else jnp.zeros((0, config.n_vertices))


@functools.partial(jax.jit, static_argnames=("config",))
def stacked_friction_forces(q, params, config):
    """(n_planes, V, 3) friction forces −∂D/∂x_v [N] of each plane on each vertex."""
    x, _ = split_dofs(q, config)
    if not config.contact.has_friction:
        return jnp.zeros((len(config.contact.planes),) + x.shape)
    anchor, lam = friction_data(params, config)
    mu = friction_coefficient(params, config)
    out = []
    for i, plane in enumerate(config.contact.planes):
        e = lambda y, i=i, plane=plane: jnp.sum(  # noqa: E731
            vertex_friction(y, anchor, lam[i], plane.normal, mu, config.contact)
        )
        out.append(-jax.grad(e)(x))
    return jnp.stack(out)


#: The line search's projection (:meth:`EquilibriumProblem.feasible_trial`) keeps at least this
#: fraction of its gap to a body for every vertex within the barrier's range: a log barrier's
#: Newton model overshoots where a vertex starts far above its equilibrium gap (docs/shell3d.md).
BARRIER_STEP_FRACTION = 0.3


def body_gap_and_normal(x, c, config: ModelConfig, body: int):
    """Gap [m] (V,) of every vertex to rigid body ``body`` (0: the indenter, if any, then the
    planes in order) and the unit direction (V, 3) in which it grows (host arrays)."""
    contact = config.contact
    if contact.indenter_radius is not None:
        if body == 0:
            offset = x - c
            distance = np.linalg.norm(offset, axis=1)
            return distance - contact.indenter_radius, offset / distance[:, None]
        body -= 1
    point, normal = (np.asarray(a, dtype=np.float64) for a in (contact.planes[body].point, contact.planes[body].normal))
    return (x - point) @ normal, np.broadcast_to(normal, x.shape)


def n_bodies(config: ModelConfig) -> int:
    """Number of rigid bodies (indenter and planes) the shell can touch."""
    return (config.contact.indenter_radius is not None) + len(config.contact.planes)


def place_at_gaps(q, config: ModelConfig, target) -> np.ndarray:
    """A copy of state ``q`` [m] with vertices moved along the bodies' normals to the gaps
    ``target(body, gap)`` [m] (NaN where a vertex stays), body after body (host)."""
    q = np.array(q, dtype=np.float64)
    x, c = q[: 3 * config.n_vertices].reshape(-1, 3), q[3 * config.n_vertices :]
    for body in range(n_bodies(config)):
        gap, normal = body_gap_and_normal(x, c, config, body)
        goal = target(body, gap)
        moved = np.isfinite(goal)
        x[moved] += (goal[moved] - gap[moved])[:, None] * normal[moved]
    return q


def body_gaps(q, config: ModelConfig) -> list:
    """Gaps [m] (V,) of every vertex to each rigid body (:func:`body_gap_and_normal`'s order)."""
    q = np.asarray(q, dtype=np.float64)
    x, c = q[: 3 * config.n_vertices].reshape(-1, 3), q[3 * config.n_vertices :]
    return [body_gap_and_normal(x, c, config, body)[0] for body in range(n_bodies(config))]
