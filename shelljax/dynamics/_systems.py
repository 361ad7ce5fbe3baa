"""Small concrete systems: verification models and the issue's 1-DOF reference.

* ``PointMassOnGround``: a point mass (or a rigid ball's centre) of mass m [kg] under gravity,
  on contact springs against planes (their laws: e.g. a ``CompressionCurve`` F(δ) [N] of the
  compression [m]). With the ground's quasi-static force–compression curve of a shell it is the
  1-DOF model m ẍ = −F_ground(x).
* ``SpringBalloon``: a closed triangle mesh of lumped masses [kg] joined by linear springs
  [N/m] along its edges, enclosing a sealed polytropic gas; a tiny discrete balloon that exercises
  gas, contact, friction and prescribed nodes on a multi-DOF system.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._errors import InvalidInputError
from ..geometry import mesh_volume
from ..physics import STANDARD_GRAVITY, ATMOSPHERIC_PRESSURE, polytropic_gas_energy, polytropic_gauge_pressure
from ..physics import Plane
from ..physics.internal import check_nonnegative, check_positive
from ._system import AbstractDynamicSystem, PrescribedRotation, gravity_vector


class PointMassOnGround(AbstractDynamicSystem):
    """A point mass ``mass`` [kg] at x (3,) [m] under ``gravity`` (g [m/s²] down, or a 3-vector), against ``planes``."""

    mass: Float[Array, ""]
    planes: tuple[Plane, ...]
    gravity: Float[Array, "3"]

    def __init__(self, mass, planes, gravity=STANDARD_GRAVITY):
        check_positive("PointMassOnGround.mass [kg]", mass, "Give the object's mass, e.g. from the session's `mass`.")
        self.mass = jnp.asarray(mass, dtype=float)
        self.planes = tuple(planes)
        self.gravity = gravity_vector(gravity)

    def lumped_mass(self):
        return jnp.full((3,), self.mass)

    def internal_energies(self, x, t):
        return {"gravity": -self.mass * (self.gravity @ x)}


class SpringBalloon(AbstractDynamicSystem):
    """Masses at mesh nodes joined by edge springs, sealing a polytropic gas.

    ``rest_nodes`` (N, 3) [m] and outward ``faces`` (F, 3) define the stress-free shape; each node
    carries ``node_masses`` (N,) [kg]; each edge a spring of ``spring_stiffness`` k [N/m]. The gas
    has gauge pressure ``gauge_pressure`` [Pa] at the rest volume and exponent κ [-] (1 isothermal,
    1.4 adiabatic). ``prescribed``: optional rigid rotation of the nodes ``prescribed_nodes``.
    """

    rest_nodes: Float[Array, "N 3"]
    faces: Int[Array, "F 3"]
    edges: Int[Array, "E 2"]
    rest_lengths: Float[Array, " E"]
    node_masses: Float[Array, " N"]
    spring_stiffness: Float[Array, ""]
    gauge_pressure: Float[Array, ""]
    gas_exponent: Float[Array, ""]
    rest_volume: Float[Array, ""]
    planes: tuple[Plane, ...]
    gravity: Float[Array, "3"]
    prescribed_nodes: tuple[int, ...] = eqx.field(static=True)
    prescribed: PrescribedRotation | None

    def __init__(
        self,
        rest_nodes,
        faces,
        node_masses,
        spring_stiffness,
        planes,
        *,
        gauge_pressure=0.0,
        gas_exponent=1.0,
        gravity=STANDARD_GRAVITY,
        prescribed_nodes=(),
        prescribed=None,
    ):
        nodes = np.asarray(rest_nodes, dtype=float)
        f = np.asarray(faces, dtype=int)
        if (
            nodes.ndim != 2
            or nodes.shape[1] != 3
            or f.ndim != 2
            or f.shape[1] != 3
            or f.min() < 0
            or f.max() >= len(nodes)
        ):
            raise InvalidInputError("SpringBalloon needs rest_nodes (N, 3) [m] and faces (F, 3) indexing them.")
        if node_masses is None:
            raise InvalidInputError(
                "SpringBalloon.node_masses [kg] is missing; give the mass per node (total mass / N)."
            )
        m = np.broadcast_to(np.asarray(node_masses, dtype=float), (len(nodes),))
        check_positive("SpringBalloon.node_masses [kg]", m, "Give the mass per node (total mass / N).")
        check_nonnegative("SpringBalloon.spring_stiffness [N/m]", spring_stiffness, "Give k ≥ 0.")
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        e = np.unique(e, axis=0)
        self.rest_nodes, self.faces, self.edges = jnp.asarray(nodes), jnp.asarray(f), jnp.asarray(e)
        self.rest_lengths = jnp.asarray(np.linalg.norm(nodes[e[:, 0]] - nodes[e[:, 1]], axis=1))
        self.node_masses, self.spring_stiffness = jnp.asarray(m), jnp.asarray(spring_stiffness, dtype=float)
        self.gauge_pressure, self.gas_exponent = (
            jnp.asarray(gauge_pressure, dtype=float),
            jnp.asarray(gas_exponent, dtype=float),
        )
        self.rest_volume = mesh_volume(self.rest_nodes, self.faces, jnp)
        if float(self.rest_volume) <= 0.0:
            raise InvalidInputError("SpringBalloon: the mesh encloses no positive volume; orient its faces outward.")
        self.planes, self.gravity = tuple(planes), gravity_vector(gravity)
        self.prescribed_nodes, self.prescribed = tuple(int(i) for i in prescribed_nodes), prescribed

    def lumped_mass(self):
        return jnp.repeat(self.node_masses, 3)

    def volume(self, x: Float[Array, " n"]) -> Float[Array, ""]:
        """Enclosed volume [m³] at positions x [m]."""
        return mesh_volume(x.reshape(-1, 3), self.faces, jnp)

    def internal_energies(self, x, t):
        nodes = x.reshape(-1, 3)
        length = jnp.linalg.norm(nodes[self.edges[:, 0]] - nodes[self.edges[:, 1]], axis=1)
        elastic = 0.5 * self.spring_stiffness * jnp.sum((length - self.rest_lengths) ** 2)
        gas = polytropic_gas_energy(self.volume(x), self.rest_volume, self.gauge_pressure, self.gas_exponent)
        gravity = -jnp.sum(self.node_masses * (nodes @ self.gravity))
        return {"elastic": elastic, "gas": gas, "gravity": gravity}

    def gas_state(self, x):
        v = self.volume(x)
        return polytropic_gauge_pressure(
            v, self.rest_volume, self.gauge_pressure, self.gas_exponent, ATMOSPHERIC_PRESSURE
        ), v

    def prescribed_dofs(self):
        return tuple(3 * i + k for i in self.prescribed_nodes for k in range(3))

    def prescribed_positions(self, t):
        if self.prescribed is None:
            return jnp.zeros((0,))
        return self.prescribed.positions(t).reshape(-1)

    def surface_faces(self):
        return np.asarray(self.faces)
