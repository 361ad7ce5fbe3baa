"""Dynamic scenarios from TOML configs (``shelljax simulate``; docs/dynamics.md, *Scenarios*).

``load_scenario`` reads and validates a config into a :class:`Scenario` (``_load``), naming the
file, the field, the value and the fix; ``run_scenario`` builds the 3D shell, calibrates the
contact damping and writes every run's ``results.json``, figures and mesh frames (``_run``);
``run_sweep`` runs a config's ``[sweep]``, one scenario per value, on ``shelljax.executor`` (``_sweep``).
"""

from ._load import SWEEP_PARAMETERS, PlaneSpec, PrescribedSpec, Scenario, SweepSpec, load_scenario
from ._run import (
    CALIBRATION_WINDOW,
    SCENARIO_CHUNK,
    ObjectModel,
    build_system,
    calibration_cor,
    eqx_replace_damping,
    held_vertices,
    hold,
    initial_state,
    resolve_object,
    run_scenario,
)
from ._sweep import run_sweep, simulate_sweep_value, sweep_table

__all__ = [
    "CALIBRATION_WINDOW",
    "SCENARIO_CHUNK",
    "ObjectModel",
    "PlaneSpec",
    "PrescribedSpec",
    "Scenario",
    "build_system",
    "calibration_cor",
    "eqx_replace_damping",
    "held_vertices",
    "hold",
    "initial_state",
    "load_scenario",
    "resolve_object",
    "run_scenario",
    "run_sweep",
    "simulate_sweep_value",
    "sweep_table",
    "SWEEP_PARAMETERS",
    "SweepSpec",
]
