"""Reading and validating session TOML files (format: docs/session-format.md).

Every check raises :class:`InvalidInputError` naming the file, the field, the value and the fix.
Nothing is dropped or reordered: samples keep the order in which they were written. The optional
[shape] table is read by :mod:`._shape`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._errors import InvalidInputError
from ..paper import DEFAULT_POISSON_RATIO
from ._ranges import check_forwards, check_plausible, check_plausible_samples, check_spread, implausible
from ._reader import _csv_rows, _read_toml, _Reader, _unit_name, file_sha256
from ._schema import Session
from ._shape import _read_shape

SCHEMA_VERSION = 1

_TOP_KEYS = {
    "schema_version",
    "kind",
    "object",
    "notes",
    "rig",
    "poisson_ratio",
    "mass",
    "mass_unit",
    "manometer_gauge_pressure",
    "pressure_unit",
    "geometry",
    "wall",
    "indentation",
    "wrinkles",
    "shape",
}
_GEOMETRY_KEYS = {"radius", "radius_std", "mesh", "poke_point", "fit_radius", "length_unit"}
_WALL_KEYS = {"thickness", "thickness_std", "thickness_unit"}
_INDENTATION_KEYS = {"force_unit", "depth_unit", "trials_csv", "trial", "force", "depth"}
_WRINKLE_KEYS = {"counts", "onset_depth"}
_CSV_COLUMNS = ("trial", "force", "depth")
MIN_FORCE_LEVELS = 3
# The `kind` key: absent means an indentation session, the only kind before presses existed.
SESSION_KINDS = ("indentation", "rigid_press")


def _check_samples(reader: _Reader, field: str, values: np.ndarray, where: list[str], *, positive: bool = True) -> None:
    """Every value finite and, with ``positive``, above zero (a magnitude); the first offender
    named, with ``where[i]`` (its CSV line, or "") before the problem."""
    bad_finite = np.flatnonzero(~np.isfinite(values))
    if bad_finite.size:
        i = bad_finite[0]
        raise reader.fail(
            f"{field}[{i}]",
            f"{where[i]}value {float(values[i])!r} is not finite",
            "re-measure or delete that sample (the whole row, in every column)",
        )
    bad_sign = np.flatnonzero(values <= 0) if positive else np.empty(0, dtype=np.int64)
    if bad_sign.size:
        i = bad_sign[0]
        raise reader.fail(
            f"{field}[{i}]",
            f"{where[i]}value {float(values[i])!r} must be positive ({bad_sign.size} non-positive samples)",
            f"{field} is a magnitude: write |value|; drop samples taken before contact",
        )


def _read_trials_csv(reader: _Reader, csv_path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]:
    """(trial, force, depth) as written in the CSV, and each sample's line number."""
    rows = _csv_rows(reader, "indentation.trials_csv", csv_path)
    if not rows or [c.strip() for c in rows[0]] != list(_CSV_COLUMNS):
        header = rows[0] if rows else []
        raise InvalidInputError(
            f"{csv_path}: header is {header!r}. Fix: the first line must be exactly "
            f"'{','.join(_CSV_COLUMNS)}' (units are set in the session's [indentation] table)"
        )
    columns: list[list[float]] = [[], [], []]
    lines = []
    for line_number, row in enumerate(rows[1:], start=2):
        if not row or all(not c.strip() for c in row):
            continue
        lines.append(line_number)
        if len(row) != 3:
            raise InvalidInputError(
                f"{csv_path}, line {line_number}: expected 3 values (trial,force,depth), got "
                f"{len(row)}: {row!r}. Fix: complete or delete the row"
            )
        for k, cell in enumerate(row):
            try:
                columns[k].append(float(cell))
            except ValueError:
                raise InvalidInputError(
                    f"{csv_path}, line {line_number}, column '{_CSV_COLUMNS[k]}': {cell!r} is not "
                    "a number. Fix: write a plain decimal number"
                ) from None
    trial, force, depth = (np.asarray(c, dtype=np.float64) for c in columns)
    if trial.size == 0:
        raise InvalidInputError(f"{csv_path}: no samples. Fix: add rows 'trial,force,depth'")
    return trial, force, depth, lines


def _trial_ids(reader: _Reader, field: str, trial: np.ndarray) -> np.ndarray:
    if not np.all(np.isfinite(trial)) or np.any(trial != np.round(trial)):
        i = int(np.flatnonzero(~np.isfinite(trial) | (trial != np.round(trial)))[0])
        raise reader.fail(
            f"{field}[{i}]", f"trial id {float(trial[i])!r} is not an integer", "number trials 1, 2, 3, ..."
        )
    return trial.astype(np.int64)


def load_session(path: str | Path) -> Session:
    """Read and validate a session TOML file; return a :class:`Session` in SI units.

    Raises:
        InvalidInputError: on any malformed, missing, non-finite or implausible field, with the
            file, field, value and fix in the message.
    """
    path = Path(path)
    reader = _Reader(path)
    data = _read_toml(path)
    if _read_kind(reader, data) == "rigid_press":
        raise reader.fail(
            "kind",
            '"rigid_press": a rigid-surface press (the finger pressed on a rigid table), not an '
            "indentation session of an object; it serves `shelljax rig calibrate`",
            "pass it to `shelljax rig calibrate`, or load it with shelljax.session.load_rigid_press",
        )
    input_files = {str(path): file_sha256(path)}
    reader.no_unknown_keys(data, _TOP_KEYS)
    header = _read_header(reader, data)
    # Wall first: its thickness bounds the plausible radius.
    thickness, thickness_std = _read_wall(reader, data)
    geometry = _read_geometry(reader, data, input_files)
    if thickness >= 0.2 * geometry["radius"]:
        raise reader.fail(
            "wall.thickness",
            f"h = {thickness:g} m is not thin against R = {geometry['radius']:g} m",
            "check thickness_unit / length_unit; the shell model needs h << R",
        )
    trial, force, depth, depth_scale = _read_indentation(reader, data, geometry["radius"], input_files)
    wrinkle_counts, onset_depth = _read_wrinkles(reader, data, trial, depth_scale)
    shape_trial, shape_force, shape = _read_shape(reader, data, trial, input_files)
    return Session(
        source=path,
        **header,
        **geometry,
        thickness=float(thickness),
        thickness_std=float(thickness_std),
        trial=trial,
        force=force,
        depth=depth,
        wrinkle_counts=wrinkle_counts,
        onset_depth=onset_depth,
        shape_trial=shape_trial,
        shape_force=shape_force,
        shape=shape,
        input_files=input_files,
    )


def _read_kind(reader: _Reader, data: dict) -> str:
    """The parsed file's ``kind`` (one of ``SESSION_KINDS``; absent: ``"indentation"``)."""
    kind = data.get("kind", "indentation")
    if kind not in SESSION_KINDS:
        raise reader.fail(
            "kind",
            f"unknown session kind {kind!r}",
            f"write one of {', '.join(repr(k) for k in SESSION_KINDS)} (absent means 'indentation')",
        )
    return kind


def _read_header(reader: _Reader, data: dict) -> dict:
    """The top-level fields: object name, notes, Poisson ratio [-], mass [kg], manometer P_g [Pa]."""
    version = data.get("schema_version", SCHEMA_VERSION)
    if version != SCHEMA_VERSION:
        raise reader.fail(
            "schema_version", f"unsupported version {version!r}", f"write schema_version = {SCHEMA_VERSION}"
        )
    object_name = data.get("object")
    if not isinstance(object_name, str) or not object_name.strip():
        raise reader.fail("object", f"missing or empty (got {object_name!r})", 'add object = "name of the object"')
    notes = data.get("notes", "")
    if not isinstance(notes, str):
        raise reader.fail("notes", f"expected text, got {notes!r}", 'write notes = "..."')
    poisson_ratio = reader.number(data, "poisson_ratio", default=None)
    poisson_ratio = DEFAULT_POISSON_RATIO if poisson_ratio is None else poisson_ratio
    if not -1.0 < poisson_ratio < 0.5:
        raise reader.fail(
            "poisson_ratio", f"value {poisson_ratio} outside (-1, 0.5)", "rubbers sit at 0.3-0.5; the default is 0.4"
        )
    mass = reader.number(data, "mass", default=None, positive=True)
    if mass is not None:
        scale = reader.unit(data, "mass_unit", "mass", "kg")
        check_plausible(reader, "mass", "mass", mass, _unit_name(data, "mass_unit", "kg"), "mass_unit")
        mass *= scale
    manometer = reader.number(data, "manometer_gauge_pressure", default=None, positive=True)
    if manometer is not None:
        scale = reader.unit(data, "pressure_unit", "pressure", "Pa")
        check_plausible(
            reader,
            "pressure",
            "manometer_gauge_pressure",
            manometer,
            _unit_name(data, "pressure_unit", "Pa"),
            "pressure_unit",
        )
        manometer *= scale
    rig_name = data.get("rig")
    if rig_name is not None and (not isinstance(rig_name, str) or not rig_name.strip()):
        raise reader.fail(
            "rig", f"expected the measuring chain's name, got {rig_name!r}", 'write rig = "alice-index-film3"'
        )
    return {
        "object_name": object_name.strip(),
        "notes": notes,
        "poisson_ratio": float(poisson_ratio),
        "mass": mass,
        "manometer_gauge_pressure": manometer,
        "rig_name": rig_name and rig_name.strip(),
    }


def _read_wall(reader: _Reader, data: dict) -> tuple[float, float]:
    """(thickness h [m], its standard deviation [m]) from [wall]."""
    wall = reader.table(data, "wall", _WALL_KEYS, required=True)
    wall_scale = reader.unit(wall, "thickness_unit", "length", "m", "wall.")
    unit = _unit_name(wall, "thickness_unit", "m")
    thickness = reader.number(wall, "thickness", "wall.", positive=True)
    check_plausible(reader, "thickness", "wall.thickness", thickness, unit, "thickness_unit")
    thickness_std = reader.number(wall, "thickness_std", "wall.")
    if thickness_std < 0:
        raise reader.fail("wall.thickness_std", f"value {thickness_std} is negative", "write a standard deviation >= 0")
    check_spread(reader, "wall.thickness_std", thickness_std, thickness, unit, "thickness", "thickness_unit")
    return thickness * wall_scale, thickness_std * wall_scale


def _read_geometry(reader: _Reader, data: dict, input_files: dict) -> dict:
    """The Session's geometry fields from [geometry]: a given radius [m], or one fitted on a mesh."""
    geometry = reader.table(data, "geometry", _GEOMETRY_KEYS, required=True)
    length_scale = reader.unit(geometry, "length_unit", "length", "m", "geometry.")
    if ("radius" in geometry) == ("mesh" in geometry):
        raise reader.fail(
            "geometry",
            "give exactly one of 'radius' or 'mesh'",
            'write radius = <R> for a measured radius of curvature, or mesh = "file" with poke_point',
        )
    if "mesh" in geometry:
        radius, radius_std, mesh_path, poke_point, fit_radius, fit_rms, mesh_volume = _mesh_geometry(
            reader, geometry, length_scale, input_files
        )
        return {
            "radius": float(radius),
            "radius_std": float(radius_std),
            "mesh_path": mesh_path,
            "poke_point": poke_point,
            "fit_radius": fit_radius,
            "fit_rms_residual": fit_rms,
            "enclosed_volume": mesh_volume,
        }
    unit = _unit_name(geometry, "length_unit", "m")
    radius = reader.number(geometry, "radius", "geometry.", positive=True)
    check_plausible(reader, "radius", "geometry.radius", radius, unit, "length_unit")
    radius_std = reader.number(geometry, "radius_std", "geometry.", default=None, nonnegative=True) or 0.0
    check_spread(reader, "geometry.radius_std", radius_std, radius, unit, "radius", "length_unit")
    return {"radius": float(radius * length_scale), "radius_std": float(radius_std * length_scale)}


def _indentation_arrays(reader: _Reader, indentation: dict, input_files: dict):
    """(trial, force, depth) as written, from trials_csv or inline arrays, and where they came from."""
    inline = [k for k in ("trial", "force", "depth") if k in indentation]
    if "trials_csv" in indentation:
        if inline:
            raise reader.fail(
                "indentation.trials_csv",
                f"given together with inline '{inline[0]}'",
                "use either trials_csv or inline arrays, not both",
            )
        csv_path = reader.path.parent / str(indentation["trials_csv"])
        trial, force, depth, lines = _read_trials_csv(reader, csv_path)
        input_files[str(csv_path)] = file_sha256(csv_path)
        return trial, force, depth, [f"(in {csv_path.name}, line {n}) " for n in lines]
    for key in ("force", "depth"):
        if key not in indentation:
            raise reader.fail(
                f"indentation.{key}",
                "missing",
                'give inline force/depth arrays (and optional trial) or trials_csv = "file.csv"',
            )
    force = reader.array(indentation, "force", "indentation.")
    depth = reader.array(indentation, "depth", "indentation.")
    trial = reader.array(indentation, "trial", "indentation.") if "trial" in indentation else np.ones_like(force)
    if not (force.size == depth.size == trial.size):
        raise reader.fail(
            "indentation",
            f"arrays differ in length (trial {trial.size}, force {force.size}, depth {depth.size})",
            "give one trial id, force and depth per sample",
        )
    return trial, force, depth, [""] * force.size


def _read_indentation_samples(reader: _Reader, data: dict, input_files: dict, *, positive_depth: bool = True):
    """(trial ids, forces [N], depths [m], the depth unit [m], where) from [indentation], in SI.

    Every value is finite and every force positive and plausible; depths must be positive only
    with ``positive_depth`` (a rigid press reads the pad's compression plus the gauge's zero error,
    which may be zero or negative). ``where[i]`` names sample i's CSV line (or is "") for the
    callers' own messages.
    """
    indentation = reader.table(data, "indentation", _INDENTATION_KEYS, required=True)
    force_scale = reader.unit(indentation, "force_unit", "force", "N", "indentation.")
    depth_scale = reader.unit(indentation, "depth_unit", "length", "m", "indentation.")
    trial, force, depth, where = _indentation_arrays(reader, indentation, input_files)
    _check_samples(reader, "indentation.force", force, where)
    _check_samples(reader, "indentation.depth", depth, where, positive=positive_depth)
    check_plausible_samples(
        reader, "force", "indentation.force", force, _unit_name(indentation, "force_unit", "N"), "force_unit", where
    )
    trial = _trial_ids(reader, "indentation.trial", trial)
    return trial, force * force_scale, depth * depth_scale, depth_scale, where


def _read_indentation(reader: _Reader, data: dict, radius: float, input_files: dict):
    """(trial ids, forces [N], depths [m], the depth unit [m]) from [indentation], checked against R [m]."""
    trial, force, depth, depth_scale, where = _read_indentation_samples(reader, data, input_files)
    if np.unique(force).size < MIN_FORCE_LEVELS:
        raise reader.fail(
            "indentation.force",
            f"only {np.unique(force).size} distinct force level(s) {np.unique(force).tolist()} N",
            f"record at least {MIN_FORCE_LEVELS} levels (the paper uses 5-20 N in 2.5 N steps)",
        )
    deepest = float(depth.max())
    if deepest >= radius:
        raise reader.fail(
            "indentation.depth",
            f"deepest indentation {deepest:g} m exceeds the radius {radius:g} m",
            'depths look like millimetres written as metres: set depth_unit = "mm"',
        )
    unit = _unit_name(data["indentation"], "depth_unit", "m")
    check_plausible_samples(reader, "depth", "indentation.depth", depth / depth_scale, unit, "depth_unit", where)
    check_forwards(reader, trial, force, depth / depth_scale, unit, where)
    return trial, force, depth, depth_scale


def _read_wrinkles(reader: _Reader, data: dict, trial: np.ndarray, depth_scale: float):
    """(one wrinkle count per trial or None, onset depths [m] or None) from [wrinkles]."""
    wrinkles = reader.table(data, "wrinkles", _WRINKLE_KEYS, required=False)
    if wrinkles is None:
        return None, None
    wrinkle_counts = onset_depth = None
    if "counts" in wrinkles:
        wrinkle_counts = _wrinkle_counts(reader, wrinkles["counts"], np.unique(trial).size)
    if "onset_depth" in wrinkles:
        onset_depth = reader.array(wrinkles, "onset_depth", "wrinkles.")
        _check_samples(reader, "wrinkles.onset_depth", onset_depth, [""] * onset_depth.size)
        check_plausible_samples(
            reader,
            "depth",
            "wrinkles.onset_depth",
            onset_depth,
            _unit_name(data["indentation"], "depth_unit", "m"),
            "depth_unit in [indentation]",
            [""] * onset_depth.size,
        )
        onset_depth = onset_depth * depth_scale
    return wrinkle_counts, onset_depth


def _wrinkle_counts(reader: _Reader, counts, n_trials: int) -> np.ndarray:
    if not isinstance(counts, list) or not counts:
        raise reader.fail(
            "wrinkles.counts", f"expected a non-empty array, got {counts!r}", "write counts = [n1, n2, ...]"
        )
    for i, c in enumerate(counts):
        if isinstance(c, bool) or not isinstance(c, int) or c < 0:
            raise reader.fail(
                f"wrinkles.counts[{i}]",
                f"{c!r} is not a non-negative integer",
                "count whole wrinkles around the poke (0 if none)",
            )
    if len(counts) != n_trials:
        raise reader.fail(
            "wrinkles.counts",
            f"{len(counts)} counts for {n_trials} trials",
            "give exactly one wrinkle count per trial, in order of trial id",
        )
    return np.asarray(counts, dtype=np.int64)


def _mesh_geometry(reader: _Reader, geometry: dict, length_scale: float, input_files: dict):
    from .. import geometry as geo  # trimesh is only needed for mesh sessions

    mesh_path = reader.path.parent / str(geometry["mesh"])
    if "poke_point" not in geometry:
        raise reader.fail("geometry.poke_point", "missing (required with mesh)", "add poke_point = [x, y, z]")
    raw_point = geometry["poke_point"]
    if (
        not isinstance(raw_point, list)
        or len(raw_point) != 3
        or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in raw_point)
    ):
        raise reader.fail("geometry.poke_point", f"expected [x, y, z], got {raw_point!r}", "write three numbers")
    poke_point = np.asarray(raw_point, dtype=np.float64) * length_scale
    if not np.all(np.isfinite(poke_point)):
        raise reader.fail("geometry.poke_point", f"{raw_point!r} is not finite", "write three finite numbers")
    fit_radius = reader.number(geometry, "fit_radius", "geometry.", default=None, positive=True)
    unit_name = _unit_name(geometry, "length_unit", "m")
    if fit_radius is not None:
        check_plausible(reader, "fit_radius", "geometry.fit_radius", fit_radius, unit_name, "length_unit")
        fit_radius *= length_scale
    try:
        mesh = geo.load_mesh(mesh_path, length_unit=unit_name)
        local = geo.fit_local_sphere(mesh, poke_point, fit_radius)
        # an open photogrammetry scan has no volume; forward_model_for warns if the sealed gas needs it
        volume = geo.enclosed_volume(mesh) if mesh.is_watertight else None
    except InvalidInputError as err:
        raise InvalidInputError(f"{reader.path}: field 'geometry.mesh': {err}") from None
    problem = implausible("radius", local.radius, "m")
    if problem is not None:
        raise reader.fail(
            "geometry.mesh",
            f"the sphere fitted at poke_point: {problem}",
            "check length_unit (it applies to the mesh's coordinates and poke_point) and fit_radius",
        )
    input_files[str(mesh_path)] = file_sha256(mesh_path)
    return local.radius, local.radius_std, mesh_path, poke_point, fit_radius, local.rms_residual, volume
