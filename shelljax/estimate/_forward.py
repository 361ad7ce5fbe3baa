"""Forward models for the simulation-fitted estimators.

A forward model maps the physical unknowns of one session — gauge pressure P_g [Pa], Young's
modulus E [Pa], wall thickness h [m] and local radius R [m] — and the recorded indenter forces F [N] to the predicted
indentation depths |w(0)| [m] at those forces and the predicted wrinkle count n [-], with a flag
saying whether the simulation converged. Estimators only see this interface, so a cheap analytic
law and the axisymmetric shell engine are interchangeable.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ..physics import bending_stiffness


class Prediction(eqx.Module):
    """Output of a forward model: ``depth`` [m] per force, ``wrinkle_count`` [-], ``converged``."""

    depth: Float[Array, " m"]
    wrinkle_count: Float[Array, ""]
    converged: Bool[Array, ""]


class AbstractForwardModel(eqx.Module):
    """F, (P_g, E, h, R) ↦ (|w(0)|, n, converged); must be jit-, vmap- and grad-compatible.

    ``poisson_ratio`` ν [-] is a fixed property of the model (the paper assumes 0.4).
    """

    poisson_ratio: eqx.AbstractVar[float]

    @abc.abstractmethod
    def __call__(self, gauge_pressure, young_modulus, thickness, radius, forces: Float[Array, " m"]) -> Prediction:
        """Depths [m] at ``forces`` [N] and the wrinkle count for P_g [Pa], E [Pa], h [m], R [m]."""


class ScalingLawModel(AbstractForwardModel):
    """The paper's scaling laws as a forward model: |w(0)| = F / (π k_s R P_g), n = 1.33 τ^½.

    Fitting it reproduces the closed form; it serves as a fast reference and to test estimators.
    ``poisson_ratio`` ν [-], ``k_s`` [-].
    """

    poisson_ratio: float = 0.4
    k_s: float = 0.64

    def __call__(self, gauge_pressure, young_modulus, thickness, radius, forces):
        depth = forces / (jnp.pi * self.k_s * radius * gauge_pressure)
        bending = bending_stiffness(young_modulus, thickness, self.poisson_ratio)
        tau = gauge_pressure * radius**2 / jnp.sqrt(young_modulus * thickness * bending)
        return Prediction(depth=depth, wrinkle_count=1.33 * jnp.sqrt(tau), converged=jnp.array(True))
