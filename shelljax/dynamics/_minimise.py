"""Minimisers of a step's incremental potential, and the step solution's implicit derivative.

A minimiser is the pluggable part of a step: ``minimise(potential, y0, memory)`` returns the
minimiser y* [m] of ``potential.value`` as the package's one :class:`shelljax.Solution` (its
``state``: what it keeps for the next step, the ``memory``), and ``linear_solve(potential, y, b)`` returns ∇²Φ_inc(y)⁻¹ b, which the implicit
derivative needs. ``DenseNewton`` does both densely (small systems); the 3D shell engine plugs in
its sparse Newton through the same methods.

:func:`simplified_newton_loop` is the simplified Newton of implicit integrators (Hairer & Wanner,
*Solving ODEs II*, IV.8): Newton's matrix is kept from an earlier iterate, possibly of an earlier
step, while the steps it gives contract by θ ≤ ``MAX_CONTRACTION`` a step and are taken in full;
otherwise it is assembled afresh. Converged when the step is below the tolerance and either the
matrix is this iterate's (Newton's own criterion) or θ, measured in this solve, is ≤
``MAX_CONTRACTION`` (the error left after the step, θ/(1 − θ) times it, is then below the
tolerance too).

``solve_step`` differentiates y* implicitly: ∇Φ_inc(y*, θ) = 0 gives, for a cotangent ȳ,
θ̄ = −(∂²Φ_inc/∂θ∂y)ᵀ λ with ∇²Φ_inc λ = ȳ; Newton's iterations are never unrolled. It is a
``custom_vjp``, not the engines' shared ``custom_jvp`` tangent (``shelljax._solution``): the step's
Solution carries the kept Newton matrix for the next step, whose cotangent a VJP may drop but to
which a JVP would have to give a tangent (docs/architecture.md).
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from .._solution import RESULTS, Solution
from ._potential import IncrementalPotential


def _solution(max_steps: int, y, converged, iterations, history, assemblies, memory=None) -> Solution:
    """The step's :class:`shelljax.Solution`: ``value`` y* [m]; ``history`` ‖∇Φ_inc‖∞ [N] per
    iteration (NaN after the last); ``stats["assemblies"]``: Newton matrices assembled; ``state``:
    the memory kept for the next step. A loop that stopped early unconverged did so on a failed
    line search; one that ran its ``max_steps``, on the iteration bound."""
    result = RESULTS.where(
        converged,
        RESULTS.successful,
        RESULTS.where(iterations < max_steps, RESULTS.line_search_failed, RESULTS.max_steps_reached),
    )
    return Solution(y, result, iterations, history, {"assemblies": assemblies}, memory)


class KeptMatrix(eqx.Module):
    """Newton's matrix kept between iterates and steps: ``values`` (the minimiser's pytree) and
    ``stale`` (assemble it afresh before its next use)."""

    values: object
    stale: Bool[Array, ""]


#: Largest contraction θ of a kept matrix's steps: above it (or when a step is cut by the line
#: search) the matrix is assembled afresh. A fresh matrix costs several kept-matrix iterations.
MAX_CONTRACTION = 0.5


class AbstractMinimiser(eqx.Module):
    """What a step needs from a solver: a minimisation and a linear solve with its Hessian."""

    @abc.abstractmethod
    def minimise(self, potential: IncrementalPotential, y0: Float[Array, " m"], memory=None) -> Solution:
        """Minimise ``potential.value`` from the feasible start y0 [m], keeping it feasible;
        ``memory``: the previous step's ``Solution.state`` (None: none)."""

    def initial_memory(self, potential: IncrementalPotential, y0: Float[Array, " m"]):
        """The ``memory`` before a roll-out's first step (same pytree structure as after a step)."""
        return None

    @abc.abstractmethod
    def linear_solve(
        self, potential: IncrementalPotential, y: Float[Array, " m"], rhs: Float[Array, " m"]
    ) -> Float[Array, " m"]:
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

    def minimise(self, potential, y0, memory=None):
        return newton_loop(self, potential, y0, lambda y, g: self._direction(potential, y, g))

    def linear_solve(self, potential, y, rhs):
        return jnp.linalg.solve(potential.dense_hessian(y), rhs)


def _line_search(minimiser, potential: IncrementalPotential, y, f, g, p):
    """Backtracking from the full step p [m]: (α, Φ_inc there, found) with the new point feasible
    and Armijo's decrease (round-off in Φ_inc allowed)."""
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


def _move(potential, y, f, alpha, f_new, found, p):
    """The iterate after a line search (unchanged if it found nothing), Φ_inc and ∇Φ_inc there."""
    y_new = jnp.where(found, y + alpha * p, y)
    return y_new, jnp.where(found, f_new, f), potential.gradient(y_new)


def newton_loop(minimiser, potential: IncrementalPotential, y0: Float[Array, " m"], direction) -> Solution:
    """Newton's method with a feasibility-keeping backtracking line search (traceable).

    ``direction(y, g)`` gives the step [m] at y [m] with gradient g [N]; reads ``step_tolerance``
    [m], ``max_steps`` and ``max_halvings`` from the minimiser.
    """
    history0 = jnp.full((minimiser.max_steps,), jnp.nan, dtype=y0.dtype)

    def cond(c):
        return (c["k"] < minimiser.max_steps) & ~c["done"]

    def body(c):
        y, f, g, k = c["y"], c["f"], c["g"], c["k"]
        history = c["history"].at[k].set(jnp.max(jnp.abs(g)))
        p = direction(y, g)
        small = jnp.max(jnp.abs(p)) <= minimiser.step_tolerance
        alpha, f_new, found = _line_search(minimiser, potential, y, f, g, p)
        y_new, f_new, g_new = _move(potential, y, f, alpha, f_new, found, p)
        # A step below tolerance is convergence even when round-off in Φ_inc defeats the line search.
        converged = small | jnp.all(g_new == 0.0)
        return dict(y=y_new, f=f_new, g=g_new, k=k + 1, done=converged | ~found, converged=converged, history=history)

    init = dict(
        y=y0,
        f=potential.value(y0),
        g=potential.gradient(y0),
        k=jnp.asarray(0),
        done=jnp.asarray(False),
        converged=jnp.asarray(False),
        history=history0,
    )
    out = jax.lax.while_loop(cond, body, init)
    return _solution(minimiser.max_steps, out["y"], out["converged"], out["k"], out["history"], out["k"])


def simplified_newton_loop(
    minimiser, potential: IncrementalPotential, y0: Float[Array, " m"], assemble, solve, memory: KeptMatrix
) -> Solution:
    """Simplified Newton (module doc) with the line search of :func:`newton_loop` (traceable).

    ``assemble(y)`` gives Newton's matrix values at y [m]; ``solve(values, g)`` the step [m] for
    the gradient g [N]; ``memory`` the matrix kept so far. The result's ``memory`` is the matrix
    kept for the next step.
    """
    history0 = jnp.full((minimiser.max_steps,), jnp.nan, dtype=y0.dtype)

    def cond(c):
        return (c["k"] < minimiser.max_steps) & ~c["done"]

    def body(c):
        y, f, g, k, kept, previous = c["y"], c["f"], c["g"], c["k"], c["kept"], c["previous"]
        history = c["history"].at[k].set(jnp.max(jnp.abs(g)))
        fresh = kept.stale
        values = jax.lax.cond(fresh, lambda: assemble(y), lambda: kept.values)
        p = solve(values, g)
        size = jnp.max(jnp.abs(p))
        # θ is measured on two successive steps with the same kept matrix in this solve; steps at
        # the round-off floor (the previous one a tenth of the tolerance) stagnate, whatever θ.
        measured = previous > 0.0
        theta = jnp.where(measured, size / jnp.where(measured, previous, 1.0), 0.0)
        settled = measured & ((theta <= MAX_CONTRACTION) | (previous <= 0.1 * minimiser.step_tolerance))
        alpha, f_new, found = _line_search(minimiser, potential, y, f, g, p)
        y_new, f_new, g_new = _move(potential, y, f, alpha, f_new, found, p)
        converged = ((size <= minimiser.step_tolerance) & (fresh | settled)) | jnp.all(g_new == 0.0)
        # A kept matrix whose step had to be cut, or that contracts slowly, is assembled afresh.
        renew = (measured & ~settled & (theta > MAX_CONTRACTION)) | (alpha < 1.0) | ~found
        return dict(
            y=y_new,
            f=f_new,
            g=g_new,
            k=k + 1,
            done=converged | (~found & fresh),
            converged=converged,
            history=history,
            kept=KeptMatrix(values, renew),
            previous=jnp.where(renew, 0.0, size),
            assemblies=c["assemblies"] + fresh.astype(c["assemblies"].dtype),
        )

    init = dict(
        y=y0,
        f=potential.value(y0),
        g=potential.gradient(y0),
        k=jnp.asarray(0),
        done=jnp.asarray(False),
        converged=jnp.asarray(False),
        history=history0,
        kept=memory,
        previous=jnp.asarray(0.0, dtype=y0.dtype),
        assemblies=jnp.asarray(0),
    )
    out = jax.lax.while_loop(cond, body, init)
    return _solution(
        minimiser.max_steps, out["y"], out["converged"], out["k"], out["history"], out["assemblies"], out["kept"]
    )


@eqx.filter_custom_vjp
def solve_step(
    potential: IncrementalPotential, minimiser: AbstractMinimiser, y0: Float[Array, " m"], memory=None
) -> Solution:
    """Minimise a step's potential; y* is differentiable in ``potential`` (implicitly, see module doc)."""
    return minimiser.minimise(potential, y0, memory)


@solve_step.def_fwd
def _solve_step_fwd(perturbed, potential, minimiser, y0, memory=None):
    result = minimiser.minimise(potential, y0, memory)
    return result, result.value


@solve_step.def_bwd
def _solve_step_bwd(y_star, grad_obj, perturbed, potential, minimiser, y0, memory=None):
    y_bar = grad_obj.value if grad_obj.value is not None else jnp.zeros_like(y_star)
    lam = minimiser.linear_solve(potential, y_star, y_bar)
    _, vjp = eqx.filter_vjp(lambda pot: jax.grad(pot.value)(y_star), potential)
    (grad_potential,) = vjp(-lam)
    return grad_potential
