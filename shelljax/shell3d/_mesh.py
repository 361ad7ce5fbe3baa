"""Closed triangle-mesh topology for the discrete shell (spheres: :func:`shelljax.geometry.sphere_mesh`).

Each face carries a 6-vertex *flap stencil* ``[v0, v1, v2, o0, o1, o2]``: ``o_i`` is the vertex
across edge i (the edge opposite ``v_i``), which the midedge bending formulation needs. Building the
stencil checks that the mesh is closed, manifold and consistently oriented; otherwise a
:class:`shelljax.InvalidInputError` names what is wrong.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._errors import InvalidInputError
from ..geometry import signed_volume, sphere_mesh


@dataclasses.dataclass(frozen=True, eq=False)
class ShellMesh:
    """A closed, outward-oriented triangle mesh: vertices (V, 3) [m], faces (F, 3), stencil (F, 6)."""

    vertices: np.ndarray
    faces: np.ndarray
    stencil: np.ndarray
    name: str = "mesh"

    @staticmethod
    def from_arrays(vertices, faces, name: str = "mesh") -> "ShellMesh":
        """Validate a closed mesh, orient it outward and build its flap stencil."""
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
            raise InvalidInputError(f"{name}: vertices must be (V, 3) and faces (F, 3); got {v.shape} and {f.shape}.")
        if not np.all(np.isfinite(v)):
            raise InvalidInputError(f"{name}: vertex coordinates contain NaN or inf.")
        if f.size == 0 or f.min() < 0 or f.max() >= len(v):
            raise InvalidInputError(f"{name}: face indices out of range [0, {len(v)}).")
        if np.any((f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])):
            raise InvalidInputError(f"{name}: degenerate face (repeated vertex); clean the mesh.")
        stencil = _flap_stencil(f, len(v), name)
        if signed_volume(v, f) < 0.0:
            f = f[:, ::-1].copy()
            stencil = _flap_stencil(f, len(v), name)
        used = np.zeros(len(v), dtype=bool)
        used[f.ravel()] = True
        if not used.all():
            raise InvalidInputError(
                f"{name}: {int((~used).sum())} vertices belong to no face; remove them "
                "(trimesh: mesh.remove_unreferenced_vertices())."
            )
        return ShellMesh(vertices=v, faces=f, stencil=stencil, name=name)

    @staticmethod
    def sphere(radius: float, n_triangles: int = 2000, *, name: str | None = None, **layout) -> "ShellMesh":
        """The sphere of :func:`shelljax.geometry.sphere_mesh` (same arguments) as a shell mesh."""
        kind = layout.get("layout", "rings")
        default = {"rings": "sphere", "random": f"random sphere (seed {layout.get('seed') or 0})"}.get(kind, kind)
        return ShellMesh.from_arrays(*sphere_mesh(radius, n_triangles, **layout), name=name or default)

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])


def _flap_stencil(faces: np.ndarray, n_vertices: int, name: str) -> np.ndarray:
    n_f = len(faces)
    # Directed edge i of face f goes v_{i+1} -> v_{i+2} (opposite vertex v_i).
    a = np.stack([faces[:, 1], faces[:, 2], faces[:, 0]], axis=1).ravel()
    b = np.stack([faces[:, 2], faces[:, 0], faces[:, 1]], axis=1).ravel()
    key = a * n_vertices + b
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    if np.any(sorted_key[1:] == sorted_key[:-1]):
        raise InvalidInputError(
            f"{name}: an edge is used twice in the same direction (non-manifold edge or "
            "inconsistently oriented faces); repair the mesh (trimesh: mesh.fix_normals())."
        )
    twin_key = b * n_vertices + a
    pos = np.searchsorted(sorted_key, twin_key)
    pos = np.minimum(pos, len(sorted_key) - 1)
    found = sorted_key[pos] == twin_key
    if not found.all():
        raise InvalidInputError(
            f"{name}: the mesh is not closed ({int((~found).sum())} boundary edges). The "
            "enclosed gas volume needs a watertight surface; fill the holes "
            "(trimesh: mesh.fill_holes()) or use a closed scan."
        )
    twin = order[pos]  # flat index f*3 + i of the twin edge
    opposite = faces.ravel()[twin].reshape(n_f, 3)  # the twin face's vertex opposite the edge
    return np.concatenate([faces, opposite], axis=1)
