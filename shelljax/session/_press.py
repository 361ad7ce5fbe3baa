"""Reading rigid-surface press files (format: docs/session-format.md, "Rigid-surface press sessions").

A press file is a session TOML with ``kind = "rigid_press"``: the finger pressed on a rigid table,
so only the top-level header and the [indentation] table of an indentation session apply. Its
samples are read by the indentation session's own code, with one difference: the depth is the
pad's compression plus the gauge's zero error, so zero and negative depths are allowed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._load import _TOP_KEYS, _read_header, _read_indentation_samples, _read_kind, _read_toml, _Reader, file_sha256
from ._reader import files_sha256
from ._schema import RigidPress

_PRESS_TOP_KEYS = {"schema_version", "kind", "object", "notes", "rig", "indentation"}
# A finger pad is millimetres thick and a gauge's zero error smaller still: a larger depth is
# millimetres (or micrometres) written in a larger unit.
_PRESS_MAX_DEPTH = 0.02  # [m]


def session_kind(path: str | Path) -> str:
    """The kind of the session file ``path``: ``"indentation"`` or ``"rigid_press"`` (its ``kind`` key).

    Raises:
        InvalidInputError: when the file is missing, not UTF-8 TOML, or names an unknown kind.
    """
    path = Path(path)
    return _read_kind(_Reader(path), _read_toml(path))


def load_rigid_press(path: str | Path) -> RigidPress:
    """Read and validate a rigid-surface press file; return a :class:`RigidPress` in SI units.

    Raises:
        InvalidInputError: on an indentation session file, any table or key of an indentation
            session, and any malformed, missing or non-finite field, a non-positive force or an
            implausible depth, with the file, field, value and fix in the message.
    """
    path = Path(path)
    reader = _Reader(path)
    data = _read_toml(path)
    if _read_kind(reader, data) != "rigid_press":
        raise reader.fail(
            "kind",
            f"{data.get('kind', 'absent')!r}: an indentation session of an object, not a rigid-surface press",
            "load it with shelljax.session.load_session, or, if it records the finger pressed on a rigid "
            'table, write kind = "rigid_press" and keep only object, notes and [indentation]',
        )
    _reject_session_keys(reader, data)
    reader.no_unknown_keys(data, _PRESS_TOP_KEYS)
    header = _read_header(reader, data)  # with no session-only keys left, only the version, object and notes
    input_files = {str(path): file_sha256(path)}
    trial, force, depth, _, where = _read_indentation_samples(reader, data, input_files, positive_depth=False)
    largest = int(np.argmax(np.abs(depth)))
    if abs(depth[largest]) > _PRESS_MAX_DEPTH:
        raise reader.fail(
            f"indentation.depth[{largest}]",
            f"{where[largest]}{depth[largest]:g} m is more than a finger pad compresses "
            f"(|depth| <= {_PRESS_MAX_DEPTH:g} m)",
            'depths look like millimetres written as metres: set depth_unit = "mm"',
        )
    return RigidPress(
        source=path,
        object_name=header["object_name"],
        notes=header["notes"],
        trial=trial,
        force=force,
        depth=depth,
        sha256=files_sha256(input_files),
        rig_name=header["rig_name"],
    )


def _reject_session_keys(reader: _Reader, data: dict) -> None:
    """Fail on the first key that only an indentation session of an object may hold."""
    foreign = sorted(set(data) & (_TOP_KEYS - _PRESS_TOP_KEYS))
    if foreign:
        key = foreign[0]
        what = f"[{key}] table" if isinstance(data[key], dict) else f"'{key}' key"
        raise reader.fail(
            key,
            f'a rigid-surface press (kind = "rigid_press": the finger on a rigid table, no object) has no {what}',
            f'delete the {what}; if the file records an object, remove kind = "rigid_press" and load it with load_session',
        )
