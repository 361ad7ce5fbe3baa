"""Rigid-contact potentials as functions of signed gaps [m] (positive = separated).

Two choices, both C¹ or smoother so Newton sees continuous forces:

* ``penalty_energy``: k/2 · max(−g, 0)² per contact point, k [N/m]. A contact point pressed with
  force f penetrates by exactly f / k, which is the stated penetration bound: choose k so that
  F_max / k is below the tolerance you need (e.g. 20 N / 1e6 N/m = 20 µm).
* ``barrier_energy``: the IPC log barrier −κ (g − ĝ)² ln(g / ĝ) for 0 < g < ĝ, zero beyond.
  Penetration is impossible (energy → ∞ as g → 0⁺) as long as the line search keeps every gap
  positive; ĝ [m] is the activation distance, κ [J/m²] the stiffness.

Gaps for the rigid bodies shelljax models: a sphere (finger) and a plane (ground, wall).

``Plane`` is the one rigid plane of the package, used by the 3D engine's static contact setup
(``shell3d.ContactConfig.planes``, where the law and friction are the setup's) and by the
dynamics' systems (with its own law, friction and damping).

Friction (``friction_energy``): the smoothed, lagged Coulomb potential of Incremental Potential
Contact (Li et al. 2020, ACM TOG 39(4) 49, Sec. 5): D = μ λ f₀(‖u‖) per contact point, with the
normal force λ [N] and the slip origin ("anchor") frozen at a lagged state, u [m] the tangential
slip since the anchor. Its force −∂D/∂u has magnitude μ λ f₁(‖u‖) ≤ μ λ (the Coulomb cone), equal
to μ λ once ‖u‖ ≥ ε (sliding) and growing linearly, with stiffness 2 μ λ / ε, below (sticking).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._errors import InvalidInputError

if TYPE_CHECKING:  # the laws' module builds planes: it imports this one
    from ._contact_laws import AbstractContactLaw


def _concrete(value) -> bool:
    """Whether ``value`` can be checked on the host (not a tracer inside jit or grad)."""
    return not isinstance(value, jax.core.Tracer)


def check_nonnegative(name: str, value, fix: str) -> None:
    """Raise InvalidInputError if a concrete ``value`` is negative or not finite."""
    if _concrete(value):
        v = np.asarray(value, dtype=float)
        if not np.all(np.isfinite(v)) or np.any(v < 0.0):
            raise InvalidInputError(f"{name} must be finite and ≥ 0; got {v.tolist()}. {fix}")


def check_positive(name: str, value, fix: str) -> None:
    """Raise InvalidInputError if a concrete ``value`` is missing, ≤ 0 or not finite."""
    if value is None:
        raise InvalidInputError(f"{name} is missing. {fix}")
    if _concrete(value):
        v = np.asarray(value, dtype=float)
        if not np.all(np.isfinite(v)) or np.any(v <= 0.0):
            raise InvalidInputError(f"{name} must be finite and > 0; got {v.tolist()}. {fix}")


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
        active, -stiffness * (safe_gap - activation_distance) ** 2 * jnp.log(safe_gap / activation_distance), 0.0
    )


def _safe_norm(u: Float[Array, "... k"]) -> Float[Array, "..."]:
    """‖u‖ along the last axis with finite derivatives of every order at u = 0 (they are 0 there).

    The double ``where`` keeps sqrt's infinite slope at 0 out of the derivative graph; every use
    below multiplies the norm by ‖u‖² or sits in the branch ‖u‖ ≥ ε > 0, so the true derivatives of
    the friction potential (Hessian (2/ε) I at u = 0) come out exactly.
    """
    sq = jnp.sum(u * u, axis=-1)
    positive = sq > 0.0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, sq, 1.0)), 0.0)


def friction_mollifier(y: Float[ArrayLike, "..."], slip_tolerance: float | Float[ArrayLike, ""]):
    """IPC friction mollifier f₀(y) [m] of a slip length y ≥ 0 [m] with tolerance ε [m].

    f₀(y) = −y³/(3ε²) + y²/ε + ε/3 for y < ε and y for y ≥ ε: C¹ at ε (f₀ = ε, f₀' = 1), with
    f₀' = f₁(y) = 2y/ε − y²/ε² ∈ [0, 1] below ε.
    """
    y = jnp.asarray(y)
    eps = slip_tolerance
    below = y < eps
    y_low = jnp.where(below, y, 0.0)
    return jnp.where(below, -(y_low**3) / (3.0 * eps**2) + y_low**2 / eps + eps / 3.0, y)


def friction_energy(
    slip: Float[ArrayLike, "... k"],
    normal_force: Float[ArrayLike, "..."],
    friction: float | Float[ArrayLike, ""],
    slip_tolerance: float | Float[ArrayLike, ""],
) -> Float[Array, "..."]:
    """Smoothed lagged Coulomb friction potential D = μ λ f₀(‖u‖) [J] per contact point.

    ``slip`` u (…, k) [m]: tangential displacement since the lagged anchor (k = 2 in-plane
    coordinates or k = 3 with the normal component already projected out); ``normal_force`` λ
    (…) [N] ≥ 0: lagged normal contact force magnitude; ``friction`` μ [-] ≥ 0: Coulomb
    coefficient; ``slip_tolerance`` ε [m] > 0: the slip below which the contact sticks (the
    friction force ramps from 0 to μ λ over ‖u‖ ∈ [0, ε]). Derivatives are finite everywhere:
    ∂D/∂u = μ λ f₁(‖u‖) u/‖u‖ (0 at u = 0), ∂²D/∂u² = 2 μ λ/ε I at u = 0.
    """
    u = jnp.asarray(slip)
    eps = slip_tolerance
    y = _safe_norm(u)
    below = y < eps
    # Below ε write the cubic with ‖u‖² = u·u (smooth) so that only the y³ term sees the safe norm.
    sq = jnp.sum(u * u, axis=-1)
    sq_low = jnp.where(below, sq, 0.0)
    f0 = jnp.where(below, -sq_low * y / (3.0 * eps**2) + sq_low / eps + eps / 3.0, y)
    return friction * jnp.asarray(normal_force) * f0


def friction_force(
    slip: Float[ArrayLike, "... k"],
    normal_force: Float[ArrayLike, "..."],
    friction: float | Float[ArrayLike, ""],
    slip_tolerance: float | Float[ArrayLike, ""],
) -> Float[Array, "... k"]:
    """Friction force −∂D/∂u [N] on the contact point (opposes the slip; ‖·‖ ≤ μ λ)."""
    u = jnp.asarray(slip)
    y = _safe_norm(u)
    eps = slip_tolerance
    f1 = jnp.where(y < eps, 2.0 * y / eps - y**2 / eps**2, 1.0)
    direction = u / jnp.where(y > 0.0, y, 1.0)[..., None]
    return -(friction * jnp.asarray(normal_force) * f1)[..., None] * direction


class Plane(eqx.Module):
    """A rigid plane through ``point`` (3,) [m] with unit ``normal`` (3,) pointing to the free side.

    ``law``: its contact law (an :class:`AbstractContactLaw`; None in the 3D engine's static
    setup, whose ``ContactConfig`` sets the law and friction of all its planes); ``friction`` μ [-]
    (lagged, smoothed Coulomb) with slip tolerance ε [m]; ``damping`` c [N·s/m]: the normal contact
    damping of each touching point, the dashpot of the potential (c / 2Δt) Σ wᵢ ((xᵢ − xᵢⁿ)·n)²;
    ``name`` labels its outputs.

    Equal planes (the same numbers) compare and hash equal, so a plane can sit in a static, jit-keyed
    setup; inside a traced computation compare their arrays instead.
    """

    point: Float[Array, "3"] = eqx.field(converter=jnp.asarray)
    normal: Float[Array, "3"]
    law: AbstractContactLaw | None
    friction: Float[Array, ""] = eqx.field(converter=jnp.asarray)
    slip_tolerance: Float[Array, ""] = eqx.field(converter=jnp.asarray)
    damping: Float[Array, ""] = eqx.field(converter=jnp.asarray)
    name: str = eqx.field(static=True)

    def __init__(self, point, normal, law=None, *, friction=0.0, slip_tolerance=1e-4, damping=0.0, name="plane"):
        n = jnp.asarray(normal, dtype=float)
        if _concrete(n):
            norm = float(np.linalg.norm(np.asarray(n)))
            if n.shape != (3,) or not np.isfinite(norm) or norm == 0.0:
                raise InvalidInputError(
                    f"Plane {name!r}: normal must be a nonzero 3-vector; got {np.asarray(normal).tolist()}."
                )
        self.point, self.normal, self.law = point, n / jnp.linalg.norm(n), law
        self.friction, self.slip_tolerance, self.damping, self.name = friction, slip_tolerance, damping, name

    def __check_init__(self):
        check_nonnegative(f"Plane {self.name!r} friction μ [-]", self.friction, "Give μ ≥ 0 (0 for frictionless).")
        check_positive(f"Plane {self.name!r} slip_tolerance ε [m]", self.slip_tolerance, "Give ε > 0, e.g. 1e-4 m.")
        check_nonnegative(
            f"Plane {self.name!r} damping c [N·s/m]", self.damping, "Give c ≥ 0 (0 for an elastic contact)."
        )

    def gap(self, points: Float[Array, "k 3"]) -> Float[Array, " k"]:
        """Signed gaps [m] of points (k, 3) [m] to this plane."""
        return plane_gap(points, self.point, self.normal)

    def _numbers(self):
        leaves, treedef = jax.tree_util.tree_flatten(self)
        return treedef, tuple(tuple(np.ravel(np.asarray(leaf)).tolist()) for leaf in leaves)

    def __hash__(self):
        return hash(self._numbers())

    def __eq__(self, other):
        return type(other) is type(self) and self._numbers() == other._numbers()
