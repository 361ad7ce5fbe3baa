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

import jax
import jax.numpy as jnp

from ._energy import (
    Config,
    Params,
    constrained_mask,
    enclosed_volume,
    gas_energy,
    local_energy,
    split,
    total_energy,
)
from ._linalg import structured_hessian, structured_solve


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


def _newton(cfg: Config, opts: SolverOptions, p: Params, y0):
    free = _free(cfg, y0.dtype)
    energy = lambda y: total_energy(y, cfg, p)  # noqa: E731
    grad = lambda y: jax.grad(energy)(y) * free  # noqa: E731

    def cond(state):
        _, _, _, res, it, _ = state
        return (res > opts.atol) & (it < opts.max_iter)

    def body(state):
        y, g, e, _, it, hist = state
        hess = hessian_at(y, cfg, p)
        d = structured_solve(hess, -g) * free
        slope = g @ d
        # Indefinite Hessian far from equilibrium: fall back to a Jacobi-scaled gradient step.
        scale = jnp.abs(jnp.concatenate([jnp.diagonal(hess.diag, axis1=1, axis2=2).ravel(),
                                         hess.corner[None]]))
        fallback = -g / jnp.maximum(scale, 1e-30)
        ok_dir = jnp.isfinite(slope) & (slope < 0.0)
        d = jnp.where(ok_dir, d, fallback)
        slope = jnp.where(ok_dir, slope, g @ fallback)
        tol_e = 64.0 * jnp.finfo(y.dtype).eps * (jnp.abs(e) + 1.0)

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
        alpha, e_new, _ = jax.lax.while_loop(
            ls_cond, ls_body, (alpha0, energy(y + alpha0 * d), 0)
        )
        y_new = y + alpha * d
        g_new = grad(y_new)
        res = jnp.max(jnp.abs(g_new))
        res = jnp.where(jnp.isfinite(res), res, jnp.inf)
        hist = hist.at[it].set(res)
        return y_new, g_new, e_new, res, it + 1, hist

    g0 = grad(y0)
    res0 = jnp.max(jnp.abs(g0))
    hist0 = jnp.full((opts.max_iter,), jnp.nan, y0.dtype)
    state = (y0, g0, energy(y0), res0, jnp.asarray(0), hist0)
    y, _, _, res, it, hist = jax.lax.while_loop(cond, body, state)
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
