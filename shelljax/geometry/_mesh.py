"""Mesh input and enclosed volume (data layer: numpy + trimesh, no JAX).

Everything returned here is in SI units: coordinates in metres, volumes in m³.
"""

from __future__ import annotations

import warnings
from importlib import resources
from pathlib import Path

import numpy as np
import trimesh

from .._errors import InvalidInputError

__all__ = [
    "GeometryWarning",
    "LENGTH_UNITS",
    "SUPPORTED_MESH_SUFFIXES",
    "bundled_mesh_path",
    "enclosed_volume",
    "load_mesh",
    "mesh_volume",
    "signed_volume",
]

#: Factor that converts a coordinate in the given unit to metres.
LENGTH_UNITS: dict[str, float] = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}

#: File suffixes ``load_mesh`` accepts (lower case, with the dot).
SUPPORTED_MESH_SUFFIXES: tuple[str, ...] = (".obj", ".ply", ".stl", ".glb", ".gltf")

# Plausibility window for the bounding-box diagonal [m] of a hand-indentable inflatable. Outside
# it the coordinates are almost surely in another unit than the one declared (a 0.3 m ball in mm
# has a diagonal of ~500 "m"; in m read as mm, ~0.5 mm).
_MAX_DIAGONAL_M = 20.0
_MIN_DIAGONAL_M = 5e-3


class GeometryWarning(UserWarning):
    """A mesh was usable but had to be repaired, or a fitted region is not what the model
    assumes."""


def bundled_mesh_path(name: str) -> Path:
    """Path of a mesh shipped with shelljax in ``shelljax/data/meshes`` (e.g. ``"hammer.stl"``).

    Bundled meshes: ``hammer.stl`` (inflatable hammer toy, metres, see
    :func:`shelljax.geometry.make_hammer_mesh`) and ``beach_ball.ply`` (R = 0.25 m icosphere
    with 1e-4 m radial noise).
    """
    path = Path(str(resources.files("shelljax") / "data" / "meshes" / name))
    if not path.is_file():
        available = sorted(p.name for p in path.parent.glob("*")) if path.parent.is_dir() else []
        raise InvalidInputError(f"no bundled mesh named {name!r} in {path.parent}; available: {available}")
    return path


def _boundary_and_nonmanifold_edges(mesh: trimesh.Trimesh) -> tuple[int, int]:
    """Number of edges used by exactly one face (holes) and by more than two faces."""
    edges = np.sort(np.asarray(mesh.edges, dtype=np.int64), axis=1)
    if len(edges) == 0:
        return 0, 0
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return int(np.sum(counts == 1)), int(np.sum(counts > 2))


def mesh_volume(vertices, faces, xp=np):
    """Σ over faces of v0 · (v1 × v2) / 6: the divergence theorem on a closed triangle surface [m³],
    of ``vertices`` (V, 3) [m] and ``faces`` (F, 3) int, with the array module ``xp`` (NumPy, or
    ``jax.numpy`` to trace it). The one enclosed volume of a mesh; the realtime runtime's compiled
    kernel repeats it with its gradient, and shell3d sums it face by face in its energy.

    Exact for any closed, consistently wound polyhedron (origin anywhere); positive when the face
    normals (right-hand rule) point outward.
    """
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    return xp.sum(xp.einsum("fi,fi->f", a, xp.cross(b, c))) / 6.0


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """:func:`mesh_volume` [m³] of NumPy-like ``vertices`` (V, 3) [m] and ``faces`` (F, 3), as a float."""
    return float(mesh_volume(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)))


def _require_watertight(mesh: trimesh.Trimesh, where: str) -> None:
    if mesh.is_watertight:  # cached by trimesh; the edge census below is only for the message
        return
    n_boundary, n_nonmanifold = _boundary_and_nonmanifold_edges(mesh)
    problems = []
    if n_boundary:
        problems.append(f"{n_boundary} boundary edge(s) (holes: edges used by only one face)")
    if n_nonmanifold:
        problems.append(f"{n_nonmanifold} non-manifold edge(s) (used by more than two faces)")
    if not problems:
        problems.append("edges whose two faces do not match up")
    raise InvalidInputError(
        f"{where}: mesh is not watertight: {'; '.join(problems)}. An enclosed volume and an "
        "outward normal need a closed surface. Fill the holes (MeshLab: Filters > Remeshing > "
        "Close Holes; or trimesh.repair.fill_holes(mesh)) and remove non-manifold edges, "
        "then save the mesh again."
    )


def load_mesh(path: str | Path, *, length_unit: str = "m", require_watertight: bool = True) -> trimesh.Trimesh:
    """Read a closed surface mesh and return it in metres with outward-facing normals.

    **Arguments:**

    - `path`: an OBJ, PLY, STL, GLB or GLTF file. A GLB/GLTF scene (several parts, transforms)
      is flattened into one mesh; coincident vertices of the parts are merged so a surface split
      into pieces (e.g. at texture seams) is closed again. Colours/UVs are dropped.
    - `length_unit`: unit of the coordinates in the file, one of ``"m"``, ``"cm"``, ``"mm"``.
    - `require_watertight`: raise if the surface has holes or non-manifold edges.

    **Returns:** a `trimesh.Trimesh` with vertices in metres [m] and consistently wound faces whose
    normals point outward, so its enclosed volume is positive. If the winding had to be changed
    a :class:`GeometryWarning` says how many faces were flipped; one is also issued when the file
    holds several disconnected bodies (their volumes add up, overlaps count twice).

    **Raises:** `InvalidInputError` for a missing file, unsupported suffix, unreadable or empty
    mesh, an unknown `length_unit`, a non-watertight mesh, or an implausible size (bounding-box
    diagonal above 20 m or below 5 mm after unit conversion, which means the unit is wrong).
    """
    path = Path(path)
    mesh = _read_triangles(path, length_unit)
    _check_size(mesh, path, length_unit)
    if require_watertight:
        _require_watertight(mesh, str(path))
        _orient_outward(mesh, path)
    return mesh


def _read_triangles(path: Path, length_unit: str) -> trimesh.Trimesh:
    """The file's triangles as one mesh in metres, vertices merged by position."""
    if length_unit not in LENGTH_UNITS:
        raise InvalidInputError(
            f"{path}: length_unit = {length_unit!r} is not supported; use one of "
            f"{sorted(LENGTH_UNITS)} (set `length_unit` in [geometry])"
        )
    if not path.is_file():
        raise InvalidInputError(
            f"mesh file {path} does not exist; check the `mesh` path in [geometry] "
            "(it is relative to the session TOML file)"
        )
    suffix = path.suffix.lower()
    if suffix not in SUPPORTED_MESH_SUFFIXES:
        raise InvalidInputError(
            f"{path}: unsupported mesh format {suffix or '(no suffix)'!r}; export the mesh as one "
            f"of {', '.join(SUPPORTED_MESH_SUFFIXES)}"
        )
    try:
        loaded = trimesh.load(path, force="mesh")
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise InvalidInputError(
            f"{path}: could not read the mesh ({type(exc).__name__}: {exc}); check that the file "
            f"is a valid {suffix[1:].upper()} file, e.g. by opening it in MeshLab and re-exporting"
        ) from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise InvalidInputError(
            f"{path}: no triangles could be read from the file (it is empty, corrupt, or holds "
            "only points/lines); check that it opens in a mesh viewer such as MeshLab and export "
            "the surface as a triangle mesh"
        )
    # Rebuild from bare arrays: drops visuals so vertices split only at UV/normal seams merge by
    # position, which is what makes a textured photogrammetry mesh watertight again.
    mesh = trimesh.Trimesh(
        vertices=np.asarray(loaded.vertices, dtype=np.float64) * LENGTH_UNITS[length_unit],
        faces=np.asarray(loaded.faces, dtype=np.int64),
        process=True,
    )
    if not np.all(np.isfinite(mesh.vertices)):
        raise InvalidInputError(f"{path}: mesh has NaN or infinite coordinates; re-export it")
    return mesh


def _check_size(mesh: trimesh.Trimesh, path: Path, length_unit: str) -> None:
    """Reject a bounding-box diagonal outside the window of indentable objects (a wrong unit)."""
    diagonal = float(np.linalg.norm(mesh.bounds[1] - mesh.bounds[0]))
    if diagonal > _MAX_DIAGONAL_M:
        raise InvalidInputError(
            f"{path}: bounding-box diagonal is {diagonal:.4g} m with length_unit = "
            f"{length_unit!r}, too large for an indentable object (> {_MAX_DIAGONAL_M:g} m); the "
            'coordinates look like millimetres: set `length_unit = "mm"` in [geometry]'
        )
    if diagonal < _MIN_DIAGONAL_M:
        raise InvalidInputError(
            f"{path}: bounding-box diagonal is {diagonal:.4g} m with length_unit = "
            f"{length_unit!r}, too small for an indentable object "
            f"(< {_MIN_DIAGONAL_M * 1e3:g} mm); "
            "this looks like the wrong unit: set `length_unit` in [geometry] to the unit the "
            'mesh was exported in ("m", "cm" or "mm")'
        )


def _orient_outward(mesh: trimesh.Trimesh, path: Path) -> None:
    """Flip the faces of a closed mesh outward in place, warning about flips and several bodies."""
    faces_before = mesh.faces.copy()
    # multibody: orient every closed body outward on its own (trimesh otherwise only checks
    # the total volume).
    trimesh.repair.fix_normals(mesh, multibody=True)
    n_flipped = int(np.sum(np.any(mesh.faces != faces_before, axis=1)))
    if n_flipped:
        warnings.warn(
            f"{path}: {n_flipped} of {len(mesh.faces)} faces had inverted or inconsistent "
            "winding and were flipped so the normals point outward "
            "(trimesh.repair.fix_normals)",
            GeometryWarning,
            stacklevel=3,
        )
    if signed_volume(mesh.vertices, mesh.faces) <= 0.0:
        raise InvalidInputError(
            f"{path}: enclosed volume is not positive even after re-orienting the faces; the "
            "surface is self-intersecting or degenerate: repair it (e.g. MeshLab) and re-export"
        )
    n_bodies = int(mesh.body_count)
    if n_bodies > 1:
        warnings.warn(
            f"{path}: mesh consists of {n_bodies} disconnected closed bodies; the enclosed "
            "volume adds them up and counts any overlap twice. Merge the parts with a boolean "
            "union (e.g. trimesh.boolean.union with manifold3d) if they overlap.",
            GeometryWarning,
            stacklevel=3,
        )


def enclosed_volume(mesh: trimesh.Trimesh) -> float:
    """Volume enclosed by a closed triangle mesh [m³] (mesh coordinates in metres).

    Computed as the signed-volume sum Σ v0 · (v1 × v2) / 6 over the faces — exact for the
    polyhedron (a mesh of a curved object encloses slightly less than the smooth object, e.g. an
    inscribed icosphere). Raises `InvalidInputError` if the mesh is not watertight or its faces
    point inward (negative volume; :func:`load_mesh` fixes that).
    """
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InvalidInputError(
            f"enclosed_volume: expected a non-empty trimesh.Trimesh, got {type(mesh).__name__}; "
            "read meshes with shelljax.geometry.load_mesh"
        )
    _require_watertight(mesh, "enclosed_volume")
    volume = signed_volume(mesh.vertices, mesh.faces)
    if volume <= 0.0:
        raise InvalidInputError(
            f"enclosed_volume: signed volume is {volume:.6g} m³ (≤ 0): the face normals point "
            "inward; load the mesh with shelljax.geometry.load_mesh or call "
            "trimesh.repair.fix_normals(mesh) first"
        )
    return volume
