"""The paper's constants and measurement protocol (Zhang et al., Sections 3.4 and 4.1), SI units.

Everything a module needs to reproduce the paper's set-up lives here, once: the calibrated k_s,
the force levels of the poke protocol, the finger radius and the assumed Poisson ratio. The laws
these constants enter (τ, the wrinkle law, point-load stiffnesses) are in :mod:`shelljax.physics`.
"""

from __future__ import annotations

PAPER_KS = 0.64  # [-], calibrated on a Pezzi and a yoga ball (Section 4.1)
# The paper quotes no error bar on k_s; its held-out pressures came out with 3.5 % mean relative
# error, which is taken as k_s's relative standard deviation when the paper's value is used.
PAPER_KS_STD = 0.035 * PAPER_KS  # [-]
PAPER_FORCES = (5.0, 7.5, 10.0, 12.5, 15.0, 17.5, 20.0)  # [N], the poke protocol's force levels
PAPER_INDENTER_RADIUS = 8e-3  # [m], the finger pad of the estimators' forward model
DEFAULT_POISSON_RATIO = 0.4  # [-], the paper's assumption (Section 3.4): rubbers sit at 0.3-0.4
