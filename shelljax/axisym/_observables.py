"""Observables of an equilibrium state: the curve's measurements and the wrinkle count (SI units).

Observables per force level (all SI; "inflated" = the pressurized state before indentation):

* ``w0`` [m]: local dimple depth, positive — vertical displacement of the top pole relative to
  the equator, w0 = Δz_equator − Δz_top. It is the depth of the dimple below the undisturbed
  (rigidly translated) upper hemisphere, which is what a user measures against the surrounding
  surface; it excludes the rigid sinking into the ground flattening (the paper's −w(0)).
* ``top_drop`` [m]: drop of the top pole from its inflated height (includes the sinking into
  the ground flattening; this is what ``shelljax.shell3d`` calls w0).
* ``travel`` [m]: indenter displacement since first contact (includes the ground flattening).
* ``height`` H [m]: highest point of the deformed ball above the ground.
* ``upper_diameter`` D_u [m]: diameter of the upper circle = the ridge (circle of maximum
  height) around the dimple; 0 while the pole is the highest point.
* ``contact_diameter`` D_l [m]: diameter of the ground contact disc, from the ground reaction
  and the gas pressure, D_l = 2 √(F_ground / (π P)): the flat disc carries the gas pressure
  and the membrane leaves the ground tangentially, so this equals the geometric disc while
  being smooth in the parameters (with a self-weight q [Pa] the disc carries P + q, and
  D_l = 2 √(F_ground / (π (P + q)))). ``contact_diameter_mesh`` [m] is the geometric edge (ground
  gap sign change, linear interpolation; resolution-limited by the local element size).
* ``sunken_depth`` d [m]: depth of the sunken region, ridge height − top-pole height (≥ 0).
* ``pressure`` [Pa], ``volume`` [m³]: gauge pressure and enclosed volume.
* ``ground_reaction`` [N]: total ground contact force (global balance: equals F, plus the
  wall's weight q · 4π R0² with a self-weight q = ``CurvePhysics.areal_weight``).
* ``wall_gap`` [m]: height of the top pole above the bottom pole (mid-surface to mid-surface).
  The indenter pushes the upper wall onto the lower one when it falls below the thickness h;
  self-contact is not modelled, so past that the state is not a ball's (the top passes through
  the bottom wall onto the ground) and :mod:`._api` reports the level as not converged.

Wrinkle count (documented local model). Where the (unrelaxed) hoop stress of the axisymmetric
indented state is compressive, a real shell wrinkles radially. The wrinkle wavelength is set by bending against the curvature-induced
elastic foundation of the shell, K = E h / R² [Pa/m] (Cerda & Mahadevan 2003; Vella et al. 2011):
a compressed strip on a foundation buckles at λ = 2π (B / K)^{1/4} = 2π ℓ_w with
ℓ_w = (B R² / (E h))^{1/4} [m]. Counting wavelengths around the mid-circle of the compressive
annulus r_w = (r_in + r_out)/2 [m] gives the continuous count

    n = 2π r_w / λ = r_w / ℓ_w,

which is differentiable through the implicit derivative of the state (r_in, r_out are linear
interpolations of the sign changes of N_θ). Because r_w ≈ l_p · O(1) in the membrane regime,
n ≈ c τ^{1/2}; Vella et al. 2011 give c ≈ 1.33 (``physics.scaling_wrinkle_count``), compared in
docs/axisym.md.
Limitations: this is a local (WKB-type) wavelength estimate, not a Fourier-mode bifurcation
analysis of the full state; radial tension and the dimple's own curvature are neglected.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from ..physics import bending_stiffness
from ._energy import (
    Config,
    Params,
    enclosed_volume,
    gauge_pressure_at,
    ground_gaps,
    hoop_tension,
    node_rest_areas,
    rest_nodes,
    split,
)


def _ridge(x: Float[Array, "n 2"]) -> tuple[Float[Array, ""], Float[Array, ""]]:
    # Highest point of the deformed meridian: parabola through the top node and its neighbours
    # (continuous in the nodal coordinates, unlike a plain argmax).
    z = x[:, 1]
    n = z.shape[0]
    i = jnp.clip(jnp.argmax(z), 1, n - 2)
    za, zb, zc = z[i - 1], z[i], z[i + 1]
    curv = za - 2.0 * zb + zc
    safe_curv = jnp.where(curv < 0, curv, -1.0)
    s = jnp.where(curv < 0.0, jnp.clip(0.5 * (za - zc) / safe_curv, -1, 1), 0.0)
    z_max = zb + 0.5 * s * (zc - za) + 0.5 * s**2 * curv
    r_a, r_b, r_c = x[i - 1, 0], x[i, 0], x[i + 1, 0]
    r_max = r_b + 0.5 * s * (r_c - r_a) + 0.5 * s**2 * (r_a - 2.0 * r_b + r_c)
    top_is_max = jnp.argmax(z) == n - 1
    z_max = jnp.where(top_is_max, z[-1], jnp.maximum(z_max, z[-1]))
    r_max = jnp.where(top_is_max, 0.0, r_max)
    return z_max, r_max


def _contact_radius(x: Float[Array, "n 2"], gaps: Float[Array, " n"]) -> Float[Array, ""]:
    # Ground contact disc: outermost penetrating node of the lower half, edge interpolated to
    # the gap's sign change (the relaxed contact zone may lift slightly at the pole).
    n = gaps.shape[0]
    lower = jnp.arange(n) < n // 2
    inside = (gaps < 0.0) & lower
    j = jnp.clip(jnp.max(jnp.where(inside, jnp.arange(n), -1)), 0, n - 2)
    g0, g1 = gaps[j], gaps[j + 1]
    frac = jnp.clip(g0 / jnp.where(g0 - g1 != 0, g0 - g1, 1.0), 0.0, 1.0)
    r_edge = x[j, 0] + frac * (x[j + 1, 0] - x[j, 0])
    return jnp.where(jnp.any(inside), r_edge, 0.0)


def compressive_annulus(
    x: Float[Array, "n 2"], n_theta: Float[Array, "2 e"], r_gauss: Float[Array, "2 e"]
) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """(r_in, r_out) [m] of the compressive-hoop annulus in the upper half (0, 0 if none).

    Edges are linear interpolations of the sign changes of the unrelaxed hoop tension
    N_θ [N/m] between Gauss points, so both are continuous in the state.
    """
    nt = n_theta.T.reshape(-1)
    rg = r_gauss.T.reshape(-1)
    k = nt.shape[0]
    upper = jnp.arange(k) >= k // 2
    comp = (nt < 0.0) & upper
    any_comp = jnp.any(comp)
    idx = jnp.arange(k)
    # outer edge: first compressive point from the equator side; inner: last one (towards pole)
    i_out = jnp.clip(jnp.min(jnp.where(comp, idx, k - 1)), 1, k - 1)
    i_in = jnp.clip(jnp.max(jnp.where(comp, idx, 0)), 0, k - 2)

    def cross(i, j):
        f0, f1 = nt[i], nt[j]
        frac = jnp.clip(f0 / jnp.where(f0 - f1 != 0, f0 - f1, 1.0), 0.0, 1.0)
        return rg[i] + frac * (rg[j] - rg[i])

    r_out = cross(i_out - 1, i_out)
    r_in = jnp.where(i_in + 1 < k, cross(i_in, i_in + 1), 0.0)
    return jnp.where(any_comp, r_in, 0.0), jnp.where(any_comp, r_out, 0.0)


def observables(
    cfg: Config, p: Params, y: Float[Array, " ny"], y_inflated: Float[Array, " ny"], zc_contact: Float[Array, ""]
) -> dict[str, Float[Array, ""]]:
    """The observables documented in the module docstring for one state ``y`` [m], given the
    inflated state [m] and the indenter height at first contact ``zc_contact`` [m]."""
    n = cfg.n_nodes
    x, zc = split(y, n)
    x_inf, _ = split(y_inflated, n)
    eq = jnp.array([n // 2 - 1, n // 2])
    dz_eq = jnp.mean(x[eq, 1]) - jnp.mean(x_inf[eq, 1])
    dz_top = x[-1, 1] - x_inf[-1, 1]
    volume = enclosed_volume(x)
    z_max, r_max = _ridge(x)
    gaps = ground_gaps(x, p)
    k_node = p.contact_stiffness * node_rest_areas(rest_nodes(cfg, p.rest_radius))
    n_theta, r_gauss = hoop_tension(x, rest_nodes(cfg, p.rest_radius), p)
    annulus = compressive_annulus(x, n_theta, r_gauss)
    # the flat contact disc carries the gas pressure and its own weight
    disc_pressure = gauge_pressure_at(volume, cfg, p) + p.areal_weight
    return dict(
        w0=dz_eq - dz_top,
        top_drop=-dz_top,
        travel=zc_contact - zc,
        height=z_max - p.ground_z,
        upper_diameter=2.0 * r_max,
        contact_diameter=2.0 * jnp.sqrt(jnp.sum(k_node * jnp.maximum(-gaps, 0.0)) / (jnp.pi * disc_pressure)),
        contact_diameter_mesh=2.0 * _contact_radius(x, gaps),
        sunken_depth=z_max - x[-1, 1],
        wall_gap=x[-1, 1] - x[0, 1],
        pressure=gauge_pressure_at(volume, cfg, p),
        volume=volume,
        ground_reaction=jnp.sum(k_node * jnp.maximum(-gaps, 0.0)),
        min_hoop_tension=jnp.min(jnp.where(jnp.arange(n_theta.shape[1]) >= n_theta.shape[1] // 2, n_theta, jnp.inf)),
        compressive_inner_radius=annulus[0],
        compressive_outer_radius=annulus[1],
    )


def wrinkle_length(radius, young_modulus, thickness, poisson_ratio):
    """ℓ_w = (B R² / (E h))^{1/4} [m]: R [m] the curvature radius; B from E [Pa], h [m], ν [-]."""
    b = bending_stiffness(young_modulus, thickness, poisson_ratio)
    return (b * radius**2 / (young_modulus * thickness)) ** 0.25


def wrinkle_count(r_inner, r_outer, radius, young_modulus, thickness, poisson_ratio):
    """Continuous wrinkle count n = (r_in + r_out) / (2 ℓ_w) [-] of the compressive annulus
    (r_in, r_out) [m] (0 without one); R [m], E [Pa], h [m], ν [-] as in :func:`wrinkle_length`."""
    mid = 0.5 * (r_inner + r_outer)
    return mid / wrinkle_length(radius, young_modulus, thickness, poisson_ratio)


__all__ = ["compressive_annulus", "observables", "wrinkle_count", "wrinkle_length"]
