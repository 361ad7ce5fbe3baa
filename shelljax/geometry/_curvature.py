"""Local radius of curvature at a poke point: sphere fit plus principal curvatures (numpy only).

The indentation formulas treat the poked region as a sphere of radius R. This module measures R on
a mesh [m] and says how far the region is from a sphere (principal curvatures) so the user knows
whether the spherical model applies.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import trimesh

from .._errors import InvalidInputError
from ._mesh import GeometryWarning, _require_watertight

__all__ = ["DEFAULT_FIT_RADIUS_FRACTION", "LocalCurvature", "fit_local_sphere"]

#: Default neighbourhood radius as a fraction of the mesh bounding-box diagonal. On a sphere of
#: radius R (diagonal 2√3 R) this gives a cap of chord 0.52 R (half-angle ≈ 30°): wide enough to
#: average photogrammetry noise, small enough to stay local on a toy's part.
DEFAULT_FIT_RADIUS_FRACTION = 0.15

# Poke points farther than this fraction of the bounding diagonal from the surface are an error
# (wrong unit or wrong frame), not a point to be snapped.
_MAX_SNAP_FRACTION = 0.05
_MIN_VERTICES = 10
# Principal curvatures differing by more than this fraction of the larger one: not a sphere.
_ANISOTROPY_LIMIT = 0.20
# A fitted radius above this multiple of the bounding diagonal means the patch is flat.
_MAX_RADIUS_FRACTION = 1e3


@dataclasses.dataclass(frozen=True)
class LocalCurvature:
    """Result of :func:`fit_local_sphere` (all lengths in metres, curvatures in 1/m).

    **Fields:**

    - `radius`: radius of the least-squares sphere through the neighbourhood [m].
    - `radius_std`: 1-σ standard error of `radius` [m] from the fit's residual covariance,
      √(s² [(JᵀJ)⁻¹]_RR) with s² = Σ rᵢ² / (n − 4), J the Jacobian of the geometric residuals
      rᵢ = |xᵢ − c| − R with respect to (c, R) at the optimum. It reflects scatter (mesh noise,
      facets) only; a systematically non-spherical region is flagged by `principal_curvatures`
      and `warnings`, not by this number.
    - `rms_residual`: √(mean rᵢ²) of the geometric residuals [m].
    - `center`: centre of the fitted sphere [m], shape (3,).
    - `poke_point`: the poke point snapped to the nearest point on the mesh surface [m].
    - `normal`: outward unit normal of the fitted quadric at the poke point.
    - `principal_curvatures`: (k1, k2) with k1 ≥ k2 [1/m] at the poke point, from an implicit
      quadric fitted to the neighbourhood; positive means curving away from the outward normal
      (convex, like a ball: k = 1/R).
    - `n_vertices`: number of mesh vertices used in the fits.
    - `fit_radius`: neighbourhood radius used [m].
    - `is_convex`: mean curvature (k1 + k2)/2 > 0, i.e. the region bulges outward.
    - `warnings`: human-readable warnings (also issued as :class:`GeometryWarning`).
    """

    radius: float
    radius_std: float
    rms_residual: float
    center: tuple[float, float, float]
    poke_point: tuple[float, float, float]
    normal: tuple[float, float, float]
    principal_curvatures: tuple[float, float]
    n_vertices: int
    fit_radius: float
    is_convex: bool
    warnings: list[str] = dataclasses.field(default_factory=list)


def _closest_surface_point(mesh: trimesh.Trimesh, point: np.ndarray) -> tuple[np.ndarray, int]:
    """Nearest point on the mesh surface to `point` and the index of its face (brute force)."""
    triangles = np.asarray(mesh.triangles, dtype=np.float64)
    # Only faces near the nearest vertex can hold the nearest surface point: a face at distance d
    # has a vertex within d + (its longest edge) of the point.
    d_vert = np.linalg.norm(mesh.vertices - point, axis=1)
    edge = np.max(np.linalg.norm(triangles - np.roll(triangles, 1, axis=1), axis=2), axis=1)
    d_face_min = np.min(d_vert[mesh.faces], axis=1)
    candidates = np.flatnonzero(d_face_min <= d_vert.min() + edge)
    closest = trimesh.triangles.closest_point(triangles[candidates], np.broadcast_to(point, (len(candidates), 3)))
    k = int(np.argmin(np.linalg.norm(closest - point, axis=1)))
    return np.asarray(closest[k], dtype=np.float64), int(candidates[k])


def _connected_neighbourhood(mesh: trimesh.Trimesh, inside: np.ndarray, seeds: np.ndarray) -> np.ndarray:
    """Vertices in `inside` reachable from `seeds` along mesh edges without leaving `inside`.

    Cuts off pieces of the surface that are close in space but not along the surface (the other
    side of a thin handle, a neighbouring finger of a glove): an approximate geodesic ball.
    """
    edges = np.asarray(mesh.edges_unique, dtype=np.int64)
    edges = edges[inside[edges[:, 0]] & inside[edges[:, 1]]]
    reached = np.zeros(len(mesh.vertices), dtype=bool)
    reached[seeds[inside[seeds]]] = True
    while True:
        grow = reached[edges[:, 0]] != reached[edges[:, 1]]
        if not grow.any():
            return reached
        reached[edges[grow].ravel()] = True


def _algebraic_sphere(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Kåsa fit: |x|² = 2 c·x + d in the least-squares sense (linear), R = √(d + |c|²)."""
    shift = points.mean(axis=0)
    scale = float(np.max(np.linalg.norm(points - shift, axis=1)))
    x = (points - shift) / scale  # O(1) coordinates keep the normal equations well conditioned
    a = np.column_stack([2.0 * x, np.ones(len(x))])
    sol, *_ = np.linalg.lstsq(a, np.sum(x * x, axis=1), rcond=None)
    r2 = sol[3] + sol[:3] @ sol[:3]
    radius = float(np.sqrt(r2)) * scale if r2 > 0 else np.inf
    return sol[:3] * scale + shift, radius


def _geometric_sphere(
    points: np.ndarray, center: np.ndarray, radius: float
) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """Gauss–Newton on rᵢ = |xᵢ − c| − R from an initial guess; returns (c, R, residuals, J)."""
    params = np.append(center, radius)

    def residual_and_jacobian(p):
        diff = points - p[:3]
        dist = np.linalg.norm(diff, axis=1)
        jac = np.column_stack([-diff / dist[:, None], -np.ones(len(points))])
        return dist - p[3], jac

    res, jac = residual_and_jacobian(params)
    cost = res @ res
    for _ in range(100):
        step, *_ = np.linalg.lstsq(jac, -res, rcond=None)
        # Step halving keeps the cost monotone when the algebraic start is poor (noisy, thin cap).
        for _ in range(30):
            trial = params + step
            res_t, jac_t = residual_and_jacobian(trial)
            if res_t @ res_t <= cost:
                break
            step = 0.5 * step
        else:
            break
        converged = np.linalg.norm(step) <= 1e-13 * max(abs(params[3]), 1e-300)
        params, res, jac, cost = trial, res_t, jac_t, res_t @ res_t
        if converged:
            break
    return params[:3], float(params[3]), res, jac


def _quadric_terms(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 10 monomials of a quadric in 3D and their gradients: shapes (n, 10) and (n, 10, 3)."""
    n = len(x)
    one, zero = np.ones(n), np.zeros(n)
    x0, x1, x2 = x[:, 0], x[:, 1], x[:, 2]
    values = np.column_stack([x0 * x0, x1 * x1, x2 * x2, x0 * x1, x0 * x2, x1 * x2, x0, x1, x2, one])
    grads = np.stack(
        [
            np.column_stack([2 * x0, zero, zero]),
            np.column_stack([zero, 2 * x1, zero]),
            np.column_stack([zero, zero, 2 * x2]),
            np.column_stack([x1, x0, zero]),
            np.column_stack([x2, zero, x0]),
            np.column_stack([zero, x2, x1]),
            np.column_stack([one, zero, zero]),
            np.column_stack([zero, one, zero]),
            np.column_stack([zero, zero, one]),
            np.column_stack([zero, zero, zero]),
        ],
        axis=1,
    )
    return values, grads


def _quadric_hessian(theta: np.ndarray) -> np.ndarray:
    a, b, c, d, e, f = theta[:6]
    return np.array([[2 * a, d, e], [d, 2 * b, f], [e, f, 2 * c]])


def _quadric_curvatures(
    points: np.ndarray, origin: np.ndarray, outward: np.ndarray, length: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Principal curvatures [1/m] at `origin` of the implicit quadric Q(x) = 0 fitted to `points`.

    Q has 10 coefficients θ, the right singular vector of the monomial matrix with the smallest
    singular value (algebraic fit, |θ| = 1) in coordinates centred at `origin` and scaled by
    `length`. A quadric contains spheres, ellipsoids and cylinders exactly, so the curvature of
    such regions is recovered without the truncation bias of a height-field polynomial. `origin`
    is projected onto Q = 0 (Newton along ∇Q); there the shape operator is
    Tᵀ Hess(Q) T / |∇Q| with T a tangent basis and ∇Q oriented along `outward`, so positive
    curvature means convex (the surface bends away from the outward normal, sphere: k = 1/R).
    Returns (k1 ≥ k2), the projected point [m] and the outward unit normal there.
    """
    x = (points - origin) / length  # O(1) coordinates for a well-conditioned SVD
    values, _ = _quadric_terms(x)
    _, _, vt = np.linalg.svd(values, full_matrices=False)
    theta = vt[-1]

    def q_and_grad(y):
        val, grad = _quadric_terms(y[None, :])
        return float(val[0] @ theta), grad[0].T @ theta

    y = np.zeros(3)
    for _ in range(20):
        q, g = q_and_grad(y)
        gg = float(g @ g)
        if gg == 0.0:
            break
        step = q * g / gg
        y = y - step
        if np.linalg.norm(step) < 1e-14:
            break
    if not np.all(np.isfinite(y)) or np.linalg.norm(y) > 0.5:
        y = np.zeros(3)  # projection failed (degenerate quadric): stay at the snapped point
    _, g = q_and_grad(y)
    gnorm = float(np.linalg.norm(g))
    if gnorm == 0.0 or not np.isfinite(gnorm):
        return np.zeros(2), origin, outward
    normal = g / gnorm
    hess = _quadric_hessian(theta)
    if normal @ outward < 0.0:
        normal, hess = -normal, -hess
    t1 = np.cross(normal, [1.0, 0.0, 0.0])
    if np.linalg.norm(t1) < 0.5:
        t1 = np.cross(normal, [0.0, 1.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(normal, t1)
    tangent = np.column_stack([t1, t2])
    shape = tangent.T @ hess @ tangent / gnorm
    k = np.sort(np.linalg.eigvalsh(0.5 * (shape + shape.T)))[::-1] / length
    return k, origin + y * length, normal


def fit_local_sphere(mesh: trimesh.Trimesh, poke_point, fit_radius: float | None = None) -> LocalCurvature:
    """Fit a sphere to the mesh around a poke point: the local radius of curvature R [m].

    **Arguments:**

    - `mesh`: closed, outward-oriented mesh in metres (as returned by :func:`load_mesh`).
    - `poke_point`: (3,) point [m] where the finger pokes; it is snapped to the nearest point on
      the surface. It must lie within 5 % of the bounding-box diagonal of the surface.
    - `fit_radius`: neighbourhood radius [m]. Default: 15 % of the bounding-box diagonal
      (``DEFAULT_FIT_RADIUS_FRACTION``). Vertices within this Euclidean distance of the snapped
      point that are connected to it along mesh edges inside that ball are used — an approximate
      geodesic ball, so the far side of a thin part is never included.

    **Method:** an algebraic (Kåsa) sphere fit gives the start for a Gauss–Newton fit of the
    geometric residuals |xᵢ − c| − R. Principal curvatures come from an implicit quadric fitted
    to the same vertices (exact for spheres, ellipsoids and cylinders), evaluated where the
    snapped point projects onto it.

    **Returns:** :class:`LocalCurvature`. A :class:`GeometryWarning` is issued (and recorded in
    ``.warnings``) when the principal curvatures differ by more than 20 % of the larger one
    (the spherical model is a poor approximation there) or the region is concave.

    **Raises:** `InvalidInputError` if the mesh is not watertight, the poke point is off the
    surface, fewer than 10 vertices fall in the neighbourhood, or the region is flat.
    """
    _require_watertight(mesh, "fit_local_sphere")
    diagonal = float(np.linalg.norm(mesh.bounds[1] - mesh.bounds[0]))
    point, fit_radius = _checked_inputs(poke_point, fit_radius, diagonal)
    snapped, face, pts = _neighbourhood(mesh, point, fit_radius, diagonal)
    face_normal = np.asarray(mesh.face_normals[face], dtype=np.float64)
    k, _, normal = _quadric_curvatures(pts, snapped, face_normal, fit_radius)
    center, radius, radius_std, rms = _sphere_fit(pts, snapped, fit_radius, diagonal, k)
    k1, k2 = float(k[0]), float(k[1])
    is_convex = bool(0.5 * (k1 + k2) > 0.0)
    messages = _shape_warnings(snapped, k1, k2, radius)
    for message in messages:
        warnings.warn(message, GeometryWarning, stacklevel=2)
    return LocalCurvature(
        radius=float(radius),
        radius_std=radius_std,
        rms_residual=rms,
        center=tuple(float(x) for x in center),
        poke_point=tuple(float(x) for x in snapped),
        normal=tuple(float(x) for x in normal),
        principal_curvatures=(k1, k2),
        n_vertices=len(pts),
        fit_radius=fit_radius,
        is_convex=is_convex,
        warnings=messages,
    )


def _checked_inputs(poke_point, fit_radius, diagonal: float) -> tuple[np.ndarray, float]:
    """(poke point [m], neighbourhood radius [m], the default's when None), checked."""
    point = np.asarray(poke_point, dtype=np.float64)
    if point.shape != (3,) or not np.all(np.isfinite(point)):
        raise InvalidInputError(
            f"fit_local_sphere: poke_point = {poke_point!r} must be three finite coordinates [m] "
            "(`poke_point = [x, y, z]` in [geometry])"
        )
    if fit_radius is None:
        fit_radius = DEFAULT_FIT_RADIUS_FRACTION * diagonal
    fit_radius = float(fit_radius)
    if not (np.isfinite(fit_radius) and fit_radius > 0.0):
        raise InvalidInputError(
            f"fit_local_sphere: fit_radius = {fit_radius!r} m must be a positive length; "
            f"omit it for the default ({DEFAULT_FIT_RADIUS_FRACTION:.0%} of the bounding diagonal)"
        )
    return point, fit_radius


def _neighbourhood(mesh: trimesh.Trimesh, point: np.ndarray, fit_radius: float, diagonal: float):
    """(the poke point snapped to the surface [m], its face, the vertices of its geodesic ball [m])."""
    snapped, face = _closest_surface_point(mesh, point)
    distance = float(np.linalg.norm(snapped - point))
    if distance > _MAX_SNAP_FRACTION * diagonal:
        raise InvalidInputError(
            f"fit_local_sphere: poke_point {point.tolist()} m is {distance:.4g} m from the mesh "
            f"surface, more than {_MAX_SNAP_FRACTION:.0%} of the bounding diagonal "
            f"({diagonal:.4g} m); the point is off the surface: check its coordinates, their "
            f"`length_unit` and that they are in the mesh's frame (mesh bounds "
            f"{mesh.bounds[0].round(4).tolist()} to {mesh.bounds[1].round(4).tolist()} m)"
        )
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    inside = np.linalg.norm(vertices - snapped, axis=1) <= fit_radius
    selected = _connected_neighbourhood(mesh, inside, np.asarray(mesh.faces[face]))
    n = int(selected.sum())
    if n < _MIN_VERTICES:
        raise InvalidInputError(
            f"fit_local_sphere: only {n} mesh vertices lie within fit_radius = {fit_radius:.4g} m "
            f"of the poke point {snapped.round(5).tolist()} m; a sphere fit needs at least "
            f"{_MIN_VERTICES}: increase fit_radius or refine the mesh "
            "(e.g. trimesh.remesh.subdivide)"
        )
    pts = vertices[selected]
    # Coplanar points make the sphere fit degenerate (a least-squares solver would silently return
    # the in-plane circle); relative thickness 1e-9 is far below any scan's noise.
    extent = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
    if extent[2] <= 1e-9 * extent[0]:
        raise InvalidInputError(_flat_message(snapped, fit_radius, None))
    return snapped, face, pts


def _sphere_fit(pts: np.ndarray, snapped: np.ndarray, fit_radius: float, diagonal: float, k: np.ndarray):
    """(centre [m], radius R [m], its standard error [m], rms residual [m]) of the geometric fit."""
    center0, radius0 = _algebraic_sphere(pts)
    if not np.isfinite(radius0) or radius0 > _MAX_RADIUS_FRACTION * diagonal:
        raise InvalidInputError(_flat_message(snapped, fit_radius, k))
    center, radius, res, jac = _geometric_sphere(pts, center0, radius0)
    if not np.isfinite(radius) or abs(radius) > _MAX_RADIUS_FRACTION * diagonal:
        raise InvalidInputError(_flat_message(snapped, fit_radius, k))
    radius = abs(radius)  # R and −R describe the same sphere in the residual
    dof = max(len(pts) - 4, 1)
    s2 = float(res @ res) / dof
    cov = s2 * np.linalg.pinv(jac.T @ jac)
    radius_std = float(np.sqrt(max(cov[3, 3], 0.0)))
    rms = float(np.sqrt(np.mean(res * res)))
    return center, radius, radius_std, rms


def _shape_warnings(snapped: np.ndarray, k1: float, k2: float, radius: float) -> list[str]:
    """Why the spherical model may not apply: unequal principal curvatures, or a concave region."""
    mean_curvature = 0.5 * (k1 + k2)
    messages = []
    spread = abs(k1 - k2) / max(abs(k1), abs(k2), 1e-300)
    if spread > _ANISOTROPY_LIMIT:
        messages.append(
            f"region around poke point {snapped.round(5).tolist()} m is far from spherical: "
            f"principal radii 1/k1 = {_inv(k1)} m and 1/k2 = {_inv(k2)} m differ by "
            f"{spread:.0%} (> {_ANISOTROPY_LIMIT:.0%}); the spherical-shell formulas assume one "
            f"radius, so R = {radius:.4g} m is an average. Poke where the surface is rounder or "
            "use the 3D shell model."
        )
    if not mean_curvature > 0.0:
        messages.append(
            f"region around poke point {snapped.round(5).tolist()} m is concave (mean curvature "
            f"{mean_curvature:.4g} 1/m relative to the outward normal, sphere centre outside the "
            "object); the indentation formulas assume a convex, outward-bulging shell."
        )
    return messages


def _inv(k: float) -> str:
    return f"{1.0 / k:.4g}" if k != 0.0 else "inf"


def _flat_message(snapped: np.ndarray, fit_radius: float, k: np.ndarray | None) -> str:
    measured = "" if k is None else f" (principal curvatures {k[0]:.3g}, {k[1]:.3g} 1/m)"
    return (
        f"fit_local_sphere: the surface within fit_radius = {fit_radius:.4g} m of "
        f"{snapped.round(5).tolist()} m is flat to the mesh's precision{measured}, so no radius "
        "of curvature can be fitted; poke a curved part of the object or increase fit_radius"
    )
