"""Rigid-contact potentials as functions of signed gaps [m] (positive = separated).

Two choices, both C¹ or smoother so Newton sees continuous forces:

* ``penalty_energy``: k/2 · max(−g, 0)² per contact point, k [N/m]. A contact point pressed with
  force f penetrates by exactly f / k, which is the stated penetration bound: choose k so that
  F_max / k is below the tolerance you need (e.g. 20 N / 1e6 N/m = 20 µm).
* ``barrier_energy``: the IPC log barrier −κ (g − ĝ)² ln(g / ĝ) for 0 < g < ĝ, zero beyond.
  Penetration is impossible (energy → ∞ as g → 0⁺) as long as the line search keeps every gap
  positive; ĝ [m] is the activation distance, κ [J/m²] the stiffness.

Gaps for the rigid bodies shelljax models: a sphere (finger) and a plane (ground, wall).
"""

from __future__ import annotations

import jax.numpy as jnp


def sphere_gap(points, center, radius):
    """Signed gap [m] of points (…, 3) [m] to a rigid sphere of ``center`` (3,) [m] and ``radius`` [m]."""
    return jnp.linalg.norm(points - center, axis=-1) - radius


def plane_gap(points, point_on_plane, normal):
    """Signed gap [m] of points (…, 3) [m] above the plane through ``point_on_plane`` with unit ``normal``."""
    return (points - point_on_plane) @ normal


def penalty_energy(gap, stiffness):
    """Quadratic penalty k/2 · max(−g, 0)² [J] of gap g [m] with stiffness k [N/m]."""
    penetration = jnp.maximum(-gap, 0.0)
    return 0.5 * stiffness * penetration**2


def barrier_energy(gap, activation_distance, stiffness):
    """IPC log barrier [J] of gap g [m] > 0; zero for g ≥ ĝ [m]; stiffness κ [J/m²]."""
    active = gap < activation_distance
    safe_gap = jnp.where(active, jnp.maximum(gap, 1e-300), activation_distance)
    return jnp.where(
        active,
        -stiffness * (safe_gap - activation_distance) ** 2 * jnp.log(safe_gap / activation_distance),
        0.0,
    )
