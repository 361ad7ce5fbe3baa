"""Exact Hessian of the meridian energy, assembled from element-local second derivatives.

Every term of ``_energy.local_energy`` is a sum of pointwise densities of a few local measures:
the membrane of (λ_s, λ_θ) per Gauss point, the bending of (M_ss, M_θθ) per hinge, the contacts
of one gap per node, the linearised gas of the element volumes. The chain rule gives each term's
Hessian as Σ ∂²W/∂a∂b ∇a ∇bᵀ + Σ ∂W/∂a ∇²a. The pointwise derivatives of the densities come
from autodiff of the shared physics laws (elementwise, so they vectorize over a batch); the
gradients and Hessians of the measures are closed forms (a segment length, a node radius, the
direction angle of a segment, a distance to the indenter centre). This replaced 12 coloured
Hessian-vector products of the whole energy, which cost as much as ~24 gradients and did not
vectorize over a batch (docs/axisym.md, *Benchmark*).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..physics import bending_density_invariants, penalty_energy
from ._energy import (
    Config,
    Params,
    _ghosted,
    constrained_mask,
    enclosed_volume,
    gas_energy,
    ground_gaps,
    indenter_gaps,
    membrane_density,
    membrane_terms,
    node_rest_areas,
    rest_nodes,
    split,
)
from ._geometry import gauss_points_2
from ._linalg import StructuredHessian


def _pointwise_second_derivatives(density_sum, a, b):
    """(∂/∂a, ∂/∂b, ∂²/∂a², ∂²/∂a∂b, ∂²/∂b²) of a sum of pointwise densities of arrays a, b."""
    grad = jax.grad(density_sum, argnums=(0, 1))
    ones, zeros = jnp.ones_like(a), jnp.zeros_like(a)
    (g_a, g_b), (h_aa, h_ab) = jax.jvp(grad, (a, b), (ones, zeros))
    _, (_, h_bb) = jax.jvp(grad, (a, b), (zeros, ones))
    return g_a, g_b, h_aa, h_ab, h_bb


def _outer(u, v):
    return u[..., :, None] * v[..., None, :]


def _pair_pattern(block, weights):
    """Node-pattern expansion: (…, 2, 2) block ⊗ (k, k) node weights → (…, 2k, 2k)."""
    k = weights.shape[0]
    out = jnp.asarray(weights)[:, None, :, None] * block[..., None, :, None, :]
    return out.reshape(block.shape[:-2] + (2 * k, 2 * k))


def _node_pattern(vec, weights):
    """(…, 2) vector ⊗ (k,) node weights → (…, 2k)."""
    return (jnp.asarray(weights)[:, None] * vec[..., None, :]).reshape(vec.shape[:-1] + (2 * len(weights),))


def _direction_derivatives(t):
    """Gradient (…, 2) and Hessian (…, 2, 2) of the direction angle atan2(t_z, t_r) of t [1/m, 1/m²].

    ∇θ = t⊥/|t|², ∇²θ = J/|t|² − 2 t⊥ tᵀ/|t|⁴ (t⊥ = J t, J the quarter turn); symmetric in 2D.
    """
    sq = jnp.sum(t**2, axis=-1)
    perp = jnp.stack([-t[..., 1], t[..., 0]], axis=-1)
    quarter_turn = jnp.asarray([[0.0, -1.0], [1.0, 0.0]])
    hess = quarter_turn / sq[..., None, None] - 2.0 * _outer(perp, t) / (sq**2)[..., None, None]
    return perp / sq[..., None], hess


def _length_derivatives(t):
    """|t| [m], its gradient t̂ (…, 2) and Hessian (I − t̂t̂ᵀ)/|t| (…, 2, 2) [1/m]."""
    length = jnp.sqrt(jnp.sum(t**2, axis=-1))
    unit = t / length[..., None]
    return length, unit, (jnp.eye(2) - _outer(unit, unit)) / length[..., None, None]


def _membrane_blocks(x, x0, cfg: Config, p: Params):
    """Element 4×4 Hessians (n − 1, 4, 4) [N/m] of the membrane, dofs (r_e, z_e, r_e+1, z_e+1)."""
    xi, _ = gauss_points_2()
    lam_s, lam_t, area0 = membrane_terms(x, x0, p, cfg.relax)

    def density_sum(ls, lt):
        return jnp.sum(area0 * membrane_density(ls, lt, p, cfg.relax, cfg.hoop_capacity))

    g_s, _, h_ss, h_st, h_tt = _pointwise_second_derivatives(density_sum, lam_s, lam_t)
    seg0 = jnp.sqrt(jnp.sum((x0[1:] - x0[:-1]) ** 2, axis=-1))
    _, unit, curv = _length_derivatives(x[1:] - x[:-1])
    ends = np.array([-1.0, 1.0])
    grad_s = _node_pattern(unit, ends) / seg0[:, None]  # ∇λ_s = ∇L / L0
    hess_s = _pair_pattern(curv, np.outer(ends, ends)) / seg0[:, None, None]
    r0_g = (1.0 - xi)[:, None] * x0[None, :-1, 0] + xi[:, None] * x0[None, 1:, 0]
    # ∇λ_θ per Gauss point: λ_θ = ((1 − ξ) r_e + ξ r_e+1) / r0_g is linear (no Hessian)
    shape = np.zeros((2, 4))
    shape[:, 0], shape[:, 2] = 1.0 - xi, xi
    grad_t = jnp.asarray(shape)[:, None, :] / r0_g[..., None]
    cross = _outer(grad_s[None], grad_t)
    per_point = (h_ss[..., None, None] * _outer(grad_s, grad_s)[None]
                 + h_st[..., None, None] * (cross + jnp.swapaxes(cross, -1, -2))
                 + h_tt[..., None, None] * _outer(grad_t, grad_t))
    return jnp.sum(per_point, axis=0) + jnp.sum(g_s, axis=0)[:, None, None] * hess_s


def _volume_blocks(x):
    """Element 4×4 Hessians (n − 1, 4, 4) [m] of V_e = π Δz (r_a² + r_a r_b + r_b²)/3."""
    ra, za, rb, zb = x[:-1, 0], x[:-1, 1], x[1:, 0], x[1:, 1]
    dz, sa, sb = zb - za, 2.0 * ra + rb, ra + 2.0 * rb
    zero = jnp.zeros_like(dz)
    rows = [[2 * dz, -sa, dz, sa], [-sa, zero, -sb, zero], [dz, -sb, 2 * dz, sb], [sa, zero, sb, zero]]
    return jnp.pi / 3.0 * jnp.stack([jnp.stack(r, -1) for r in rows], -2)


def _hinge_measures(xe):
    """(M-independent) hinge geometry of the ghosted nodes: the turning angle φ [-], dual length
    [m], sin/cos of the bisector angle ψ [-], and their local 6-dof gradients and Hessians."""
    t1, t2 = xe[1:-1] - xe[:-2], xe[2:] - xe[1:-1]
    q1, hq1 = _direction_derivatives(t1)
    q2, hq2 = _direction_derivatives(t2)
    len1, u1, c1 = _length_derivatives(t1)
    len2, u2, c2 = _length_derivatives(t2)
    first, second = np.array([-1.0, 1.0, 0.0]), np.array([0.0, -1.0, 1.0])
    grad_a1, grad_a2 = _node_pattern(q1, first), _node_pattern(q2, second)
    hess_a1 = _pair_pattern(hq1, np.outer(first, first))
    hess_a2 = _pair_pattern(hq2, np.outer(second, second))
    turning = jnp.arctan2(t1[:, 0] * t2[:, 1] - t1[:, 1] * t2[:, 0], jnp.sum(t1 * t2, axis=-1))
    dual = 0.5 * (len1 + len2)
    grad_dual = 0.5 * (_node_pattern(u1, first) + _node_pattern(u2, second))
    hess_dual = 0.5 * (_pair_pattern(c1, np.outer(first, first)) + _pair_pattern(c2, np.outer(second, second)))
    bisector = jnp.arctan2(t1[:, 1], t1[:, 0]) + 0.5 * turning
    return dict(
        turning=turning, grad_turning=grad_a2 - grad_a1, hess_turning=hess_a2 - hess_a1,
        dual=dual, grad_dual=grad_dual, hess_dual=hess_dual,
        sin=jnp.sin(bisector), cos=jnp.cos(bisector),
        grad_bisector=0.5 * (grad_a1 + grad_a2), hess_bisector=0.5 * (hess_a1 + hess_a2),
    )


def _bending_blocks(x, x0, p: Params):
    """Hinge 6×6 Hessians (n, 6, 6) [N/m] of the bending energy, ghosted dofs (i−1, i, i+1)."""
    h = _hinge_measures(_ghosted(x))
    h0 = _hinge_measures(_ghosted(x0))
    dual0 = h0["dual"]
    m_ss = (h["turning"] * h["dual"] / dual0 - h0["turning"]) / dual0
    grad_ss = (h["dual"][:, None] * h["grad_turning"] + h["turning"][:, None] * h["grad_dual"]) / (dual0**2)[:, None]
    cross = _outer(h["grad_turning"], h["grad_dual"])
    hess_ss = (cross + jnp.swapaxes(cross, -1, -2) + h["dual"][:, None, None] * h["hess_turning"]
               + h["turning"][:, None, None] * h["hess_dual"]) / (dual0**2)[:, None, None]
    # M_θθ = (r sin ψ − r0 sin ψ0)/r0² with r the hinge node's radius (local dof 2)
    r, r0 = x[:, 0], x0[:, 0]
    safe_r0 = jnp.where(r0 > 0.0, r0, 1.0)
    e_r = jnp.zeros(6).at[2].set(1.0)
    grad_sin = h["cos"][:, None] * h["grad_bisector"]
    hess_sin = (-h["sin"][:, None, None] * _outer(h["grad_bisector"], h["grad_bisector"])
                + h["cos"][:, None, None] * h["hess_bisector"])
    m_tt = (r * h["sin"] - r0 * h0["sin"]) / safe_r0**2
    grad_tt = (h["sin"][:, None] * e_r + r[:, None] * grad_sin) / (safe_r0**2)[:, None]
    hess_tt = (_outer(e_r, grad_sin) + _outer(grad_sin, e_r) + r[:, None, None] * hess_sin) / (safe_r0**2)[:, None, None]
    # poles: M_θθ = M_ss by isotropy
    interior = jnp.asarray(np.r_[False, np.ones(x0.shape[0] - 2, bool), False])
    m_tt = jnp.where(interior, m_tt, m_ss)
    grad_tt = jnp.where(interior[:, None], grad_tt, grad_ss)
    hess_tt = jnp.where(interior[:, None, None], hess_tt, hess_ss)
    area = node_rest_areas(x0)

    def density_sum(a, b):
        dens = bending_density_invariants(a + b, a**2 + b**2, p.thickness, p.young_modulus, p.poisson_ratio)
        return p.bending_scale * jnp.sum(area * dens)

    g_ss, g_tt, h_aa, h_ab, h_bb = _pointwise_second_derivatives(density_sum, m_ss, m_tt)
    cross = _outer(grad_ss, grad_tt)
    return (h_aa[:, None, None] * _outer(grad_ss, grad_ss) + h_ab[:, None, None] * (cross + jnp.swapaxes(cross, -1, -2))
            + h_bb[:, None, None] * _outer(grad_tt, grad_tt)
            + g_ss[:, None, None] * hess_ss + g_tt[:, None, None] * hess_tt)


def _penalty_derivatives(gaps, stiffness):
    """(∂P/∂g [N], ∂²P/∂g² [N/m]) of the contact penalty per node (shared physics law)."""
    grad = jax.grad(lambda g: jnp.sum(penalty_energy(g, stiffness)))
    return jax.jvp(grad, (gaps,), (jnp.ones_like(gaps),))


def _fold_ghosts(d0, d1, d2):
    """Node bands over the ghosted nodes (n + 2) → the real nodes' (n, n − 1, n − 2 blocks).

    The ghosts are mirror images P x (P = diag(−1, 1)) of the pole neighbours x_1 and x_n−2, so
    their rows and columns fold onto those nodes: H_eff = Tᵀ H T.
    """
    mirror = jnp.asarray(np.diag([-1.0, 1.0]))
    lo, hi = d0[0], d0[-1]
    d0, d1_lo, d1_hi, d2_lo, d2_hi = d0[1:-1], d1[0], d1[-1], d2[0], d2[-1]
    d1, d2 = d1[1:-1], d2[1:-1]
    # bottom ghost g = P x_1: couples to itself, node 0 (d1_lo = H(g, x_0)) and node 1 (d2_lo = H(g, x_1))
    d0 = d0.at[1].add(mirror @ lo @ mirror + mirror @ d2_lo + d2_lo.T @ mirror)
    d1 = d1.at[0].add(d1_lo.T @ mirror)
    # top ghost g = P x_n−2: d1_hi = H(x_n−1, g), d2_hi = H(x_n−2, g)
    d0 = d0.at[-2].add(mirror @ hi @ mirror + d2_hi @ mirror + mirror @ d2_hi.T)
    d1 = d1.at[-1].add(mirror @ d1_hi.T)
    return d0, d1, d2


def _blocks_from_bands(d0, d1, d2):
    """Node bands (2×2 blocks: node i with i, i+1, i+2) → 4×4 diagonal and upper blocks."""
    zero = jnp.zeros_like(d2[0::2])
    diag = jnp.concatenate([jnp.concatenate([d0[0::2], d1[0::2]], -1),
                            jnp.concatenate([jnp.swapaxes(d1[0::2], -1, -2), d0[1::2]], -1)], -2)
    upper = jnp.concatenate([jnp.concatenate([d2[0::2], zero], -1),
                             jnp.concatenate([d1[1::2], d2[1::2]], -1)], -2)
    return diag, upper


def _pad(a, before, after):
    return jnp.pad(a, ((before, after),) + ((0, 0),) * (a.ndim - 1))


def hessian_at(y, cfg: Config, p: Params) -> StructuredHessian:
    """Structured Hessian [N/m] of the total energy at y [m] (exact; fixed dofs → identity)."""
    n = cfg.n_nodes
    x, zc = split(y, n)
    x0 = rest_nodes(cfg, p.rest_radius)
    volume = enclosed_volume(x)
    d_gas = jax.grad(gas_energy)(volume, cfg, p)
    d2_gas = jax.grad(jax.grad(gas_energy))(volume, cfg, p)
    grad_volume = jax.grad(lambda xx: enclosed_volume(xx))(x).ravel()

    element = _membrane_blocks(x, x0, cfg, p) + d_gas * _volume_blocks(x)
    d0 = _pad(element[:, :2, :2], 0, 1) + _pad(element[:, 2:, 2:], 1, 0)
    d1 = element[:, :2, 2:]
    k_node = p.contact_stiffness * node_rest_areas(x0)
    arrow = jnp.zeros((n, 2))
    corner = jnp.zeros(())
    if cfg.ground:
        _, stiff = _penalty_derivatives(ground_gaps(x, p), k_node)
        d0 = d0.at[:, 1, 1].add(stiff)
    if cfg.loading == "sphere":
        force, stiff = _penalty_derivatives(indenter_gaps(x, zc, p), k_node)
        rel = x - jnp.stack([jnp.zeros_like(zc), zc])
        _, normal, curv = _length_derivatives(rel)
        node = stiff[:, None, None] * _outer(normal, normal) + force[:, None, None] * curv
        d0 = d0 + node
        arrow = -node[:, :, 1]  # ∂(x − c)/∂z_c = (0, −1)
        corner = jnp.sum(node[:, 1, 1])

    hinge = _bending_blocks(x, x0, p)
    # ghosted node bands: hinge i couples ghosted nodes i, i + 1, i + 2
    d0_g = (_pad(hinge[:, :2, :2], 0, 2) + _pad(hinge[:, 2:4, 2:4], 1, 1) + _pad(hinge[:, 4:, 4:], 2, 0))
    d1_g = _pad(hinge[:, :2, 2:4], 0, 1) + _pad(hinge[:, 2:4, 4:], 1, 0)
    b0, b1, b2 = _fold_ghosts(d0_g, d1_g, hinge[:, :2, 4:])
    diag, upper = _blocks_from_bands(d0 + b0, d1 + b1, b2)

    mask = constrained_mask(cfg)
    free = jnp.asarray(~mask, dtype=y.dtype)
    free_blocks = free[:-1].reshape(-1, 4)
    diag = diag * _outer(free_blocks, free_blocks) + jnp.eye(4) * (1.0 - free_blocks)[:, None, :]
    upper = upper * _outer(free_blocks[:-1], free_blocks[1:])
    arrow = arrow.ravel() * free[:-1] * free[-1]
    corner = jnp.where(mask[-1], 1.0, corner)
    return StructuredHessian(diag, upper, arrow, corner, d2_gas, grad_volume * free[:-1])


__all__ = ["hessian_at"]
