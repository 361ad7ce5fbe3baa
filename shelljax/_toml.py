"""The one reader of shelljax's TOML inputs: sessions, experiment and scenario configs, rig files
and force-sensor calibrations.

Every check raises :class:`~shelljax.InvalidInputError` in one shape,
``<file>: field '<field>'[ = <value>]: <problem>. Fix: <fix>``, so a user always learns which
file, which field, what was wrong with the value and what to write instead. It imports only
``tomllib`` and the error types, so every layer may use it.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

from ._errors import InvalidInputError

#: ``default`` of the readers' value methods: the key must be present.
REQUIRED: Any = object()
_NO_VALUE = object()


def read_toml(
    path: str | Path, what: str, *, fix_missing: str, fix_syntax: str = "correct the syntax"
) -> dict[str, Any]:
    """The TOML document at ``path`` (``what``: "session file", "rig file", ... for the messages).

    Raises InvalidInputError when there is no such file (fix: ``fix_missing``), when it is not
    UTF-8, or when it is not valid TOML (fix: ``fix_syntax``).
    """
    path = Path(path)
    if not path.is_file():
        raise InvalidInputError(f"{path}: {what} does not exist. Fix: {fix_missing}")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InvalidInputError(f"{path}: not a UTF-8 text file. Fix: save it as UTF-8 TOML") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise InvalidInputError(f"{path}: not valid TOML ({err}). Fix: {fix_syntax}") from None


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


class TomlReader:
    """Checked access to the fields of one TOML document, read from ``path``.

    ``fix``: the fix of every failure whose caller names none (files a program writes, such as a
    rig file, are re-created rather than edited); without it each check gives its own. ``doc``: the
    page that documents the format, named where a required table is missing. Keys are named by
    ``prefix + key``, e.g. ``prefix="wall."`` for the ``[wall]`` table.
    """

    def __init__(self, path: str | Path, *, fix: str | None = None, doc: str | None = None):
        self.path = Path(path)
        self.fix = fix
        self.doc = doc

    def fail(self, field: str, problem: str, fix: str | None = None, *, value: Any = _NO_VALUE) -> InvalidInputError:
        """The error for ``field`` (its ``value`` when given); the caller raises it."""
        shown = "" if value is _NO_VALUE else f" = {value!r}"
        return InvalidInputError(
            f"{self.path}: field '{field}'{shown}: {problem}. Fix: {fix or self.fix or 'correct it'}"
        )

    def _fix(self, fix: str | None, own: str) -> str:
        return fix or self.fix or own

    def no_unknown_keys(self, table: Mapping, allowed: Collection[str], prefix: str = "") -> None:
        """Refuse keys of ``table`` outside ``allowed`` (a misspelt key would otherwise be ignored)."""
        unknown = sorted(set(table) - set(allowed))
        if unknown:
            raise self.fail(
                prefix + unknown[0],
                f"unknown key (unknown keys: {', '.join(prefix + k for k in unknown)})",
                f"remove it or fix its spelling; allowed keys here: {', '.join(sorted(allowed))}",
            )

    def table(
        self,
        data: Mapping,
        name: str,
        allowed: Collection[str] | None = None,
        *,
        required: bool = False,
        prefix: str = "",
    ) -> dict | None:
        """The table ``data[name]`` with only ``allowed`` keys (None: any), or None when absent and not required."""
        if name not in data:
            if required:
                see = f" (see {self.doc})" if self.doc else ""
                raise self.fail(prefix + name, "missing table", self._fix(None, f"add a [{prefix + name}] table{see}"))
            return None
        table = data[name]
        if not isinstance(table, dict):
            raise self.fail(
                prefix + name, f"expected a table, got {table!r}", self._fix(None, f"write it as [{prefix + name}]")
            )
        if allowed is not None:
            self.no_unknown_keys(table, allowed, prefix=f"{prefix}{name}.")
        return table

    def number(
        self,
        table: Mapping,
        key: str,
        prefix: str = "",
        *,
        default: Any = REQUIRED,
        positive: bool = False,
        nonnegative: bool = False,
        fix: str | None = None,
    ) -> float | None:
        """A finite number as float (``default`` when absent, REQUIRED: it must be there)."""
        field = prefix + key
        if key not in table:
            if default is REQUIRED:
                raise self.fail(field, "missing", self._fix(fix, f"add '{key} = <value>'"))
            return default
        value = table[key]
        if not _is_number(value):
            raise self.fail(field, f"expected a number, got {value!r}", self._fix(fix, "write a plain number"))
        if not math.isfinite(value):
            raise self.fail(field, f"value {value!r} is not finite", self._fix(fix, "write a finite number"))
        if positive and value <= 0:
            raise self.fail(field, f"value {value!r} must be positive", self._fix(fix, "write a positive number"))
        if nonnegative and value < 0:
            raise self.fail(field, f"value {value!r} must be non-negative", self._fix(fix, "write a number ≥ 0"))
        return float(value)

    def integer(
        self,
        table: Mapping,
        key: str,
        prefix: str = "",
        *,
        default: Any = REQUIRED,
        minimum: int = 0,
        fix: str | None = None,
    ) -> int:
        """An integer ≥ ``minimum`` (``default`` when absent)."""
        field = prefix + key
        if key not in table:
            if default is REQUIRED:
                raise self.fail(field, "missing", self._fix(fix, f"add '{key} = <integer>'"))
            return default
        value = table[key]
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            kind = "a non-negative integer" if minimum == 0 else f"an integer >= {minimum}"
            raise self.fail(field, f"{value!r} is not {kind}", self._fix(fix, f"e.g. {key} = {max(minimum, 0)}"))
        return value

    def flag(self, table: Mapping, key: str, prefix: str = "", *, default: bool) -> bool:
        """A boolean (``default`` when absent)."""
        value = table.get(key, default)
        if not isinstance(value, bool):
            raise self.fail(prefix + key, f"{value!r} is not true/false", self._fix(None, "write true or false"))
        return value

    def choice(
        self,
        table: Mapping,
        key: str,
        prefix: str = "",
        options: Collection = (),
        default: Any = REQUIRED,
        *,
        what: str = "value",
    ) -> Any:
        """One of ``options`` (``default`` when absent); ``what`` names the kind of choice in the message."""
        if key not in table and default is REQUIRED:
            raise self.fail(prefix + key, "missing", self._fix(None, f"use one of {', '.join(map(str, options))}"))
        value = table.get(key, default)
        if not isinstance(value, (str, int, float)) or value not in options:
            raise self.fail(
                prefix + key, f"unknown {what} {value!r}", self._fix(None, f"use one of {', '.join(map(str, options))}")
            )
        return value

    def vector(
        self, table: Mapping, key: str, prefix: str = "", size: int = 3, default: Any = REQUIRED
    ) -> tuple[float, ...]:
        """A list of exactly ``size`` numbers, as floats (``default`` when absent)."""
        value = table.get(key, None if default is REQUIRED else default)
        if not (isinstance(value, list) and len(value) == size and all(_is_number(v) for v in value)):
            raise self.fail(
                prefix + key,
                f"expected a list of {size} numbers",
                self._fix(None, f"write e.g. {[0.0] * size}"),
                value=value,
            )
        return tuple(float(v) for v in value)

    def direction(
        self, table: Mapping, key: str, prefix: str = "", *, fix: str, default: Any = REQUIRED
    ) -> tuple[float, ...]:
        """A nonzero list of 3 numbers, as floats, as given (a normal or an axis; not normalised);
        ``fix`` says which way it should point."""
        vector = self.vector(table, key, prefix, 3, default=default)
        if not any(vector):
            raise self.fail(prefix + key, "must be nonzero", fix, value=list(vector))
        return vector

    def entry(self, entry: Any, array: str, index: int, allowed: Collection[str]) -> str:
        """Check that item ``index`` of the array of tables ``array`` is a table with only ``allowed``
        keys; return its fields' prefix, ``"<array>[<index>]."``."""
        if not isinstance(entry, dict):
            raise self.fail(f"{array}[{index}]", "expected a table", f"write it as [[{array}]]", value=entry)
        prefix = f"{array}[{index}]."
        self.no_unknown_keys(entry, allowed, prefix)
        return prefix

    def array(self, table: Mapping, key: str, prefix: str = "") -> list[float]:
        """A non-empty list of numbers (any value, NaN included: the caller checks what it needs)."""
        field = prefix + key
        values = table.get(key)
        if not isinstance(values, list) or not values:
            raise self.fail(
                field, f"expected a non-empty array, got {values!r}", self._fix(None, f"write '{key} = [v1, v2, ...]'")
            )
        for i, v in enumerate(values):
            if not _is_number(v):
                raise self.fail(
                    f"{field}[{i}]", f"expected a number, got {v!r}", self._fix(None, "write plain numbers")
                )
        return [float(v) for v in values]

    def typed(self, table: Mapping, key: str, kind: type, prefix: str = "", *, fix: str | None = None):
        """The value of ``key``, which must be there and be a ``kind`` (float: finite; an int is accepted)."""
        field = prefix + key
        if key not in table:
            raise self.fail(field, "missing", self._fix(fix, f"add '{key}'"))
        value = table[key]
        if kind is float and _is_number(value):
            value = float(value)
        if not isinstance(value, kind) or (kind is float and not math.isfinite(value)):
            raise self.fail(
                field,
                f"{value!r} is not a {'finite number' if kind is float else kind.__name__}",
                self._fix(fix, f"write a {kind.__name__}"),
            )
        return value
