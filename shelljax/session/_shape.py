"""The optional [shape] table of a session (format: docs/session-format.md): shape observables
measured during the indentation, inline or in a CSV, validated and converted to SI.

Every check raises :class:`InvalidInputError` naming the file, the field, the value and the fix.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .._errors import InvalidInputError
from ._ranges import check_plausible_samples
from ._reader import _csv_rows, _Reader, _unit_name, file_sha256
from ._schema import SHAPE_OBSERVABLES

_SHAPE_KEYS = {"length_unit", "force_unit", "shape_csv", "trial", "force", *SHAPE_OBSERVABLES}
_SHAPE_COLUMNS = ("trial", "force", *SHAPE_OBSERVABLES)
# A shape column: the values as written and which of them were measured (False: an empty CSV cell).
_ShapeColumns = dict[str, tuple[np.ndarray, np.ndarray]]


def _read_shape(reader: _Reader, data: dict, trial: np.ndarray, input_files: dict):
    """The optional [shape] table in SI: (trial ids, forces [N], observables [m], NaN = not measured).

    All three are None when the session has no [shape] table.
    """
    table = reader.table(data, "shape", _SHAPE_KEYS, required=False)
    if table is None:
        return None, None, None
    length_scale = reader.unit(table, "length_unit", "length", "m", "shape.")
    force_scale = reader.unit(table, "force_unit", "force", "N", "shape.")
    inline = [k for k in _SHAPE_COLUMNS if k in table]
    if ("shape_csv" in table) == bool(inline):
        given = f"shape_csv together with inline '{inline[0]}'" if inline else "neither"
        raise reader.fail(
            "shape",
            f"give exactly one of shape_csv or inline arrays (got {given})",
            'write shape_csv = "file.csv" or inline trial, force and observable arrays, not both',
        )
    if "shape_csv" in table:
        if not isinstance(table["shape_csv"], str) or not table["shape_csv"].strip():
            raise reader.fail(
                "shape.shape_csv", f"expected a file name, got {table['shape_csv']!r}", 'write shape_csv = "file.csv"'
            )
        csv_path = reader.path.parent / table["shape_csv"]
        columns, lines = _read_shape_csv(reader, csv_path)
        input_files[str(csv_path)] = file_sha256(csv_path)
        where = [f"(in {csv_path.name}, line {n}) " for n in lines]
    else:
        columns = _inline_shape_columns(reader, table)
        where = [""] * columns["trial"][0].size
    units = (_unit_name(table, "length_unit", "m"), _unit_name(table, "force_unit", "N"))
    return _check_shape(reader, columns, where, np.unique(trial), length_scale, force_scale, units)


def _inline_shape_columns(reader: _Reader, table: dict) -> _ShapeColumns:
    for key in ("trial", "force"):
        if key not in table:
            raise reader.fail(f"shape.{key}", "missing", "give inline trial, force and observable arrays, or shape_csv")
    names = [k for k in _SHAPE_COLUMNS if k in table]
    if len(names) == 2:
        raise reader.fail("shape", "no observable given", f"add at least one of {', '.join(SHAPE_OBSERVABLES)}")
    values = {k: reader.array(table, k, "shape.") for k in names}
    if len({v.size for v in values.values()}) > 1:
        sizes = ", ".join(f"{k} {v.size}" for k, v in values.items())
        raise reader.fail(
            "shape",
            f"arrays differ in length ({sizes})",
            "give one value per shape point in every array; to leave a point unmeasured use "
            "shape_csv with an empty cell",
        )
    return {k: (v, np.ones(v.size, dtype=bool)) for k, v in values.items()}


def _read_shape_csv(reader: _Reader, csv_path: Path) -> tuple[_ShapeColumns, list[int]]:
    """Columns of a shape CSV (an empty observable cell = not measured) and each row's line number."""
    rows = _csv_rows(reader, "shape.shape_csv", csv_path)
    header = [c.strip() for c in rows[0]] if rows else []
    fix_header = (
        f"the first line names trial, force and at least one of {', '.join(SHAPE_OBSERVABLES)}, "
        "each once (units are set in the session's [shape] table)"
    )
    for name in header:
        if name not in _SHAPE_COLUMNS:
            raise InvalidInputError(
                f"{csv_path}: header column {name!r} is unknown (header {header!r}). Fix: {fix_header}"
            )
        if header.count(name) > 1:
            raise InvalidInputError(
                f"{csv_path}: header column {name!r} appears {header.count(name)} times. Fix: {fix_header}"
            )
    for name in ("trial", "force"):
        if name not in header:
            raise InvalidInputError(f"{csv_path}: header {header!r} has no {name!r} column. Fix: {fix_header}")
    if len(header) == 2:
        raise InvalidInputError(f"{csv_path}: header {header!r} has no observable column. Fix: {fix_header}")
    values: dict[str, list[float]] = {name: [] for name in header}
    measured: dict[str, list[bool]] = {name: [] for name in header}
    lines = []
    for line_number, row in enumerate(rows[1:], start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            raise InvalidInputError(
                f"{csv_path}, line {line_number}: expected {len(header)} cells ({','.join(header)}), "
                f"got {len(row)}: {row!r}. Fix: complete or delete the row (leave a cell empty, not "
                "absent, where an observable was not measured)"
            )
        for name, cell in zip(header, row):
            cell = cell.strip()
            if not cell and name in SHAPE_OBSERVABLES:
                values[name].append(math.nan)
                measured[name].append(False)
                continue
            try:
                values[name].append(float(cell))
            except ValueError:
                fix = "write a plain decimal number" + (
                    "" if name in ("trial", "force") else ", or leave it empty if not measured"
                )
                raise InvalidInputError(
                    f"{csv_path}, line {line_number}, column '{name}': {cell!r} is not a number. Fix: {fix}"
                ) from None
            measured[name].append(True)
        lines.append(line_number)
    if not lines:
        raise InvalidInputError(f"{csv_path}: no shape points. Fix: add rows '{','.join(header)}'")
    for name in header:
        if not any(measured[name]):
            raise InvalidInputError(
                f"{csv_path}: column '{name}' is empty in every row. Fix: fill in its measured values "
                "or delete the column"
            )
    columns = {name: (np.asarray(values[name], dtype=np.float64), np.asarray(measured[name])) for name in header}
    return columns, lines


def _check_shape(
    reader: _Reader,
    columns: _ShapeColumns,
    where: list[str],
    trial_ids: np.ndarray,
    length_scale: float,
    force_scale: float,
    units: tuple[str, str],
):
    """Validate parsed shape columns (values as written; ``units``: the length and force units
    they are written in) and convert them to SI."""
    for name, (values, measured) in columns.items():
        field = f"shape.{name}"
        bad = np.flatnonzero(measured & ~np.isfinite(values))
        if bad.size:
            i = bad[0]
            raise reader.fail(
                f"{field}[{i}]",
                f"{where[i]}value {float(values[i])!r} is not finite",
                "write the measured value; in shape_csv leave the cell empty if it was not measured",
            )
        if name == "trial":
            bad = np.flatnonzero(values != np.round(values))
            if bad.size:
                i = bad[0]
                raise reader.fail(
                    f"{field}[{i}]",
                    f"{where[i]}trial id {float(values[i])!r} is not an integer",
                    "number trials 1, 2, 3, ...",
                )
            bad = np.flatnonzero(~np.isin(values, trial_ids))
            if bad.size:
                i = bad[0]
                raise reader.fail(
                    f"{field}[{i}]",
                    f"{where[i]}trial id {float(values[i]):g} is not among the [indentation] "
                    f"trial ids {trial_ids.tolist()}",
                    "give the id of the indentation trial during which the shape was measured",
                )
            continue
        zero_ok = name == "sunken_depth"  # no dimple yet: the poke point is the highest point
        bad = np.flatnonzero(measured & ((values < 0) if zero_ok else (values <= 0)))
        if bad.size:
            i = bad[0]
            sign = "non-negative" if zero_ok else "positive"
            raise reader.fail(
                f"{field}[{i}]",
                f"{where[i]}value {float(values[i])!r} must be {sign}",
                f"{name} is a {'force magnitude' if name == 'force' else 'length'}: write |value|",
            )
        if name == "force":
            kind, unit, unit_key = "force", units[1], "force_unit in [shape]"
        else:
            kind, unit, unit_key = "shape_length", units[0], "length_unit in [shape]"
        checked = measured & ~((values == 0) & zero_ok)  # a sunken depth of 0: no dimple yet
        check_plausible_samples(reader, kind, field, np.where(checked, values, np.nan), unit, unit_key, where)
    unmeasured = np.flatnonzero(~np.any([columns[k][1] for k in columns if k in SHAPE_OBSERVABLES], axis=0))
    if unmeasured.size:
        i = unmeasured[0]
        raise reader.fail(
            f"shape[{i}]",
            f"{where[i]}shape point {i} (trial {columns['trial'][0][i]:g}, force "
            f"{columns['force'][0][i]:g}) has no measured observable",
            "fill in what was measured at that point or delete the row",
        )
    shape_trial = columns["trial"][0].astype(np.int64)
    shape_force = columns["force"][0] * force_scale
    shape = {k: columns[k][0] * length_scale for k in SHAPE_OBSERVABLES if k in columns}
    return shape_trial, shape_force, shape
