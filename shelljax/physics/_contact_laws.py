"""The contact laws that push a body's contact points off a rigid plane (ground, wall).

A contact law is a potential e(g) [J] of one contact point's signed gap g [m] (positive =
separated). Its normal force is λ(g) = −de/dg [N] ≥ 0. Two kinds:

* ``BarrierContact``: the IPC log barrier of ``shelljax.physics.barrier_energy``; gaps stay
  positive (the minimiser's line search keeps them so), active below the distance ĝ [m].
* ``PowerLawContact``: F = K δ^p (linear p = 1, Hertz p = 1.5), with a differentiable K.
* ``CompressionCurve`` / ``TabulatedCompressionCurve``: a nonlinear contact spring given by its
  force–compression curve F(δ) [N] of the compression δ = max(−g, 0) [m], the issue's 1-DOF model
  m ẍ = −F_ground(x) (e.g. a quasi-static ground force–compression curve of the shell engine).

Each law also gives the weight w(g) ∈ [0, 1] of its point in the contact damping potential and the
gap below which the point counts as touching (for impact detection).

The plane itself is :class:`Plane` (``_contact``), the one plane of the package, which carries
its law (the 3D engine's static contact setup sets one law for all its planes instead); the
dynamics' systems read them.
"""

from __future__ import annotations

import abc
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from .._errors import InvalidInputError
from ._contact import Plane, barrier_energy, check_positive

# 16-point Gauss–Legendre nodes and weights on [−1, 1]: the energy ∫₀^δ F of a smooth curve to ~1e-15.
_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(16)  # NumPy: importing initialises no JAX backend


class AbstractContactLaw(eqx.Module):
    """A contact potential of one point's gap g [m]; see the module docstring."""

    @abc.abstractmethod
    def energy(self, gap: Float[Array, "..."]) -> Float[Array, "..."]:
        """Contact energy e(g) [J] per point of gaps g [m]."""

    @abc.abstractmethod
    def damping_weight(self, gap: Float[Array, "..."]) -> Float[Array, "..."]:
        """Weight w(g) ∈ [0, 1] [-] of a point in the contact damping potential."""

    @abc.abstractmethod
    def contact_distance(self) -> Float[Array, ""]:
        """Gap [m] below which a point counts as touching the plane."""

    def force(self, gap: Float[Array, "..."]) -> Float[Array, "..."]:
        """Normal contact force λ(g) = −de/dg [N] per point (≥ 0, pushing the point off the plane)."""
        g = jnp.asarray(gap)
        flat = jax.vmap(jax.grad(self.energy))(g.reshape(-1))
        return -flat.reshape(g.shape)

    def is_feasible(self, gap: Float[Array, "..."]) -> Bool[Array, ""]:
        """Whether every gap [m] is admissible (barriers need g > 0)."""
        return jnp.asarray(True)


class BarrierContact(AbstractContactLaw):
    """IPC log barrier −κ (g − ĝ)² ln(g/ĝ) [J] for 0 < g < ĝ, ĝ [m] the activation distance, κ [J/m²]."""

    activation_distance: Float[Array, ""] = eqx.field(converter=jnp.asarray)
    stiffness: Float[Array, ""] = eqx.field(converter=jnp.asarray)

    def __check_init__(self):
        check_positive("BarrierContact.activation_distance [m]", self.activation_distance, "Give ĝ, e.g. 1e-3 m.")
        check_positive("BarrierContact.stiffness [J/m²]", self.stiffness, "Give κ, e.g. 1e3 J/m².")

    def energy(self, gap):
        return barrier_energy(gap, self.activation_distance, self.stiffness)

    def damping_weight(self, gap):
        # (1 − g/ĝ)² rises C¹ from 0 at ĝ, so the damped trajectory stays differentiable at onset.
        s = jnp.clip(1.0 - gap / self.activation_distance, 0.0, 1.0)
        return s * s

    def contact_distance(self):
        return self.activation_distance

    def is_feasible(self, gap):
        return jnp.all(gap > 0.0)


def _compression(gap):
    """δ = max(−g, 0) [m], with derivative 0 (not ½) at g = 0."""
    return jnp.where(gap < 0.0, -gap, 0.0)


def _step_weight(compression, ramp):
    """1 once compressed (ramp = 0), or a C¹ ramp over the first ``ramp`` [m] of compression."""
    s = jnp.clip(compression / jnp.where(ramp > 0.0, ramp, 1.0), 0.0, 1.0)
    smooth = s * s * (3.0 - 2.0 * s)
    return jnp.where(ramp > 0.0, smooth, (compression > 0.0).astype(compression.dtype))


class CompressionCurve(AbstractContactLaw):
    """A contact spring F(δ) [N] of the compression δ = max(−g, 0) [m], given as a callable.

    ``force``: δ [m] ↦ F [N], with F(0) = 0, traceable by JAX. ``energy``: optionally its exact
    integral U(δ) = ∫₀^δ F [J]; otherwise U comes from 16-point Gauss–Legendre quadrature.
    ``damping_ramp`` [m]: 0 weights damping by a step at δ = 0 (Kelvin–Voigt); > 0 ramps it in C¹.
    """

    force_curve: Callable = eqx.field(static=True)
    energy_curve: Callable | None = eqx.field(static=True, default=None)
    damping_ramp: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)

    def energy(self, gap):
        d = _compression(jnp.asarray(gap))
        if self.energy_curve is not None:
            return jnp.where(d > 0.0, self.energy_curve(d), 0.0)
        half = 0.5 * d[..., None]
        values = self.force_curve(half * (_GL_NODES + 1.0))
        return jnp.sum(_GL_WEIGHTS * values, axis=-1) * half[..., 0]

    def damping_weight(self, gap):
        return _step_weight(_compression(jnp.asarray(gap)), self.damping_ramp)

    def contact_distance(self):
        return jnp.asarray(0.0)


class PowerLawContact(AbstractContactLaw):
    """A contact spring F = K δ^p [N] of the compression δ = max(−g, 0) [m]; p = 1.5 is Hertz's law.

    ``stiffness`` K [N/m^p] is a traced array (differentiable, calibratable); ``exponent`` p ≥ 1 [-].
    Its energy is K δ^(p+1) / (p + 1) [J]. ``damping_ramp`` [m] as for ``CompressionCurve``.
    """

    stiffness: Float[Array, ""] = eqx.field(converter=jnp.asarray)
    exponent: float = eqx.field(static=True, default=1.5)
    damping_ramp: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)

    def __check_init__(self):
        check_positive("PowerLawContact.stiffness [N/m^p]", self.stiffness, "Give K > 0.")
        if not self.exponent >= 1.0:
            raise InvalidInputError(
                f"PowerLawContact.exponent must be ≥ 1; got {self.exponent}. Use 1 (linear) or 1.5 (Hertz)."
            )

    def energy(self, gap):
        d = _compression(jnp.asarray(gap))
        # δ^(p+1) through a positive base so that its derivatives stay finite at δ = 0.
        safe = jnp.where(d > 0.0, d, 1.0)
        return jnp.where(d > 0.0, self.stiffness * safe ** (self.exponent + 1.0) / (self.exponent + 1.0), 0.0)

    def damping_weight(self, gap):
        return _step_weight(_compression(jnp.asarray(gap)), self.damping_ramp)

    def contact_distance(self):
        return jnp.asarray(0.0)


class TabulatedCompressionCurve(AbstractContactLaw):
    """A contact spring from tabulated points (δᵢ [m], Fᵢ [N]), linear between them and beyond.

    The force is the piecewise-linear interpolant (extrapolated with the last slope) and the energy
    its exact piecewise-quadratic integral, so Newton sees a force consistent with its energy. A
    point (0, 0) is prepended when the table does not start there.
    """

    compression: Float[Array, " n"]
    force_values: Float[Array, " n"]
    cumulative_energy: Float[Array, " n"]
    damping_ramp: Float[Array, ""] = eqx.field(converter=jnp.asarray)

    def __init__(self, compression: ArrayLike, force: ArrayLike, damping_ramp: float = 0.0):
        d = np.asarray(compression, dtype=float).ravel()
        f = np.asarray(force, dtype=float).ravel()
        if d.shape != f.shape or d.size < 1:
            raise InvalidInputError(
                f"TabulatedCompressionCurve needs as many compressions as forces (got {d.size} and {f.size}); give matching lists in m and N."
            )
        if not (np.all(np.isfinite(d)) and np.all(np.isfinite(f))) or d[0] < 0.0 or np.any(f < 0.0):
            raise InvalidInputError(
                "TabulatedCompressionCurve: compressions [m] and forces [N] must be finite and ≥ 0."
            )
        if d[0] > 0.0:
            d, f = np.concatenate([[0.0], d]), np.concatenate([[0.0], f])
        if d.size < 2 or np.any(np.diff(d) <= 0.0):
            raise InvalidInputError(
                f"TabulatedCompressionCurve: compressions must increase strictly from 0 m; got {d.tolist()}. Sort the table and drop repeats."
            )
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(d))])
        self.compression, self.force_values, self.cumulative_energy = jnp.asarray(d), jnp.asarray(f), jnp.asarray(cum)
        self.damping_ramp = damping_ramp

    def energy(self, gap):
        d = _compression(jnp.asarray(gap))
        n = self.compression.shape[0]
        i = jnp.clip(jnp.searchsorted(self.compression, d, side="right") - 1, 0, n - 2)
        d0, f0 = self.compression[i], self.force_values[i]
        slope = (self.force_values[i + 1] - f0) / (self.compression[i + 1] - d0)
        s = d - d0
        return self.cumulative_energy[i] + f0 * s + 0.5 * slope * s * s

    def damping_weight(self, gap):
        return _step_weight(_compression(jnp.asarray(gap)), self.damping_ramp)

    def contact_distance(self):
        return jnp.asarray(0.0)


def ground(law: AbstractContactLaw, *, height: float = 0.0, friction=0.0, slip_tolerance=1e-4, damping=0.0) -> Plane:
    """The horizontal ground plane z = ``height`` [m] (normal +z) with the given contact law."""
    return Plane(
        jnp.array([0.0, 0.0, height]),
        jnp.array([0.0, 0.0, 1.0]),
        law,
        friction=friction,
        slip_tolerance=slip_tolerance,
        damping=damping,
        name="ground",
    )
