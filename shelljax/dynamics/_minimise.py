"""Minimisers of a step's incremental potential, and the step solution's implicit derivative.

A minimiser is the pluggable part of a step: ``minimise(potential, y0)`` returns the minimiser y*
[m] of ``potential.value`` with its convergence record, and ``linear_solve(potential, y, b)``
returns ∇²Φ_inc(y)⁻¹ b, which the implicit derivative needs. ``DenseNewton`` does both densely
(small systems); the 3D shell engine plugs in its sparse Newton through the same two methods.

``solve_step`` differentiates y* implicitly: ∇Φ_inc(y*, θ) = 0 gives, for a cotangent ȳ,
θ̄ = −(∂²Φ_inc/∂θ∂y)ᵀ λ with ∇²Φ_inc λ = ȳ; Newton's iterations are never unrolled.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ._potential import IncrementalPotential


class MinimiserResult(eqx.Module):
    """y* [m]; ``converged``; Newton ``iterations``; ``history``: ‖∇Φ_inc‖∞ [N] per iteration (NaN after the last)."""

    y: Float[Array, " m"]
    converged: Bool[Array, ""]
    iterations: Int[Array, ""]
    history: Float[Array, " K"]


class AbstractMinimiser(eqx.Module):
    """What a step needs from a solver: a minimisation and a linear solve with its Hessian."""

    @abc.abstractmethod
    def minimise(self, potential: IncrementalPotential, y0: Float[Array, " m"]) -> MinimiserResult:
        """Minimise ``potential.value`` from the feasible start y0 [m], keeping it feasible."""

    @abc.abstractmethod
    def linear_solve(self, potential: IncrementalPotential, y: Float[Array, " m"], rhs: Float[Array, " m"]) -> Float[Array, " m"]:
        """∇²Φ_inc(y)⁻¹ rhs, for rhs in [m] per [N] units of the cotangent."""


class DenseNewton(AbstractMinimiser):
    """Newton's method with a dense Hessian and a feasibility-keeping backtracking line search.

    Converged when the Newton step's largest component is below ``step_tolerance`` [m] (the step
    is then taken). ``max_steps`` bounds the Newton iterations, ``max_halvings`` the line search.
    """

    step_tolerance: float = eqx.field(static=True, default=1e-11)
    max_steps: int = eqx.field(static=True, default=40)
    max_halvings: int = eqx.field(static=True, default=40)

    def _direction(self, potential, y, g):
        h = potential.dense_hessian(y)
        p = jnp.linalg.solve(h, -g)
        # An indefinite or singular Hessian can give an ascent or NaN step: fall back to scaled descent.
        scale = jnp.maximum(jnp.max(jnp.abs(jnp.diag(h))), 1e-300)
        ok = jnp.all(jnp.isfinite(p)) & (g @ p < 0.0)
        return jnp.where(ok, p, -g / scale)

    def minimise(self, potential, y0):
        return newton_loop(self, potential, y0, lambda y, g: self._direction(potential, y, g))

    def linear_solve(self, potential, y, rhs):
        return jnp.linalg.solve(potential.dense_hessian(y), rhs)


def newton_loop(minimiser, potential: IncrementalPotential, y0: Float[Array, " m"], direction) -> MinimiserResult:
    """Newton's method with a feasibility-keeping backtracking line search (traceable).

    ``direction(y, g)`` gives the step [m] at y [m] with gradient g [N]; reads ``step_tolerance``
    [m], ``max_steps`` and ``max_halvings`` from the minimiser.
    """
    f0 = potential.value(y0)
    g0 = potential.gradient(y0)
    history0 = jnp.full((minimiser.max_steps,), jnp.nan, dtype=y0.dtype)

    def line_search(y, f, g, p):
        slope = g @ p
        # Round-off in Φ_inc (its terms are far larger than their change near the minimum) is allowed.
        allowance = 64.0 * jnp.finfo(y.dtype).eps * jnp.abs(f)

        def bad(carry):
            alpha, f_new, _ = carry
            y_new = y + alpha * p
            return ~(potential.is_feasible(y_new) & jnp.isfinite(f_new) & (f_new <= f + 1e-4 * alpha * slope + allowance))

        def cond(carry):
            return (carry[2] < minimiser.max_halvings) & bad(carry)

        def body(carry):
            alpha, _, k = carry
            alpha = 0.5 * alpha
            return alpha, potential.value(y + alpha * p), k + 1

        alpha, f_new, k = jax.lax.while_loop(cond, body, (jnp.asarray(1.0), potential.value(y + p), jnp.asarray(0)))
        return alpha, f_new, ~bad((alpha, f_new, k))

    def cond(c):
        return (c["k"] < minimiser.max_steps) & ~c["done"]

    def body(c):
        y, f, g, k = c["y"], c["f"], c["g"], c["k"]
        history = c["history"].at[k].set(jnp.max(jnp.abs(g)))
        p = direction(y, g)
        small = jnp.max(jnp.abs(p)) <= minimiser.step_tolerance
        alpha, f_new, found = line_search(y, f, g, p)
        y_new = jnp.where(found, y + alpha * p, y)
        f_new = jnp.where(found, f_new, f)
        g_new = potential.gradient(y_new)
        # A step below tolerance is convergence even when round-off in Φ_inc defeats the line search.
        converged = small | jnp.all(g_new == 0.0)
        done = converged | ~found
        return dict(y=y_new, f=f_new, g=g_new, k=k + 1, done=done, converged=converged, history=history)

    init = dict(y=y0, f=f0, g=g0, k=jnp.asarray(0), done=jnp.asarray(False), converged=jnp.asarray(False), history=history0)
    out = jax.lax.while_loop(cond, body, init)
    return MinimiserResult(out["y"], out["converged"], out["k"], out["history"])


@eqx.filter_custom_vjp
def solve_step(potential: IncrementalPotential, minimiser: AbstractMinimiser, y0: Float[Array, " m"]) -> MinimiserResult:
    """Minimise a step's potential; y* is differentiable in ``potential`` (implicitly, see module doc)."""
    return minimiser.minimise(potential, y0)


@solve_step.def_fwd
def _solve_step_fwd(perturbed, potential, minimiser, y0):
    result = minimiser.minimise(potential, y0)
    return result, result.y


@solve_step.def_bwd
def _solve_step_bwd(y_star, grad_obj, perturbed, potential, minimiser, y0):
    y_bar = grad_obj.y if grad_obj.y is not None else jnp.zeros_like(y_star)
    lam = minimiser.linear_solve(potential, y_star, y_bar)
    _, vjp = eqx.filter_vjp(lambda pot: jax.grad(pot.value)(y_star), potential)
    (grad_potential,) = vjp(-lam)
    return grad_potential
