"""Implicit dynamics as incremental potential minimisation: drops, bounces and swings (SI units).

Build a system (``PointMassOnGround``, ``SpringBalloon``, or the 3D shell engine's own
``AbstractDynamicSystem``), start it with ``initial_state``, run it with ``simulate`` (or the
differentiable ``rollout``), read its impacts with ``measured_cor`` and write them with
``write_results``. See docs/dynamics.md.
"""

from ..physics import (
    AbstractContactLaw,
    BarrierContact,
    CompressionCurve,
    Plane,
    PowerLawContact,
    TabulatedCompressionCurve,
    ground,
)
from ._cor import DampingCalibration, Impact, calibrate_contact_damping, contact_diameter, measured_cor, mesh_edges
from ._integrators import TRBDF2, AbstractIntegrator, BackwardEuler, Newmark, Rayleigh, Stage
from ._minimise import AbstractMinimiser, DenseNewton, KeptMatrix, simplified_newton_loop, solve_step
from ._output import write_results
from ._potential import IncrementalPotential, incremental_potential, stage_potential
from ._reference import hertz_impact, pressurized_ball_contact_time, pressurized_ball_stiffness
from ._run import StepRecord, Trajectory, drop_state, initial_state, rollout, simulate, step
from ._system import AbstractDynamicSystem, DynamicState, PrescribedRotation
from ._shell import ShellDynamicSystem, remeshed, shell_system
from ._krylov import KrylovNewton
from ._sparse import SparseNewton
from ._systems import PointMassOnGround, SpringBalloon
