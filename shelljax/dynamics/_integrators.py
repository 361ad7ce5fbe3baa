"""Implicit time steps posed as incremental potentials.

A step from state n (positions xₙ [m], velocities vₙ [m/s], accelerations aₙ [m/s²]) to time
tₙ₊₁ = tₙ + Δt [s] minimises

    Φ_inc(x) = (x − x̂)ᵀ M (x − x̂) / (2 κ Δt²) + Φ(x, tₙ₊₁) + dissipation potentials,

whose stationarity is M (x − x̂) / (κ Δt²) = F(x): the integrator's update of the acceleration.

* backward Euler: κ = 1, x̂ = xₙ + Δt vₙ; then v = (x − xₙ)/Δt. First order, dissipative.
* Newmark (β, γ): κ = β, x̂ = xₙ + Δt vₙ + Δt² (½ − β) aₙ; then a = (x − x̂)/(β Δt²),
  v = vₙ + Δt ((1 − γ) aₙ + γ a). β = ¼, γ = ½ (average acceleration) conserves energy on linear
  systems and integrates constant gravity exactly.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float, Scalar

from ._system import DynamicState


class AbstractIntegrator(eqx.Module):
    """An implicit one-step scheme: its predictor x̂, inertia factor κ and state update."""

    @abc.abstractmethod
    def predictor(self, state: DynamicState, dt: Scalar) -> Float[Array, " n"]:
        """x̂ [m] of the inertia term for a step of Δt [s]."""

    @abc.abstractmethod
    def inertia_factor(self) -> float:
        """κ [-] in the inertia term (x − x̂)ᵀ M (x − x̂) / (2 κ Δt²)."""

    @abc.abstractmethod
    def advance(self, state: DynamicState, x_new: Float[Array, " n"], dt: Scalar) -> DynamicState:
        """The state at tₙ + Δt [s] from the minimiser's positions [m]."""


class BackwardEuler(AbstractIntegrator):
    """Backward (implicit) Euler: first order, unconditionally stable, numerically dissipative."""

    def predictor(self, state, dt):
        return state.position + dt * state.velocity

    def inertia_factor(self):
        return 1.0

    def advance(self, state, x_new, dt):
        v = (x_new - state.position) / dt
        return DynamicState(state.time + dt, x_new, v, (v - state.velocity) / dt)


class Newmark(AbstractIntegrator):
    """Newmark-β with ``beta`` β [-] and ``gamma`` γ [-]; the defaults are the average acceleration rule."""

    beta: float = eqx.field(static=True, default=0.25)
    gamma: float = eqx.field(static=True, default=0.5)

    def predictor(self, state, dt):
        return state.position + dt * state.velocity + dt * dt * (0.5 - self.beta) * state.acceleration

    def inertia_factor(self):
        return self.beta

    def advance(self, state, x_new, dt):
        a = (x_new - self.predictor(state, dt)) / (self.beta * dt * dt)
        v = state.velocity + dt * ((1.0 - self.gamma) * state.acceleration + self.gamma * a)
        return DynamicState(state.time + dt, x_new, v, a)


class Rayleigh(eqx.Module):
    """Rayleigh (material) damping C = α M + β K(xₙ), as the potential (Δx)ᵀ C Δx / (2 Δt).

    ``mass_coefficient`` α [1/s], ``stiffness_coefficient`` β [s]; K is the Hessian of the
    internal energy at the step's start, Δx = x − xₙ [m].
    """

    mass_coefficient: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)
    stiffness_coefficient: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)
