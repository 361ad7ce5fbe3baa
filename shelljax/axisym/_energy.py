"""Total potential energy of an axisymmetric shell of revolution (meridian elements).

Unknowns ``y`` (2n + 1,): node coordinates (r_0, z_0, …, r_{n−1}, z_{n−1}) [m] followed by the
indenter-centre height z_c [m]. The energy [J] is

  membrane (2-point Gauss per linear element, principal stretches λ_s = L/L0, λ_θ = r/r0;
  compressible Neo-Hookean, Gent-stiffened by the traced ``stiffening``, 0 by default)
+ bending (per node, discrete meridional curvature from the turning angle of the polygon and
  hoop curvature sin ψ / r; poles use the isotropy M_θθ = M_ss)
+ gas (prescribed gauge pressure, sealed isothermal ideal gas, or sealed polytropic gas of
  traced exponent κ; V = Σ ∫ π r² dz, exact for the polygon of revolution)
+ rigid contact (indenter sphere on top and ground plane below: area-weighted penalty)
+ self-weight q ∫ z dA₀ with the ground (traced ``areal_weight`` q [Pa], 0 by default)
+ ground friction Σ_i μ λ̂_i f₀(|r_i − r̂_i|) (smoothed lagged Coulomb, traced μ, 0 by default;
  ``ground_friction_energy``)
+ load potential F·z_c (force control: the indenter is a dof loaded by F [N] downwards).

Material laws, gas and contact potentials are the shared ones in ``shelljax.physics``; the only
axisymmetric-specific law here is the wrinkling relaxation of the hoop direction (compressive hoop
stress saturating at a buckling-limited value, ``membrane_density``).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from .._errors import InvalidInputError
from ..physics import (
    AbstractGasLaw,
    IsothermalGas,
    PolytropicGas,
    PrescribedGas,
    bending_density_invariants,
    bending_stiffness,
    gent_membrane_invariants,
    lame_constants_2d,
    friction_energy,
    penalty_energy,
    plane_gap,
    prescribed_pressure_energy,
    self_weight_energy,
    sphere_gap,
)
from ._geometry import gauss_points_2

# the compiled program's gas laws: the adiabatic one (and every other κ) is the polytropic one,
# whose κ is traced (``Params.gas_exponent``)
COMPILED_GAS_LAWS = (PrescribedGas, IsothermalGas, PolytropicGas)
RELAX_WIDTH = 1e-3  # [-] smoothing width of the wrinkling switch, in units of stretch²
# c_w [-]: hoop compression a wrinkled wall carries, in classical buckling resultants, calibrated
# on one 3D curve (docs/axisym.md, *Post-onset F–w(0)*).
WRINKLED_HOOP_CAPACITY = 2.0
COLLAPSE_HOOP_STRETCH = 0.5  # [-] below it the relaxed hoop direction stiffens again (a barrier)
LOADINGS = ("none", "sphere", "point")


class Config(eqx.Module):
    """Static (compile-time) description of one axisymmetric problem.

    ``theta``: rest polar angles of the nodes [rad] (tuple, even count); ``gas``: a
    ``physics.PrescribedGas``, ``IsothermalGas`` or ``PolytropicGas`` (whose κ is the traced
    ``Params.gas_exponent``: the Config's own is not read); ``loading``: "none",
    "sphere" (rigid spherical indenter, force control) or
    "point" (point force on the top pole); ``ground``: rigid plane under the bottom pole;
    ``pin_bottom``: fix z of the bottom pole (removes the vertical rigid mode when nothing
    else does); ``relax``: relaxation of compressive hoop stress (wrinkling), which saturates at
    ``hoop_capacity`` [-] times the classical buckling resultant (0: tension field).
    """

    theta: tuple = eqx.field(static=True)
    gas: AbstractGasLaw = eqx.field(static=True, default=PrescribedGas())
    loading: str = eqx.field(static=True, default="none")
    ground: bool = eqx.field(static=True, default=False)
    pin_bottom: bool = eqx.field(static=True, default=True)
    relax: bool = eqx.field(static=True, default=False)
    hoop_capacity: float = eqx.field(static=True, default=0.0)

    def __check_init__(self):
        if type(self.gas) not in COMPILED_GAS_LAWS:
            raise InvalidInputError(
                f"Config: gas = {self.gas!r} is no compiled gas law. "
                f"Fix: use one of {', '.join(law.__name__ for law in COMPILED_GAS_LAWS)}"
            )

    @property
    def n_nodes(self) -> int:
        return len(self.theta)


class Params(eqx.Module):
    """Traced scalars of one solve (all SI).

    young_modulus E [Pa], thickness h [m], poisson_ratio ν [-], rest_radius R0 [m],
    gauge_pressure P_g [Pa] (prescribed value, or sealed gas gauge pressure at reference_volume),
    reference_volume V_ref [m³] (sealed gas only), force F [N], indenter_radius a [m],
    ground_z [m] (height of the ground plane), contact_stiffness k_c [N/m³] (contact pressure
    per unit penetration: penetration = contact pressure / k_c), bending_scale [-] (multiplies
    the bending energy; 1 for physical shells, < 1 only to emulate large τ in shallow-shell checks),
    gas_volume_ratio [-] (sealed gas volume over V_ref),
    gas_exponent κ [-] (a ``PolytropicGas`` only: p V^κ constant; 0 prescribed, 1 isothermal,
    1.4 adiabatic), stiffening s [-] (Gent stiffening 1/J_m of the membrane; 0: Neo-Hookean),
    areal_weight q [Pa] (self-weight ρ h g per unit rest area along −z, with the ground only;
    0: no gravity); ground friction (``ground_friction_energy``, with the ground only):
    friction_coefficient μ [-] (0: frictionless), friction_anchor r̂ (n,) [m] (lagged node radii,
    the slip origin), friction_normal_force λ̂ (n,) [N] (lagged ground contact force per node) and
    friction_slip_tolerance ε [m] > 0 (slip below which a node sticks); ``inflating``: the solve is
    the inflation, in the indentation's configuration (one Newton program for both): the gas is held
    at its gauge pressure, the wall is not relaxed, and z of the bottom pole and z_c are fixed
    (``fixed_mask``); its parameters switch the contacts, load and weight off.
    """

    young_modulus: Float[Array, ""]
    thickness: Float[Array, ""]
    poisson_ratio: Float[Array, ""]
    rest_radius: Float[Array, ""]
    gauge_pressure: Float[Array, ""]
    reference_volume: Float[Array, ""]
    force: Float[Array, ""]
    indenter_radius: Float[Array, ""]
    ground_z: Float[Array, ""]
    contact_stiffness: Float[Array, ""]
    bending_scale: Float[Array, ""]
    # the per-curve effects default to today's physics (CurvePhysics carries them in the curve API)
    gas_volume_ratio: Float[Array, ""] = 1.0
    gas_exponent: Float[Array, ""] = 1.0
    stiffening: Float[Array, ""] = 0.0
    areal_weight: Float[Array, ""] = 0.0
    friction_coefficient: Float[Array, ""] = 0.0
    friction_anchor: Float[Array, "n"] | float = 0.0
    friction_normal_force: Float[Array, "n"] | float = 0.0
    friction_slip_tolerance: Float[Array, ""] = 1e-6
    inflating: Bool[Array, ""] | bool = False


def rest_nodes(cfg: Config, rest_radius) -> Float[Array, "n 2"]:
    """Rest node coordinates (r0, z0) [m] on the sphere of radius R0 [m], bottom pole first."""
    th = np.asarray(cfg.theta)
    unit = np.stack([np.sin(th), -np.cos(th)], axis=-1)
    unit[0, 0] = unit[-1, 0] = 0.0
    return rest_radius * jnp.asarray(unit)


def split(y, n):
    """(node coordinates (n, 2) [m], indenter height z_c [m]) from the flat unknown vector."""
    return y[: 2 * n].reshape(n, 2), y[2 * n]


def wrinkled_hoop_resultant(p: Params, hoop_capacity: float):
    """Hoop compression [N/m] (per rest meridian length) a wrinkled wall carries.

    ``hoop_capacity`` c_w [-] times the classical buckling resultant of a spherical shell,
    E h² / (R0 √(3(1−ν²))) = 2 √(B·E h) / R0: wrinkles on a wall curved along their crests sit on
    an effective foundation (curvature- and tension-induced stiffness, Paulsen et al. 2016), so the
    compressive hoop stress saturates at 2 √(B K) instead of vanishing (c_w = 0: tension field).
    The scale is h/R0 × E h, so the exact similarity of the forward model (docs/axisym.md) holds.
    """
    bending = bending_stiffness(p.young_modulus, p.thickness, p.poisson_ratio)
    return hoop_capacity * 2.0 * jnp.sqrt(bending * p.young_modulus * p.thickness) / p.rest_radius


def wrinkling_hoop_stretch_sq(lam_s_sq, hoop_resultant, p: Params):
    """Hoop stretch² λ_c² [-] at which the Neo-Hookean nominal hoop stress ∂W/∂λ_θ equals −N_c.

    From ∂W/∂λ_θ = h[β(λ_θ − 1/λ_θ) + α/2 (λ_s² λ_θ − 1/λ_θ)] = −N_c, a quadratic in λ_θ; with
    N_c = 0 the natural (stress-free) hoop stretch of tension-field theory. It stays the
    Neo-Hookean closed form under Gent stiffening (``Params.stiffening`` s ≠ 0), whose hoop stress
    is the shear part's times 1/(1 − s I): the switch to the wrinkled branch then sits where the
    Gent hoop stress is −N_c up to that factor, O(s I) off with I ≈ 2–4 ε² for strains ε (≤ 1e-3
    for s = 0.1 at 5 % strain). The relaxed energy stays smooth; only the switch point moves.
    """
    alpha, beta = lame_constants_2d(p.young_modulus, p.poisson_ratio)
    a = p.thickness * (beta + 0.5 * alpha * lam_s_sq)
    c = p.thickness * (beta + 0.5 * alpha)
    lam_c = (-hoop_resultant + jnp.sqrt(hoop_resultant**2 + 4.0 * a * c)) / (2.0 * a)
    return lam_c**2


def membrane_terms(x, x0, p: Params, relax: bool):
    """Per-Gauss-point (λ_s, λ_θ, rest area weight [m²]) of the linear meridian elements."""
    xi, wts = gauss_points_2()
    seg = x[1:] - x[:-1]
    seg0 = x0[1:] - x0[:-1]
    length = jnp.sqrt(jnp.sum(seg**2, axis=-1))
    length0 = jnp.sqrt(jnp.sum(seg0**2, axis=-1))
    lam_s = length / length0
    r_g = (1.0 - xi)[:, None] * x[None, :-1, 0] + xi[:, None] * x[None, 1:, 0]
    r0_g = (1.0 - xi)[:, None] * x0[None, :-1, 0] + xi[:, None] * x0[None, 1:, 0]
    lam_t = r_g / r0_g
    area0 = jnp.asarray(wts)[:, None] * 2.0 * jnp.pi * r0_g * length0[None, :]
    return jnp.broadcast_to(lam_s, lam_t.shape), lam_t, area0


def membrane_density(lam_s, lam_t, p: Params, relax: bool, hoop_capacity: float = 0.0):
    """Neo-Hookean membrane energy per rest area [J/m²], Gent-stiffened by ``p.stiffening`` (the
    shared ``physics.gent_membrane_invariants``; 0: Neo-Hookean); hoop-relaxed if asked.

    Relaxed: where the hoop stretch falls below λ_c (``wrinkling_hoop_stretch_sq``) the wall
    wrinkles and the energy continues linearly, W(λ_s, λ_c) + N_c (λ_c − λ_θ): a constant
    compressive hoop force N_c (``wrinkled_hoop_resultant``; 0 is tension-field theory).
    """
    lam_s_sq = lam_s**2
    lam_t_sq = lam_t**2
    wrinkle_work = 0.0
    if relax:
        hoop_resultant = wrinkled_hoop_resultant(p, hoop_capacity)
        star = wrinkling_hoop_stretch_sq(lam_s_sq, hoop_resultant, p)
        # Smooth maximum (width RELAX_WIDTH in stretch²): the plain max has a jump in the
        # tangent stiffness that makes Newton cycle between slack and taut states.
        relaxed = 0.5 * (lam_t_sq + star + jnp.sqrt((lam_t_sq - star) ** 2 + RELAX_WIDTH**2))
        # Only the indented (upper) half is relaxed: there the hoop compression is the
        # wrinkling of the paper; in the ground-contact disc relaxation lets the pole lift
        # into a micrometre blister that makes Newton cycle on the contact kink.
        # The inflating wall is taut: it is never relaxed (the smooth maximum would move it).
        n_el = lam_t_sq.shape[-1]
        upper = (jnp.arange(n_el) >= n_el // 2) & ~jnp.asarray(p.inflating, bool)
        wrinkle_work = jnp.where(upper, hoop_resultant * (jnp.sqrt(relaxed) - jnp.abs(lam_t)), 0.0)
        # Relaxation removes the log barrier of det C against λ_θ → 0, so a Newton step could park
        # a node on the axis: restore a barrier far below any physical state.
        _, beta = lame_constants_2d(p.young_modulus, p.poisson_ratio)
        collapse = jnp.minimum(jnp.log(lam_t_sq / COLLAPSE_HOOP_STRETCH**2), 0.0) ** 2
        wrinkle_work = wrinkle_work + jnp.where(upper, p.thickness * beta * collapse, 0.0)
        lam_t_sq = jnp.where(upper, relaxed, lam_t_sq)
    dens = (
        gent_membrane_invariants(
            lam_s_sq + lam_t_sq, lam_s_sq * lam_t_sq, p.thickness, p.young_modulus, p.poisson_ratio, p.stiffening
        )
        + wrinkle_work
    )
    # λ_θ = r / r0 < 0 means a node crossed the axis (an inverted, folded meridian); det C
    # only sees λ_θ², so forbid it explicitly: the line search rejects infinite energies.
    return jnp.where(lam_t > 0.0, dens, jnp.inf)


def _ghosted(x):
    # Mirror images of the pole neighbours across the axis make the poles ordinary hinge nodes.
    lo = jnp.stack([-x[1, 0], x[1, 1]])[None]
    hi = jnp.stack([-x[-2, 0], x[-2, 1]])[None]
    return jnp.concatenate([lo, x, hi], axis=0)


def _hinges(x):
    xe = _ghosted(x)
    t = xe[1:] - xe[:-1]
    seg_len = jnp.sqrt(jnp.sum(t**2, axis=-1))
    cross = t[:-1, 0] * t[1:, 1] - t[:-1, 1] * t[1:, 0]
    dot = jnp.sum(t[:-1] * t[1:], axis=-1)
    turning = jnp.arctan2(cross, dot)
    dual = 0.5 * (seg_len[:-1] + seg_len[1:])
    u = t[:-1] / seg_len[:-1, None] + t[1:] / seg_len[1:, None]
    sin_psi = u[:, 1] / jnp.sqrt(jnp.sum(u**2, axis=-1))
    return turning, dual, sin_psi


def node_rest_areas(x0):
    """Rest dual area [m²] of each node: 2π r0 × half the adjacent rest lengths; pole disks."""
    seg0 = jnp.sqrt(jnp.sum((x0[1:] - x0[:-1]) ** 2, axis=-1))
    dual0 = 0.5 * (jnp.concatenate([seg0[:1], seg0]) + jnp.concatenate([seg0, seg0[-1:]]))
    area = 2.0 * jnp.pi * x0[:, 0] * dual0
    area = area.at[0].set(jnp.pi * (0.5 * seg0[0]) ** 2)
    return area.at[-1].set(jnp.pi * (0.5 * seg0[-1]) ** 2)


def bending_changes(x, x0):
    """(M_ss, M_θθ) [1/m] per node: M = ā⁻¹(b − b̄) in rest arc-length/angle coordinates.

    M_ss = κ_s λ_s² − κ̄_s, M_θθ = κ_θ λ_θ² − κ̄_θ = (r sin ψ − r0 sin ψ0)/r0² (the libshell
    convention of ``physics.bending_density``); at the poles M_θθ = M_ss by isotropy.
    """
    turning, dual, sin_psi = _hinges(x)
    turning0, dual0, sin_psi0 = _hinges(x0)
    m_ss = (turning * dual / dual0 - turning0) / dual0
    r, r0 = x[:, 0], x0[:, 0]
    safe_r0 = jnp.where(r0 > 0.0, r0, 1.0)
    m_tt = (r * sin_psi - r0 * sin_psi0) / safe_r0**2
    interior = jnp.asarray(np.r_[False, np.ones(x0.shape[0] - 2, bool), False])
    m_tt = jnp.where(interior, m_tt, m_ss)
    return m_ss, m_tt


def bending_energy(x, x0, p: Params):
    """Σ_nodes rest dual area × bending density [J]."""
    m_ss, m_tt = bending_changes(x, x0)
    dens = bending_density_invariants(m_ss + m_tt, m_ss**2 + m_tt**2, p.thickness, p.young_modulus, p.poisson_ratio)
    return p.bending_scale * jnp.sum(node_rest_areas(x0) * dens)


def enclosed_volume(x):
    """Volume [m³] enclosed by the polygon of revolution: Σ π Δz (r_a² + r_a r_b + r_b²)/3."""
    ra, rb = x[:-1, 0], x[1:, 0]
    dz = x[1:, 1] - x[:-1, 1]
    return jnp.pi * jnp.sum(dz * (ra**2 + ra * rb + rb**2)) / 3.0


def gas_energy(volume, cfg: Config, p: Params):
    """Gas potential [J] of the enclosed volume [m³] (shared ``physics`` gas laws)."""
    if not cfg.gas.sealed:
        return cfg.gas.energy(volume, None, p.gauge_pressure)
    # The gas fills ratio·V_ref and loses exactly the volume the ball's wall sweeps: ΔV = V − V_ref.
    gas_volume = p.gas_volume_ratio * p.reference_volume
    law = PolytropicGas(p.gas_exponent) if isinstance(cfg.gas, PolytropicGas) else cfg.gas  # κ is traced
    sealed = law.energy(volume - p.reference_volume + gas_volume, gas_volume, p.gauge_pressure)
    # the gas is sealed once the ball is inflated at its gauge pressure
    return jnp.where(p.inflating, prescribed_pressure_energy(volume, p.gauge_pressure), sealed)


def gauge_pressure_at(volume, cfg: Config, p: Params):
    """Gauge pressure [Pa] acting on the wall at enclosed volume [m³]: −dΠ_gas/dV."""
    return -jax.grad(gas_energy)(volume, cfg, p)


def indenter_gaps(x, zc, p: Params):
    """Signed gaps [m] of the nodes to the indenter sphere centred at (0, z_c)."""
    return sphere_gap(x, jnp.stack([jnp.zeros_like(zc), zc]), p.indenter_radius)


def ground_gaps(x, p: Params):
    """Signed gaps [m] of the nodes above the ground plane z = ground_z."""
    origin = jnp.stack([jnp.zeros_like(p.ground_z), p.ground_z])
    return plane_gap(x, origin, jnp.array([0.0, 1.0]))


def rest_zone_areas(cfg: Config, rest_radius) -> Float[Array, " e"]:
    """Rest area [m²] of the sphere zone each element spans, 2π R0² (cos θ_a − cos θ_b).

    They sum to 4π R0² exactly, where the polygon of revolution's frustums fall short by
    O(Δθ²): the wall's weight is that of the object's rest sphere.
    """
    cos = np.cos(np.asarray(cfg.theta))
    return 2.0 * jnp.pi * rest_radius**2 * jnp.asarray(cos[:-1] - cos[1:])


def weight_potential(x, x0, cfg: Config, p: Params):
    """Self-weight potential q ∫ z dA₀ [J] (shared ``physics.self_weight_energy``).

    Each element's zone area (``rest_zone_areas``) is spread over its two Gauss points in
    proportion to their frustum areas, so the load is the consistent one of a linear element.
    """
    xi, wts = gauss_points_2()
    r0_g = (1.0 - xi)[:, None] * x0[None, :-1, 0] + xi[:, None] * x0[None, 1:, 0]
    z_g = (1.0 - xi)[:, None] * x[None, :-1, 1] + xi[:, None] * x[None, 1:, 1]
    share = jnp.asarray(wts)[:, None] * r0_g
    area = rest_zone_areas(cfg, p.rest_radius)[None, :] * share / jnp.sum(share, axis=0)
    return jnp.sum(self_weight_energy(z_g, area, p.areal_weight))


def ground_normal_forces(x, cfg: Config, p: Params) -> Float[Array, " n"]:
    """Ground contact force [N] on each node: k_c × rest dual area × penetration."""
    k_node = p.contact_stiffness * node_rest_areas(rest_nodes(cfg, p.rest_radius))
    return k_node * jnp.maximum(-ground_gaps(x, p), 0.0)


def ground_slip(x, p: Params) -> Float[Array, " n"]:
    """Radial slip u_i = r_i − r̂_i [m] of each node since its lag anchor (the only tangential
    motion on the ground an axisymmetric node has)."""
    return x[:, 0] - p.friction_anchor


def ground_friction_energy(x, p: Params):
    """Smoothed lagged Coulomb friction of the ground, Σ_i μ λ̂_i f₀(|u_i|) [J].

    The shared IPC potential ``physics.friction_energy`` (Li et al. 2020) with the radial slip u_i
    (``ground_slip``) as a one-component tangential slip and the lagged normal forces λ̂_i; its
    force is ≤ μ λ̂_i per node (the Coulomb cone) and a spring 2 μ λ̂_i / ε while |u_i| < ε.
    """
    slip = ground_slip(x, p)[:, None]
    return jnp.sum(friction_energy(slip, p.friction_normal_force, p.friction_coefficient, p.friction_slip_tolerance))


def local_energy(y, cfg: Config, p: Params):
    """All energy terms [J] except the gas: elasticity + contact + self-weight + load potential."""
    n = cfg.n_nodes
    x, zc = split(y, n)
    x0 = rest_nodes(cfg, p.rest_radius)
    lam_s, lam_t, area0 = membrane_terms(x, x0, p, cfg.relax)
    energy = jnp.sum(area0 * membrane_density(lam_s, lam_t, p, cfg.relax, cfg.hoop_capacity))
    energy = energy + bending_energy(x, x0, p)
    k_node = p.contact_stiffness * node_rest_areas(x0)
    if cfg.loading == "sphere":
        energy = energy + jnp.sum(penalty_energy(indenter_gaps(x, zc, p), k_node))
        energy = energy + p.force * zc
    elif cfg.loading == "point":
        energy = energy + p.force * x[-1, 1]
    if cfg.ground:
        energy = energy + jnp.sum(penalty_energy(ground_gaps(x, p), k_node))
        # Gravity only acts where the ground carries it: without a support (the inflation) the
        # weight would be an unbalanced load.
        energy = energy + weight_potential(x, x0, cfg, p)
        # μ = 0 (the default) adds an exact zero: frictionless results are unchanged
        energy = energy + ground_friction_energy(x, p)
    return energy


def total_energy(y, cfg: Config, p: Params):
    """Total potential energy [J] at unknowns y [m]."""
    n = cfg.n_nodes
    x, _ = split(y, n)
    return local_energy(y, cfg, p) + gas_energy(enclosed_volume(x), cfg, p)


def constrained_mask(cfg: Config) -> np.ndarray:
    """Boolean mask (2n + 1,) of fixed unknowns: pole radii, optionally z_0, z_c if unused."""
    n = cfg.n_nodes
    mask = np.zeros(2 * n + 1, bool)
    mask[0] = mask[2 * (n - 1)] = True
    if cfg.pin_bottom:
        mask[1] = True
    if cfg.loading != "sphere":
        mask[-1] = True
    return mask


def fixed_mask(cfg: Config, p: Params) -> Bool[Array, " ny"]:
    """Fixed unknowns of a solve: ``constrained_mask`` and, while ``p.inflating``, z of the bottom
    pole (the vertical rigid mode nothing else removes) and z_c."""
    inflation = np.zeros(2 * cfg.n_nodes + 1, bool)
    inflation[1] = inflation[-1] = True
    return jnp.asarray(constrained_mask(cfg)) | (jnp.asarray(p.inflating, bool) & jnp.asarray(inflation))


def hoop_tension(x, x0, p: Params):
    """Unrelaxed hoop stress resultant N_θ [N/m] per Gauss point (per deformed meridian length).

    N_θ = (1/λ_s) ∂W/∂λ_θ with W the (unrelaxed) membrane energy per rest area; negative =
    compressive hoop stress (where a real shell wrinkles). Returns (N_θ, r at Gauss points [m]).
    """
    lam_s, lam_t, _ = membrane_terms(x, x0, p, False)
    dw = jax.grad(lambda lt, ls: jnp.sum(membrane_density(ls, lt, p, False)))(lam_t, lam_s)
    xi, _ = gauss_points_2()
    r_g = (1.0 - xi)[:, None] * x[None, :-1, 0] + xi[:, None] * x[None, 1:, 0]
    return dw / lam_s, r_g
