"""Tests of shelljax.geometry: mesh input, enclosed volume, local radius of curvature."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh
from scipy import integrate

from shelljax import InvalidInputError
from shelljax.geometry import (
    HAMMER_HANDLE_LENGTH,
    HAMMER_HANDLE_RADIUS,
    HAMMER_HEAD_LENGTH,
    HAMMER_HEAD_RADIUS,
    HAMMER_POKE_POINT,
    GeometryWarning,
    LocalCurvature,
    bundled_mesh_path,
    enclosed_volume,
    fit_local_sphere,
    load_mesh,
    make_ball_mesh,
    make_hammer_mesh,
)


def _no_warnings(fn, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return fn(*args, **kwargs)


def _dimpled_ball(radius=0.1, cut=0.06, subdivisions=5):
    """Icosphere with the cap z > cut mirrored about the plane z = cut: a concave spherical dimple
    of radius `radius` whose bottom is at z = 2 cut − radius."""
    ball = make_ball_mesh(radius, subdivisions)
    v = np.array(ball.vertices)
    cap = v[:, 2] > cut
    v[cap, 2] = 2.0 * cut - v[cap, 2]
    return trimesh.Trimesh(v, ball.faces, process=False)


# ----------------------------------------------------------------------------- enclosed volume


def test_box_volume_is_exact():
    extents = np.array([0.3, 0.2, 0.1])
    box = trimesh.creation.box(extents=extents)
    box.apply_translation([1.0, -2.0, 0.5])  # the signed sum must not depend on the origin
    # A box is its own polyhedron: the divergence-theorem sum is exact up to round-off.
    assert enclosed_volume(box) == pytest.approx(np.prod(extents), rel=1e-12)


@pytest.mark.parametrize("subdivisions", [2, 4])
def test_icosphere_volume_matches_polyhedron_and_sphere_bounds(subdivisions):
    radius = 0.25
    ball = make_ball_mesh(radius, subdivisions)
    volume = enclosed_volume(ball)
    tri = np.asarray(ball.triangles)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    areas = 0.5 * np.linalg.norm(normals, axis=1)
    heights = np.einsum("ij,ij->i", tri[:, 0], normals / (2.0 * areas[:, None]))
    # Independent formula: a star-shaped polyhedron around the origin is the union of pyramids
    # with base = face and apex = origin, V = Σ A_f h_f / 3.
    assert volume == pytest.approx(np.sum(areas * heights) / 3.0, rel=1e-12)
    # Vertices lie on the sphere, so the polyhedron lies between the ball of radius
    # min(face-plane distance) and the ball of radius R: the discretisation bound.
    assert 4.0 / 3.0 * np.pi * heights.min() ** 3 < volume < 4.0 / 3.0 * np.pi * radius**3


def test_volume_rejects_open_and_inverted_meshes():
    ball = make_ball_mesh(0.1, 2)
    open_ball = trimesh.Trimesh(ball.vertices, ball.faces[1:], process=False)
    with pytest.raises(InvalidInputError, match="not watertight: 3 boundary edge"):
        enclosed_volume(open_ball)
    inverted = trimesh.Trimesh(ball.vertices, ball.faces[:, ::-1], process=False)
    with pytest.raises(InvalidInputError, match="normals point inward"):
        enclosed_volume(inverted)


# --------------------------------------------------------------------------------- load_mesh


def test_load_converts_millimetres_to_metres(tmp_path):
    ball = make_ball_mesh(0.25, 3)
    mm = trimesh.Trimesh(ball.vertices * 1e3, ball.faces, process=False)
    path = tmp_path / "ball_mm.stl"
    mm.export(path)
    loaded = _no_warnings(load_mesh, path, length_unit="mm")
    # Binary STL stores float32: 250 mm carries ~1.5e-5 mm = 1.5e-8 m of rounding.
    radii = np.linalg.norm(loaded.vertices, axis=1)
    np.testing.assert_allclose(radii, 0.25, atol=1e-7)
    assert len(loaded.vertices) == len(ball.vertices)
    cm = _no_warnings(load_mesh, path, length_unit="cm")  # the same numbers read as cm: ×10
    np.testing.assert_allclose(np.linalg.norm(cm.vertices, axis=1), 2.5, atol=1e-6)


def test_load_rejects_implausible_scales(tmp_path):
    ball = make_ball_mesh(0.25, 2)
    path = tmp_path / "ball_mm.ply"
    trimesh.Trimesh(ball.vertices * 1e3, ball.faces, process=False).export(path)
    with pytest.raises(InvalidInputError, match=r'look like millimetres: set `length_unit = "mm"`'):
        load_mesh(path)
    metres = tmp_path / "ball_m.ply"
    ball.export(metres)
    with pytest.raises(InvalidInputError, match="too small.*looks like the wrong unit"):
        load_mesh(metres, length_unit="mm")


def test_load_errors_name_file_problem_and_fix(tmp_path):
    with pytest.raises(InvalidInputError, match=r"nope\.stl does not exist; check the `mesh` path"):
        load_mesh(tmp_path / "nope.stl")
    text = tmp_path / "ball.txt"
    text.write_text("not a mesh")
    with pytest.raises(InvalidInputError, match=r"ball\.txt: unsupported mesh format '\.txt'.*\.glb"):
        load_mesh(text)
    garbage = tmp_path / "garbage.stl"
    garbage.write_bytes(b"\x00\x01 certainly not an STL")
    with pytest.raises(InvalidInputError, match=r"garbage\.stl: no triangles could be read"):
        load_mesh(garbage)
    points = tmp_path / "points.obj"
    points.write_text("v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\n")
    with pytest.raises(InvalidInputError, match=r"points\.obj: no triangles"):
        load_mesh(points)
    ball = make_ball_mesh(0.1, 2)
    ball.export(tmp_path / "ball.ply")
    with pytest.raises(InvalidInputError, match=r"length_unit = 'inch' is not supported"):
        load_mesh(tmp_path / "ball.ply", length_unit="inch")


def test_load_rejects_holes_with_edge_count_and_fix(tmp_path):
    ball = make_ball_mesh(0.1, 3)
    # Remove two faces that share no edge: each leaves a triangular hole of 3 boundary edges.
    face_adjacent = {tuple(sorted(p)) for p in ball.face_adjacency.tolist()}
    second = next(f for f in range(1, len(ball.faces)) if (0, f) not in face_adjacent)
    keep = np.setdiff1d(np.arange(len(ball.faces)), [0, second])
    path = tmp_path / "holey.obj"
    trimesh.Trimesh(ball.vertices, ball.faces[keep], process=False).export(path)
    with pytest.raises(
        InvalidInputError,
        match=r"holey\.obj: mesh is not watertight: 6 boundary"
        r" edge.*trimesh\.repair\.fill_holes",
    ):
        load_mesh(path)
    # Opting out returns the open mesh as is (e.g. for display).
    assert not load_mesh(path, require_watertight=False).is_watertight


def test_load_fixes_inverted_winding_and_warns(tmp_path):
    ball = make_ball_mesh(0.1, 3)
    path = tmp_path / "inverted.ply"
    trimesh.Trimesh(ball.vertices, ball.faces[:, ::-1], process=False).export(path)
    with pytest.warns(GeometryWarning, match=rf"{len(ball.faces)} of {len(ball.faces)} faces"):
        mesh = load_mesh(path)
    # PLY as trimesh writes it stores float32 coordinates: ~1e-7 relative volume error.
    assert enclosed_volume(mesh) == pytest.approx(enclosed_volume(ball), rel=1e-6)

    mixed = ball.faces.copy()
    mixed[::3] = mixed[::3, ::-1]  # a third of the faces wound the wrong way
    trimesh.Trimesh(ball.vertices, mixed, process=False).export(path)
    with pytest.warns(GeometryWarning, match="flipped"):
        mesh = load_mesh(path)
    assert mesh.is_winding_consistent
    assert enclosed_volume(mesh) == pytest.approx(enclosed_volume(ball), rel=1e-6)


def test_glb_scene_round_trip(tmp_path):
    ball = make_ball_mesh(0.2, 3)
    # Split the surface into two scene nodes, as GLB exports of textured scans often are: the
    # loader must flatten the scene and merge the seam vertices to close the surface again.
    upper = ball.triangles_center[:, 2] > 0.0
    scene = trimesh.Scene(
        [ball.submesh([np.flatnonzero(upper)], append=True), ball.submesh([np.flatnonzero(~upper)], append=True)]
    )
    path = tmp_path / "ball.glb"
    scene.export(path)
    mesh = _no_warnings(load_mesh, path)
    assert mesh.is_watertight and mesh.body_count == 1
    assert len(mesh.vertices) == len(ball.vertices)
    # GLB stores float32 coordinates: relative volume error ~ 3 × 6e-8.
    assert enclosed_volume(mesh) == pytest.approx(enclosed_volume(ball), rel=1e-6)


def test_glb_with_separate_bodies_warns(tmp_path):
    a = make_ball_mesh(0.1, 2)
    b = make_ball_mesh(0.1, 2).apply_translation([0.5, 0.0, 0.0])
    path = tmp_path / "two.glb"
    trimesh.Scene([a, b]).export(path)
    with pytest.warns(GeometryWarning, match="2 disconnected closed bodies"):
        mesh = load_mesh(path)
    assert enclosed_volume(mesh) == pytest.approx(2 * enclosed_volume(a), rel=1e-6)


# ---------------------------------------------------------------------------- fit_local_sphere


@pytest.mark.parametrize("subdivisions", [3, 5])
def test_icosphere_radius_and_curvature_are_recovered(subdivisions):
    radius = 0.13
    ball = make_ball_mesh(radius, subdivisions)
    fit = _no_warnings(fit_local_sphere, ball, [0.05, -0.03, 0.115])
    assert isinstance(fit, LocalCurvature)
    # Icosphere vertices lie exactly on the sphere and a sphere/quadric is in the model class, so
    # the fits are exact up to float64 round-off, whatever the subdivision level.
    assert fit.radius == pytest.approx(radius, rel=1e-10)
    assert fit.rms_residual < 1e-12
    assert fit.radius_std < 1e-12
    np.testing.assert_allclose(fit.principal_curvatures, 1.0 / radius, rtol=1e-8)
    np.testing.assert_allclose(fit.center, 0.0, atol=1e-10)
    assert fit.is_convex and fit.warnings == []
    # Snapped onto a face: within the facet sagitta below the sphere, along the outward normal.
    assert 0.0 < radius - np.linalg.norm(fit.poke_point) < 0.05 * radius
    radial = np.array(fit.poke_point) / np.linalg.norm(fit.poke_point)
    np.testing.assert_allclose(fit.normal, radial, atol=1e-8)
    # Default neighbourhood: 15 % of the bounding diagonal 2√3 R.
    assert fit.fit_radius == pytest.approx(0.15 * 2.0 * np.sqrt(3.0) * radius, rel=1e-12)


def test_ellipsoid_principal_curvatures_and_nonspherical_warning():
    a, b, c = 0.3, 0.2, 0.15
    ellipsoid = make_ball_mesh(1.0, 5).apply_scale([a, b, c])
    with pytest.warns(GeometryWarning, match="far from spherical"):
        fit = fit_local_sphere(ellipsoid, [a, 0.0, 0.0], fit_radius=0.05)
    # Scaling a sphere's vertices puts them exactly on the ellipsoid, and an ellipsoid is a
    # quadric, so the analytic tip curvatures a/c² (along z) and a/b² (along y) come out to
    # round-off.
    np.testing.assert_allclose(fit.principal_curvatures, [a / c**2, a / b**2], rtol=1e-8)
    assert fit.is_convex
    # The sphere through a non-spherical patch averages the two principal radii.
    assert c**2 / a < fit.radius < b**2 / a
    assert len(fit.warnings) == 1 and "differ by 44%" in fit.warnings[0]


def test_concave_region_warns():
    radius, cut = 0.1, 0.06
    dimpled = _dimpled_ball(radius, cut)
    with pytest.warns(GeometryWarning, match="concave"):
        fit = fit_local_sphere(dimpled, [0.0, 0.0, 2 * cut - radius], fit_radius=0.03)
    # The dimple is a mirrored spherical cap: radius R, curvatures −1/R w.r.t. the outward normal
    # (+z at the dimple's bottom), vertices exactly on that sphere.
    assert not fit.is_convex
    assert fit.radius == pytest.approx(radius, rel=1e-9)
    np.testing.assert_allclose(fit.principal_curvatures, -1.0 / radius, rtol=1e-8)
    np.testing.assert_allclose(fit.normal, [0.0, 0.0, 1.0], atol=1e-8)
    np.testing.assert_allclose(fit.center, [0.0, 0.0, 2 * cut], atol=1e-9)


def test_radius_std_matches_monte_carlo_scatter():
    radius, sigma = 0.25, 1e-4
    ball = make_ball_mesh(radius, 4)
    unit = ball.vertices / radius
    rng = np.random.default_rng(7)
    fits = []
    for _ in range(40):
        noisy = trimesh.Trimesh(unit * (radius + rng.normal(0.0, sigma, (len(unit), 1))), ball.faces, process=False)
        fits.append(_no_warnings(fit_local_sphere, noisy, [0.0, 0.0, radius], fit_radius=0.1))
    radii = np.array([f.radius for f in fits])
    predicted = np.mean([f.radius_std for f in fits])
    # With 40 samples the sample standard deviation is within ±35 % of the truth at > 99 %
    # (its relative standard error is 1/√(2·39) ≈ 11 %).
    assert np.std(radii, ddof=1) == pytest.approx(predicted, rel=0.35)
    assert abs(np.mean(radii) - radius) < 4 * predicted / np.sqrt(len(fits))
    # rms of n residuals after fitting 4 parameters: σ √((n − 4)/n) ≈ σ for n > 50.
    assert np.mean([f.rms_residual for f in fits]) == pytest.approx(sigma, rel=0.1)


def test_fit_errors_name_problem_and_fix():
    ball = make_ball_mesh(0.1, 3)
    with pytest.raises(InvalidInputError, match=r"is 0\.1 m from the mesh surface.*off the surface"):
        fit_local_sphere(ball, [0.0, 0.0, 0.2])
    with pytest.raises(
        InvalidInputError,
        match=r"only \d mesh vertices lie within fit_radius.*"
        r"increase fit_radius or refine the mesh",
    ):
        fit_local_sphere(ball, [0.0, 0.0, 0.1], fit_radius=0.01)
    with pytest.raises(InvalidInputError, match="fit_radius = -0.01 m must be a positive length"):
        fit_local_sphere(ball, [0.0, 0.0, 0.1], fit_radius=-0.01)
    with pytest.raises(InvalidInputError, match="must be three finite coordinates"):
        fit_local_sphere(ball, [0.0, 0.1])
    box = trimesh.creation.box(extents=[0.2, 0.2, 0.2]).subdivide().subdivide().subdivide()
    with pytest.raises(InvalidInputError, match="is flat.*poke a curved part"):
        fit_local_sphere(box, [0.0, 0.0, 0.1], fit_radius=0.05)
    open_ball = trimesh.Trimesh(ball.vertices, ball.faces[1:], process=False)
    with pytest.raises(InvalidInputError, match="fit_local_sphere: mesh is not watertight"):
        fit_local_sphere(open_ball, [0.0, 0.0, 0.1])


def test_neighbourhood_stays_on_the_connected_surface():
    # Two parallel sheets 2 mm apart (a thin flat-ish toy): a Euclidean ball around a point on the
    # top would also catch the bottom sheet; the connected neighbourhood must not.
    ball = make_ball_mesh(0.1, 4).apply_scale([1.0, 1.0, 0.01])
    fit = fit_local_sphere(ball, [0.0, 0.0, 0.001], fit_radius=0.03)
    inside = np.linalg.norm(ball.vertices - np.array(fit.poke_point), axis=1) <= 0.03
    top = ball.vertices[:, 2] > 0.0
    assert np.any(inside & ~top)  # the Euclidean ball does reach the bottom sheet ...
    assert fit.n_vertices == np.sum(inside & top)  # ... but only the top sheet is used
    assert fit.normal[2] > 0.99
    # Apex of the oblate ellipsoid (a = b = 0.1 m, c = 1 mm): both curvatures c/a² = 0.1 1/m.
    np.testing.assert_allclose(fit.principal_curvatures, 0.001 / 0.1**2, rtol=1e-6)


# -------------------------------------------------------------------------- primitives, data


def _hammer_analytic_volume():
    """Smooth hammer volume [m³]: two capsules minus the part of the handle inside the head."""
    big, small = HAMMER_HEAD_RADIUS, HAMMER_HANDLE_RADIUS
    head = np.pi * big**2 * (HAMMER_HEAD_LENGTH - 2 * big) + 4 / 3 * np.pi * big**3
    total = big + HAMMER_HANDLE_LENGTH
    handle = np.pi * small**2 * (total - 2 * small) + 4 / 3 * np.pi * small**3
    top_cap = 2 / 3 * np.pi * small**3  # the handle's upper hemisphere lies inside the head
    # Handle cylinder (z < −small) inside the head cylinder y² + z² < big².
    inside, _ = integrate.dblquad(
        lambda y, x: np.sqrt(big**2 - y**2) - small,
        -small,
        small,
        lambda x: -np.sqrt(small**2 - x**2),
        lambda x: np.sqrt(small**2 - x**2),
    )
    return head + handle - top_cap - inside


def test_hammer_mesh_is_closed_and_has_the_analytic_volume():
    hammer = make_hammer_mesh()
    assert hammer.is_watertight and hammer.is_winding_consistent and hammer.body_count == 1
    expected = _hammer_analytic_volume()
    # Vertices lie on the smooth capsules, so the polygonal mesh is slightly smaller; an inscribed
    # n-gon loses (2π/n)²/6 of a circle's area, ≤ 1.1 % for the handle's 24 sections, twice that
    # bounds the two curved directions of the caps.
    deficit = 1.0 - enclosed_volume(hammer) / expected
    assert 0.0 < deficit < 2 * (2 * np.pi / 24) ** 2 / 6


def test_bundled_hammer_radius_at_documented_poke_point():
    path = bundled_mesh_path("hammer.stl")
    assert path.stat().st_size < 2e6
    hammer = _no_warnings(load_mesh, path)
    # The bundled file is what make_hammer_mesh produces (float32 STL: ~1e-7 relative).
    assert enclosed_volume(hammer) == pytest.approx(enclosed_volume(make_hammer_mesh()), rel=1e-6)
    fit = _no_warnings(fit_local_sphere, hammer, HAMMER_POKE_POINT)
    # The default neighbourhood (15 % of the 0.62 m diagonal = 0.093 m, a cap of half-angle 71°)
    # stays on the head's hemispherical end cap, whose vertices lie on a sphere of radius 0.08 m
    # up to float32 rounding (~1e-8 m).
    assert fit.fit_radius == pytest.approx(0.15 * np.linalg.norm(np.ptp(hammer.vertices, axis=0)))
    assert fit.fit_radius < np.sqrt(2) * HAMMER_HEAD_RADIUS
    assert fit.radius == pytest.approx(HAMMER_HEAD_RADIUS, abs=1e-7)
    np.testing.assert_allclose(fit.principal_curvatures, 1 / HAMMER_HEAD_RADIUS, rtol=1e-5)
    assert fit.is_convex and fit.warnings == []


def test_bundled_beach_ball():
    path = bundled_mesh_path("beach_ball.ply")
    assert path.stat().st_size < 2e6
    ball = _no_warnings(load_mesh, path)
    fit = _no_warnings(fit_local_sphere, ball, [0.0, 0.0, 0.25])
    # Radial noise σ = 1e-4 m on an R = 0.25 m icosphere.
    assert fit.rms_residual == pytest.approx(1e-4, rel=0.2)
    assert abs(fit.radius - 0.25) < 4 * fit.radius_std
    with pytest.raises(InvalidInputError, match="no bundled mesh named 'nope.stl'"):
        bundled_mesh_path("nope.stl")
