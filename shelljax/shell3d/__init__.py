"""3D engine: differentiable Neo-Hookean shell FEM on closed triangle meshes.

Quick start (SI units)::

    import shelljax.shell3d as s3
    ball = s3.ball(radius=0.13, thickness=0.9e-3, n_triangles=5000)
    sim = s3.Indentation(ball, young_modulus=2.34e6, poisson_ratio=0.4, gauge_pressure=1300.0,
                         gas="isothermal", indenter_radius=0.008, ground=True)
    state = sim.solve(depth=0.02)      # or sim.curve(depths), sim.solve(force=10.0)
    print(state.observables())         # force [N], w0/H/D_u/D_l/d [m], pressure [Pa], volume [m³]
    state.export("poked.obj"); state.plot("poked.png")
    state.wrinkles(max_radius=0.08, ring_width=0.005).count   # radial wrinkles (angular Fourier)
"""

from ._energy import face_energy, fundamental_forms, rest_geometry
from ._indent import Indentation, IndentationState, Shell, ball, load
from ._mesh import ShellMesh, signed_volume, sphere_mesh, random_sphere_mesh
from ._model import ContactConfig, ModelConfig, ShellModel, rigid_mode_pins
from ._observables import observables
from ._rest import solve_rest_shape
from ._wrinkles import WrinkleSpectrum, wrinkle_spectrum
