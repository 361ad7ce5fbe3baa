"""Compiled (Numba) elastic kernels of the real-time runtime (float64, SI units).

The shell energies are exactly :mod:`shelljax.shell3d`'s (``_energy.fundamental_forms``,
``physics.neo_hookean_membrane_density`` and ``physics.bending_density``): per face, on its
6-vertex flap stencil ``[v0, v1, v2, o0, o1, o2]``,

* membrane  W_m = h [β/2 (tr C − 2 − ln det C) + α/4 (det C − 1 − ln det C)], C = ā⁻¹a,
* bending   W_b = h³/12 [α/2 (tr M)² + β tr M²], M = ā⁻¹(b − b̄),

with a the face's first fundamental form [m²] and b the Hessian of the quadratic height field
interpolating the six stencil vertices over the face plane [m]; each face contributes
``rest_area · (W_m + W_b)`` [J]. The gradient is written out by hand (reverse mode through the
same arithmetic: the Cramer solve of the three flap heights, the projection of the flap vertices
onto the face plane, the unit normal), and tests/test_realtime.py checks it against ``jax.grad``
of shell3d's energy.

Small vectors travel between the inlined helpers as tuples: ``e1``, ``e2`` (the face's edges from
x₀ [m]), ``n`` (its unit normal), ``metric`` (a00, a01, a11, det a, 1/det a) of the first
fundamental form [m², m⁴, 1/m⁴] and ``q`` (q00, q01, q11) of the rest metric's inverse [1/m²].
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _flap(x, i0, j, e1, e2, n, metric):
    """Flap vertex j relative to x₀: offset d (3) [m], r = (d·e1, d·e2) [m²], (u, v) [-], height w [m]."""
    e1x, e1y, e1z = e1
    e2x, e2y, e2z = e2
    nx, ny, nz = n
    a00, a01, a11, _, inv_det = metric
    dx = x[j, 0] - x[i0, 0]
    dy = x[j, 1] - x[i0, 1]
    dz = x[j, 2] - x[i0, 2]
    r1 = dx * e1x + dy * e1y + dz * e1z
    r2 = dx * e2x + dy * e2y + dz * e2z
    u = (a11 * r1 - a01 * r2) * inv_det
    v = (a00 * r2 - a01 * r1) * inv_det
    w = dx * nx + dy * ny + dz * nz
    return dx, dy, dz, r1, r2, u, v, w


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _flap_back(lk, gamma, flap, metric, e1, e2, n):
    """Reverse pass of one flap (``flap``: its d, r1, r2, u, v from ``_flap``) with w̄ = λ_k:
    (d̄ (3), Ā00, Ā01, Ā11, r̄1, r̄2)."""
    ga0, ga1, ga2 = gamma
    _, _, _, r1, r2, u, v, _ = flap
    a00, a01, a11, _, inv_det = metric
    e1x, e1y, e1z = e1
    e2x, e2y, e2z = e2
    nx, ny, nz = n
    mb0 = -lk * ga0
    mb1 = -lk * ga1
    mb2 = -lk * ga2
    phi0 = 1.0 - u - v
    ub = mb0 * (phi0 - u) + mb1 * v - mb2 * v
    vb = -mb0 * u + mb1 * u + mb2 * (phi0 - v)
    # (u, v) = A⁻¹ (r1, r2): r̄ = A⁻¹ (ū, v̄); ∂u/∂A00 = −u a11/det, ∂u/∂A11 = (r1 − u a00)/det, ...
    r1b = (a11 * ub - a01 * vb) * inv_det
    r2b = (a00 * vb - a01 * ub) * inv_det
    bA00 = (-ub * u * a11 + vb * (r2 - v * a11)) * inv_det
    bA11 = (ub * (r1 - u * a00) - vb * v * a00) * inv_det
    bA01 = (ub * (-r2 + 2.0 * u * a01) + vb * (-r1 + 2.0 * v * a01)) * inv_det
    # d̄ = r̄1 e1 + r̄2 e2 + w̄ n
    ddx = r1b * e1x + r2b * e2x + lk * nx
    ddy = r1b * e1y + r2b * e2y + lk * ny
    ddz = r1b * e1z + r2b * e2z + lk * nz
    return ddx, ddy, ddz, bA00, bA01, bA11, r1b, r2b


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _membrane(metric, q, material, with_energy):
    """Membrane energy density × h [J/m²] (0 unless ``with_energy``) and ∂/∂(a00, a01, a11) of it,
    C = ā⁻¹a (ā⁻¹ = [[q00, q01], [q01, q11]]); a01 stands for both off-diagonal entries."""
    a00, a01, a11, det, inv_det = metric
    q00, q01, q11 = q
    h, alpha, beta = material.thickness, material.alpha, material.beta
    det_rest_inv = q00 * q11 - q01 * q01
    trace_c = q00 * a00 + 2.0 * q01 * a01 + q11 * a11
    det_c = det * det_rest_inv
    energy = 0.0
    if with_energy:
        log_det = math.log(det_c)
        energy = h * (0.5 * beta * (trace_c - 2.0 - log_det) + 0.25 * alpha * (det_c - 1.0 - log_det))
    cl = -0.5 * beta + 0.25 * alpha * (det_c - 1.0)  # coefficient of ∂ ln det a
    ba00 = h * (0.5 * beta * q00 + cl * a11 * inv_det)
    ba01 = h * (beta * q01 - cl * 2.0 * a01 * inv_det)
    ba11 = h * (0.5 * beta * q11 + cl * a00 * inv_det)
    return energy, ba00, ba01, ba11


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _flap_solve(u0, v0, w0, u1, v1, w1, u2, v2, w2):
    """The quadratic height field's coefficients γ (3) from the flap heights w (Cramer on the rows
    m_k = (φ0 u, u v, v φ0) of flap k), with the adjugate's columns c0, c1, c2 and 1/det m."""
    m00 = (1.0 - u0 - v0) * u0
    m01 = u0 * v0
    m02 = v0 * (1.0 - u0 - v0)
    m10 = (1.0 - u1 - v1) * u1
    m11 = u1 * v1
    m12 = v1 * (1.0 - u1 - v1)
    m20 = (1.0 - u2 - v2) * u2
    m21 = u2 * v2
    m22 = v2 * (1.0 - u2 - v2)
    # Cramer: the adjugate's columns c0 = m1 × m2, c1 = m2 × m0, c2 = m0 × m1 (rows m_k = flap k).
    c00 = m11 * m22 - m12 * m21
    c01 = m12 * m20 - m10 * m22
    c02 = m10 * m21 - m11 * m20
    c10 = m21 * m02 - m22 * m01
    c11 = m22 * m00 - m20 * m02
    c12 = m20 * m01 - m21 * m00
    c20 = m01 * m12 - m02 * m11
    c21 = m02 * m10 - m00 * m12
    c22 = m00 * m11 - m01 * m10
    dm = m00 * c00 + m01 * c01 + m02 * c02
    inv_dm = 1.0 / dm
    ga0 = (w0 * c00 + w1 * c10 + w2 * c20) * inv_dm
    ga1 = (w0 * c01 + w1 * c11 + w2 * c21) * inv_dm
    ga2 = (w0 * c02 + w1 * c12 + w2 * c22) * inv_dm
    return ga0, ga1, ga2, c00, c01, c02, c10, c11, c12, c20, c21, c22, inv_dm


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _bending_moment(gamma, rest_b, q, material, with_energy):
    """Bending energy density × h³/12 [J/m²] (0 unless ``with_energy``) of the curvature change
    Δb = b(γ) − b̄ (``rest_b``: b̄00, b̄01, b̄11 [m]) and its gradient γ̄ (3) with respect to γ."""
    ga0, ga1, ga2 = gamma
    rb00, rb01, rb11 = rest_b
    q00, q01, q11 = q
    h, alpha, beta = material.thickness, material.alpha, material.beta
    # b = [[−2γ0, γ1 − γ0 − γ2], [·, −2γ2]]; Δb = b − b̄
    db00 = -2.0 * ga0 - rb00
    db01 = ga1 - ga0 - ga2 - rb01
    db11 = -2.0 * ga2 - rb11
    # M = ā⁻¹ Δb
    k00 = q00 * db00 + q01 * db01
    k01 = q00 * db01 + q01 * db11
    k10 = q01 * db00 + q11 * db01
    k11 = q01 * db01 + q11 * db11
    tr_m = k00 + k11
    tr_m2 = k00 * k00 + 2.0 * k01 * k10 + k11 * k11
    hb = h * h * h / 12.0
    energy = 0.0
    if with_energy:
        energy = hb * (0.5 * alpha * tr_m * tr_m + beta * tr_m2)
    # ∂W/∂Δb (symmetric 2×2) = hb [α tr M ā⁻¹ + 2β ā⁻¹ Δb ā⁻¹], ā⁻¹Δbā⁻¹ = M ā⁻¹
    s00 = hb * (alpha * tr_m * q00 + 2.0 * beta * (k00 * q00 + k01 * q01))
    s01 = hb * (alpha * tr_m * q01 + 2.0 * beta * (k00 * q01 + k01 * q11))
    s11 = hb * (alpha * tr_m * q11 + 2.0 * beta * (k10 * q01 + k11 * q11))
    # to γ: b00 = −2γ0, b11 = −2γ2, b01 = b10 = γ1 − γ0 − γ2
    return energy, -2.0 * s00 - 2.0 * s01, 2.0 * s01, -2.0 * s11 - 2.0 * s01


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _unit_normal(e1, e2):
    """n = (e1 × e2)/|e1 × e2| (3) and 1/|e1 × e2| [1/m²]."""
    e1x, e1y, e1z = e1
    e2x, e2y, e2z = e2
    cx = e1y * e2z - e1z * e2y
    cy = e1z * e2x - e1x * e2z
    cz = e1x * e2y - e1y * e2x
    cn = math.sqrt(cx * cx + cy * cy + cz * cz)
    inv_cn = 1.0 / cn
    return cx * inv_cn, cy * inv_cn, cz * inv_cn, inv_cn


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _edge_bars(r_bars, d, lam, n, inv_cn, e1, e2):
    """ē1, ē2 (3 each) of the flaps' r̄1, r̄2 (``r_bars``: flap 0's, 1's, 2's, from ``_flap_back``),
    their offsets d (``d``: 3 × 3, from ``_flap``) and weights λ_k (3), through r = (d·e1, d·e2)
    and the unit normal n = c/|c| (flat tuples: Numba's parfor analysis fails on nested ones)."""
    lam0, lam1, lam2 = lam
    nx, ny, nz = n
    e1x, e1y, e1z = e1
    e2x, e2y, e2z = e2
    d0x, d0y, d0z, d1x, d1y, d1z, d2x, d2y, d2z = d
    r1b0, r2b0, r1b1, r2b1, r1b2, r2b2 = r_bars
    b1x = r1b0 * d0x + r1b1 * d1x + r1b2 * d2x
    b1y = r1b0 * d0y + r1b1 * d1y + r1b2 * d2y
    b1z = r1b0 * d0z + r1b1 * d1z + r1b2 * d2z
    b2x = r2b0 * d0x + r2b1 * d1x + r2b2 * d2x
    b2y = r2b0 * d0y + r2b1 * d1y + r2b2 * d2y
    b2z = r2b0 * d0z + r2b1 * d1z + r2b2 * d2z
    bn_x = lam0 * d0x + lam1 * d1x + lam2 * d2x
    bn_y = lam0 * d0y + lam1 * d1y + lam2 * d2y
    bn_z = lam0 * d0z + lam1 * d1z + lam2 * d2z
    # n = c/|c|: c̄ = (n̄ − n (n·n̄))/|c|; ē1 += e2 × c̄, ē2 += c̄ × e1
    nd = nx * bn_x + ny * bn_y + nz * bn_z
    cbx = (bn_x - nx * nd) * inv_cn
    cby = (bn_y - ny * nd) * inv_cn
    cbz = (bn_z - nz * nd) * inv_cn
    b1x += e2y * cbz - e2z * cby
    b1y += e2z * cbx - e2x * cbz
    b1z += e2x * cby - e2y * cbx
    b2x += cby * e1z - cbz * e1y
    b2y += cbz * e1x - cbx * e1z
    b2z += cbx * e1y - cby * e1x
    return b1x, b1y, b1z, b2x, b2y, b2z


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _bending(x, f, e1, e2, metric, q, geometry, material, g, with_energy):
    """Bending of face f: its energy density [J/m²] (0 unless ``with_energy``); the flap vertices'
    gradient [N] into g[3:6]; and, for the caller's chain rule, x̄₀ (3) (the flaps' share), the
    increments of ā (a00, a01, a11) and ē1, ē2 (3 each)."""
    stencil = geometry.stencil
    i0 = stencil[f, 0]
    area = geometry.rest_area[f]
    nx, ny, nz, inv_cn = _unit_normal(e1, e2)
    n = (nx, ny, nz)
    # flap vertices: offsets d, in-plane coordinates (u, v), heights w
    f0 = _flap(x, i0, stencil[f, 3], e1, e2, n, metric)
    f1 = _flap(x, i0, stencil[f, 4], e1, e2, n, metric)
    f2 = _flap(x, i0, stencil[f, 5], e1, e2, n, metric)
    ga0, ga1, ga2, c00, c01, c02, c10, c11, c12, c20, c21, c22, inv_dm = _flap_solve(
        f0[5], f0[6], f0[7], f1[5], f1[6], f1[7], f2[5], f2[6], f2[7]
    )
    gamma = (ga0, ga1, ga2)
    rest_b = (geometry.rest_b[f, 0], geometry.rest_b[f, 1], geometry.rest_b[f, 2])
    energy, gb0, gb1, gb2 = _bending_moment(gamma, rest_b, q, material, with_energy)
    # γ = m⁻¹ w, m⁻¹ = [c0 c1 c2]/dm: w̄_k = λ_k = c_k · γ̄ / dm, m̄_k = −λ_k γ
    lam0 = (c00 * gb0 + c01 * gb1 + c02 * gb2) * inv_dm
    lam1 = (c10 * gb0 + c11 * gb1 + c12 * gb2) * inv_dm
    lam2 = (c20 * gb0 + c21 * gb1 + c22 * gb2) * inv_dm
    t0 = _flap_back(lam0, gamma, f0, metric, e1, e2, n)
    t1 = _flap_back(lam1, gamma, f1, metric, e1, e2, n)
    t2 = _flap_back(lam2, gamma, f2, metric, e1, e2, n)
    for k in range(3):
        g[3, k] = area * t0[k]
        g[4, k] = area * t1[k]
        g[5, k] = area * t2[k]
    r_bars = (t0[6], t0[7], t1[6], t1[7], t2[6], t2[7])
    d = (f0[0], f0[1], f0[2], f1[0], f1[1], f1[2], f2[0], f2[1], f2[2])
    b1x, b1y, b1z, b2x, b2y, b2z = _edge_bars(r_bars, d, (lam0, lam1, lam2), n, inv_cn, e1, e2)
    return (
        energy,
        -(t0[0] + t1[0] + t2[0]),
        -(t0[1] + t1[1] + t2[1]),
        -(t0[2] + t1[2] + t2[2]),
        t0[3] + t1[3] + t2[3],
        t0[4] + t1[4] + t2[4],
        t0[5] + t1[5] + t2[5],
        b1x,
        b1y,
        b1z,
        b2x,
        b2y,
        b2z,
    )


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _face_grad(x, f, geometry, material, g, with_energy):
    """Energy [J] of face f (0 unless ``with_energy``); its gradient [N] (6, 3) into g (overwritten)."""
    stencil = geometry.stencil
    i0 = stencil[f, 0]
    i1 = stencil[f, 1]
    i2 = stencil[f, 2]
    e1x = x[i1, 0] - x[i0, 0]
    e1y = x[i1, 1] - x[i0, 1]
    e1z = x[i1, 2] - x[i0, 2]
    e2x = x[i2, 0] - x[i0, 0]
    e2y = x[i2, 1] - x[i0, 1]
    e2z = x[i2, 2] - x[i0, 2]
    a00 = e1x * e1x + e1y * e1y + e1z * e1z
    a01 = e1x * e2x + e1y * e2y + e1z * e2z
    a11 = e2x * e2x + e2y * e2y + e2z * e2z
    det = a00 * a11 - a01 * a01
    inv_det = 1.0 / det
    metric = (a00, a01, a11, det, inv_det)
    q = (geometry.rest_inv[f, 0], geometry.rest_inv[f, 1], geometry.rest_inv[f, 2])
    area = geometry.rest_area[f]
    energy, ba00, ba01, ba11 = _membrane(metric, q, material, with_energy)
    if material.bending:
        eb, gx0, gy0, gz0, da00, da01, da11, b1x, b1y, b1z, b2x, b2y, b2z = _bending(
            x, f, (e1x, e1y, e1z), (e2x, e2y, e2z), metric, q, geometry, material, g, with_energy
        )
        energy += eb
        ba00 += da00
        ba01 += da01
        ba11 += da11
    else:
        gx0 = gy0 = gz0 = 0.0
        b1x = b1y = b1z = b2x = b2y = b2z = 0.0  # ē1, ē2 accumulators
        for k in range(3, 6):
            g[k, 0] = 0.0
            g[k, 1] = 0.0
            g[k, 2] = 0.0
    # a00 = e1·e1, a01 = e1·e2, a11 = e2·e2
    b1x += 2.0 * ba00 * e1x + ba01 * e2x
    b1y += 2.0 * ba00 * e1y + ba01 * e2y
    b1z += 2.0 * ba00 * e1z + ba01 * e2z
    b2x += ba01 * e1x + 2.0 * ba11 * e2x
    b2y += ba01 * e1y + 2.0 * ba11 * e2y
    b2z += ba01 * e1z + 2.0 * ba11 * e2z
    g[0, 0] = area * (gx0 - b1x - b2x)
    g[0, 1] = area * (gy0 - b1y - b2y)
    g[0, 2] = area * (gz0 - b1z - b2z)
    g[1, 0] = area * b1x
    g[1, 1] = area * b1y
    g[1, 2] = area * b1z
    g[2, 0] = area * b2x
    g[2, 1] = area * b2y
    g[2, 2] = area * b2z
    return area * energy


@njit(cache=True, fastmath=False, error_model="numpy")
def elastic_forces_serial(x, geometry, material, force, with_energy=True):
    """Elastic energy [J] (0 unless ``with_energy``); ``force`` (V, 3) [N] ← −∇E (overwritten). One thread."""
    stencil = geometry.stencil
    force[:, :] = 0.0
    g = np.empty((6, 3))
    energy = 0.0
    for f in range(stencil.shape[0]):
        energy += _face_grad(x, f, geometry, material, g, with_energy)
        for k in range(6):
            j = stencil[f, k]
            force[j, 0] -= g[k, 0]
            force[j, 1] -= g[k, 1]
            force[j, 2] -= g[k, 2]
    return energy


@njit(cache=True, fastmath=False, error_model="numpy", parallel=True)
def elastic_forces_parallel(x, geometry, material, force, face_grad, face_energy, with_energy=True):
    """As ``elastic_forces_serial``, threads over faces (into ``face_grad`` (F, 6, 3)), then over
    vertices (gathering the faces' slots through the geometry's CSR incidence = 6 f + k)."""
    n_faces = geometry.stencil.shape[0]
    incidence_ptr, incidence = geometry.incidence_ptr, geometry.incidence
    for f in prange(n_faces):
        face_energy[f] = _face_grad(x, f, geometry, material, face_grad[f], with_energy)
    for i in prange(x.shape[0]):
        fx = 0.0
        fy = 0.0
        fz = 0.0
        for p in range(incidence_ptr[i], incidence_ptr[i + 1]):
            s = incidence[p]
            f = s // 6
            k = s - 6 * f
            fx -= face_grad[f, k, 0]
            fy -= face_grad[f, k, 1]
            fz -= face_grad[f, k, 2]
        force[i, 0] = fx
        force[i, 1] = fy
        force[i, 2] = fz
    return face_energy.sum()
