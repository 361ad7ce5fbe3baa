"""Synthetic meshes (metres): the package's one sphere builder, a ball and an inflatable hammer toy."""

from __future__ import annotations

import numpy as np
import trimesh

from .._errors import InvalidInputError

__all__ = [
    "HAMMER_HEAD_LENGTH",
    "HAMMER_HEAD_RADIUS",
    "HAMMER_HANDLE_LENGTH",
    "HAMMER_HANDLE_RADIUS",
    "HAMMER_POKE_POINT",
    "make_ball_mesh",
    "make_hammer_mesh",
    "sphere_mesh",
]

#: Default hammer dimensions [m]: head is a capsule along x, centred at the origin.
HAMMER_HEAD_LENGTH = 0.32
HAMMER_HEAD_RADIUS = 0.08
#: Handle: capsule along −z from the head's axis; `HAMMER_HANDLE_LENGTH` is the part that sticks
#: out below the head (from z = −head_radius to the tip at z = −head_radius − handle_length).
HAMMER_HANDLE_LENGTH = 0.35
HAMMER_HANDLE_RADIUS = 0.03
#: Poke point [m] on the default hammer: apex of the head's striking face (the hemispherical end
#: cap at +x). The surface there is a sphere of radius `HAMMER_HEAD_RADIUS` = 0.08 m out to 90°
#: from the apex, so the local radius is 0.08 m for any fit_radius up to ~0.11 m.
HAMMER_POKE_POINT = (HAMMER_HEAD_LENGTH / 2.0, 0.0, 0.0)


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not (np.isfinite(value) and value > 0.0):
        raise InvalidInputError(f"{name} = {value!r} m must be a positive length")
    return value


def make_ball_mesh(radius: float, subdivisions: int = 4) -> trimesh.Trimesh:
    """Icosphere of the given radius [m], centred at the origin (:func:`sphere_mesh`'s).

    All vertices lie exactly on the sphere; the flat faces lie inside it, so the enclosed volume
    is slightly below 4/3 π R³. `subdivisions` = 4 gives 2562 vertices (edge ≈ 0.06 R).
    """
    vertices, faces = sphere_mesh(radius, layout="icosphere", subdivisions=subdivisions)
    return trimesh.Trimesh(
        vertices=vertices, faces=faces, metadata={"shape": "sphere", "radius": float(radius)}, process=False
    )


def make_hammer_mesh(
    head_length: float = HAMMER_HEAD_LENGTH,
    head_radius: float = HAMMER_HEAD_RADIUS,
    handle_length: float = HAMMER_HANDLE_LENGTH,
    handle_radius: float = HAMMER_HANDLE_RADIUS,
    *,
    sections: int = 48,
) -> trimesh.Trimesh:
    """Inflatable hammer toy [m]: capsule head along x on a capsule handle along −z.

    The head (total length `head_length`, radius `head_radius`) is centred at the origin; the
    handle (radius `handle_radius`) starts on the head's axis and sticks out `handle_length` below
    the head. The two capsules are merged by a boolean union (manifold3d), which yields a single
    closed, manifold surface. `sections` sets the latitude/longitude resolution of the head
    (the handle uses half). See `HAMMER_POKE_POINT` for a poke point with local radius
    `head_radius`.
    """
    head_length = _positive("head_length", head_length)
    head_radius = _positive("head_radius", head_radius)
    handle_length = _positive("handle_length", handle_length)
    handle_radius = _positive("handle_radius", handle_radius)
    if head_length <= 2.0 * head_radius:
        raise InvalidInputError(f"head_length = {head_length} m must exceed the head diameter {2 * head_radius} m")
    if handle_radius >= head_radius:
        raise InvalidInputError(f"handle_radius = {handle_radius} m must be smaller than head_radius = {head_radius} m")
    try:
        import manifold3d  # noqa: F401  (trimesh's boolean engine)
    except ImportError:
        raise InvalidInputError(
            "make_hammer_mesh needs the boolean engine manifold3d: pip install manifold3d "
            "(or load the bundled mesh: shelljax.geometry.bundled_mesh_path('hammer.stl'))"
        ) from None

    head = trimesh.creation.capsule(
        height=head_length - 2.0 * head_radius, radius=head_radius, count=[sections, sections]
    )
    head.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2.0, [0.0, 1.0, 0.0]))
    handle_total = head_radius + handle_length  # from the head's axis to the handle tip
    handle = trimesh.creation.capsule(
        height=handle_total - 2.0 * handle_radius,
        radius=handle_radius,
        count=[max(sections // 2, 8), max(sections // 2, 8)],
    )
    handle.apply_translation([0.0, 0.0, -handle_total / 2.0])
    hammer = trimesh.boolean.union([head, handle], engine="manifold")
    # manifold3d works in float32; return float64 coordinates with merged duplicates.
    hammer = trimesh.Trimesh(
        vertices=np.asarray(hammer.vertices, dtype=np.float64),
        faces=np.asarray(hammer.faces, dtype=np.int64),
        process=True,
    )
    if not (hammer.is_watertight and hammer.is_winding_consistent and hammer.volume > 0):
        raise RuntimeError("boolean union of the hammer parts is not a closed manifold")
    return hammer


SPHERE_LAYOUTS = ("rings", "random", "icosphere")


def sphere_mesh(
    radius: float,
    n_triangles: int = 2000,
    *,
    layout: str = "rings",
    pole_refinement: float = 1.0,
    growth: float = 0.25,
    max_spacing: float | None = None,
    pole_spacing: float | None = None,
    top_spacing: float | None = None,
    bottom_spacing: float | None = None,
    refined_arc: float = 0.0,
    smoothing_iterations: int = 25,
    subdivisions: int | None = None,
    seed: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) [m] and outward faces (F, 3) of a closed mesh of the sphere of ``radius`` [m]
    centred at the origin: the one sphere builder of the package, in three layouts.

    ``"rings"``: rings of vertices about the z axis, one vertex at each pole (where the indenter
    and the ground contact sit) and one equator vertex on the +x axis, of about ``n_triangles``
    faces. ``pole_refinement`` ≥ 1 divides the edge length at the poles; it grows back to the
    uniform length at a rate ``growth`` (edge length per unit arc distance). With ``max_spacing``
    [m] the uniform edge length is given instead of the face count, and ``pole_spacing`` [m] the
    poles' (default: ``max_spacing / pole_refinement``).

    ``"random"``: no rings, sectors or spirals, refined about the top pole. The rings carry a
    6-sector pattern that a poke excites (modes 6, 12, ...), and a golden-angle spiral of vertices
    carries its parastichies (measured: every leading mode of a poked spiral mesh is a Fibonacci
    number), so wrinkle counts near those numbers cannot be told from the mesh. Here the
    vertices are ``seed``-ed random points (no long-range order) whose density follows a target
    edge length s(θ): ``top_spacing`` [m] up to the arc distance ``refined_arc`` [m] from the top
    pole, then growing at ``growth`` up to ``max_spacing`` [m], and from ``bottom_spacing`` [m]
    (default: ``top_spacing``) at the bottom pole. Polar angles are stratified (the density is
    exact band by band), azimuths uniform; ``smoothing_iterations`` half-steps to the neighbours'
    mean spread the clusters. The triangulation is the sphere's Delaunay one (the convex hull),
    with one vertex at each pole.

    ``"icosphere"``: trimesh's icosphere of ``subdivisions`` (0..7; default: the one nearest
    ``n_triangles`` = 20·4^k faces), every vertex on the sphere (12 at 0 subdivisions, 2562 at 4).
    A ``seed`` turns a seeded random vertex to the top (+z), so that no symmetry axis of the
    icosahedron lines up with the indenter.
    """
    if layout == "rings":
        return _rings_layout(radius, n_triangles, pole_refinement, growth, max_spacing, pole_spacing)
    if layout == "random":
        return _random_layout(
            radius,
            top_spacing,
            max_spacing,
            bottom_spacing,
            refined_arc,
            growth,
            0 if seed is None else seed,
            smoothing_iterations,
        )
    if layout == "icosphere":
        return _icosphere_layout(radius, n_triangles, subdivisions, seed)
    raise InvalidInputError(f"sphere_mesh: layout = {layout!r} is not one of {SPHERE_LAYOUTS}.")


def _rings_layout(radius, n_triangles, pole_refinement, growth, max_spacing, pole_spacing):
    if radius <= 0 or n_triangles < 20 or pole_refinement < 1.0 or growth <= 0:
        raise InvalidInputError(
            f"sphere_mesh: need radius > 0 (got {radius}), n_triangles ≥ 20 (got {n_triangles}), "
            f"pole_refinement ≥ 1 (got {pole_refinement}), growth > 0 (got {growth})."
        )
    if max_spacing is not None:
        pole = max_spacing / pole_refinement if pole_spacing is None else pole_spacing
        return _ring_sphere(radius, max_spacing, min(pole, max_spacing), growth)
    # Equilateral lattice: n_tri ≈ 2 V and area per vertex (√3/2) s², so s from the target count.
    spacing = np.sqrt(8.0 * np.pi * radius**2 / (np.sqrt(3.0) * n_triangles))
    for _ in range(6):  # adjust the uniform spacing so the graded mesh meets the target count
        verts, faces = _ring_sphere(radius, spacing, spacing / pole_refinement, growth)
        ratio = len(faces) / n_triangles
        if abs(ratio - 1.0) < 0.05:
            break
        spacing *= np.sqrt(ratio)
    return verts, faces


def _random_layout(radius, top_spacing, max_spacing, bottom_spacing, refined_arc, growth, seed, smoothing_iterations):
    bottom_spacing = top_spacing if bottom_spacing is None else bottom_spacing
    if not (
        radius > 0
        and top_spacing is not None
        and max_spacing is not None
        and 0 < top_spacing <= max_spacing
        and 0 < bottom_spacing <= max_spacing
        and refined_arc >= 0
        and growth > 0
    ):
        raise InvalidInputError(
            f"sphere_mesh(layout='random'): need radius > 0 (got {radius}), 0 < top_spacing, bottom_spacing ≤ "
            f"max_spacing (got {top_spacing}, {bottom_spacing}, {max_spacing}), refined_arc ≥ 0 "
            f"(got {refined_arc}) and growth > 0 (got {growth})."
        )
    verts = _random_sphere_points(radius, top_spacing, max_spacing, bottom_spacing, refined_arc, growth, seed)
    verts = _smooth_on_sphere(verts, radius, smoothing_iterations)
    verts, faces = _hull_without_valence_three(verts)
    return verts, _outward(verts, faces)


def _icosphere_layout(radius, n_triangles, subdivisions, seed):
    radius = _positive("radius", radius)
    if subdivisions is None:
        subdivisions = max(0, int(round(np.log(n_triangles / 20.0) / np.log(4.0))))
    if int(subdivisions) != subdivisions or not 0 <= subdivisions <= 7:
        raise InvalidInputError(f"subdivisions = {subdivisions!r} must be an integer in 0..7")
    sphere = trimesh.creation.icosphere(subdivisions=int(subdivisions), radius=radius)
    if seed is not None:
        top = np.random.default_rng(seed).integers(len(sphere.vertices))
        sphere.apply_transform(trimesh.geometry.align_vectors(sphere.vertices[top], [0.0, 0.0, 1.0]))
    return np.asarray(sphere.vertices, dtype=np.float64), np.asarray(sphere.faces, dtype=np.int64)


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


def _random_sphere_points(radius, top_spacing, max_spacing, bottom_spacing, refined_arc, growth, seed) -> np.ndarray:
    """Poles and seeded random points [m] whose density follows the target edge length s(θ):
    polar angles stratified band by band, azimuths uniform."""
    theta = np.linspace(0.0, np.pi, 20001)  # polar angle from the bottom pole [rad]
    arc_top, arc_bottom = radius * (np.pi - theta), radius * theta
    spacing = np.minimum.reduce(
        [
            np.full_like(theta, max_spacing),
            top_spacing + growth * np.maximum(arc_top - refined_arc, 0.0),
            bottom_spacing + growth * arc_bottom,
        ]
    )
    # vertices per unit polar angle for an equilateral lattice: area per vertex (√3/2) s²
    density = 2.0 * np.pi * radius**2 * np.sin(theta) / (0.5 * np.sqrt(3.0) * spacing**2)
    count = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(theta))])
    n_inner = max(int(round(count[-1])) - 2, 4)
    rng = np.random.default_rng(seed)
    quantile = (np.arange(n_inner) + rng.uniform(0.0, 1.0, n_inner)) / n_inner
    polar = np.interp(quantile * count[-1], count, theta)
    azimuth = rng.uniform(0.0, 2.0 * np.pi, n_inner)
    return np.concatenate(
        [
            [[0.0, 0.0, -radius]],
            radius * np.stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), -np.cos(polar)], -1),
            [[0.0, 0.0, radius]],
        ]
    )


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


def _ring_sphere(radius, spacing_max, spacing_pole, growth):
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
            verts.append((radius * np.sin(th) * np.cos(p), radius * np.sin(th) * np.sin(p), radius * np.cos(th)))
        rings.append((np.arange(start, start + n), phi))
    faces = []
    for (ia, pa), (ib, pb) in zip(rings[:-1], rings[1:]):
        faces.extend(_stitch(ia, pa, ib, pb))
    verts = np.asarray(verts)
    faces = np.asarray(faces, dtype=np.int64)
    return verts, _outward(verts, faces)


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
