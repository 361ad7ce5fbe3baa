"""3D engine: differentiable Neo-Hookean shell FEM on closed triangle meshes.

Quick start (SI units)::

    import shelljax.shell3d as s3
    from shelljax.physics import IsothermalGas, ShellProperties
    ball = s3.ball(radius=0.13, thickness=0.9e-3, n_triangles=5000)
    pezzi = ShellProperties(gauge_pressure=1300.0, young_modulus=2.34e6, thickness=0.9e-3, poisson_ratio=0.4)
    sim = s3.Indentation(ball, pezzi, gas=IsothermalGas(), indenter_radius=0.008, ground=True)
    state = sim.solve(depth=0.02)      # or sim.curve(depths), sim.solve(force=10.0)
    print(state.observables())         # force [N], w0/H/D_u/D_l/d [m], pressure [Pa], volume [m³]
    state.export("poked.obj"); state.plot("poked.png")
    state.wrinkles(max_radius=0.08, ring_width=0.005).count   # radial wrinkles (angular Fourier)

Lower layers, for benchmarks and verification: :class:`ShellModel` (energy, gradient, sparse
Hessian, :meth:`ShellModel.equilibrium`), the free shell's rest shape and pressurized reference
state (:func:`inflated_reference`), the Newton solver (:func:`newton` on an
:class:`AbstractEnergyProblem`, returning a :class:`shelljax.Solution`), the sparse factorization
(:class:`SparseSolver`, its caches freed by :func:`release_factorizations`), the linear solvers
that Newton and the implicit tangents take (:class:`DirectSolver`, the default, host CHOLMOD;
:class:`KrylovSolver`, CG in JAX on the arrays' device) and implicit differentiation
(:func:`implicit_equilibrium`).
"""

from ._config import ContactConfig, ModelConfig
from ._continuation import continuation
from ._energy import (
    ShellGeometry,
    elastic_energy,
    face_energy,
    fundamental_forms,
    gas_energy,
    rest_geometry,
    total_energy,
)
from ._energy import volume as enclosed_volume
from ._hessian import face_hessians, hessian_values
from ._hessian import rank_one as gas_rank_one
from ._implicit import implicit_equilibrium
from ._indent import Indentation, IndentationState, Shell, ball, load
from ._linear import AbstractLinearSolver, DirectSolver, KrylovSolver
from ._mesh import ShellMesh
from ._model import EquilibriumProblem, ShellModel, rigid_mode_pins
from ._newton import AbstractEnergyProblem, newton
from ._params import ShellParams
from ._observables import observables
from ._rest import InflatedReference, inflated_reference, solve_rest_shape
from ._search import match_forces, solve_travels
from ._sparse import SparseSolver, SparsityPattern, kept_assembly, kept_factorization, release_factorizations
from ._wrinkles import WrinkleSpectrum, wrinkle_spectrum
