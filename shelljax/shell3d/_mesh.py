"""Closed triangle-mesh topology for the discrete shell, and sphere (ball) mesh generation.

Each face carries a 6-vertex *flap stencil* ``[v0, v1, v2, o0, o1, o2]``: ``o_i`` is the vertex
across edge i (the edge opposite ``v_i``), which the midedge bending formulation needs. Building the
stencil checks that the mesh is closed, manifold and consistently oriented; otherwise a
:class:`shelljax.InvalidInputError` names what is wrong.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._errors import InvalidInputError
from ..geometry import signed_volume


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
            raise InvalidInputError(
                f"{name}: vertices must be (V, 3) and faces (F, 3); got {v.shape} and {f.shape}."
            )
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


def _sphere_rings(radius: float, spacing_max: float, spacing_pole: float, growth: float):
    """Polar angles [rad] of the vertex rings, graded from both poles, symmetric about the equator."""
    thetas = [0.0]
    while thetas[-1] < 0.5 * np.pi:
        s = min(spacing_max, spacing_pole + growth * radius * thetas[-1])
        thetas.append(thetas[-1] + s / radius)
    north = np.array(thetas)
    if len(north) < 3:
        north = np.linspace(0.0, 0.5 * np.pi, 3)
    north = north * (0.5 * np.pi / north[-1])
    return np.concatenate([north, np.pi - north[-2::-1]])


def sphere_mesh(
    radius: float,
    n_triangles: int = 2000,
    *,
    pole_refinement: float = 1.0,
    growth: float = 0.25,
    max_spacing: float | None = None,
    pole_spacing: float | None = None,
    name: str = "sphere",
) -> ShellMesh:
    """Closed sphere mesh [m] of about ``n_triangles`` faces, ring-structured about the z axis.

    Vertices lie on the sphere of ``radius`` [m] with one vertex at each pole (the indenter and
    the ground contact sit there), and one equator vertex on the +x axis. ``pole_refinement`` ≥ 1
    divides the edge length at the poles; it grows back to the uniform length at a rate
    ``growth`` (edge length per unit arc distance), which concentrates resolution where the
    indentation and contact happen.
    """
    if radius <= 0 or n_triangles < 20 or pole_refinement < 1.0 or growth <= 0:
        raise InvalidInputError(
            f"sphere_mesh: need radius > 0 (got {radius}), n_triangles ≥ 20 (got {n_triangles}), "
            f"pole_refinement ≥ 1 (got {pole_refinement}), growth > 0 (got {growth})."
        )
    # Equilateral lattice: n_tri ≈ 2 V and area per vertex (√3/2) s², so s from the target count.
    if max_spacing is not None:
        pole = max_spacing / pole_refinement if pole_spacing is None else pole_spacing
        return _ring_sphere(radius, max_spacing, min(pole, max_spacing), growth, name)
    spacing = np.sqrt(8.0 * np.pi * radius**2 / (np.sqrt(3.0) * n_triangles))
    for _ in range(6):  # adjust the uniform spacing so the graded mesh meets the target count
        mesh = _ring_sphere(radius, spacing, spacing / pole_refinement, growth, name)
        ratio = mesh.n_faces / n_triangles
        if abs(ratio - 1.0) < 0.05:
            break
        spacing *= np.sqrt(ratio)
    return mesh


def random_sphere_mesh(
    radius: float,
    *,
    top_spacing: float,
    max_spacing: float,
    bottom_spacing: float | None = None,
    refined_arc: float = 0.0,
    growth: float = 0.25,
    seed: int = 0,
    smoothing_iterations: int = 25,
) -> ShellMesh:
    """Closed sphere mesh [m] with no rings, sectors or spirals, refined about the top pole.

    ``sphere_mesh``'s rings carry a 6-sector pattern that a poke excites (modes 6, 12, ...), and a
    golden-angle spiral of vertices carries its parastichies (measured: every leading mode of a
    poked spiral mesh is a Fibonacci number), so wrinkle counts near those numbers cannot
    be told from the mesh. Here the vertices are seeded random points (no long-range order) whose
    density follows a target edge length s(θ): ``top_spacing`` [m] up to the arc distance
    ``refined_arc`` [m] from the top pole, then growing at ``growth`` (edge length per unit arc
    distance) up to ``max_spacing`` [m], and from ``bottom_spacing`` [m] (default: ``top_spacing``)
    at the bottom pole. Polar angles are stratified (the density is exact band by band), azimuths
    uniform; ``smoothing_iterations`` half-steps to the neighbours' mean spread the clusters. The
    triangulation is the sphere's Delaunay one (the convex hull), with one vertex at each pole.
    """
    bottom_spacing = top_spacing if bottom_spacing is None else bottom_spacing
    if not (radius > 0 and 0 < top_spacing <= max_spacing and 0 < bottom_spacing <= max_spacing
            and refined_arc >= 0 and growth > 0):
        raise InvalidInputError(
            f"random_sphere_mesh: need radius > 0 (got {radius}), 0 < top_spacing, bottom_spacing ≤ "
            f"max_spacing (got {top_spacing}, {bottom_spacing}, {max_spacing}), refined_arc ≥ 0 "
            f"(got {refined_arc}) and growth > 0 (got {growth})."
        )
    verts = _random_sphere_points(radius, top_spacing, max_spacing, bottom_spacing, refined_arc, growth, seed)
    verts = _smooth_on_sphere(verts, radius, smoothing_iterations)
    verts, faces = _hull_without_valence_three(verts)
    return ShellMesh.from_arrays(verts, _outward(verts, faces), name=f"random sphere (seed {seed})")


def _random_sphere_points(radius, top_spacing, max_spacing, bottom_spacing, refined_arc, growth, seed) -> np.ndarray:
    """Poles and seeded random points [m] whose density follows the target edge length s(θ):
    polar angles stratified band by band, azimuths uniform."""
    theta = np.linspace(0.0, np.pi, 20001)  # polar angle from the bottom pole [rad]
    arc_top, arc_bottom = radius * (np.pi - theta), radius * theta
    spacing = np.minimum.reduce([
        np.full_like(theta, max_spacing),
        top_spacing + growth * np.maximum(arc_top - refined_arc, 0.0),
        bottom_spacing + growth * arc_bottom,
    ])
    # vertices per unit polar angle for an equilateral lattice: area per vertex (√3/2) s²
    density = 2.0 * np.pi * radius**2 * np.sin(theta) / (0.5 * np.sqrt(3.0) * spacing**2)
    count = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(theta))])
    n_inner = max(int(round(count[-1])) - 2, 4)
    rng = np.random.default_rng(seed)
    quantile = (np.arange(n_inner) + rng.uniform(0.0, 1.0, n_inner)) / n_inner
    polar = np.interp(quantile * count[-1], count, theta)
    azimuth = rng.uniform(0.0, 2.0 * np.pi, n_inner)
    return np.concatenate([
        [[0.0, 0.0, -radius]],
        radius * np.stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), -np.cos(polar)], -1),
        [[0.0, 0.0, radius]],
    ])


def _smooth_on_sphere(verts: np.ndarray, radius: float, iterations: int) -> np.ndarray:
    """``iterations`` half-steps of every vertex but the poles to its hull neighbours' mean,
    projected back onto the sphere: spreads the random clusters."""
    from scipy.spatial import ConvexHull

    for _ in range(iterations):
        faces = ConvexHull(verts).simplices
        edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        total = np.zeros_like(verts)
        valence = np.zeros(len(verts))
        np.add.at(total, edges[:, 0], verts[edges[:, 1]])
        np.add.at(valence, edges[:, 0], 1.0)
        step = 0.5 * (total / valence[:, None] - verts)
        step[[0, -1]] = 0.0  # the poles stay
        verts = verts + step
        verts *= radius / np.linalg.norm(verts, axis=1, keepdims=True)
    return verts


def _hull_without_valence_three(verts: np.ndarray):
    """(vertices, faces) of the sphere's Delaunay triangulation (the convex hull) with every
    valence-3 vertex dropped: its faces' flap stencils would repeat a vertex, which makes the
    bending's six-point curvature fit singular (the poles never are)."""
    from scipy.spatial import ConvexHull

    faces = ConvexHull(verts).simplices.astype(np.int64)
    for _ in range(10):
        valence = np.bincount(faces.ravel(), minlength=len(verts))
        keep = valence >= 4
        if keep.all():
            break
        verts = verts[keep]
        faces = ConvexHull(verts).simplices.astype(np.int64)
    return verts, faces


def _outward(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``faces`` of a star-shaped mesh about the origin, each wound with its normal outward."""
    p = verts[faces]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    flip = np.einsum("ij,ij->i", normal, p.mean(axis=1)) < 0
    faces[flip] = faces[flip][:, ::-1]
    return faces


def _ring_sphere(radius, spacing_max, spacing_pole, growth, name) -> ShellMesh:
    thetas = _sphere_rings(radius, spacing_max, spacing_pole, growth)
    n_equator = (len(thetas) - 1) // 2
    rings, verts = [], []
    for k, th in enumerate(thetas):
        if k == 0 or k == len(thetas) - 1:
            n, offset = 1, 0.0
        else:
            s = min(spacing_max, spacing_pole + growth * radius * min(th, np.pi - th))
            n = max(6, int(round(2.0 * np.pi * radius * np.sin(th) / s)))
            offset = 0.0 if (k - n_equator) % 2 == 0 else 0.5
        phi = 2.0 * np.pi * (np.arange(n) + offset) / n
        start = len(verts)
        for p in phi:
            verts.append(
                (radius * np.sin(th) * np.cos(p), radius * np.sin(th) * np.sin(p), radius * np.cos(th))
            )
        rings.append((np.arange(start, start + n), phi))
    faces = []
    for (ia, pa), (ib, pb) in zip(rings[:-1], rings[1:]):
        faces.extend(_stitch(ia, pa, ib, pb))
    verts = np.asarray(verts)
    faces = np.asarray(faces, dtype=np.int64)
    # Orient each face outward (the sphere is star-shaped about the origin).
    p = verts[faces]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    flip = np.einsum("ij,ij->i", normal, p.mean(axis=1)) < 0
    faces[flip] = faces[flip][:, ::-1]
    return ShellMesh.from_arrays(verts, faces, name=name)


def _stitch(ia, pa, ib, pb):
    """Triangles joining two consecutive rings (indices ia/ib at azimuths pa/pb [rad])."""
    na, nb = len(ia), len(ib)
    if na == 1:
        return [(ia[0], ib[j], ib[(j + 1) % nb]) for j in range(nb)]
    if nb == 1:
        return [(ia[i], ia[(i + 1) % na], ib[0]) for i in range(na)]
    ua = np.concatenate([pa, pa[:1] + 2 * np.pi])
    ub = np.concatenate([pb, pb[:1] + 2 * np.pi])
    out, i, j = [], 0, 0
    while i < na or j < nb:
        if j == nb or (i < na and ua[i + 1] < ub[j + 1]):
            out.append((ia[i % na], ia[(i + 1) % na], ib[j % nb]))
            i += 1
        else:
            out.append((ia[i % na], ib[(j + 1) % nb], ib[j % nb]))
            j += 1
    return out
