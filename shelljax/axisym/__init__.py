"""Fast axisymmetric Neo-Hookean shell engine (meridian elements) for fitting indentation data.

Entry point for estimators: :func:`indentation_curves` (batched F → w(0) curves, observables,
wrinkle count, ``converged`` flags; jit/vmap/implicit-grad via :func:`indentation_curves_raw`).
The shell's P_g, E, h, ν (and R) arrive as one :class:`shelljax.physics.ShellProperties`.
Per-curve traced effects (finger radius, gas volume and exponent, Gent stiffening, self-weight,
ground friction): :class:`CurvePhysics`. The gas laws are ``physics.AbstractGasLaw`` objects.
Shell theory's closed forms (τ, the 1.33 τ^½ wrinkle law,
Reissner's and Vella's stiffnesses) live in :mod:`shelljax.physics`, the paper's force levels in
:mod:`shelljax.paper`. See docs/axisym.md.
"""

from .._parallel import cpu_workers, map_batch
from ._api import CurveResult, indentation_curves, indentation_curves_raw
from ._energy import Config, Params, enclosed_volume, hoop_tension, rest_nodes, total_energy
from ._inflation import gent_sphere_pressure, inflation_stretch, neo_hookean_sphere_pressure
from ._model import CurvePhysics, Setup, curve_single, inflate
from ._newton import SolverOptions, equilibrium
from ._observables import compressive_annulus, observables, wrinkle_count, wrinkle_length
from ._shallow import pinch_linear_stiffness, pinch_observables, pinch_setup, pinch_state

__all__ = [
    "Config",
    "CurvePhysics",
    "CurveResult",
    "Params",
    "Setup",
    "SolverOptions",
    "compressive_annulus",
    "cpu_workers",
    "curve_single",
    "enclosed_volume",
    "equilibrium",
    "gent_sphere_pressure",
    "hoop_tension",
    "indentation_curves",
    "indentation_curves_raw",
    "inflate",
    "inflation_stretch",
    "map_batch",
    "neo_hookean_sphere_pressure",
    "observables",
    "pinch_linear_stiffness",
    "pinch_observables",
    "pinch_setup",
    "pinch_state",
    "rest_nodes",
    "total_energy",
    "wrinkle_count",
    "wrinkle_length",
]
