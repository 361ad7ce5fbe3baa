"""Fast axisymmetric Neo-Hookean shell engine (meridian elements) for fitting indentation data.

Entry point for estimators: :func:`indentation_curves` (batched F → w(0) curves, observables,
wrinkle count, ``converged`` flags; jit/vmap/implicit-grad via :func:`indentation_curves_raw`).
Per-curve traced effects (finger radius, gas volume and exponent, Gent stiffening, self-weight,
ground friction):
:class:`CurvePhysics`. See docs/axisym.md.
"""

from ._api import PAPER_FORCES, CurveResult, indentation_curves, indentation_curves_raw
from ._energy import Config, Params, enclosed_volume, hoop_tension, rest_nodes, total_energy
from ._inflation import gent_sphere_pressure, inflation_stretch, neo_hookean_sphere_pressure
from ._model import CurvePhysics, Setup, curve_single, inflate
from ._newton import SolverOptions, equilibrium
from ._wrinkles import tau, vella_wrinkle_count, wrinkle_count, wrinkle_length
from ._shallow import (
    pinch_linear_stiffness,
    pinch_observables,
    pinch_setup,
    pinch_state,
    reissner_stiffness,
    vella_linear_stiffness,
)
