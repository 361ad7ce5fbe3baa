"""Implicit time steps posed as incremental potentials.

A step from state n (positions xₙ [m], velocities vₙ [m/s], accelerations aₙ [m/s²]) to time
tₙ₊₁ = tₙ + Δt [s] minimises

    Φ_inc(x) = (x − x̂)ᵀ M (x − x̂) / (2 κ Δt²) + Φ(x, tₙ₊₁) + dissipation potentials,

whose stationarity is M (x − x̂) / (κ Δt²) = F(x): the integrator's update of the acceleration.

* backward Euler: κ = 1, x̂ = xₙ + Δt vₙ; then v = (x − xₙ)/Δt. First order, dissipative.
* Newmark (β, γ): κ = β, x̂ = xₙ + Δt vₙ + Δt² (½ − β) aₙ; then a = (x − x̂)/(β Δt²),
  v = vₙ + Δt ((1 − γ) aₙ + γ a). β = ¼, γ = ½ (average acceleration) conserves energy on linear
  systems and integrates constant gravity exactly.
* TR-BDF2 (γ = 2 − √2): two such minimisations per step, a trapezoidal stage to tₙ + γΔt, then a
  BDF2 stage through tₙ, tₙ + γΔt and tₙ₊₁ (Bank et al. 1985; Hosea & Shampine 1996). Second
  order, L-stable (its spectral radius falls to 0 at high frequency: the shell's unresolved
  membrane waves are damped, not pumped as under Newmark), and its amplitude error per step at
  ωΔt = θ is O(θ⁴) (1 − 2e-8 at θ = 0.05): the reference scheme (docs/dynamics.md, *The
  reference integrator*).

A step is a sequence of stages (one for backward Euler and Newmark, two for TR-BDF2). Stage k is
an incremental potential described by a :class:`Stage`: its end time, x̂, the inertia scale κΔt²
[s²], and where its dissipation potentials measure the velocity from: each stage's end velocity is
v = (x − x_ref)/Δt_d + (terms fixed in the stage), so the dashpots, friction and Rayleigh damping
use (x − x_ref) over Δt_d [s] as backward Euler's use (x − xₙ) over Δt.
"""

from __future__ import annotations

import abc
import math

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float, Scalar

from ._system import DynamicState


class Stage(eqx.Module):
    """One minimisation of a step: Φ_inc(x) = (x − x̂)ᵀ M (x − x̂) / (2 ``inertia_scale``) + Φ(x, ``time``) + dissipation.

    ``time`` [s]: the stage's end; ``x_hat`` (n,) [m]; ``inertia_scale`` κΔt² [s²];
    ``damping_reference`` x_ref (n,) [m] and ``damping_dt`` Δt_d [s]: the dissipation potentials
    measure the stage's velocity as (x − x_ref)/Δt_d (backward Euler: xₙ and Δt).
    """

    time: Float[Array, ""]
    x_hat: Float[Array, " n"]
    inertia_scale: Float[Array, ""]
    damping_reference: Float[Array, " n"]
    damping_dt: Float[Array, ""]


class AbstractIntegrator(eqx.Module):
    """An implicit scheme: its predictor x̂, inertia factor κ and state update (one stage per step).

    A multi-stage scheme overrides ``num_stages``, ``stage`` and ``finish_stage`` instead; the
    one-stage methods then describe its first stage.
    """

    @abc.abstractmethod
    def predictor(self, state: DynamicState, dt: Scalar) -> Float[Array, " n"]:
        """x̂ [m] of the inertia term for a step of Δt [s]."""

    @abc.abstractmethod
    def inertia_factor(self) -> float:
        """κ [-] in the inertia term (x − x̂)ᵀ M (x − x̂) / (2 κ Δt²)."""

    @abc.abstractmethod
    def advance(self, state: DynamicState, x_new: Float[Array, " n"], dt: Scalar) -> DynamicState:
        """The state at tₙ + Δt [s] from the minimiser's positions [m]."""

    def num_stages(self) -> int:
        """Minimisations per step (static)."""
        return 1

    def stage(self, k: int, start: DynamicState, current: DynamicState, dt: Scalar) -> Stage:
        """Stage ``k`` of the step of Δt [s] from ``start``; ``current`` is the state after stage k − 1
        (``start`` for k = 0). One stage by default: the predictor and κ, velocities from xₙ over Δt."""
        dt = jnp.asarray(dt)
        return Stage(start.time + dt, self.predictor(start, dt), self.inertia_factor() * dt * dt, start.position, dt)

    def finish_stage(
        self, k: int, start: DynamicState, current: DynamicState, x_new: Float[Array, " n"], dt: Scalar
    ) -> DynamicState:
        """The state at the end of stage ``k`` from its minimiser's positions [m] (``advance`` by default)."""
        return self.advance(start, x_new, dt)


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


#: TR-BDF2's stage fraction γ = 2 − √2: both stages then have the same κΔt² (γ²/4 = d²), so one
#: Newton matrix serves both, and the scheme is L-stable.
TR_BDF2_GAMMA = 2.0 - math.sqrt(2.0)


class TRBDF2(AbstractIntegrator):
    """TR-BDF2 (γ = 2 − √2): a trapezoidal stage to tₙ + γΔt, then a BDF2 stage to tₙ₊₁.

    Second order, L-stable (spectral radius → 0 as ωΔt → ∞) and nearly conservative where Δt
    resolves the motion (amplitude loss per step O((ωΔt)⁴)); two minimisations per step.

    Stage 1 (trapezoid = average-acceleration Newmark over γΔt): x_γ = xₙ + γΔt vₙ + (γΔt)²(aₙ + a_γ)/4,
    v_γ = vₙ + γΔt (aₙ + a_γ)/2, M a_γ = F(x_γ). Stage 2 (BDF2 on tₙ, tₙ + γΔt, tₙ₊₁):
    x = c₁ x_γ − c₀ xₙ + dΔt v, v = c₁ v_γ − c₀ vₙ + dΔt a, M a = F(x), with
    c₁ = 1/(γ(2 − γ)), c₀ = (1 − γ)²/(γ(2 − γ)), d = (1 − γ)/(2 − γ) [-].
    """

    def _coefficients(self):
        g = TR_BDF2_GAMMA
        return g, 1.0 / (g * (2.0 - g)), (1.0 - g) ** 2 / (g * (2.0 - g)), (1.0 - g) / (2.0 - g)

    def predictor(self, state, dt):
        g = TR_BDF2_GAMMA
        return state.position + g * dt * state.velocity + 0.25 * (g * dt) ** 2 * state.acceleration

    def inertia_factor(self):
        return 0.25 * TR_BDF2_GAMMA**2

    def advance(self, state, x_new, dt):
        raise NotImplementedError("TRBDF2 has two stages: use stage() and finish_stage() (step() does).")

    def num_stages(self):
        return 2

    def stage(self, k, start, current, dt):
        dt = jnp.asarray(dt)
        g, c1, c0, dd = self._coefficients()
        if k == 0:
            h = g * dt
            return Stage(
                start.time + h,
                self.predictor(start, dt),
                0.25 * h * h,
                start.position + 0.5 * h * start.velocity,
                0.5 * h,
            )
        reference = c1 * current.position - c0 * start.position
        x_hat = reference + dd * dt * (c1 * current.velocity - c0 * start.velocity)
        return Stage(start.time + dt, x_hat, (dd * dt) ** 2, reference, dd * dt)

    def finish_stage(self, k, start, current, x_new, dt):
        dt = jnp.asarray(dt)
        g, c1, c0, dd = self._coefficients()
        if k == 0:
            h = g * dt
            a = (x_new - self.predictor(start, dt)) / (0.25 * h * h)
            v = start.velocity + 0.5 * h * (start.acceleration + a)
            return DynamicState(start.time + h, x_new, v, a)
        spec = self.stage(1, start, current, dt)
        a = (x_new - spec.x_hat) / spec.inertia_scale
        v = c1 * current.velocity - c0 * start.velocity + dd * dt * a
        return DynamicState(start.time + dt, x_new, v, a)


class Rayleigh(eqx.Module):
    """Rayleigh (material) damping C = α M + β K(xₙ), as the potential (Δx)ᵀ C Δx / (2 Δt).

    ``mass_coefficient`` α [1/s], ``stiffness_coefficient`` β [s]; K is the Hessian of the
    internal energy at the step's start, Δx = x − xₙ [m].
    """

    mass_coefficient: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)
    stiffness_coefficient: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)
