"""The session files' use of the one TOML reader (shelljax._toml): their units, arrays, CSV rows and hash."""

from __future__ import annotations

import csv
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


def _unit_name(table: dict, key: str, default: str) -> str:
    """The unit ``key`` names (already checked by ``_Reader.unit``), or ``default``."""
    return table.get(key, default)


def _csv_rows(reader: _Reader, field: str, csv_path: Path) -> list[list[str]]:
    """The rows of the CSV that ``field`` names, or an error saying the file is missing."""
    if not csv_path.is_file():
        raise reader.fail(
            field,
            f"file {csv_path} does not exist",
            "put the CSV beside the session file or fix the path (relative to the TOML)",
        )
    with csv_path.open(newline="") as handle:
        return list(csv.reader(handle))
