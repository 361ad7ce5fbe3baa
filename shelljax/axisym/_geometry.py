"""Meridian discretisation of a closed shell of revolution (sphere by default).

The meridian runs from the bottom pole (node 0, rest polar angle θ = 0) to the top pole
(node n − 1, θ = π) through nodes (r, z) [m]. Everything here is a pure function of the rest
radius R0 [m] times a dimensionless unit-sphere layout, so the rest shape is differentiable in
R0 (which itself depends on P_g, E, h, ν through the pressurized-radius convention).

The node spacing is graded towards both poles (indenter on top, ground contact below):
θ(t) = π [t − a sin(2πt) / (2π)], t uniform in [0, 1]; a ∈ [0, 1) is ``grading``; pole
elements are (1 − a) times the mean, equator elements (1 + a) times the mean.
"""

from __future__ import annotations

import numpy as np


def unit_polar_angles(n_elements: int, grading: float) -> np.ndarray:
    """Rest polar angles θ_i [rad] of the n_elements + 1 meridian nodes, θ_0 = 0, θ_n = π.

    ``n_elements`` must be odd so the node count is even (the Hessian is stored as a
    block-tridiagonal matrix of 2-node blocks).
    """
    t = np.linspace(0.0, 1.0, n_elements + 1)
    theta = np.pi * (t - grading * np.sin(2.0 * np.pi * t) / (2.0 * np.pi))
    theta[0], theta[-1] = 0.0, np.pi
    return theta


def gauss_points_2() -> tuple[np.ndarray, np.ndarray]:
    """Two-point Gauss rule on [0, 1]: abscissae ξ [-] and weights [-] (summing to 1)."""
    d = 0.5 / np.sqrt(3.0)
    return np.array([0.5 - d, 0.5 + d]), np.array([0.5, 0.5])
