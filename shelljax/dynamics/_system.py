"""What the time integrator needs from a model: ``AbstractDynamicSystem``, and its state.

Degrees of freedom are the flat positions x (3N,) [m] of N nodes, ordered node by node (x, y, z),
as in the 3D shell engine's vertex array. A system gives

* ``lumped_mass()``: the mass per degree of freedom (3N,) [kg];
* ``internal_energies(x, t)``: its potential energies [J] by kind (``"elastic"``, ``"gas"``,
  ``"gravity"``), contact excluded;
* ``planes``: the rigid planes its ``contact_points(x)`` (k, 3) [m] touch (all nodes by default);
* optionally, prescribed degrees of freedom: ``prescribed_dofs()`` (static indices) and their
  positions ``prescribed_positions(t)`` [m] at time t [s];
* optionally, ``gas_state(x)``: the gauge pressure [Pa] and enclosed volume [m³];
* optionally, ``surface_faces()``: triangles (F, 3) of the nodes, for mesh output.

The potential the integrator minimises over is Φ(x, t) = Σ internal energies + Σ over planes of
the contact energies of the contact points (``potential``).
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int, Scalar

from ..physics import Plane

ENERGY_KINDS = ("elastic", "gas", "gravity")


class DynamicState(eqx.Module):
    """The state at time ``time`` [s]: positions x (n,) [m], velocities (n,) [m/s], accelerations (n,) [m/s²]."""

    time: Float[Array, ""] = eqx.field(converter=jnp.asarray)
    position: Float[Array, " n"] = eqx.field(converter=jnp.asarray)
    velocity: Float[Array, " n"] = eqx.field(converter=jnp.asarray)
    acceleration: Float[Array, " n"] = eqx.field(converter=jnp.asarray)


class AbstractDynamicSystem(eqx.Module):
    """A model the integrator can advance; see the module docstring for the contract."""

    planes: eqx.AbstractVar[tuple[Plane, ...]]
    gravity: eqx.AbstractVar[Float[Array, "3"]]

    @abc.abstractmethod
    def lumped_mass(self) -> Float[Array, " n"]:
        """Mass per degree of freedom (n,) [kg], each node's mass repeated for x, y, z."""

    @abc.abstractmethod
    def internal_energies(self, x: Float[Array, " n"], t: Scalar) -> dict[str, Scalar]:
        """Potential energies [J] by kind (keys among ``ENERGY_KINDS``) at positions x [m], time t [s]."""

    def contact_points(self, x: Float[Array, " n"]) -> Float[Array, "k 3"]:
        """The points [m] that touch the planes: every node by default."""
        return x.reshape(-1, 3)

    def prescribed_dofs(self) -> tuple[int, ...]:
        """Indices of the degrees of freedom whose positions follow a schedule (none by default)."""
        return ()

    def prescribed_positions(self, t: Scalar) -> Float[Array, " p"]:
        """Positions [m] of the prescribed degrees of freedom at time t [s]."""
        return jnp.zeros((0,))

    def gas_state(self, x: Float[Array, " n"]) -> tuple[Scalar, Scalar]:
        """(gauge pressure [Pa], enclosed volume [m³]); NaN for a system without gas."""
        return jnp.asarray(jnp.nan), jnp.asarray(jnp.nan)

    def damping_weights(self, weights: Float[Array, " k"]) -> Float[Array, " k"]:
        """The contact points' damping weights [-] against one plane from its law's weights (k,)
        [-]; the identity by default (each touching point is a dashpot c)."""
        return weights

    def body_damping_weights(self, weights: Float[Array, " k"]) -> Scalar:
        """Weight W [-] of the dashpot c on the centre of mass's approach to one plane, from the
        law's weights (k,) of the contact points; 0 by default (the dashpots sit on the points)."""
        return jnp.asarray(0.0)

    def surface_faces(self) -> Int[np.ndarray, "f 3"] | None:
        """Triangles of the nodes for mesh output, or None."""
        return None

    def node_mass(self) -> Float[Array, " N"]:
        """Mass per node (N,) [kg]."""
        return self.lumped_mass().reshape(-1, 3)[:, 0]

    def centre_of_mass(self, x: Float[Array, " n"]) -> Float[Array, "3"]:
        """Centre of mass [m] of the nodes at positions x [m]."""
        m = self.node_mass()
        return jnp.sum(m[:, None] * x.reshape(-1, 3), axis=0) / jnp.sum(m)

    def internal_energy(self, x: Float[Array, " n"], t: Scalar) -> Scalar:
        """Sum of the internal energies [J]."""
        return sum(self.internal_energies(x, t).values(), jnp.asarray(0.0))

    def contact_energy(self, x: Float[Array, " n"]) -> Scalar:
        """Sum over planes of the contact energies [J] of the contact points."""
        points = self.contact_points(x)
        return sum((jnp.sum(p.law.energy(p.gap(points))) for p in self.planes), jnp.asarray(0.0))

    def potential(self, x: Float[Array, " n"], t: Scalar) -> Scalar:
        """Φ(x, t) [J]: internal plus contact energy."""
        return self.internal_energy(x, t) + self.contact_energy(x)


def gravity_vector(gravity) -> Float[Array, "3"]:
    """Gravity as a vector [m/s²]: a scalar g means (0, 0, −g)."""
    g = jnp.asarray(gravity, dtype=float)
    return jnp.array([0.0, 0.0, -1.0]) * g if g.ndim == 0 else g


class PrescribedRotation(eqx.Module):
    """Rigid rotation of some nodes about an axis on a schedule of angles.

    Nodes at rest positions (N_p, 3) [m] turn about the axis through ``axis_point`` (3,) [m] along
    ``axis_direction`` (3,) by the angle θ(t) [rad], interpolated piecewise-linearly (with C¹
    smoothstep blending within each segment, so velocities start and stop smoothly) between
    ``times`` (K,) [s] and ``angles`` (K,) [rad]; constant before the first and after the last.
    """

    rest_positions: Float[Array, "m 3"] = eqx.field(converter=jnp.asarray)
    axis_point: Float[Array, "3"] = eqx.field(converter=jnp.asarray)
    axis_direction: Float[Array, "3"] = eqx.field(converter=jnp.asarray)
    times: Float[Array, " K"] = eqx.field(converter=jnp.asarray)
    angles: Float[Array, " K"] = eqx.field(converter=jnp.asarray)

    def angle(self, t: Scalar) -> Scalar:
        """θ(t) [rad]."""
        k = self.times.shape[0]
        i = jnp.clip(jnp.searchsorted(self.times, t, side="right") - 1, 0, k - 2)
        span = self.times[i + 1] - self.times[i]
        s = jnp.clip((t - self.times[i]) / span, 0.0, 1.0)
        s = s * s * (3.0 - 2.0 * s)
        return self.angles[i] + s * (self.angles[i + 1] - self.angles[i])

    def positions(self, t: Scalar) -> Float[Array, "m 3"]:
        """Node positions (N_p, 3) [m] at time t [s] (Rodrigues' rotation)."""
        k = self.axis_direction / jnp.linalg.norm(self.axis_direction)
        r = self.rest_positions - self.axis_point
        th = self.angle(t)
        c, s = jnp.cos(th), jnp.sin(th)
        rotated = r * c + jnp.cross(k, r) * s + jnp.outer(r @ k, k) * (1.0 - c)
        return self.axis_point + rotated
