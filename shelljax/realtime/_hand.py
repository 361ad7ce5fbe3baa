"""Compiled (Numba) contact of the real-time runtime's moving capsule collider (the user's hand)
with the shell (float64, SI units): the vertices' springs along their normals (``exit_distance``)
and the triangles' closest-point backstop (``segment_triangle_closest``). ``collider_contact`` is
the entry point (:mod:`._kernels` calls it once per force evaluation, after the planes')."""

from __future__ import annotations

import math

from numba import njit

from ._contact import _friction

#: The collider's slip velocity v_ε [m/s] of its regularised Coulomb friction.
COLLIDER_SLIP_VELOCITY = 1e-2

#: The triangles' backstop engages past this fraction of the collider's radius [-] of a face's
#: penetration: an ordinary press stays on the vertices' springs (the reference's indenter), a
#: collider slipping between vertices meets the face before its axis does.
BACKSTOP_DEPTH = 0.25


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _clamp01(t):
    return min(1.0, max(0.0, t))


@njit(cache=True, fastmath=False, error_model="numpy")
def _point_triangle(p, a, b, c):
    """Barycentric weights (w_a, w_b, w_c) [-] of the point of the triangle a b c closest to p (each
    (3,) [m]) (Ericson, *Real-Time Collision Detection* §5.1.5: by Voronoi region, so a degenerate
    triangle is safe)."""
    px, py, pz = p
    ax, ay, az = a
    bx, by, bz = b
    cx, cy, cz = c
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3)
        return 1.0 - t, t, 0.0
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        return 1.0 - t, 0.0, t
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return 0.0, 1.0 - t, t
    denom = 1.0 / (va + vb + vc)
    v = vb * denom
    w = vc * denom
    return 1.0 - v - w, v, w


@njit(cache=True, fastmath=False, error_model="numpy")
def _segment_segment(p1, q1, p2, q2):
    """Parameters (s, t) ∈ [0, 1]² [-] of the closest points of segments p1–q1 and p2–q2 (each end
    (3,) [m]) (Ericson §5.1.9, with its parallel and degenerate cases)."""
    p1x, p1y, p1z = p1
    q1x, q1y, q1z = q1
    p2x, p2y, p2z = p2
    q2x, q2y, q2z = q2
    d1x, d1y, d1z = q1x - p1x, q1y - p1y, q1z - p1z
    d2x, d2y, d2z = q2x - p2x, q2y - p2y, q2z - p2z
    rx, ry, rz = p1x - p2x, p1y - p2y, p1z - p2z
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    f = d2x * rx + d2y * ry + d2z * rz
    if a <= 0.0 and e <= 0.0:
        return 0.0, 0.0
    if a <= 0.0:
        return 0.0, _clamp01(f / e)
    c = d1x * rx + d1y * ry + d1z * rz
    if e <= 0.0:
        return _clamp01(-c / a), 0.0
    b = d1x * d2x + d1y * d2y + d1z * d2z
    denom = a * e - b * b
    s = _clamp01((b * f - c * e) / denom) if denom > 0.0 else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        return _clamp01(-c / a), 0.0
    if t > 1.0:
        return _clamp01((b - c) / a), 1.0
    return s, t


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _gap2(s, w0, w1, w2, a, d, p0, p1, p2):
    """|segment point at s − triangle point at (w0, w1, w2)|² [m²]."""
    g = 0.0
    for c in range(3):
        r = a[c] + s * d[c] - (w0 * p0[c] + w1 * p1[c] + w2 * p2[c])
        g += r * r
    return g


@njit(cache=True, fastmath=False, error_model="numpy")
def segment_triangle_closest(a, b, p0, p1, p2):
    """The closest points of the segment a–b and the triangle p0 p1 p2 (each (3,) [m]): (s, w0, w1, w2) [-], the
    point a + s (b − a) and the point w0 p0 + w1 p1 + w2 p2. The least distance is reached at an end
    of the segment (point–triangle), on an edge of the triangle (segment–segment), or, where the
    segment crosses the triangle, at the crossing (distance 0); the best of the candidates."""
    ax, ay, az = a
    bx, by, bz = b
    p0x, p0y, p0z = p0
    p1x, p1y, p1z = p1
    p2x, p2y, p2z = p2
    d = (bx - ax, by - ay, bz - az)
    best = (0.0, 1.0, 0.0, 0.0)
    best_g = math.inf
    for s in (0.0, 1.0):
        w0, w1, w2 = _point_triangle((ax + s * d[0], ay + s * d[1], az + s * d[2]), p0, p1, p2)
        g = _gap2(s, w0, w1, w2, a, d, p0, p1, p2)
        if g < best_g:
            best_g, best = g, (s, w0, w1, w2)
    for k in range(3):
        u, v = (p0, p1, p2)[k], (p1, p2, p0)[k]
        s, t = _segment_segment(a, b, u, v)
        w = (1.0 - t, t, 0.0) if k == 0 else ((0.0, 1.0 - t, t) if k == 1 else (t, 0.0, 1.0 - t))
        g = _gap2(s, w[0], w[1], w[2], a, d, p0, p1, p2)
        if g < best_g:
            best_g, best = g, (s, w[0], w[1], w[2])
    # the crossing: a + s d on the triangle's plane, inside it (Möller–Trumbore's barycentrics)
    e1x, e1y, e1z = p1x - p0x, p1y - p0y, p1z - p0z
    e2x, e2y, e2z = p2x - p0x, p2y - p0y, p2z - p0z
    hx, hy, hz = d[1] * e2z - d[2] * e2y, d[2] * e2x - d[0] * e2z, d[0] * e2y - d[1] * e2x
    det = e1x * hx + e1y * hy + e1z * hz
    if det != 0.0:
        tx, ty, tz = ax - p0x, ay - p0y, az - p0z
        u1 = (tx * hx + ty * hy + tz * hz) / det
        qx, qy, qz = ty * e1z - tz * e1y, tz * e1x - tx * e1z, tx * e1y - ty * e1x
        u2 = (d[0] * qx + d[1] * qy + d[2] * qz) / det
        s = (e2x * qx + e2y * qy + e2z * qz) / det
        if 0.0 <= s <= 1.0 and u1 >= 0.0 and u2 >= 0.0 and u1 + u2 <= 1.0:
            g = _gap2(s, 1.0 - u1 - u2, u1, u2, a, d, p0, p1, p2)
            if g < best_g:
                best = (s, 1.0 - u1 - u2, u1, u2)
    return best


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _face_push(x, f0, f1, f2, collider, s, w0, w1, w2):
    """(unit direction of the force on the shell, its penetration δ [m]) at the closest points d [m]
    apart (s on the collider's axis, (w0, w1, w2) on the face). Closest at an edge or a vertex:
    along the gap from the axis, δ = r − d. Closest inside the face (or the axis through it): along
    the face's inward normal −n, δ = r − h with h [m] the height over the face's plane of the axis's
    lower end (h = d in front of the face; h < 0 when the axis crosses the face or lies behind it,
    within r), so that a deep axis is pushed back out, harder the deeper it is. δ ≤ 0: none."""
    r = collider[6]
    sx = collider[0] + s * (collider[3] - collider[0])
    sy = collider[1] + s * (collider[4] - collider[1])
    sz = collider[2] + s * (collider[5] - collider[2])
    gx = w0 * x[f0, 0] + w1 * x[f1, 0] + w2 * x[f2, 0] - sx
    gy = w0 * x[f0, 1] + w1 * x[f1, 1] + w2 * x[f2, 1] - sy
    gz = w0 * x[f0, 2] + w1 * x[f1, 2] + w2 * x[f2, 2] - sz
    d = math.sqrt(gx * gx + gy * gy + gz * gz)
    if d >= r:
        return 0.0, 0.0, 0.0, 0.0
    if not (d == 0.0 or (w0 > 0.0 and w1 > 0.0 and w2 > 0.0)):
        return gx / d, gy / d, gz / d, r - d
    e1x, e1y, e1z = x[f1, 0] - x[f0, 0], x[f1, 1] - x[f0, 1], x[f1, 2] - x[f0, 2]
    e2x, e2y, e2z = x[f2, 0] - x[f0, 0], x[f2, 1] - x[f0, 1], x[f2, 2] - x[f0, 2]
    nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    nn = math.sqrt(nx * nx + ny * ny + nz * nz)
    if nn == 0.0:
        return 0.0, 0.0, 0.0, 0.0
    nx, ny, nz = nx / nn, ny / nn, nz / nn
    h = math.inf
    for e in (0, 3):  # the axis's ends' heights over the face's plane
        h = min(
            h, (collider[e] - x[f0, 0]) * nx + (collider[e + 1] - x[f0, 1]) * ny + (collider[e + 2] - x[f0, 2]) * nz
        )
    return -nx, -ny, -nz, r - min(h, d)


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _press(v, dt, body, buffers, collider, corners, push):
    """Add the spring ``push`` = (unit direction of the force on the shell, magnitude f_n [N]) with
    the collider's friction on the slip of the point Σ w_j x_j (``corners``: (j, w_j) × 3) to
    ``buffers.force`` (by w) and ``buffers.collider_force``."""
    nx, ny, nz, fn = push
    (f0, w0), (f1, w1), (f2, w2) = corners
    mass, force, collider_force = body.masses, buffers.force, buffers.collider_force
    wx = w0 * v[f0, 0] + w1 * v[f1, 0] + w2 * v[f2, 0] - collider[7]
    wy = w0 * v[f0, 1] + w1 * v[f1, 1] + w2 * v[f2, 1] - collider[8]
    wz = w0 * v[f0, 2] + w1 * v[f1, 2] + w2 * v[f2, 2] - collider[9]
    vn = wx * nx + wy * ny + wz * nz
    least = min(mass[f0], min(mass[f1], mass[f2]))
    tx, ty, tz = wx - vn * nx, wy - vn * ny, wz - vn * nz
    gx, gy, gz = _friction(tx, ty, tz, fn, collider[10], COLLIDER_SLIP_VELOCITY, least, dt)
    fx, fy, fz = fn * nx + gx, fn * ny + gy, fn * nz + gz
    for j, w in corners:
        force[j, 0] += w * fx
        force[j, 1] += w * fy
        force[j, 2] += w * fz
    collider_force[0] += fx
    collider_force[1] += fy
    collider_force[2] += fz


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _far_root(qa, qb, qc):
    """The larger root of qa t² + 2 qb t + qc = 0 (qa > 0), −inf where there is none."""
    disc = qb * qb - qa * qc
    if qa <= 0.0 or disc < 0.0:
        return -math.inf
    return (-qb + math.sqrt(disc)) / qa


@njit(cache=True, fastmath=False, error_model="numpy")
def exit_distance(p, u, collider):
    """How far [m] the point p (3,) [m] inside the capsule ``collider`` goes along the unit vector u
    to leave it: the capsule is convex, the union of its two end spheres and its cylinder, so the
    exit is the farthest of their far crossings (the cylinder's only within the segment)."""
    r = collider[6]
    far = -math.inf
    for e in (0, 3):
        cx, cy, cz = p[0] - collider[e], p[1] - collider[e + 1], p[2] - collider[e + 2]
        far = max(far, _far_root(1.0, cx * u[0] + cy * u[1] + cz * u[2], cx * cx + cy * cy + cz * cz - r * r))
    dx, dy, dz = collider[3] - collider[0], collider[4] - collider[1], collider[5] - collider[2]
    ll = dx * dx + dy * dy + dz * dz
    if ll > 0.0:
        cx, cy, cz = p[0] - collider[0], p[1] - collider[1], p[2] - collider[2]
        cd, ud = (cx * dx + cy * dy + cz * dz) / ll, (u[0] * dx + u[1] * dy + u[2] * dz) / ll
        # the components across the axis: c⊥ = c − (c·d̂) d̂, u⊥ likewise
        px, py, pz = cx - cd * dx, cy - cd * dy, cz - cd * dz
        qx, qy, qz = u[0] - ud * dx, u[1] - ud * dy, u[2] - ud * dz
        t = _far_root(qx * qx + qy * qy + qz * qz, px * qx + py * qy + pz * qz, px * px + py * py + pz * pz - r * r)
        if math.isfinite(t) and 0.0 <= cd + t * ud <= 1.0:
            far = max(far, t)
    return max(far, 0.0)


@njit(cache=True, fastmath=False, error_model="numpy")
def _vertex_contact(x, v, dt, body, contact, buffers, depth, slot, energy):
    """The vertices' springs: a vertex inside the capsule (closer than r to the axis) is pushed
    into the shell, along −n_j (n_j = ∂V/∂x_j / |∂V/∂x_j|, its outward area-weighted normal, in
    ``buffers.volume_gradient``), by k_j δ_j (``contact.stiffness``), δ_j [m] the distance it has to
    go that way to leave the capsule (``exit_distance``): r − d under the axis, as the reference's
    indenter pushes a vertex, and growing past r, never losing its direction, as the vertex gets
    behind the axis (a vertex pushed along the gap from the axis would slip round it), up to 2r."""
    collider, k_contact, normal = contact.collider, contact.stiffness, buffers.volume_gradient
    r = collider[6]
    for j in range(x.shape[0]):
        qx, qy, qz = _on_axis(x[j, 0], x[j, 1], x[j, 2], collider)
        gx, gy, gz = x[j, 0] - qx, x[j, 1] - qy, x[j, 2] - qz
        nn = math.sqrt(normal[j, 0] ** 2 + normal[j, 1] ** 2 + normal[j, 2] ** 2)
        if gx * gx + gy * gy + gz * gz >= r * r or nn == 0.0:
            continue
        nx, ny, nz = -normal[j, 0] / nn, -normal[j, 1] / nn, -normal[j, 2] / nn
        delta = exit_distance((x[j, 0], x[j, 1], x[j, 2]), (nx, ny, nz), collider)
        depth[slot] = max(depth[slot], delta)
        # at most the capsule's width: a vertex deep in a long capsule, its normal along the axis, is not flung
        pushed = min(delta, 2.0 * r)
        energy += k_contact[j] * pushed * (delta - 0.5 * pushed)  # ∫ k min(δ, 2r) dδ
        _press(v, dt, body, buffers, collider, ((j, 1.0), (j, 0.0), (j, 0.0)), (nx, ny, nz, k_contact[j] * pushed))
    return energy


@njit(cache=True, fastmath=False, error_model="numpy")
def collider_contact(x, v, dt, body, geometry, contact, buffers, depth, slot, energy):
    """The moving capsule's contact with the shell, added to ``buffers.force``;
    ``buffers.collider_force`` (3,) ← the force on the shell [N]; ``depth[slot]`` ← the deepest
    penetration [m]. Returns ``energy`` [J] plus the contact's.

    ``contact.collider`` (11,): a, b (segment ends [m]; equal: a sphere), radius r [m], velocity (3)
    [m/s], μ [-]. Two layers: the vertices' springs (``_vertex_contact``), which carry an ordinary
    press as the reference's indenter does, and the triangles' backstop, for a collider thinner
    than the mesh that its vertices would let through. For each face near the axis (its bounding
    sphere within r of the axis), the closest points d [m] apart (``segment_triangle_closest``) and
    the face's penetration δ (``_face_push``); past ``BACKSTOP_DEPTH`` × r a spring k_f (δ − δ_b),
    δ_b = ``BACKSTOP_DEPTH`` r, k_f = Σ w_j k_j / Σ w_j² n_j [N/m] (the face's vertices'
    ``contact.stiffness`` k_j by the closest point's barycentric weights w, n_j = ``contact.valence``:
    the faces around vertex j), so that a vertex's stiffness from all its faces, Σ_f w_j² k_f, stays
    below the largest k of their vertices. Both with the planes' friction against the slip of the
    pressed point relative to the collider (v_ε = ``COLLIDER_SLIP_VELOCITY``); a face's force goes to
    its vertices by w, so the shell gets exactly −(the collider's reaction)."""
    collider, faces, k_contact, valence = contact.collider, geometry.faces, contact.stiffness, contact.valence
    buffers.collider_force[:] = 0.0
    r = collider[6]
    if r <= 0.0:
        return energy
    energy = _vertex_contact(x, v, dt, body, contact, buffers, depth, slot, energy)
    allowance = BACKSTOP_DEPTH * r
    for f in range(faces.shape[0]):
        f0, f1, f2 = faces[f, 0], faces[f, 1], faces[f, 2]
        # cheap reject: the face's bounding sphere (centroid, farthest vertex) farther than r from the axis
        cx = (x[f0, 0] + x[f1, 0] + x[f2, 0]) / 3.0
        cy = (x[f0, 1] + x[f1, 1] + x[f2, 1]) / 3.0
        cz = (x[f0, 2] + x[f1, 2] + x[f2, 2]) / 3.0
        bound = 0.0
        for j in (f0, f1, f2):
            bound = max(bound, (x[j, 0] - cx) ** 2 + (x[j, 1] - cy) ** 2 + (x[j, 2] - cz) ** 2)
        qx, qy, qz = _on_axis(cx, cy, cz, collider)
        reach = math.sqrt(bound) + r
        if (cx - qx) ** 2 + (cy - qy) ** 2 + (cz - qz) ** 2 >= reach * reach:
            continue
        s, w0, w1, w2 = segment_triangle_closest(
            (collider[0], collider[1], collider[2]),
            (collider[3], collider[4], collider[5]),
            (x[f0, 0], x[f0, 1], x[f0, 2]),
            (x[f1, 0], x[f1, 1], x[f1, 2]),
            (x[f2, 0], x[f2, 1], x[f2, 2]),
        )
        nx, ny, nz, delta = _face_push(x, f0, f1, f2, collider, s, w0, w1, w2)
        if delta <= allowance:
            continue
        depth[slot] = max(depth[slot], delta)
        share = w0 * w0 * valence[f0] + w1 * w1 * valence[f1] + w2 * w2 * valence[f2]
        k = (w0 * k_contact[f0] + w1 * k_contact[f1] + w2 * k_contact[f2]) / share
        energy += 0.5 * k * (delta - allowance) ** 2
        _press(v, dt, body, buffers, collider, ((f0, w0), (f1, w1), (f2, w2)), (nx, ny, nz, k * (delta - allowance)))
    return energy


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _on_axis(px, py, pz, collider):
    """The collider's axis point closest to p [m]."""
    dx, dy, dz = collider[3] - collider[0], collider[4] - collider[1], collider[5] - collider[2]
    ll = dx * dx + dy * dy + dz * dz
    t = 0.0
    if ll > 0.0:
        t = min(1.0, max(0.0, ((px - collider[0]) * dx + (py - collider[1]) * dy + (pz - collider[2]) * dz) / ll))
    return collider[0] + t * dx, collider[1] + t * dy, collider[2] + t * dz
