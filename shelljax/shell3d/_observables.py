"""Observables of an indented shell on the ground (the paper's elasticity figure, panel b).

All lengths in m, forces in N, pressure in Pa, volume in m³. With the ground at z = 0 and the
indenter on the vertical axis through the top vertex:

* ``force`` F: the indenter's push on the shell, −∂E_contact/∂c_z (c: indenter center).
* ``depth``: indenter travel from first touch of the unloaded (pressurized) shell.
* ``w0``: indentation depth w(0), the drop of the top (loaded) vertex from its unloaded height.
* ``H``: deformed height, the highest point of the shell above the ground.
* ``D_u``: upper-circle diameter, 2 × the distance from the axis of the highest point (the rim of
  the dimple; 0 while the top vertex is still the highest point).
* ``D_l``: ground-contact diameter from the ground reaction, 2 √(F_ground / (π p)): the flat
  contact disc carries the gas pressure (the membrane leaves the ground tangentially, so its
  tension at the disc edge is horizontal). The axisymmetric engine uses the same definition.
* ``D_l_mesh``: geometric ground-contact diameter, 2 × the largest distance from the axis of a
  vertex within the contact activation distance ĝ of the ground. It overestimates the disc by
  the ring where the shell lifts off by less than ĝ, plus up to one edge length of vertex
  resolution.
* ``d``: sunken depth, rim height minus top-vertex height.
* ``pressure`` (gauge) and ``volume`` of the gas; ``ground_reaction``: vertical force of the
  ground on the shell (equals F plus the weight at equilibrium).
* ``friction_force`` [N]: magnitude of the ground's total tangential friction force on the shell,
  ‖Σ_v f_v‖ with f_v = −∂D/∂x_v (≈ 0 by symmetry for a centred poke; 0 without friction).
* ``friction_inward`` [N]: total radial friction force on the ground-contact vertices (gap below the
  activation distance), counted positive *inward*: −Σ_contact f_v · r̂_v, r̂_v the horizontal unit
  vector from the axis to the vertex. Positive when the ground holds the contact patch back from
  spreading outward, negative when it holds it from sliding inward; 0 without friction.

On ring meshes the rim radius is refined by a parabola through the heights of the three rings
nearest the highest vertex (upper half only); on other meshes the highest vertex is the rim.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..physics import plane_gap
from ._config import split_dofs
from ._contact import plane_contact_energy, sphere_contact_energy


def observables(sim, q, params) -> dict:
    """Observables dict of a solved indentation state ``q`` of ``sim`` (an :class:`Indentation`)
    with its parameters ``params`` (``sim.params_at(q, **friction)``); see the module docstring."""
    model = sim.model
    qj = jnp.asarray(q)
    x, c = split_dofs(qj, model.config)
    f_ind = -jax.grad(lambda cc: sphere_contact_energy(x, cc, model.geometry, model.config))(c)
    out = {"force": float(f_ind[2])}
    ground = 0.0
    for plane in model.config.contact.planes:
        f = -jax.grad(lambda xx: plane_contact_energy(xx, plane, model.geometry, model.config))(x)
        ground += float(jnp.sum(f[:, 2]))
    xn = np.asarray(x)
    axis = np.asarray(model.rest_vertices)[sim.top, :2]
    r = np.hypot(xn[:, 0] - axis[0], xn[:, 1] - axis[1])
    z = xn[:, 2]
    top_z = z[sim.top]
    i_max = int(np.argmax(z))
    z_rim, r_rim = float(z[i_max]), float(r[i_max])
    if i_max != sim.top:
        r_rim, z_rim = _parabola_peak(r, z, r_rim)
    gaps = np.asarray(plane_gap(x, jnp.zeros(3), jnp.array([0.0, 0.0, 1.0])))
    touching = gaps < model.config.contact.activation_distance
    d_l = 2.0 * float(r[touching].max()) if touching.any() else 0.0
    friction_force, friction_inward = 0.0, 0.0
    if model.config.contact.has_friction:
        f_fric = model.friction_forces(qj, params).sum(axis=0)  # (V, 3) over all planes
        friction_force = float(np.linalg.norm(f_fric.sum(axis=0)))
        radial = np.stack([xn[:, 0] - axis[0], xn[:, 1] - axis[1]], axis=1)
        radial = radial / np.maximum(r, 1e-300)[:, None]  # r = 0 (on the axis): no radial direction
        friction_inward = -float(np.sum(np.sum(f_fric[touching, :2] * radial[touching], axis=1)))
    pressure = float(model.gauge_pressure(qj, params))
    out.update(
        depth=float(sim.touch_center[2] - np.asarray(c)[2]),
        w0=float(sim.top_height - top_z),
        H=float(z_rim),
        D_u=2.0 * r_rim if i_max != sim.top else 0.0,
        D_l=2.0 * float(np.sqrt(max(ground, 0.0) / (np.pi * pressure))) if pressure > 0 else 0.0,
        D_l_mesh=d_l,
        d=float(z_rim - top_z),
        pressure=pressure,
        volume=float(model.volume(qj)),
        ground_reaction=ground,
        friction_force=friction_force,
        friction_inward=friction_inward,
    )
    return out


RING_MIN_VERTICES = 3  # a radius shared by fewer vertices is not a ring (irregular or wrinkled mesh)


def _parabola_peak(r, z, r0):
    """Peak (r*, z*) of z(r) from a parabola through the ring heights near r0 (ring meshes).

    Only the upper half of the shell is searched: a vertex near the ground can share the rim's
    radius, and would then bend the parabola far above the ball. Without three
    real rings there (irregular meshes, or rings split by wrinkles) the highest vertex is the rim.
    """
    fallback = (r0, float(z.max()))
    upper = z > 0.5 * (z.max() + z.min())
    r, z = r[upper], z[upper]
    rings = np.unique(np.round(r, 9))
    near = rings[np.argsort(np.abs(rings - r0))[:3]]
    if near.size < 3:
        return fallback
    members = [np.isclose(r, rv, atol=1e-9) for rv in near]
    if min(int(m.sum()) for m in members) < RING_MIN_VERTICES:
        return fallback
    zs = np.array([z[m].max() for m in members])
    a, b, c = np.polyfit(near, zs, 2)
    if a >= 0:
        return r0, float(zs.max())
    rp = -b / (2 * a)
    if not (near.min() <= rp <= near.max()):
        return r0, float(zs.max())
    return float(rp), float(c - b * b / (4 * a))
