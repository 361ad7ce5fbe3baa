"""Newton solve of the meridian equilibrium, with implicit differentiation.

``equilibrium`` minimises the total energy by damped Newton (structured direct solve, Armijo
backtracking on the energy) inside ``lax.while_loop`` so it jits and vmaps; convergence is
measured in force units: max |∂E/∂y| [N] over the free unknowns ≤ ``atol``. Its derivative
with respect to the parameters is the implicit one, dy = −H⁻¹ ∂²E/∂y∂θ · dθ, through
``jax.custom_jvp`` + ``lax.custom_linear_solve`` (so reverse mode works too); Newton iterations
are never unrolled.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp

from ._energy import (
    Config,
    Params,
    constrained_mask,
    enclosed_volume,
    gas_energy,
    ground_gaps,
    local_energy,
    node_rest_areas,
    rest_nodes,
    split,
    total_energy,
)
from ..physics import ATMOSPHERIC_PRESSURE
from ._linalg import StructuredHessian, structured_hessian, structured_solve

ACTIVE_SET_PASSES = 2  # re-solves per Newton step with the ground contact set the step predicts
MIN_DESCENT_FRACTION = 1e-3  # of a Jacobi-scaled gradient step's rate, for a contact-predicted step


class SolverOptions(tuple):
    """(atol [N], max_iter, max_backtracks, max_step [m]) as a hashable tuple (static under jit).

    ``max_step`` caps the largest coordinate change of one Newton step: it keeps the indenter
    from tunnelling through the shell (a penalty contact cannot stop a jump past it).
    """

    def __new__(cls, atol: float = 1e-7, max_iter: int = 60, max_backtracks: int = 30,
                max_step: float = float("inf")):
        return super().__new__(
            cls, (float(atol), int(max_iter), int(max_backtracks), float(max_step))
        )

    atol = property(lambda s: s[0])
    max_iter = property(lambda s: s[1])
    max_backtracks = property(lambda s: s[2])
    max_step = property(lambda s: s[3])


def _free(cfg: Config, dtype):
    return jnp.asarray(~constrained_mask(cfg), dtype=dtype)


def residual(y, cfg: Config, p: Params):
    """Out-of-balance force ∂E/∂y [N] on the free unknowns (zero on fixed ones)."""
    return jax.grad(total_energy)(y, cfg, p) * _free(cfg, y.dtype)


def hessian_at(y, cfg: Config, p: Params):
    """Structured Hessian [N/m] of the total energy at y."""
    n = cfg.n_nodes
    vol_of = lambda yy: enclosed_volume(split(yy, n)[0])  # noqa: E731
    volume = vol_of(y)
    d_gas = jax.grad(gas_energy)(volume, cfg, p)
    d2_gas = jax.grad(jax.grad(gas_energy))(volume, cfg, p)
    band = lambda yy: local_energy(yy, cfg, p) + d_gas * vol_of(yy)  # noqa: E731
    grad_v = jax.grad(vol_of)(y)[:-1]
    return structured_hessian(jax.grad(band), y, constrained_mask(cfg), d2_gas, grad_v)


def _add_ground_springs(hess: StructuredHessian, springs):
    """H + diag(springs) on the nodes' z unknowns; ``springs`` (n,) [N/m]."""
    on_z = jnp.stack([jnp.zeros_like(springs), springs], axis=-1).reshape(hess.diag.shape[:2])
    diag = hess.diag + on_z[:, :, None] * jnp.eye(4)[None]
    return eqx.tree_at(lambda h: h.diag, hess, diag)


def _ground_active_set_step(hess, g, y, cfg: Config, p: Params, free):
    """Newton direction for the ground contact set that the step itself predicts.

    The quadratic penalty's Hessian is k on a touching node and 0 on a free one, so a plain
    Newton step drives a node about to touch the ground deep into it: the line search then
    crawls (measured: 3–8 iterations of step length 1e-2 … 1e-4 each time the contact disc
    grows by a node). As in a primal–dual active-set method, the step is recomputed with the
    exact piecewise-quadratic penalty model of the free nodes it predicts in contact (spring k
    and force k·gap added); the line search is unchanged, so this only changes the direction.
    """
    n = cfg.n_nodes
    x, _ = split(y, n)
    gaps = ground_gaps(x, p)
    k_node = p.contact_stiffness * node_rest_areas(rest_nodes(cfg, p.rest_radius))
    touching = gaps < 0.0
    d = structured_solve(hess, -g) * free
    for _ in range(ACTIVE_SET_PASSES):
        # Only touching nodes are added: dropping the springs of nodes the step lifts off can
        # leave the ball's vertical rigid mode unrestrained (singular H) near first contact.
        predicted = ((gaps + split(d, n)[0][:, 1]) < 0.0) & ~touching
        change = k_node * predicted.astype(y.dtype)
        force = jnp.zeros_like(y).at[1 : 2 * n : 2].set(change * gaps) * free
        d_pred = structured_solve(_add_ground_springs(hess, change * free[1 : 2 * n : 2]),
                                  -(g + force)) * free
        # The model's pull k·gap on a node still above the ground is not in the true gradient:
        # keep the predicted direction only if it still descends the true energy, by at least a
        # fraction of a Jacobi-scaled gradient step's rate. A node hovering at a gap where k·gap
        # equals its true load makes the model's step vanish (measured: 1e-17 m, Newton stuck
        # for 300 iterations on a hammer surrogate node). An SPD Newton step keeps at least
        # 1/λmax of that rate, and Gershgorin bounds λmax of the Jacobi-scaled H by the nonzeros
        # per row (12 in the blocks, the contact nodes in the indenter row): 1e-3 rejects only
        # such degenerate steps.
        slope = g @ d_pred
        floor = MIN_DESCENT_FRACTION * (g @ (g / _jacobi_diagonal(hess)))
        d = jnp.where(jnp.isfinite(slope) & (slope < -floor), d_pred, d)
    return d


def _jacobi_diagonal(hess: StructuredHessian):
    """|diag H| as a flat vector (the scaling of the gradient fallback step), floored at 1e-30."""
    diag = jnp.concatenate([jnp.diagonal(hess.diag, axis1=1, axis2=2).ravel(), hess.corner[None]])
    return jnp.maximum(jnp.abs(diag), 1e-30)


def _shift(hess: StructuredHessian, mu):
    """H + μ |diag H| (Levenberg shift, Jacobi-scaled so it is unit-free)."""
    diag = hess.diag + mu * jnp.abs(hess.diag) * jnp.eye(4)[None]
    return eqx.tree_at(lambda h: (h.diag, h.corner), hess,
                       (diag, hess.corner + mu * jnp.abs(hess.corner)))


def _newton(cfg: Config, opts: SolverOptions, p: Params, y0):
    free = _free(cfg, y0.dtype)
    # A sealed gas's energy is computed from p_abs·V (≈ 1e5 Pa × the volume) and carries its
    # round-off: on large balls that noise (≈ 1e-12 J) hid the true decrease of Newton steps near
    # equilibrium and Newton stalled at 1e-5–1e-4 N; the line search tolerates noise of that size.
    gas_scale = ((ATMOSPHERIC_PRESSURE + jnp.abs(p.gauge_pressure)) * jnp.abs(p.reference_volume) * cfg.gas_volume_ratio
                 if cfg.gas == "isothermal" else 0.0)  # fmt: skip
    energy = lambda y: total_energy(y, cfg, p)  # noqa: E731
    grad = lambda y: jax.grad(energy)(y) * free  # noqa: E731

    def cond(state):
        _, _, _, res, it, _, _ = state
        return (res > opts.atol) & (it < opts.max_iter)

    def body(state):
        y, g, e, _, it, hist, mu = state
        hess = _shift(hessian_at(y, cfg, p), mu)
        if cfg.ground:
            d = _ground_active_set_step(hess, g, y, cfg, p, free)
        else:
            d = structured_solve(hess, -g) * free
        slope = g @ d
        # Indefinite Hessian far from equilibrium: fall back to a Jacobi-scaled gradient step.
        fallback = -g / _jacobi_diagonal(hess)
        ok_dir = jnp.isfinite(slope) & (slope < 0.0)
        d = jnp.where(ok_dir, d, fallback)
        slope = jnp.where(ok_dir, slope, g @ fallback)
        tol_e = 64.0 * jnp.finfo(y.dtype).eps * (jnp.abs(e) + gas_scale + 1.0)

        def accept(alpha, e_new):
            return jnp.isfinite(e_new) & (e_new <= e + 1e-4 * alpha * slope + tol_e)

        def ls_cond(s):
            alpha, e_new, k = s
            return (~accept(alpha, e_new)) & (k < opts.max_backtracks)

        def ls_body(s):
            alpha, _, k = s
            alpha = 0.5 * alpha
            return alpha, energy(y + alpha * d), k + 1

        alpha0 = jnp.minimum(1.0, opts.max_step / jnp.maximum(jnp.max(jnp.abs(d)), 1e-300))
        alpha, e_new, backtracks = jax.lax.while_loop(
            ls_cond, ls_body, (alpha0, energy(y + alpha0 * d), 0)
        )
        # Levenberg shift: where the Hessian is indefinite (a buckling dimple), the scaled
        # gradient step crawls (measured: 30+ iterations on soft balls); shifting the next
        # Hessians until Newton descends again, and relaxing the shift after clean steps,
        # recovers in a few. The shift only changes directions, never the equilibrium.
        # A step the line search could not make acceptable is not taken (it may sit past the
        # infinite-energy wall of a node crossing the axis); the next direction is shifted instead.
        accepted = accept(alpha, e_new)
        mu = jnp.where(~ok_dir | ~accepted, jnp.maximum(100.0 * mu, 1e-4),
                       jnp.where(backtracks == 0, jnp.where(mu > 1e-8, 0.1 * mu, 0.0), mu))
        y_new = jnp.where(accepted, y + alpha * d, y)
        e_new = jnp.where(accepted, e_new, e)
        g_new = grad(y_new)
        res = jnp.max(jnp.abs(g_new))
        res = jnp.where(jnp.isfinite(res), res, jnp.inf)
        hist = hist.at[it].set(res)
        return y_new, g_new, e_new, res, it + 1, hist, mu

    g0 = grad(y0)
    res0 = jnp.max(jnp.abs(g0))
    hist0 = jnp.full((opts.max_iter,), jnp.nan, y0.dtype)
    state = (y0, g0, energy(y0), res0, jnp.asarray(0), hist0, jnp.zeros((), y0.dtype))
    y, _, _, res, it, hist, _ = jax.lax.while_loop(cond, body, state)
    return y, res, it.astype(y.dtype), hist


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def equilibrium(cfg: Config, opts: SolverOptions, p: Params, y0):
    """Equilibrium unknowns y* [m] from initial guess y0 [m].

    Returns (y*, final residual max|∂E/∂y| [N], Newton iterations (float), residual history
    (max_iter,) [N], NaN past the last iteration). y* is differentiable in ``p`` (implicit
    function theorem); it does not depend on y0 (no tangent flows through the guess).
    """
    return _newton(cfg, opts, p, y0)


@equilibrium.defjvp
def _equilibrium_jvp(cfg, opts, primals, tangents):
    p, y0 = primals
    dp, _ = tangents
    out = equilibrium(cfg, opts, p, y0)
    y = out[0]
    free = _free(cfg, y.dtype)
    fixed = 1.0 - free
    _, dg = jax.jvp(lambda pp: residual(y, cfg, pp), (p,), (dp,))
    hess = hessian_at(y, cfg, p)

    def matvec(v):
        return jax.jvp(lambda yy: residual(yy, cfg, p), (y,), (v,))[1] + fixed * v

    dy = jax.lax.custom_linear_solve(
        matvec, -dg, solve=lambda _, b: structured_solve(hess, b), symmetric=True
    )
    zeros = tuple(jnp.zeros_like(o) for o in out[1:])
    return out, (dy,) + zeros


__all__ = ["SolverOptions", "equilibrium", "hessian_at", "residual"]
