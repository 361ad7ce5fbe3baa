"""Newton solve of the meridian equilibrium, with implicit differentiation.

``equilibrium`` minimises the total energy by damped Newton (structured direct solve, Armijo
backtracking on the energy) inside ``lax.while_loop`` so it jits and vmaps; convergence is
measured in force units: max |∂E/∂y| [N] over the free unknowns ≤ ``atol``. Its derivative
with respect to the parameters is the implicit one, dy = −H⁻¹ ∂²E/∂y∂θ · dθ, through
``jax.custom_jvp`` + ``lax.custom_linear_solve`` (:func:`shelljax._solution.implicit_tangent`,
shared with the 3D engine, so reverse mode works too); Newton iterations are never unrolled. It
returns the package's one :class:`shelljax.Solution`.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp

from ._energy import (
    Config,
    Params,
    fixed_mask,
    ground_gaps,
    indenter_gaps,
    node_rest_areas,
    rest_nodes,
    split,
    total_energy,
)
from .._solution import RESULTS, Solution, implicit_tangent
from ..physics import ATMOSPHERIC_PRESSURE
from ._hessian import hessian_at
from ._linalg import StructuredHessian, structured_solve
from ._tracing import tied_to

ACTIVE_SET_PASSES = 2  # re-solves per Newton step with the contact set the step predicts
MIN_DESCENT_FRACTION = 1e-3  # of a Jacobi-scaled gradient step's rate, for a contact-predicted step


class SolverOptions(eqx.Module):
    """Newton settings, all static: hashable, so a jit or ``custom_jvp`` can key on them.

    ``atol`` [N]: tolerance on the out-of-balance force; ``max_steps``: Newton iterations;
    ``max_halvings``: line-search halvings per iteration; ``step_cap`` [m] caps one Newton step:
    the nodes' motion relative to a spherical indenter (``_step_cap``), or the largest coordinate
    change without one. It keeps the indenter from tunnelling through the shell (a penalty contact
    cannot stop a jump past it).
    """

    atol: float = eqx.field(static=True, default=1e-7, converter=float)
    max_steps: int = eqx.field(static=True, default=60, converter=int)
    max_halvings: int = eqx.field(static=True, default=30, converter=int)
    step_cap: float = eqx.field(static=True, default=float("inf"), converter=float)


def _free(cfg: Config, p: Params, dtype):
    return (~fixed_mask(cfg, p)).astype(dtype)


def residual(y, cfg: Config, p: Params):
    """Out-of-balance force ∂E/∂y [N] on the free unknowns (zero on fixed ones)."""
    return jax.grad(total_energy)(y, cfg, p) * _free(cfg, p, y.dtype)


def _add_contact_springs(hess: StructuredHessian, ground, indenter, normal):
    """H + the springs of nodes predicted in contact: ``ground`` (n,) [N/m] on the nodes' z;
    ``indenter`` (n,) [N/m] along the indenter normals ``normal`` (n, 2), on (x_i, z_c)."""
    node = [[indenter * normal[:, a] * normal[:, b] for b in range(2)] for a in range(2)]
    node[1][1] = node[1][1] + ground
    # block k holds nodes 2k (dofs 0, 1) and 2k + 1 (dofs 2, 3)
    diag = tuple(
        tuple(entry + node[i % 2][j % 2][i // 2 :: 2] if i // 2 == j // 2 else entry for j, entry in enumerate(row))
        for i, row in enumerate(hess.diag)
    )
    arrow = -(indenter * normal[:, 1])[:, None] * normal  # ∂(x − c)/∂z_c = (0, −1)
    corner = jnp.sum(indenter * normal[:, 1] ** 2)
    return eqx.tree_at(
        lambda h: (h.diag, h.arrow, h.corner), hess, (diag, hess.arrow + arrow.ravel(), hess.corner + corner)
    )


def _contact_active_set_step(hess, g, y, cfg: Config, p: Params, free):
    """Newton direction for the contact set (ground and indenter) that the step itself predicts.

    The quadratic penalty's Hessian is k on a touching node and 0 on a free one, so a plain
    Newton step drives a node about to touch a contact deep into it and the line search crawls.
    As in a primal–dual active-set method, the step is recomputed with the exact
    piecewise-quadratic penalty model of the free nodes it predicts in contact (spring k along the
    contact normal and force k·gap added; the indenter gap linearised); the line search is
    unchanged, so this only changes the direction (docs/axisym.md, *Solver*).
    """
    n = cfg.n_nodes
    x, zc = split(y, n)
    k_node = p.contact_stiffness * node_rest_areas(rest_nodes(cfg, p.rest_radius))
    zero = jnp.zeros(n, y.dtype)
    ground_gap = ground_gaps(x, p) if cfg.ground else jnp.full(n, jnp.inf)
    if cfg.loading == "sphere":
        rel = x - jnp.stack([jnp.zeros_like(zc), zc])
        normal = rel / jnp.sqrt(jnp.sum(rel**2, axis=-1))[:, None]
        indenter_gap = indenter_gaps(x, zc, p)
    else:
        normal, indenter_gap = jnp.zeros((n, 2), y.dtype), jnp.full(n, jnp.inf)
    free_z = free[1 : 2 * n : 2]
    free_node = free[: 2 * n].reshape(n, 2)

    def predicted(d):
        # Only touching nodes are added: dropping the springs of nodes the step lifts off can
        # leave the ball's vertical rigid mode unrestrained (singular H) near first contact.
        dx, dzc = split(d, n)
        ground_hit = ((ground_gap + dx[:, 1]) < 0.0) & ~(ground_gap < 0.0)
        indenter_hit = ((indenter_gap + jnp.sum(normal * dx, -1) - normal[:, 1] * dzc) < 0.0) & ~(indenter_gap < 0.0)
        return ground_hit, indenter_hit

    def repredict(d, hits):
        ground_hit, indenter_hit = hits
        k_ground = jnp.where(ground_hit, k_node, 0.0)
        k_indenter = jnp.where(indenter_hit, k_node, 0.0)
        pull_ground = k_ground * jnp.where(ground_hit, ground_gap, 0.0)
        pull_indenter = k_indenter * jnp.where(indenter_hit, indenter_gap, 0.0)
        node_force = jnp.stack([zero, pull_ground], -1) + pull_indenter[:, None] * normal
        zc_force = -jnp.sum(pull_indenter * normal[:, 1])
        force = jnp.concatenate([node_force.ravel(), zc_force[None]]) * free
        springs = _add_contact_springs(hess, k_ground * free_z, k_indenter * free[-1], normal * free_node)
        d_pred = structured_solve(springs, -(g + force)) * free
        # The model's pull k·gap on a node still clear of contact is not in the true gradient,
        # and can cancel a node's load: keep the direction only if it still descends the true
        # energy at ≥ MIN_DESCENT_FRACTION of a Jacobi-scaled gradient step's rate.
        slope = g @ d_pred
        floor = MIN_DESCENT_FRACTION * (g @ (g / _jacobi_diagonal(hess)))
        return jnp.where(jnp.isfinite(slope) & (slope < -floor), d_pred, d)

    # A pass whose predicted set is the one d was solved with would reproduce d: stop there.
    # The state carries the set d was solved with and the set d predicts.
    def changed(state):
        _, passes, (used_ground, used_indenter), (ground_hit, indenter_hit) = state
        return (passes < ACTIVE_SET_PASSES) & jnp.any((ground_hit != used_ground) | (indenter_hit != used_indenter))

    def one_pass(state):
        d, passes, _, hits = state
        d = repredict(d, hits)
        return d, passes + 1, hits, predicted(d)

    d = structured_solve(hess, -g) * free
    passes, none = tied_to(d, jnp.asarray(0), jnp.zeros(n, bool))
    d, _, _, _ = jax.lax.while_loop(changed, one_pass, (d, passes, (none, none), predicted(d)))
    return d


def _step_cap(d, y, cfg: Config, p: Params, step_cap):
    """Largest step length α ≤ 1 along ``d`` allowed by ``step_cap`` [m].

    Under a spherical indenter the cap is on each node's motion relative to the indenter, and
    a node farther away than ``step_cap`` may move up to its gap: α |Δx_i − Δc| ≤
    max(step_cap, gap_i). A node can pass through the sphere only by moving relative to it by
    more than its gap, so this keeps the indenter from tunnelling while letting the shell and the
    indenter translate together. Without an indenter (or while inflating) the cap is on every
    coordinate.
    """
    coordinate_cap = jnp.minimum(1.0, step_cap / jnp.maximum(jnp.max(jnp.abs(d)), 1e-300))
    if cfg.loading != "sphere":
        return coordinate_cap
    n = cfg.n_nodes
    x, zc = split(y, n)
    dx, dzc = split(d, n)
    relative = jnp.sqrt(jnp.sum((dx - jnp.stack([jnp.zeros_like(dzc), dzc])) ** 2, axis=-1))
    # A traced indenter radius smaller than the static cap shrinks it (a small sphere is
    # tunnelled through by a shorter jump); a larger one keeps the static cap.
    allowed = jnp.maximum(jnp.minimum(step_cap, p.indenter_radius), indenter_gaps(x, zc, p))
    sphere_cap = jnp.minimum(1.0, jnp.min(allowed / jnp.maximum(relative, 1e-300)))
    return jnp.where(p.inflating, coordinate_cap, sphere_cap)


def _jacobi_diagonal(hess: StructuredHessian):
    """|diag H| as a flat vector (the scaling of the gradient fallback step), floored at 1e-30."""
    diag = jnp.concatenate([jnp.stack([hess.diag[i][i] for i in range(4)], -1).ravel(), hess.corner[None]])
    return jnp.maximum(jnp.abs(diag), 1e-30)


def _shift(hess: StructuredHessian, mu):
    """H + μ |diag H| (Levenberg shift, Jacobi-scaled so it is unit-free)."""
    diag = tuple(
        tuple(entry + mu * jnp.abs(entry) if i == j else entry for j, entry in enumerate(row))
        for i, row in enumerate(hess.diag)
    )
    return eqx.tree_at(lambda h: (h.diag, h.corner), hess, (diag, hess.corner + mu * jnp.abs(hess.corner)))


def _levenberg(mu, descends, accepted, backtracks):
    """Next Levenberg shift μ [-]: ×100 (at least 1e-4) after a non-descent direction or a step
    the line search could not accept, ÷10 after a full step, else unchanged."""
    return jnp.where(
        ~descends | ~accepted,
        jnp.maximum(100.0 * mu, 1e-4),
        jnp.where(backtracks == 0, jnp.where(mu > 1e-8, 0.1 * mu, 0.0), mu),
    )


def _direction(hess, g, y, cfg: Config, p: Params, free):
    """(Newton direction, whether it descends): the contact-predicted step where contacts
    exist, with a Jacobi-scaled gradient step where the Hessian gives no descent."""
    if cfg.ground or cfg.loading == "sphere":
        d = _contact_active_set_step(hess, g, y, cfg, p, free)
    else:
        d = structured_solve(hess, -g) * free
    slope = g @ d
    fallback = -g / _jacobi_diagonal(hess)
    descends = jnp.isfinite(slope) & (slope < 0.0)
    return jnp.where(descends, d, fallback), descends


def _gas_energy_scale(cfg: Config, p: Params):
    """Size [J] of a sealed gas's p_abs·V energy, whose round-off the line search must tolerate."""
    if not cfg.gas.sealed:
        return 0.0
    scale = (
        (ATMOSPHERIC_PRESSURE + jnp.abs(p.gauge_pressure)) * jnp.abs(p.reference_volume) * jnp.abs(p.gas_volume_ratio)
    )
    return jnp.where(p.inflating, 0.0, scale)  # an inflating ball's gas is held at its pressure


def _lowest_energy_start(energy, y0):
    """The candidate start (a row of ``y0``) of lowest energy, the quantity the line search
    decreases (the force residual ranks poorly: one misplaced touching node dominates it); NaN or
    infinite rows are never taken."""
    e_starts = jax.vmap(energy)(y0)
    return y0[jnp.argmin(jnp.where(jnp.isfinite(e_starts), e_starts, jnp.inf))]


def _newton(cfg: Config, opts: SolverOptions, p: Params, y0):
    free = _free(cfg, p, y0.dtype)
    gas_scale = _gas_energy_scale(cfg, p)
    energy = lambda y: total_energy(y, cfg, p)  # noqa: E731
    energy_and_grad = jax.value_and_grad(energy)

    def cond(state):
        _, _, _, res, it, _, _ = state
        return (res > opts.atol) & (it < opts.max_steps)

    def body(state):
        y, g, e, _, it, hist, mu = state
        hess = _shift(hessian_at(y, cfg, p), mu)
        d, descends = _direction(hess, g, y, cfg, p, free)
        slope = g @ d
        tol_e = 64.0 * jnp.finfo(y.dtype).eps * (jnp.abs(e) + gas_scale + 1.0)

        def accept(alpha, e_new):
            return jnp.isfinite(e_new) & (e_new <= e + 1e-4 * alpha * slope + tol_e)

        # Each trial returns its gradient too, the next residual if accepted. The loop starts at
        # 2·alpha0 with no trial made, so one copy of the energy and gradient is compiled, not two.
        def ls_cond(s):
            alpha, e_new, _, k = s
            return (~accept(alpha, e_new)) & (k < opts.max_halvings)

        def ls_body(s):
            alpha, _, _, k = s
            alpha = 0.5 * alpha
            return (alpha, *energy_and_grad(y + alpha * d), k + 1)

        alpha0 = _step_cap(d, y, cfg, p, opts.step_cap)
        no_trial = tied_to(y, jnp.asarray(jnp.inf, e.dtype), jnp.zeros_like(g), jnp.asarray(-1))
        alpha, e_new, g_trial, backtracks = jax.lax.while_loop(ls_cond, ls_body, (2.0 * alpha0, *no_trial))
        # A step the line search could not accept is not taken (it may sit past the infinite-energy
        # wall of a node crossing the axis); the Levenberg shift changes the next direction instead.
        accepted = accept(alpha, e_new)
        mu = _levenberg(mu, descends, accepted, backtracks)
        y_new = jnp.where(accepted, y + alpha * d, y)
        e_new = jnp.where(accepted, e_new, e)
        g_new = jnp.where(accepted, g_trial * free, g)
        res = jnp.max(jnp.abs(g_new))
        res = jnp.where(jnp.isfinite(res), res, jnp.inf)
        hist = hist.at[it].set(res)
        return y_new, g_new, e_new, res, it + 1, hist, mu

    if y0.ndim == 2:
        y0 = _lowest_energy_start(energy, y0)
    e0, g0 = energy_and_grad(y0)
    g0 = g0 * free
    res0 = jnp.max(jnp.abs(g0))
    hist0 = jnp.full((opts.max_steps,), jnp.nan, y0.dtype)
    state = (y0, g0, e0, res0, *tied_to(y0, jnp.asarray(0), hist0, jnp.zeros((), y0.dtype)))
    y, _, _, res, it, hist, _ = jax.lax.while_loop(cond, body, state)
    return y, res, it.astype(y.dtype), hist


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def _equilibrium(cfg: Config, opts: SolverOptions, p: Params, y0):
    """(y*, final residual [N], iterations (float: a tangent-free output), history [N])."""
    return _newton(cfg, opts, p, y0)


@_equilibrium.defjvp
def _equilibrium_jvp(cfg, opts, primals, tangents):
    p, y0 = primals
    dp, _ = tangents
    out = _equilibrium(cfg, opts, p, y0)
    y = out[0]
    hess = hessian_at(y, cfg, p)
    dy = implicit_tangent(
        lambda yy, pp: residual(yy, cfg, pp), y, p, dp, _free(cfg, p, y.dtype), lambda b: structured_solve(hess, b)
    )
    zeros = tuple(jnp.zeros_like(o) for o in out[1:])
    return out, (dy,) + zeros


def equilibrium(cfg: Config, opts: SolverOptions, p: Params, y0) -> Solution:
    """Equilibrium of the meridian from initial guess y0 [m] ((n_y,), or (m, n_y) candidate
    guesses, of which Newton starts from the one of lowest energy; NaN rows are never taken).

    Returns a :class:`shelljax.Solution`: ``value`` y* [m], ``result`` (``successful`` once
    max|∂E/∂y| ≤ ``opts.atol``), ``iterations`` (a float), ``history`` (max_steps,) [N] (NaN past
    the last iteration) and ``stats["residual"]``, the final max|∂E/∂y| [N]. y* is
    differentiable in ``p`` (implicit function theorem); it does not depend on y0 (no tangent
    flows through the guess).
    """
    y, res, it, hist = _equilibrium(cfg, opts, p, y0)
    result = RESULTS.where(
        res <= opts.atol,
        RESULTS.successful,
        RESULTS.where(jnp.isfinite(res), RESULTS.max_steps_reached, RESULTS.nonfinite),
    )
    return Solution(y, result, it, hist, {"residual": res})


__all__ = ["SolverOptions", "equilibrium", "hessian_at", "residual"]
