"""Exact Hessian of the meridian energy, assembled from element-local second derivatives.

Every term of ``_energy.local_energy`` is a sum of pointwise densities of a few local measures:
the membrane of (λ_s, λ_θ) per Gauss point, the bending of (M_ss, M_θθ) per hinge, the contacts
of one gap per node, the ground friction of one radial slip per node, the linearised gas of the
element volumes. The chain rule gives each term's
Hessian as Σ ∂²W/∂a∂b ∇a ∇bᵀ + Σ ∂W/∂a ∇²a. The pointwise derivatives of the densities come
from autodiff of the shared physics laws (elementwise, so they vectorize over a batch); the
gradients and Hessians of the measures are closed forms (a segment length, a node radius, the
direction angle of a segment, a distance to the indenter centre). Unlike Hessian-vector products
of the whole energy, this vectorizes over a batch (docs/axisym.md, *Solver*).

The membrane, contact and gas terms and the assembly are written as structs of arrays: a local
gradient is a list of one array per local dof (``None`` where it is zero, skipped when tracing),
a local Hessian a nested list of them, each array running over the elements, and so is the
result (``StructuredHessian``). XLA:CPU compiles that to flat loops over the elements, where
arrays of small blocks recompute the block expressions in every slice that consumes them. The
bending hinges stay 6×6 block arrays, computed once, for a smaller program (docs/axisym.md,
*Performance notes*).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..physics import bending_density_invariants, penalty_energy
from ._energy import (
    _ghosted,
    Config,
    Params,
    enclosed_volume,
    fixed_mask,
    gas_energy,
    ground_friction_energy,
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


def _computed_once(*arrays):
    """``arrays`` (finite) unchanged, exactly (x·1 + Σ y·0), each computed once.

    XLA:CPU fuses cheap elementwise producers into each of their consumers and recomputes them
    there: the relaxed membrane law's second derivatives, a long chain per Gauss point, feed all
    ten entries of an element Hessian. XLA does not fuse a product with the identity matrix.
    """
    return tuple(jnp.tensordot(jnp.eye(len(arrays)), jnp.stack(arrays), axes=1))


# --- struct-of-arrays algebra: None is an exact zero (skipped at trace time) -------------------


def _sum(*terms):
    terms = [t for t in terms if t is not None]
    if not terms:
        return None
    out = terms[0]
    for t in terms[1:]:
        out = out + t
    return out


def _scale(c, a):
    """c · a; c a Python number or an array, a an array or None."""
    if a is None or (isinstance(c, (int, float)) and c == 0):
        return None
    return a if isinstance(c, (int, float)) and c == 1 else c * a


def _product(a, b):
    return None if a is None or b is None else a * b


def _vector_sum(*vectors):
    return [_sum(*entries) for entries in zip(*vectors)]


def _vector_scale(c, v):
    return [_scale(c, a) for a in v]


def _matrix_sum(*matrices):
    return [_vector_sum(*rows) for rows in zip(*matrices)]


def _matrix_scale(c, m):
    return [_vector_scale(c, row) for row in m]


def _symmetrized(m):
    """The upper triangle mirrored: XLA then drops the lower triangle's (equal) computations."""
    return [[m[min(i, j)][max(i, j)] for j in range(len(m))] for i in range(len(m))]


def _outer(u, v):
    return [[_product(a, b) for b in v] for a in u]


def _symmetric_outer(u, v):
    """u vᵀ + v uᵀ."""
    return [[_sum(_product(a, d), _product(c, b)) for d, b in zip(v, u)] for a, c in zip(u, v)]


def _node_pattern(weights, vec):
    """Node weights (k,) ⊗ a 2-vector → a 2k-vector (dofs r, z per node)."""
    return [_scale(float(w), a) for w in weights for a in vec]


def _pair_pattern(weights, block):
    """Node weights (k, k) ⊗ a 2×2 block → a 2k × 2k matrix."""
    k = len(weights)
    return [
        [_scale(float(weights[i][j]), block[ci][cj]) for j in range(k) for cj in range(2)]
        for i in range(k)
        for ci in range(2)
    ]


def _length_derivatives(t_r, t_z):
    """|t| [m], its gradient t̂ and Hessian (I − t̂t̂ᵀ)/|t| [1/m]."""
    length = jnp.sqrt(t_r**2 + t_z**2)
    u_r, u_z = t_r / length, t_z / length
    off = -u_r * u_z / length
    return length, [u_r, u_z], [[u_z**2 / length, off], [off, u_r**2 / length]]


# --- element and hinge Hessians ----------------------------------------------------------------


def _membrane_and_gas_entries(x, x0, cfg: Config, p: Params, d_gas):
    """Element 4×4 Hessians [N/m] of membrane + linearised gas, dofs (r_e, z_e, r_e+1, z_e+1)."""
    xi, _ = gauss_points_2()
    lam_s, lam_t, area0 = membrane_terms(x, x0, p, cfg.relax)

    def density_sum(ls, lt):
        return jnp.sum(area0 * membrane_density(ls, lt, p, cfg.relax, cfg.hoop_capacity))

    g_s, _, h_ss, h_st, h_tt = _pointwise_second_derivatives(density_sum, lam_s, lam_t)
    g_s, h_ss, h_st, h_tt = _computed_once(g_s, h_ss, h_st, h_tt)
    r, z, r0 = x[:, 0], x[:, 1], x0[:, 0]
    seg0 = jnp.sqrt(jnp.sum((x0[1:] - x0[:-1]) ** 2, axis=-1))
    _, unit, curv = _length_derivatives(r[1:] - r[:-1], z[1:] - z[:-1])
    ends = np.array([-1.0, 1.0])
    grad_s = _vector_scale(1.0 / seg0, _node_pattern(ends, unit))  # ∇λ_s = ∇L / L0
    hess_s = _pair_pattern(np.outer(ends, ends), curv)
    # λ_θ = ((1 − ξ) r_e + ξ r_e+1) / r0 per Gauss point is linear in the dofs (no Hessian)
    r0_g = [(1.0 - s) * r0[:-1] + s * r0[1:] for s in xi]
    shapes = [(1.0 - s, s) for s in xi]
    cross = _vector_sum(
        *[[h_st[g] * a / r0_g[g], None, h_st[g] * b / r0_g[g], None] for g, (a, b) in enumerate(shapes)]
    )
    hoop = [h_tt[g] / r0_g[g] ** 2 for g in range(2)]
    hoop_block = [
        [_sum(*[hoop[g] * shapes[g][i] * shapes[g][j] for g in range(2)]) for j in range(2)] for i in range(2)
    ]
    hess_hoop = [
        [hoop_block[i // 2][j // 2] if i % 2 == 0 and j % 2 == 0 else None for j in range(4)] for i in range(4)
    ]
    # Volume V_e = π Δz (r_a² + r_a r_b + r_b²)/3 times the gas pressure slope dΠ/dV
    ra, rb = r[:-1], r[1:]
    dz, sa, sb = z[1:] - z[:-1], 2.0 * ra + rb, ra + 2.0 * rb
    c = d_gas * jnp.pi / 3.0
    volume = [
        [2.0 * c * dz, -c * sa, c * dz, c * sa],
        [-c * sa, None, -c * sb, None],
        [c * dz, -c * sb, 2.0 * c * dz, c * sb],
        [c * sa, None, c * sb, None],
    ]
    return _symmetrized(
        _matrix_sum(
            _matrix_scale(h_ss[0] + h_ss[1], _outer(grad_s, grad_s)),
            _symmetric_outer(grad_s, cross),
            hess_hoop,
            _matrix_scale((g_s[0] + g_s[1]) / seg0, hess_s),
            volume,
        )
    )


# --- hinge Hessians as arrays of 6×6 blocks (smaller programs than entry-wise: docs/axisym.md) ---


def _block_outer(u, v):
    return u[..., :, None] * v[..., None, :]


def _block_pair_pattern(block, weights):
    """Node-pattern expansion: (…, 2, 2) block ⊗ (k, k) node weights → (…, 2k, 2k)."""
    k = weights.shape[0]
    out = jnp.asarray(weights)[:, None, :, None] * block[..., None, :, None, :]
    return out.reshape(block.shape[:-2] + (2 * k, 2 * k))


def _block_node_pattern(vec, weights):
    """(…, 2) vector ⊗ (k,) node weights → (…, 2k)."""
    return (jnp.asarray(weights)[:, None] * vec[..., None, :]).reshape(vec.shape[:-1] + (2 * len(weights),))


def _block_direction_derivatives(t):
    """Gradient (…, 2) and Hessian (…, 2, 2) of the direction angle atan2(t_z, t_r) of t [1/m, 1/m²].

    ∇θ = t⊥/|t|², ∇²θ = J/|t|² − 2 t⊥ tᵀ/|t|⁴ (t⊥ = J t, J the quarter turn); symmetric in 2D.
    """
    sq = jnp.sum(t**2, axis=-1)
    perp = jnp.stack([-t[..., 1], t[..., 0]], axis=-1)
    quarter_turn = jnp.asarray([[0.0, -1.0], [1.0, 0.0]])
    hess = quarter_turn / sq[..., None, None] - 2.0 * _block_outer(perp, t) / (sq**2)[..., None, None]
    return perp / sq[..., None], hess


def _block_length_derivatives(t):
    """``_length_derivatives`` of t (…, 2) as arrays: |t| [m], t̂ (…, 2), (I − t̂t̂ᵀ)/|t| (…, 2, 2) [1/m]."""
    length, unit, curv = _length_derivatives(t[..., 0], t[..., 1])
    return length, jnp.stack(unit, -1), jnp.stack([jnp.stack(row, -1) for row in curv], -2)


def _hinge_measures(xe):
    """(M-independent) hinge geometry of the ghosted nodes: the turning angle φ [-], dual length
    [m], sin/cos of the bisector angle ψ [-], and their local 6-dof gradients and Hessians."""
    t1, t2 = xe[1:-1] - xe[:-2], xe[2:] - xe[1:-1]
    q1, hq1 = _block_direction_derivatives(t1)
    q2, hq2 = _block_direction_derivatives(t2)
    len1, u1, c1 = _block_length_derivatives(t1)
    len2, u2, c2 = _block_length_derivatives(t2)
    first, second = np.array([-1.0, 1.0, 0.0]), np.array([0.0, -1.0, 1.0])
    grad_a1, grad_a2 = _block_node_pattern(q1, first), _block_node_pattern(q2, second)
    hess_a1 = _block_pair_pattern(hq1, np.outer(first, first))
    hess_a2 = _block_pair_pattern(hq2, np.outer(second, second))
    turning = jnp.arctan2(t1[:, 0] * t2[:, 1] - t1[:, 1] * t2[:, 0], jnp.sum(t1 * t2, axis=-1))
    dual = 0.5 * (len1 + len2)
    grad_dual = 0.5 * (_block_node_pattern(u1, first) + _block_node_pattern(u2, second))
    hess_dual = 0.5 * (
        _block_pair_pattern(c1, np.outer(first, first)) + _block_pair_pattern(c2, np.outer(second, second))
    )
    bisector = jnp.arctan2(t1[:, 1], t1[:, 0]) + 0.5 * turning
    return dict(
        turning=turning,
        grad_turning=grad_a2 - grad_a1,
        hess_turning=hess_a2 - hess_a1,
        dual=dual,
        grad_dual=grad_dual,
        hess_dual=hess_dual,
        sin=jnp.sin(bisector),
        cos=jnp.cos(bisector),
        grad_bisector=0.5 * (grad_a1 + grad_a2),
        hess_bisector=0.5 * (hess_a1 + hess_a2),
    )


def _bending_blocks(x, x0, p: Params):
    """Hinge 6×6 Hessians (n, 6, 6) [N/m] of the bending energy, ghosted dofs (i−1, i, i+1)."""
    h = _hinge_measures(_ghosted(x))
    h0 = _hinge_measures(_ghosted(x0))
    dual0 = h0["dual"]
    m_ss = (h["turning"] * h["dual"] / dual0 - h0["turning"]) / dual0
    grad_ss = (h["dual"][:, None] * h["grad_turning"] + h["turning"][:, None] * h["grad_dual"]) / (dual0**2)[:, None]
    cross = _block_outer(h["grad_turning"], h["grad_dual"])
    hess_ss = (
        cross
        + jnp.swapaxes(cross, -1, -2)
        + h["dual"][:, None, None] * h["hess_turning"]
        + h["turning"][:, None, None] * h["hess_dual"]
    ) / (dual0**2)[:, None, None]
    # M_θθ = (r sin ψ − r0 sin ψ0)/r0² with r the hinge node's radius (local dof 2)
    r, r0 = x[:, 0], x0[:, 0]
    safe_r0 = jnp.where(r0 > 0.0, r0, 1.0)
    e_r = jnp.zeros(6).at[2].set(1.0)
    grad_sin = h["cos"][:, None] * h["grad_bisector"]
    hess_sin = (
        -h["sin"][:, None, None] * _block_outer(h["grad_bisector"], h["grad_bisector"])
        + h["cos"][:, None, None] * h["hess_bisector"]
    )
    m_tt = (r * h["sin"] - r0 * h0["sin"]) / safe_r0**2
    grad_tt = (h["sin"][:, None] * e_r + r[:, None] * grad_sin) / (safe_r0**2)[:, None]
    hess_tt = (_block_outer(e_r, grad_sin) + _block_outer(grad_sin, e_r) + r[:, None, None] * hess_sin) / (safe_r0**2)[
        :, None, None
    ]
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
    cross = _block_outer(grad_ss, grad_tt)
    return (
        h_aa[:, None, None] * _block_outer(grad_ss, grad_ss)
        + h_ab[:, None, None] * (cross + jnp.swapaxes(cross, -1, -2))
        + h_bb[:, None, None] * _block_outer(grad_tt, grad_tt)
        + g_ss[:, None, None] * hess_ss
        + g_tt[:, None, None] * hess_tt
    )


def _penalty_derivatives(gaps, stiffness):
    """(∂P/∂g [N], ∂²P/∂g² [N/m]) of the contact penalty per node (shared physics law)."""
    grad = jax.grad(lambda g: jnp.sum(penalty_energy(g, stiffness)))
    return jax.jvp(grad, (gaps,), (jnp.ones_like(gaps),))


def _friction_stiffness(x, p: Params):
    """∂²D/∂r_i² [N/m] of the ground friction per node: D is a sum of per-node functions of the
    radii alone, so its Hessian is this diagonal (2 μ λ̂/ε while sticking, 0 once sliding)."""

    def energy_of_radii(r):
        return ground_friction_energy(jnp.stack([r, x[:, 1]], -1), p)

    return jax.jvp(jax.grad(energy_of_radii), (x[:, 0],), (jnp.ones_like(x[:, 0]),))[1]


# --- assembly into node bands and 4×4 blocks ---------------------------------------------------


def _pad(a, before, after):
    return None if a is None else jnp.pad(a, (before, after))


def _node_block(matrix, i, j):
    """The 2×2 block of local nodes (i, j) of a local Hessian."""
    return [[matrix[2 * i + a][2 * j + b] for b in range(2)] for a in range(2)]


def _band_sum(blocks_and_offsets, length):
    """Σ 2×2 blocks of (k,) entries placed at ``offset`` in bands of ``length`` (zero-padded)."""
    return [
        [
            _sum(
                *[
                    _pad(block[a][b], offset, length - offset - block[a][b].shape[0])
                    for block, offset in blocks_and_offsets
                ]
            )
            for b in range(2)
        ]
        for a in range(2)
    ]


def _fold_ghosts(d0, d1, d2):
    """Node bands over the ghosted nodes (n + 2) → the real nodes' (n, n − 1, n − 2 bands).

    The ghosts are mirror images P x (P = diag(−1, 1)) of the pole neighbours x_1 and x_n−2, so
    their rows and columns fold onto those nodes: H_eff = Tᵀ H T. Bands are 2×2 nested lists.
    """
    sign = (-1.0, 1.0)

    def at(band, k):
        return [[band[a][b][k] for b in range(2)] for a in range(2)]

    lo, hi, d1_lo, d1_hi, d2_lo, d2_hi = at(d0, 0), at(d0, -1), at(d1, 0), at(d1, -1), at(d2, 0), at(d2, -1)
    # bottom ghost g = P x_1: couples to itself, node 0 (d1_lo = H(g, x_0)) and node 1 (d2_lo = H(g, x_1))
    add_d0_lo = [
        [sign[a] * sign[b] * lo[a][b] + sign[a] * d2_lo[a][b] + d2_lo[b][a] * sign[b] for b in range(2)]
        for a in range(2)
    ]
    add_d1_lo = [[d1_lo[b][a] * sign[b] for b in range(2)] for a in range(2)]
    # top ghost g = P x_n−2: d1_hi = H(x_n−1, g), d2_hi = H(x_n−2, g)
    add_d0_hi = [
        [sign[a] * sign[b] * hi[a][b] + d2_hi[a][b] * sign[b] + sign[a] * d2_hi[b][a] for b in range(2)]
        for a in range(2)
    ]
    add_d1_hi = [[sign[a] * d1_hi[b][a] for b in range(2)] for a in range(2)]
    inner0 = [[d0[a][b][1:-1] for b in range(2)] for a in range(2)]
    inner1 = [[d1[a][b][1:-1] for b in range(2)] for a in range(2)]
    n = inner0[0][0].shape[0]
    one_hot = lambda k, m: jnp.asarray(np.eye(m)[k])  # noqa: E731
    d0 = [
        [inner0[a][b] + add_d0_lo[a][b] * one_hot(1, n) + add_d0_hi[a][b] * one_hot(n - 2, n) for b in range(2)]
        for a in range(2)
    ]
    d1 = [
        [inner1[a][b] + add_d1_lo[a][b] * one_hot(0, n - 1) + add_d1_hi[a][b] * one_hot(n - 2, n - 1) for b in range(2)]
        for a in range(2)
    ]
    d2 = [[d2[a][b][1:-1] for b in range(2)] for a in range(2)]
    return d0, d1, d2


def _blocks_from_bands(d0, d1, d2):
    """Node bands (2×2 blocks: node i with i, i+1, i+2) → entries of the 4×4 diagonal and upper
    blocks (block k: nodes 2k, 2k + 1)."""
    even = lambda a: a[0::2]  # noqa: E731
    odd = lambda a: a[1::2]  # noqa: E731
    zero = jnp.zeros_like(even(d2[0][0]))
    diag = [[even(d0[a][0]), even(d0[a][1]), even(d1[a][0]), even(d1[a][1])] for a in range(2)] + [
        [even(d1[0][a]), even(d1[1][a]), odd(d0[a][0]), odd(d0[a][1])] for a in range(2)
    ]
    upper = [[even(d2[a][0]), even(d2[a][1]), zero, zero] for a in range(2)] + [
        [odd(d1[a][0]), odd(d1[a][1]), odd(d2[a][0]), odd(d2[a][1])] for a in range(2)
    ]
    return diag, upper


def hessian_at(y, cfg: Config, p: Params) -> StructuredHessian:
    """Structured Hessian [N/m] of the total energy at y [m] (exact; fixed dofs → identity)."""
    n = cfg.n_nodes
    x, zc = split(y, n)
    x0 = rest_nodes(cfg, p.rest_radius)
    volume = enclosed_volume(x)
    d_gas = jax.grad(gas_energy)(volume, cfg, p)
    d2_gas = jax.grad(jax.grad(gas_energy))(volume, cfg, p)
    grad_volume = jax.grad(lambda xx: enclosed_volume(xx))(x).ravel()

    element = _membrane_and_gas_entries(x, x0, cfg, p, d_gas)
    d0 = _band_sum([(_node_block(element, 0, 0), 0), (_node_block(element, 1, 1), 1)], n)
    d1 = _node_block(element, 0, 1)
    k_node = p.contact_stiffness * node_rest_areas(x0)
    arrow = [jnp.zeros(n), jnp.zeros(n)]
    corner = jnp.zeros(())
    if cfg.ground:
        _, stiff = _penalty_derivatives(ground_gaps(x, p), k_node)
        d0[1][1] = d0[1][1] + stiff
        d0[0][0] = d0[0][0] + _friction_stiffness(x, p)
    if cfg.loading == "sphere":
        force, stiff = _penalty_derivatives(indenter_gaps(x, zc, p), k_node)
        _, normal, curv = _length_derivatives(x[:, 0], x[:, 1] - zc)
        node = [[stiff * normal[a] * normal[b] + force * curv[a][b] for b in range(2)] for a in range(2)]
        d0 = [[d0[a][b] + node[a][b] for b in range(2)] for a in range(2)]
        arrow = [-node[0][1], -node[1][1]]  # ∂(x − c)/∂z_c = (0, −1)
        corner = jnp.sum(node[1][1])

    # computed once, as in ``_computed_once``: each band slice below would recompute the blocks
    blocks = jnp.tensordot(_bending_blocks(x, x0, p), jnp.eye(6), axes=1)
    hinge = [[blocks[:, i, j] for j in range(6)] for i in range(6)]
    # ghosted node bands: hinge i couples ghosted nodes i, i + 1, i + 2
    hinge_d0 = _band_sum(
        [(_node_block(hinge, 0, 0), 0), (_node_block(hinge, 1, 1), 1), (_node_block(hinge, 2, 2), 2)], n + 2
    )
    hinge_d1 = _band_sum([(_node_block(hinge, 0, 1), 0), (_node_block(hinge, 1, 2), 1)], n + 1)
    b0, b1, b2 = _fold_ghosts(hinge_d0, hinge_d1, _node_block(hinge, 0, 2))
    diag, upper = _blocks_from_bands(_matrix_sum(d0, b0), _matrix_sum(d1, b1), b2)

    mask = fixed_mask(cfg, p)
    free = (~mask).astype(y.dtype)
    free_entry = [(~mask[i:-1:4]).astype(y.dtype) for i in range(4)]  # (m,) per dof of a block
    diag = tuple(
        tuple(
            diag[i][j] * (free_entry[i] * free_entry[j]) + (1.0 - free_entry[i])
            if i == j
            else diag[i][j] * (free_entry[i] * free_entry[j])
            for j in range(4)
        )
        for i in range(4)
    )
    upper = tuple(tuple(upper[i][j] * (free_entry[i][:-1] * free_entry[j][1:]) for j in range(4)) for i in range(4))
    arrow = jnp.stack(arrow, -1).ravel() * free[:-1] * free[-1]
    corner = jnp.where(mask[-1], 1.0, corner)
    return StructuredHessian(diag, upper, arrow, corner, d2_gas, grad_volume * free[:-1])


__all__ = ["hessian_at"]
