"""The measuring chain, learned once where the pressure is known and carried to every later
estimate (docs/rig.md): :func:`calibrate_rig` fits and selects the rig's terms on sessions with
manometer readings, :func:`write_rig`/:func:`load_rig` keep it as TOML, and
:func:`estimate_with_rig` measures P_g and E of any object through it.
"""

from ._calibrate import Rig, RigModel, RigWarning, calibrate_rig, pseudo_bma_plus
from ._estimate import (
    RigEstimate,
    check_compatible,
    estimate_with_rig,
    normal_mixture,
    psis,
    rig_measurement,
    updated_weights,
)
from ._file import load_rig, physical_parameter, write_rig
from ._terms import FAMILIES, RIG_PARAMETERS, RIG_TERMS, RigTerm
