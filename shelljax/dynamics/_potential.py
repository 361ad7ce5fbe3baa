"""The incremental potential of one time step: what a minimiser receives.

Φ_inc(y) over the free degrees of freedom y (the positions x [m] less the prescribed ones) is

    ½ Σᵢ wᵢ (xᵢ − x̂ᵢ)²                               inertia, wᵢ = Mᵢ / (κ Δt²) [N/m]
  + Φ(x, tₙ₊₁)                                         internal (elastic, gas, gravity) + contact
  + Σ_planes (c / 2Δt) Σⱼ ωⱼ ((pⱼ − pⱼⁿ)·n)²          normal contact damping, ωⱼ lagged at xₙ
  + Σ_planes Σⱼ μ λⱼⁿ f₀(‖(I − n nᵀ)(pⱼ − pⱼⁿ)‖)      lagged smoothed Coulomb friction
  + (x − xₙ)ᵀ (α M + β K(xₙ)) (x − xₙ) / (2Δt)         optional Rayleigh damping,

with pⱼ the contact points [m]. The lagged quantities (the contact points pⁿ, normal forces λⁿ [N]
and damping weights ωⁿ [-] at the step's start) are arrays of this module, so gradients with
respect to the previous state flow through them.

For a scheme whose stage velocity is not (x − xₙ)/Δt (TR-BDF2's stages), ``x_prev`` and ``dt``
are the stage's damping reference x_ref and Δt_d (``_integrators.Stage``): the dashpots, friction
and Rayleigh terms above then read xₙ → x_ref, pⁿ → p(x_ref), Δt → Δt_d, and act on the stage's
own velocity; λⁿ and ωⁿ stay lagged at the last computed state (feasible for barriers).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, Scalar

from ..physics import friction_energy
from ._integrators import AbstractIntegrator, Rayleigh, Stage
from ._system import AbstractDynamicSystem, DynamicState


class IncrementalPotential(eqx.Module):
    """Φ_inc of one step (see the module docstring); ``value`` [J] of the free positions y [m]."""

    system: AbstractDynamicSystem
    time: Float[Array, ""]
    dt: Float[Array, ""]
    x_hat: Float[Array, " n"]
    inertia_weight: Float[Array, " n"]
    x_prev: Float[Array, " n"]
    points_prev: Float[Array, "k 3"]
    normal_force_prev: Float[Array, "P k"]
    damping_weight_prev: Float[Array, "P k"]
    body_damping_prev: Float[Array, " P"]
    rayleigh: Rayleigh | None
    free_dofs: Int[Array, " m"]
    prescribed_dofs: Int[Array, " p"]
    prescribed_values: Float[Array, " p"]

    def full(self, y: Float[Array, " m"]) -> Float[Array, " n"]:
        """All positions x (n,) [m] from the free ones y (m,) [m] and the prescribed values."""
        x = jnp.zeros_like(self.x_prev).at[self.free_dofs].set(y)
        return x.at[self.prescribed_dofs].set(self.prescribed_values)

    def free(self, x: Float[Array, " n"]) -> Float[Array, " m"]:
        """The free positions y [m] of a full vector x [m]."""
        return x[self.free_dofs]

    def point_energies(self, index: int, points: Float[Array, "k 3"]) -> Float[Array, " k"]:
        """Contact, damping and friction energy [J] of each contact point [m] against plane ``index``.

        Each point's energy depends on that point alone, so these terms' Hessian is block diagonal.
        """
        plane = self.system.planes[index]
        step = points - self.points_prev
        normal_step = step @ plane.normal
        slip = step - normal_step[:, None] * plane.normal
        contact = plane.law.energy(plane.gap(points))
        damping = plane.damping / (2.0 * self.dt) * self.damping_weight_prev[index] * normal_step**2
        friction = friction_energy(slip, self.normal_force_prev[index], plane.friction, plane.slip_tolerance)
        return contact + damping + friction

    def plane_energy(self, index: int, points: Float[Array, "k 3"]) -> Scalar:
        """Contact, damping and friction energy [J] of plane ``index`` at contact points [m]."""
        return jnp.sum(self.point_energies(index, points))

    def point_hessian_blocks(self, x: Float[Array, " n"]) -> Float[Array, "k 3 3"]:
        """The 3×3 Hessian blocks [N/m] of all planes' point terms at each contact point, at x [m].

        A sparse minimiser assembles ∇²Φ_inc = diag(inertia_weight) + ∇²(internal energy)
        [+ Rayleigh] + Jᵀ blockdiag(these) J, J the Jacobian of the contact points (a selection
        of nodes for a shell).
        """
        points = self.system.contact_points(x)

        def total(p):
            return sum((self.plane_energy(i, p) for i in range(len(self.system.planes))), jnp.asarray(0.0))

        # Block diagonal: the product with one axis direction at every point gives that column of
        # every block at once (three products, linear in k, where a per-point Hessian of the sum is k²).
        directions = jnp.broadcast_to(jnp.eye(3)[:, None, :], (3,) + points.shape)
        columns = jax.vmap(lambda v: jax.jvp(jax.grad(total), (points,), (v,))[1])(directions)
        return jnp.moveaxis(columns, 0, -1)

    def value_full(self, x: Float[Array, " n"]) -> Scalar:
        """Φ_inc [J] at all positions x [m]."""
        inertia = 0.5 * jnp.sum(self.inertia_weight * (x - self.x_hat) ** 2)
        points = self.system.contact_points(x)
        planes = sum((self.plane_energy(i, points) for i in range(len(self.system.planes))), jnp.asarray(0.0))
        total = inertia + self.system.internal_energy(x, self.time) + planes + self.body_damping(x)
        if self.rayleigh is not None:
            d = x - self.x_prev
            t_prev = self.time - self.dt
            kd = jax.jvp(jax.grad(lambda z: self.system.internal_energy(z, t_prev)), (self.x_prev,), (d,))[1]
            mass = self.system.lumped_mass()
            quad = self.rayleigh.mass_coefficient * jnp.sum(mass * d * d) + self.rayleigh.stiffness_coefficient * (
                d @ kd
            )
            total = total + quad / (2.0 * self.dt)
        return total

    def body_damping(self, x: Float[Array, " n"]) -> Scalar:
        """Σ_planes (c / 2Δt) Wⁿ ((x_com − x_comⁿ)·n)² [J]: the dashpot on the body's approach (see the system's ``body_damping_weights``)."""
        step = self.system.centre_of_mass(x) - self.system.centre_of_mass(self.x_prev)
        total = jnp.asarray(0.0)
        for i, plane in enumerate(self.system.planes):
            total = total + plane.damping / (2.0 * self.dt) * self.body_damping_prev[i] * (step @ plane.normal) ** 2
        return total

    def value(self, y: Float[Array, " m"]) -> Scalar:
        """Φ_inc [J] at the free positions y [m]."""
        return self.value_full(self.full(y))

    def gradient(self, y: Float[Array, " m"]) -> Float[Array, " m"]:
        """∇Φ_inc [N] at y [m]."""
        return jax.grad(self.value)(y)

    def dense_hessian(self, y: Float[Array, " m"]) -> Float[Array, "m m"]:
        """∇²Φ_inc [N/m] at y [m], dense (for small systems only)."""
        return jax.hessian(self.value)(y)

    def is_feasible(self, y: Float[Array, " m"]) -> Bool[Array, ""]:
        """Whether y [m] keeps every barrier gap admissible."""
        points = self.system.contact_points(self.full(y))
        ok = jnp.asarray(True)
        for plane in self.system.planes:
            ok = ok & plane.law.is_feasible(plane.gap(points))
        return ok

    def plane_forces(self, x: Float[Array, " n"]) -> Float[Array, "P 3"]:
        """Force [N] each plane exerts on the body at x [m] (contact, damping and friction)."""
        points = self.system.contact_points(x)
        rows = [
            -jnp.sum(jax.grad(lambda p, i=i: self.plane_energy(i, p))(points), axis=0)
            for i in range(len(self.system.planes))
        ]
        return jnp.stack(rows) if rows else jnp.zeros((0, 3))


def lagged_contact(system: AbstractDynamicSystem, x: Float[Array, " n"]):
    """Contact points (k, 3) [m], normal forces (P, k) [N] and damping weights (P, k) [-] at x [m]."""
    points = system.contact_points(x)
    k = points.shape[0]
    forces = [jnp.maximum(p.law.force(p.gap(points)), 0.0) for p in system.planes]
    weights = [system.damping_weights(p.law.damping_weight(p.gap(points))) for p in system.planes]
    stack = lambda rows: jnp.stack(rows) if rows else jnp.zeros((0, k))  # noqa: E731
    return points, stack(forces), stack(weights)


def free_dofs(system: AbstractDynamicSystem, n: int) -> tuple[Int[Array, " m"], Int[Array, " p"]]:
    """Indices of the free and the prescribed degrees of freedom of a system with n of them."""
    prescribed = [int(i) for i in system.prescribed_dofs()]
    taken = set(prescribed)
    free = [i for i in range(n) if i not in taken]
    return jnp.asarray(free, dtype=int), jnp.asarray(prescribed, dtype=int)


def incremental_potential(
    system: AbstractDynamicSystem,
    integrator: AbstractIntegrator,
    state: DynamicState,
    dt: Scalar,
    rayleigh: Rayleigh | None = None,
) -> IncrementalPotential:
    """The incremental potential of the step of Δt [s] from ``state`` under ``integrator`` (its
    first stage, for a multi-stage scheme)."""
    return stage_potential(system, integrator.stage(0, state, state, dt), state.position, rayleigh)


def stage_potential(
    system: AbstractDynamicSystem, stage: Stage, lagged_position: Float[Array, " n"], rayleigh: Rayleigh | None = None
) -> IncrementalPotential:
    """The incremental potential of one integrator ``stage``, its contact data lagged at
    ``lagged_position`` [m] (the last computed state's positions: feasible for barriers).

    ``dt`` and ``x_prev`` of the result are the stage's damping Δt_d [s] and reference x_ref [m]:
    the dissipation potentials measure velocities as (x − x_ref)/Δt_d (one step of backward Euler:
    Δt and xₙ), their anchors pⁿ are the contact points of x_ref.
    """
    dt = jnp.asarray(stage.damping_dt)
    x = lagged_position
    free, prescribed = free_dofs(system, x.shape[0])
    points, forces, weights = lagged_contact(system, x)
    body = (
        jnp.stack([system.body_damping_weights(p.law.damping_weight(p.gap(points))) for p in system.planes])
        if system.planes
        else jnp.zeros((0,))
    )
    mass = system.lumped_mass()
    return IncrementalPotential(
        system=system,
        time=jnp.asarray(stage.time),
        dt=dt,
        x_hat=stage.x_hat,
        inertia_weight=mass / stage.inertia_scale,
        x_prev=stage.damping_reference,
        points_prev=system.contact_points(stage.damping_reference),
        normal_force_prev=forces,
        damping_weight_prev=weights,
        body_damping_prev=body,
        rayleigh=rayleigh,
        free_dofs=free,
        prescribed_dofs=prescribed,
        prescribed_values=jnp.asarray(system.prescribed_positions(stage.time), dtype=x.dtype).reshape(-1),
    )
