"""Measurement sessions: the TOML/CSV format, its validation, and the Session and RigidPress records (SI units)."""

from ._bundled import bundled_sessions
from ._load import SCHEMA_VERSION, file_sha256, load_session
from ._reader import files_sha256
from ._press import load_rigid_press, session_kind
from ._ranges import RANGES as PLAUSIBLE_RANGES
from ._ranges import convert_unit, implausible, likely_unit
from ._schema import SHAPE_OBSERVABLES, RigidPress, Session
from ._units import FORCE_UNITS, LENGTH_UNITS, MASS_UNITS, PRESSURE_UNITS
from ._write import write_rigid_press, write_session
