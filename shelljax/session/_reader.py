"""The session files' use of the one TOML reader (shelljax._toml): their units, arrays and hash."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import numpy as np

from .._toml import TomlReader, read_toml
from ._units import QUANTITY_UNITS


def file_sha256(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def files_sha256(paths) -> str:
    """Hex sha256 of the files' bytes one after the other (a session's TOML, then the data files it
    reads): for one file, its own sha256."""
    digest = hashlib.sha256()
    for path in paths:
        digest.update(Path(path).read_bytes())
    return digest.hexdigest()


class _Reader(TomlReader):
    """The TOML reader with the session format's units; arrays come back as float64 NumPy arrays."""

    def __init__(self, path: Path):
        super().__init__(path, doc="docs/session-format.md")

    def unit(self, table: dict, key: str, quantity: str, default: str, prefix: str = "") -> float:
        """The SI factor of the ``quantity`` unit named by ``key`` (``default`` when absent)."""
        units = QUANTITY_UNITS[quantity]
        return units[self.choice(table, key, prefix, units, default, what=f"{quantity} unit")]

    def array(self, table: dict, key: str, prefix: str = "") -> np.ndarray:
        return np.asarray(super().array(table, key, prefix), dtype=np.float64)


def _read_toml(path: Path) -> dict[str, Any]:
    return read_toml(path, "session file", fix_missing="check the path")
