"""Exact similarity of a pressurized shell poked by a sphere: one engine radius reaches every ball.

At fixed gauge pressure P_g, Young's modulus E and Poisson ratio ν, scaling every length of the
problem (radius, thickness, finger radius, depths) by s = R/R₀ scales every force by s², so the
engine solves once at its own radius R₀ and a ball of radius R reads its curve back by s. A
contact penalty k_c per unit volume [N/m³] scales by 1/s (its engine value is k_c·s).
"""

from __future__ import annotations

import equinox as eqx
from jaxtyping import ArrayLike, Float

__all__ = ["Similarity"]


class Similarity(eqx.Module):
    """The map between a ball of radius R and the engine's at R₀: ``scale`` s = R/R₀ [-] (a
    scalar, or one per session)."""

    scale: Float[ArrayLike, "*batch"]

    @classmethod
    def between(cls, radius, engine_radius) -> Similarity:
        """The similarity of a ball of radius R [m] to the engine's, of radius R₀ [m]."""
        return cls(scale=radius / engine_radius)

    def at(self, index) -> Similarity:
        """The similarity of the sessions ``index`` picks out of a per-session ``scale``."""
        return Similarity(scale=self.scale[index])

    def length_to_engine(self, length):
        """A length [m] of the ball as the engine's [m]."""
        return length / self.scale

    def length_from_engine(self, length):
        """A length [m] of the engine as the ball's [m]."""
        return self.scale * length

    def force_to_engine(self, force):
        """A force [N] on the ball as the engine's [N]."""
        return force / self.scale**2

    def penalty_to_engine(self, penalty):
        """A contact penalty per unit volume [N/m³] of the ball as the engine's [N/m³]."""
        return penalty * self.scale
