"""Writing session files (format: docs/session-format.md) from SI values, for scripts.

Each writer checks what it writes with its reader (:func:`load_session`, :func:`load_rigid_press`)
before anything reaches the target path, so a script cannot leave behind a file that the reader
would reject.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import tomli_w

from .._errors import InvalidInputError
from ..paper import DEFAULT_POISSON_RATIO
from ._load import SCHEMA_VERSION, load_session
from ._press import load_rigid_press
from ._schema import SHAPE_OBSERVABLES, RigidPress, Session

_HEADER = "# Written by shelljax.session.{writer}; format: docs/session-format.md; SI units.\n"


def _vector(argument: str, values, writer: str = "write_session") -> np.ndarray:
    array = np.asarray(values, dtype=np.float64)
    if array.ndim != 1 or array.size == 0:
        raise InvalidInputError(
            f"{writer}: argument '{argument}' must be a non-empty 1-D array, got shape "
            f"{array.shape}. Fix: pass one value per sample"
        )
    return array


def _ids(array: np.ndarray) -> list:
    # Integral ids are written as TOML/CSV integers; anything else is written as it is, for the
    # reader to reject with the offending value.
    if np.all(np.isfinite(array)) and np.all(array == np.round(array)):
        return array.astype(np.int64).tolist()
    return array.tolist()


def _shape_csv(shape: dict) -> str:
    """The shape CSV text: header trial,force,<observables>; a NaN observable is an empty cell."""
    unknown = sorted(set(shape) - {"trial", "force", *SHAPE_OBSERVABLES})
    missing = [k for k in ("trial", "force") if k not in shape]
    observables = [k for k in SHAPE_OBSERVABLES if k in shape]
    if unknown or missing or not observables:
        problem = (
            f"unknown key {unknown[0]!r}" if unknown else f"missing key {missing[0]!r}" if missing else "no observable"
        )
        raise InvalidInputError(
            f"write_session: argument 'shape': {problem} (keys {sorted(shape)}). Fix: give 'trial', "
            f"'force' [N] and at least one of {', '.join(SHAPE_OBSERVABLES)} [m]"
        )
    columns = {k: _vector(f"shape['{k}']", shape[k]) for k in ("trial", "force", *observables)}
    sizes = {k: v.size for k, v in columns.items()}
    if len(set(sizes.values())) > 1:
        raise InvalidInputError(
            f"write_session: argument 'shape': arrays differ in length ({sizes}). Fix: give one "
            "value per shape point in every array, NaN where an observable was not measured"
        )
    cells = {"trial": [str(t) for t in _ids(columns["trial"])], "force": [repr(float(f)) for f in columns["force"]]}
    for k in observables:
        cells[k] = ["" if math.isnan(v) else repr(float(v)) for v in columns[k]]
    rows = [",".join(cells[k][i] for k in cells) for i in range(columns["trial"].size)]
    return "\n".join([",".join(cells), *rows]) + "\n"


def write_session(
    path: str | Path,
    *,
    object_name: str,
    radius: float,
    radius_std: float,
    thickness: float,
    thickness_std: float,
    trial,
    force,
    depth,
    wrinkle_counts=None,
    manometer_gauge_pressure: float | None = None,
    mass: float | None = None,
    poisson_ratio: float = DEFAULT_POISSON_RATIO,
    notes: str = "",
    shape: dict | None = None,
    rig_name: str | None = None,
) -> Session:
    """Write a session TOML (and, with ``shape``, a shape CSV beside it); return it as loaded.

    Every value is in SI units and is written in SI units (inline arrays in the TOML). With
    ``shape``, the shape points go to ``<stem>_shape.csv`` beside ``path``, where an empty cell
    stands for an observable not measured at that point.

    Args:
        path: the session TOML to write (``.toml``); its directory is created if missing.
        object_name: free name of the object.
        radius, radius_std: local radius of curvature R at the poke point and its std [m].
        thickness, thickness_std: wall thickness h and its std [m].
        trial: trial id of each indentation sample, shape (n,).
        force: indenter force F of each sample [N], shape (n,).
        depth: indentation depth |w(0)| of each sample [m] (positive), shape (n,).
        wrinkle_counts: radial wrinkle count per trial, in order of trial id; None to omit.
        manometer_gauge_pressure: manometer reading P_g [Pa]; None to omit.
        mass: total mass [kg]; None to omit.
        poisson_ratio: ν [-].
        notes: free text.
        shape: the measured deformed shape: ``"trial"`` and ``"force"`` [N], shape (m,), and any
            of ``SHAPE_OBSERVABLES`` [m], shape (m,), NaN where not measured; None to omit.
        rig_name: the name of the measuring chain it was recorded with (``rig``); None to omit.

    Returns:
        The written session, as :func:`load_session` reads it back.

    Raises:
        InvalidInputError: when an argument is malformed, or the session would not load (the
            message is the reader's, naming the target file and field); nothing is written then.
    """
    path = Path(path)
    if path.suffix != ".toml":
        raise InvalidInputError(f"write_session: path {path} does not end in .toml. Fix: name the session NAME.toml")
    doc = _session_document(
        object_name=object_name,
        radius=radius,
        radius_std=radius_std,
        thickness=thickness,
        thickness_std=thickness_std,
        trial=trial,
        force=force,
        depth=depth,
        wrinkle_counts=wrinkle_counts,
        manometer_gauge_pressure=manometer_gauge_pressure,
        mass=mass,
        poisson_ratio=poisson_ratio,
        notes=notes,
        rig_name=rig_name,
    )
    files: dict[str, str] = {}
    if shape is not None:
        csv_name = f"{path.stem}_shape.csv"
        doc["shape"] = {"length_unit": "m", "force_unit": "N", "shape_csv": csv_name}
        files[csv_name] = _shape_csv(shape)
    files[path.name] = _HEADER.format(writer="write_session") + tomli_w.dumps(doc)
    _write_if_valid(path, files, load_session)
    return load_session(path)


def write_rigid_press(
    path: str | Path, *, object_name: str, trial, force, depth, notes: str = "", rig_name: str | None = None
) -> RigidPress:
    """Write a rigid-surface press TOML (``kind = "rigid_press"``); return it as loaded.

    Every value is in SI units and is written in SI units (inline arrays, ``force_unit = "N"``,
    ``depth_unit = "m"``).

    Args:
        path: the press TOML to write (``.toml``); its directory is created if missing.
        object_name: what the finger was pressed on (e.g. "table").
        trial: trial id of each sample, shape (n,).
        force: force F read by the sensor at each sample [N] (positive), shape (n,).
        depth: recorded depth of each sample [m]: the finger pad's compression plus the depth
            gauge's zero error (may be zero or negative), shape (n,).
        notes: free text.
        rig_name: the name of the measuring chain pressed (``rig``), or None.

    Returns:
        The written press, as :func:`load_rigid_press` reads it back.

    Raises:
        InvalidInputError: when an argument is malformed, or the press would not load (the
            message is the reader's, naming the target file and field); nothing is written then.
    """
    path = Path(path)
    writer = "write_rigid_press"
    if path.suffix != ".toml":
        raise InvalidInputError(f"{writer}: path {path} does not end in .toml. Fix: name the press file NAME.toml")
    doc: dict = {"schema_version": SCHEMA_VERSION, "kind": "rigid_press", "object": object_name}
    if notes:
        doc["notes"] = notes
    if rig_name:
        doc["rig"] = rig_name
    doc["indentation"] = {
        "force_unit": "N",
        "depth_unit": "m",
        "trial": _ids(_vector("trial", trial, writer)),
        "force": _vector("force", force, writer).tolist(),
        "depth": _vector("depth", depth, writer).tolist(),
    }
    _write_if_valid(path, {path.name: _HEADER.format(writer=writer) + tomli_w.dumps(doc)}, load_rigid_press)
    return load_rigid_press(path)


def _session_document(
    *,
    object_name,
    radius,
    radius_std,
    thickness,
    thickness_std,
    trial,
    force,
    depth,
    wrinkle_counts,
    manometer_gauge_pressure,
    mass,
    poisson_ratio,
    notes,
    rig_name,
) -> dict:
    """The session TOML's tables, every value in SI units (see :func:`write_session`)."""
    doc: dict = {"schema_version": SCHEMA_VERSION, "object": object_name}
    if notes:
        doc["notes"] = notes
    if rig_name:
        doc["rig"] = rig_name
    doc["poisson_ratio"] = float(poisson_ratio)
    if mass is not None:
        doc["mass"] = float(mass)
    if manometer_gauge_pressure is not None:
        doc["manometer_gauge_pressure"] = float(manometer_gauge_pressure)
    doc["geometry"] = {"radius": float(radius), "radius_std": float(radius_std), "length_unit": "m"}
    doc["wall"] = {"thickness": float(thickness), "thickness_std": float(thickness_std), "thickness_unit": "m"}
    doc["indentation"] = {
        "force_unit": "N",
        "depth_unit": "m",
        "trial": _ids(_vector("trial", trial)),
        "force": _vector("force", force).tolist(),
        "depth": _vector("depth", depth).tolist(),
    }
    if wrinkle_counts is not None:
        doc["wrinkles"] = {"counts": np.asarray(wrinkle_counts).tolist()}
    return doc


def _write_if_valid(path: Path, files: dict[str, str], load: Callable[[Path], object]) -> None:
    """Write ``files`` (name → text) beside ``path`` only if ``load`` then reads ``path`` without error."""
    path.parent.mkdir(parents=True, exist_ok=True)
    # Written and read back in a scratch folder beside the target, so that a rejected session
    # never replaces a good one and the final moves stay on one file system.
    with tempfile.TemporaryDirectory(dir=path.parent, prefix=".write_session-") as scratch:
        for name, text in files.items():
            (Path(scratch) / name).write_text(text)
        try:
            load(Path(scratch) / path.name)
        except InvalidInputError as err:
            raise InvalidInputError(str(err).replace(scratch, str(path.parent))) from None
        for name in files:  # the TOML last: it never names a CSV that is not there yet
            os.replace(Path(scratch) / name, path.parent / name)
