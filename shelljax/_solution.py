"""The result every Newton solver of shelljax returns, and the implicit tangent they share.

Three Newtons minimise energies here: the axisymmetric engine's (dense banded, pure JAX, vmapped
over curves), the 3D engine's (sparse, factorised on the host) and the dynamics' step minimisers
(traceable, inside ``lax.scan``). Their linear algebra differs in kind and stays theirs; what a
caller reads back does not, so they share one :class:`Solution` with a :class:`RESULTS` code,
modelled on optimistix's ``Solution`` and ``RESULTS``. The traced solvers set the code with
``RESULTS.where`` (it is a JAX array, so it vmaps); the host solver sets it in Python and raises
:class:`shelljax.NoConvergenceError` from it (:func:`raise_if_failed`) where its callers always
did. Options share their names too: ``max_steps`` (Newton iterations, optimistix's name) and
``max_halvings`` (line-search halvings per iteration).

:func:`implicit_tangent` is the tangent of an equilibrium x*(θ) through r(x*, θ) = 0, used by the
two engines' ``custom_jvp`` rules; the dynamics' step keeps its own ``custom_vjp`` (see
docs/architecture.md, *The two engines, side by side*).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import equinox.internal as eqxi
import jax
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PyTree, Real

from ._errors import NoConvergenceError


class RESULTS(eqxi.Enumeration):
    """Why a Newton solve stopped (``successful``: its tolerance was met)."""

    successful = ""
    max_steps_reached = "the residual is above tolerance after max_steps Newton iterations."
    line_search_failed = "the line search found no sufficient decrease within max_halvings halvings."
    no_descent_direction = "no descent direction (Hessian singular or indefinite even after projection and shift)."
    infeasible_start = "the initial state is infeasible (its energy is not finite)."
    nonfinite = "the residual is not finite."


class Solution(eqx.Module):
    """What a Newton solve returns (SI units).

    ``value``: the final iterate x* [m]; ``result``: a :class:`RESULTS` code; ``iterations``:
    Newton iterations; ``history``: the residual max |free ∂E/∂x| [N] per iterate (traced
    solvers: a fixed-length array, NaN past the last iterate; the host solver: a list, the
    start's residual first); ``stats``: the solver's own counts (e.g. ``factorizations``,
    ``products``, ``assemblies``, ``energy`` [J]); ``state``: what the solver keeps for a next,
    nearby solve (a factorisation, a kept Newton matrix), or None.
    """

    value: PyTree[ArrayLike]
    result: RESULTS
    iterations: Real[ArrayLike, ""]
    history: Float[ArrayLike, " K"] | list
    stats: dict[str, Any] = eqx.field(default_factory=dict)
    state: Any = None

    @property
    def converged(self):
        """Whether the tolerance was met (a JAX bool, batched as ``result`` is)."""
        return self.result == RESULTS.successful


def raise_if_failed(solution: Solution, name: str, detail: str = "") -> Solution:
    """``solution`` if it converged; else :class:`NoConvergenceError` naming the solver ``name``,
    the reason from its result code (or ``detail``, which says more) and its residual history."""
    if bool(np.asarray(solution.converged)):
        return solution
    reason = detail or RESULTS[solution.result]
    raise NoConvergenceError(f"{name}: {reason}", list(solution.history))


def implicit_tangent(
    residual: Callable, x: Float[Array, " n"], theta: PyTree, dtheta: PyTree, free: Float[Array, " n"], solve: Callable
) -> Float[Array, " n"]:
    """Tangent dx* = −H⁻¹ (∂r/∂θ) dθ [m] of an equilibrium r(x*, θ) = 0 on the free dofs.

    ``residual(x, θ)`` (n,) [N]: the energy gradient (masked or not); ``free`` (n,): 1 on the free
    dofs, 0 on the fixed ones (which do not move with θ); ``solve(b)``: H⁻¹ b for the symmetric
    Hessian H = ∂r/∂x with the fixed dofs folded in as unit pivots. The linear solve is a
    ``lax.custom_linear_solve`` whose matvec is a JAX Hessian-vector product, so reverse mode
    transposes it with the same ``solve`` and Newton's iterations are never unrolled.
    """
    _, dr = jax.jvp(lambda th: residual(x, th), (theta,), (dtheta,))

    def matvec(v):
        hv = jax.jvp(lambda y: residual(y, theta), (x,), (free * v,))[1]
        return free * hv + (1.0 - free) * v

    return jax.lax.custom_linear_solve(matvec, -free * dr, lambda _, b: solve(b), symmetric=True)


__all__ = ["RESULTS", "Solution", "implicit_tangent", "raise_if_failed"]
