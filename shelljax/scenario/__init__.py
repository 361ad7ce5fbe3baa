"""Dynamic scenarios from TOML configs (``shelljax simulate``; docs/dynamics.md, *Scenarios*).

``load_scenario`` reads and validates a config into a :class:`Scenario` (``_load``), naming the
file, the field, the value and the fix; ``run_scenario`` builds the 3D shell, calibrates the
contact damping and writes every run's ``results.json``, figures and mesh frames (``_run``).
"""

from ._load import PlaneSpec, PrescribedSpec, Scenario, load_scenario
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

__all__ = [
    "CALIBRATION_WINDOW", "SCENARIO_CHUNK", "ObjectModel", "PlaneSpec", "PrescribedSpec", "Scenario", "build_system",
    "calibration_cor", "eqx_replace_damping", "held_vertices", "hold", "initial_state", "load_scenario",
    "resolve_object", "run_scenario",
]  # fmt: skip
