"""The TOML reader of session files: field access that names the file, field, value and fix."""

from __future__ import annotations

import hashlib
import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from .._errors import InvalidInputError
from ._units import QUANTITY_UNITS


def file_sha256(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


class _Reader:
    """Field access that knows which file and table it reads from, for error messages."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, field: str, problem: str, fix: str) -> InvalidInputError:
        return InvalidInputError(f"{self.path}: field '{field}': {problem}. Fix: {fix}")

    def table(self, data: dict, name: str, keys: set[str], *, required: bool) -> dict | None:
        if name not in data:
            if required:
                raise self.fail(name, "missing table", f"add a [{name}] table (see docs/session-format.md)")
            return None
        table = data[name]
        if not isinstance(table, dict):
            raise self.fail(name, f"expected a table, got {table!r}", f"write it as [{name}]")
        self.no_unknown_keys(table, keys, prefix=f"{name}.")
        return table

    def no_unknown_keys(self, table: dict, allowed: set[str], prefix: str = "") -> None:
        unknown = sorted(set(table) - allowed)
        if unknown:
            raise self.fail(
                prefix + unknown[0],
                f"unknown key (unknown keys: {', '.join(prefix + k for k in unknown)})",
                f"remove it or fix its spelling; allowed keys here: {', '.join(sorted(allowed))}",
            )

    def unit(self, table: dict, key: str, quantity: str, default: str, prefix: str = "") -> float:
        name = table.get(key, default)
        units = QUANTITY_UNITS[quantity]
        if name not in units:
            raise self.fail(prefix + key, f"unknown {quantity} unit {name!r}", f"use one of {', '.join(units)}")
        return units[name]

    def number(self, table: dict, key: str, prefix: str = "", *, required: bool = True,
               positive: bool = True) -> float | None:  # fmt: skip
        field = prefix + key
        if key not in table:
            if required:
                raise self.fail(field, "missing", f"add '{key} = <value>'")
            return None
        value = table[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(field, f"expected a number, got {value!r}", "write a plain number")
        if not math.isfinite(value):
            raise self.fail(field, f"value {value!r} is not finite", "write a finite number")
        if positive and value <= 0:
            raise self.fail(field, f"value {value!r} must be positive", "write a positive number")
        return float(value)

    def array(self, table: dict, key: str, prefix: str = "") -> np.ndarray:
        field = prefix + key
        values = table[key]
        if not isinstance(values, list) or not values:
            raise self.fail(field, f"expected a non-empty array, got {values!r}", f"write '{key} = [v1, v2, ...]'")
        for i, v in enumerate(values):
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise self.fail(f"{field}[{i}]", f"expected a number, got {v!r}", "write plain numbers")
        return np.asarray(values, dtype=np.float64)


def _read_toml(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise InvalidInputError(f"{path}: session file does not exist. Fix: check the path")
    try:
        return tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise InvalidInputError(f"{path}: not valid TOML ({err}). Fix: correct the syntax") from None
    except UnicodeDecodeError:
        raise InvalidInputError(f"{path}: not a UTF-8 text file. Fix: save it as UTF-8 TOML") from None
