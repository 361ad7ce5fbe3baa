"""Compiled (Numba) per-element kernels of the real-time runtime (float64, SI units).

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

The gas enters through the enclosed volume V = Σ_f x₀·(x₁ × x₂)/6 [m³] and its gradient; the
gauge pressure P(V) [Pa] follows the law (prescribed, isothermal, adiabatic), and the pressure
force on the vertices is P ∂V/∂x [N].

``advance`` runs n velocity-Verlet substeps (kick Δt/2, drift Δt, force, kick Δt/2) in one
compiled call, with penalty contact against planes and a moving sphere/capsule, and stops at the
first substep that fails the blow-up guard (NaN/inf, or a vertex deeper than the tunnelling
depth behind a plane), returning a status code for the Python layer to raise.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..physics import AdiabaticGas, IsothermalGas, PrescribedGas
from ._contact import contact_forces

# Status codes of ``advance``.
OK = 0
NOT_FINITE = 1
TUNNELLED = 2

# Gas laws, as integers for the kernels (``gas_pressure_energy``): the code of each law's class.
GAS_CODES = {PrescribedGas: 0, IsothermalGas: 1, AdiabaticGas: 2}


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _flap(x, i0, j, e1x, e1y, e1z, e2x, e2y, e2z, nx, ny, nz, a00, a01, a11, inv_det):
    """Flap vertex j relative to x₀: offset d (3) [m], r = (d·e1, d·e2) [m²], (u, v) [-], height w [m]."""
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
def _flap_back(
    lk, ga0, ga1, ga2, u, v, r1, r2, dx, dy, dz, a00, a01, a11, inv_det, e1x, e1y, e1z, e2x, e2y, e2z, nx, ny, nz
):
    """Reverse pass of one flap with w̄ = λ_k: (d̄ (3), Ā00, Ā01, Ā11, r̄1, r̄2)."""
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
def _membrane(a00, a01, a11, det, inv_det, q00, q01, q11, h, alpha, beta, with_energy):
    """Membrane energy density × h [J/m²] (0 unless ``with_energy``) and ∂/∂(a00, a01, a11) of it,
    C = ā⁻¹a (ā⁻¹ = [[q00, q01], [q01, q11]]); a01 stands for both off-diagonal entries."""
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
def _bending_moment(ga0, ga1, ga2, rb00, rb01, rb11, q00, q01, q11, h, alpha, beta, with_energy):
    """Bending energy density × h³/12 [J/m²] (0 unless ``with_energy``) of the curvature change
    Δb = b(γ) − b̄ and its gradient γ̄ (3) with respect to γ."""
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
def _bending(
    x,
    f,
    stencil,
    i0,
    e1x,
    e1y,
    e1z,
    e2x,
    e2y,
    e2z,
    a00,
    a01,
    a11,
    inv_det,
    q00,
    q01,
    q11,
    rest_b,
    area,
    h,
    alpha,
    beta,
    g,
    with_energy,
):
    """Bending of face f: its energy density [J/m²] (0 unless ``with_energy``); the flap vertices'
    gradient [N] into g[3:6]; and, for the caller's chain rule, x̄₀ (3) (the flaps' share), the
    increments of ā (a00, a01, a11) and ē1, ē2 (3 each)."""
    # normal n = (e1 × e2)/|e1 × e2|
    cx = e1y * e2z - e1z * e2y
    cy = e1z * e2x - e1x * e2z
    cz = e1x * e2y - e1y * e2x
    cn = math.sqrt(cx * cx + cy * cy + cz * cz)
    inv_cn = 1.0 / cn
    nx = cx * inv_cn
    ny = cy * inv_cn
    nz = cz * inv_cn
    # flap vertices: offsets d, in-plane coordinates (u, v), heights w
    d0x, d0y, d0z, r10, r20, u0, v0, w0 = _flap(
        x, i0, stencil[f, 3], e1x, e1y, e1z, e2x, e2y, e2z, nx, ny, nz, a00, a01, a11, inv_det
    )
    d1x, d1y, d1z, r11, r21, u1, v1, w1 = _flap(
        x, i0, stencil[f, 4], e1x, e1y, e1z, e2x, e2y, e2z, nx, ny, nz, a00, a01, a11, inv_det
    )
    d2x, d2y, d2z, r12, r22, u2, v2, w2 = _flap(
        x, i0, stencil[f, 5], e1x, e1y, e1z, e2x, e2y, e2z, nx, ny, nz, a00, a01, a11, inv_det
    )
    ga0, ga1, ga2, c00, c01, c02, c10, c11, c12, c20, c21, c22, inv_dm = _flap_solve(u0, v0, w0, u1, v1, w1, u2, v2, w2)
    energy, gb0, gb1, gb2 = _bending_moment(
        ga0, ga1, ga2, rest_b[f, 0], rest_b[f, 1], rest_b[f, 2], q00, q01, q11, h, alpha, beta, with_energy
    )
    # γ = m⁻¹ w, m⁻¹ = [c0 c1 c2]/dm: w̄_k = λ_k = c_k · γ̄ / dm, m̄_k = −λ_k γ
    lam0 = (c00 * gb0 + c01 * gb1 + c02 * gb2) * inv_dm
    lam1 = (c10 * gb0 + c11 * gb1 + c12 * gb2) * inv_dm
    lam2 = (c20 * gb0 + c21 * gb1 + c22 * gb2) * inv_dm
    t0 = _flap_back(
        lam0,
        ga0,
        ga1,
        ga2,
        u0,
        v0,
        r10,
        r20,
        d0x,
        d0y,
        d0z,
        a00,
        a01,
        a11,
        inv_det,
        e1x,
        e1y,
        e1z,
        e2x,
        e2y,
        e2z,
        nx,
        ny,
        nz,
    )
    t1 = _flap_back(
        lam1,
        ga0,
        ga1,
        ga2,
        u1,
        v1,
        r11,
        r21,
        d1x,
        d1y,
        d1z,
        a00,
        a01,
        a11,
        inv_det,
        e1x,
        e1y,
        e1z,
        e2x,
        e2y,
        e2z,
        nx,
        ny,
        nz,
    )
    t2 = _flap_back(
        lam2,
        ga0,
        ga1,
        ga2,
        u2,
        v2,
        r12,
        r22,
        d2x,
        d2y,
        d2z,
        a00,
        a01,
        a11,
        inv_det,
        e1x,
        e1y,
        e1z,
        e2x,
        e2y,
        e2z,
        nx,
        ny,
        nz,
    )
    for k in range(3):
        g[3, k] = area * t0[k]
        g[4, k] = area * t1[k]
        g[5, k] = area * t2[k]
    r1b0, r2b0, r1b1, r2b1, r1b2, r2b2 = t0[6], t0[7], t1[6], t1[7], t2[6], t2[7]
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
def _face_grad(x, f, stencil, rest_inv, rest_b, rest_area, h, alpha, beta, g, with_bending, with_energy):
    """Energy [J] of face f (0 unless ``with_energy``); its gradient [N] (6, 3) into g (overwritten)."""
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
    q00 = rest_inv[f, 0]
    q01 = rest_inv[f, 1]
    q11 = rest_inv[f, 2]
    area = rest_area[f]
    energy, ba00, ba01, ba11 = _membrane(a00, a01, a11, det, inv_det, q00, q01, q11, h, alpha, beta, with_energy)
    if with_bending:
        eb, gx0, gy0, gz0, da00, da01, da11, b1x, b1y, b1z, b2x, b2y, b2z = _bending(
            x,
            f,
            stencil,
            i0,
            e1x,
            e1y,
            e1z,
            e2x,
            e2y,
            e2z,
            a00,
            a01,
            a11,
            inv_det,
            q00,
            q01,
            q11,
            rest_b,
            area,
            h,
            alpha,
            beta,
            g,
            with_energy,
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
def elastic_forces_serial(
    x, stencil, rest_inv, rest_b, rest_area, h, alpha, beta, with_bending, force, with_energy=True
):
    """Elastic energy [J] (0 unless ``with_energy``); ``force`` (V, 3) [N] ← −∇E (overwritten). One thread."""
    force[:, :] = 0.0
    g = np.empty((6, 3))
    energy = 0.0
    for f in range(stencil.shape[0]):
        energy += _face_grad(x, f, stencil, rest_inv, rest_b, rest_area, h, alpha, beta, g, with_bending, with_energy)
        for k in range(6):
            j = stencil[f, k]
            force[j, 0] -= g[k, 0]
            force[j, 1] -= g[k, 1]
            force[j, 2] -= g[k, 2]
    return energy


@njit(cache=True, fastmath=False, error_model="numpy", parallel=True)
def elastic_forces_parallel(
    x,
    stencil,
    rest_inv,
    rest_b,
    rest_area,
    h,
    alpha,
    beta,
    with_bending,
    force,
    face_grad,
    face_energy,
    incidence_ptr,
    incidence,
    with_energy=True,
):
    """As ``elastic_forces_serial``, threads over faces (into ``face_grad`` (F, 6, 3)), then over
    vertices (gathering the faces' slots through the CSR ``incidence_ptr``/``incidence`` = 6 f + k)."""
    n_faces = stencil.shape[0]
    for f in prange(n_faces):
        face_energy[f] = _face_grad(
            x, f, stencil, rest_inv, rest_b, rest_area, h, alpha, beta, face_grad[f], with_bending, with_energy
        )
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


@njit(cache=True, fastmath=False, error_model="numpy")
def volume_and_gradient(x, faces, grad):
    """Enclosed volume V [m³]; ``grad`` (V, 3) [m²] ← ∂V/∂x (overwritten)."""
    grad[:, :] = 0.0
    vol = 0.0
    for f in range(faces.shape[0]):
        i = faces[f, 0]
        j = faces[f, 1]
        k = faces[f, 2]
        ax, ay, az = x[i, 0], x[i, 1], x[i, 2]
        bx, by, bz = x[j, 0], x[j, 1], x[j, 2]
        cx, cy, cz = x[k, 0], x[k, 1], x[k, 2]
        # b × c, c × a, a × b
        bcx = by * cz - bz * cy
        bcy = bz * cx - bx * cz
        bcz = bx * cy - by * cx
        vol += (ax * bcx + ay * bcy + az * bcz) / 6.0
        grad[i, 0] += bcx / 6.0
        grad[i, 1] += bcy / 6.0
        grad[i, 2] += bcz / 6.0
        grad[j, 0] += (cy * az - cz * ay) / 6.0
        grad[j, 1] += (cz * ax - cx * az) / 6.0
        grad[j, 2] += (cx * ay - cy * ax) / 6.0
        grad[k, 0] += (ay * bz - az * by) / 6.0
        grad[k, 1] += (az * bx - ax * bz) / 6.0
        grad[k, 2] += (ax * by - ay * bx) / 6.0
    return vol


@njit(cache=True, fastmath=False, error_model="numpy")
def gas_pressure_energy(vol, law, p_gauge, v_ref, p_atm, gamma):
    """(gauge pressure [Pa], gas energy [J]) at volume ``vol`` [m³] (physics._gas's formulas)."""
    if law == 0:
        return p_gauge, -p_gauge * vol
    p0 = p_atm + p_gauge
    change = vol - v_ref
    if law == 1:
        return p0 * v_ref / vol - p_atm, -p0 * v_ref * math.log1p(change / v_ref) + p_atm * change
    gm1 = gamma - 1.0
    return (
        p0 * (v_ref / vol) ** gamma - p_atm,
        p0 * v_ref / gm1 * math.expm1(-gm1 * math.log1p(change / v_ref)) + p_atm * change,
    )


@njit(cache=True, fastmath=False, error_model="numpy")
def kinetic_energy(v, mass):
    """½ Σ m |v|² [J]."""
    e = 0.0
    for i in range(v.shape[0]):
        e += 0.5 * mass[i] * (v[i, 0] ** 2 + v[i, 1] ** 2 + v[i, 2] ** 2)
    return e


@njit(cache=True, fastmath=False, error_model="numpy")
def _total_force(
    x,
    v,
    dt,
    mass,
    gravity,
    stencil,
    faces,
    rest_inv,
    rest_b,
    rest_area,
    h,
    alpha,
    beta,
    with_bending,
    gas_law,
    p_gauge,
    v_ref,
    p_atm,
    gamma,
    planes,
    clamps,
    vertex_area,
    mean_area,
    k_contact,
    c_contact,
    collider,
    sample_idx,
    sample_w,
    sample_k,
    parallel,
    face_grad,
    face_energy,
    incidence_ptr,
    incidence,
    force,
    vgrad,
    plane_force,
    collider_force,
    out,
):
    """``force`` (V, 3) [N] ← elastic + gas + gravity + contact at (x, v); ``out`` as in ``advance``."""
    if parallel:
        e_el = elastic_forces_parallel(
            x,
            stencil,
            rest_inv,
            rest_b,
            rest_area,
            h,
            alpha,
            beta,
            with_bending,
            force,
            face_grad,
            face_energy,
            incidence_ptr,
            incidence,
            False,
        )
    else:
        e_el = elastic_forces_serial(
            x, stencil, rest_inv, rest_b, rest_area, h, alpha, beta, with_bending, force, False
        )
    vol = volume_and_gradient(x, faces, vgrad)
    pres, e_gas = gas_pressure_energy(vol, gas_law, p_gauge, v_ref, p_atm, gamma)
    nv = x.shape[0]
    finite = math.isfinite(vol)
    for i in range(nv):
        force[i, 0] += pres * vgrad[i, 0] + mass[i] * gravity[0]
        force[i, 1] += pres * vgrad[i, 1] + mass[i] * gravity[1]
        force[i, 2] += pres * vgrad[i, 2] + mass[i] * gravity[2]
        if not (math.isfinite(force[i, 0]) and math.isfinite(force[i, 1]) and math.isfinite(force[i, 2])):
            finite = False
    e_con, depth = contact_forces(
        x,
        v,
        mass,
        dt,
        planes,
        clamps,
        vertex_area,
        mean_area,
        k_contact,
        c_contact,
        collider,
        sample_idx,
        sample_w,
        sample_k,
        force,
        plane_force,
        collider_force,
    )
    n_planes = planes.shape[0]
    dmax = 0.0
    for p in range(n_planes):
        dmax = max(dmax, depth[p])
    out[0] = e_el
    out[1] = e_gas
    out[3] = e_con
    out[4] = vol
    out[5] = pres
    out[6] = dmax
    out[7] = depth[n_planes]
    if not finite:
        return NOT_FINITE
    return OK


@njit(cache=True, fastmath=False, error_model="numpy")
def advance(
    x,
    v,
    n_steps,
    dt,
    mass,
    gravity,
    stencil,
    faces,
    rest_inv,
    rest_b,
    rest_area,
    h,
    alpha,
    beta,
    with_bending,
    gas_law,
    p_gauge,
    v_ref,
    p_atm,
    gamma,
    planes,
    clamps,
    vertex_area,
    mean_area,
    k_contact,
    c_contact,
    collider,
    sample_idx,
    sample_w,
    sample_k,
    tunnel_depth,
    parallel,
    face_grad,
    face_energy,
    incidence_ptr,
    incidence,
    force,
    vgrad,
    plane_force,
    collider_force,
    out,
    velocity_decay,
):
    """``n_steps`` velocity-Verlet substeps of Δt = ``dt`` [s] in place on x, v (V, 3) [m], [m/s]:

        v ← v + Δt/2 M⁻¹F;  x ← x + Δt v;  F ← F(x, v);  v ← v + Δt/2 M⁻¹F

    (the velocity-dependent contact dampers and friction see the half-step velocity). The force at
    the start is evaluated once per call; the collider's ends move with its velocity (in place in
    ``collider``). Returns (status, steps done). ``out`` (8,) ← elastic
    (not evaluated: 0), gas, −, contact energy [J], volume [m³], gauge pressure [Pa], deepest plane
    penetration [m], deepest collider penetration [m] at the last force evaluation.
    ``plane_force`` (P, 3), ``collider_force`` (3,) [N]: the contact forces averaged over the
    substeps done (trapezoidal: their impulse divided by the time, as the kicks apply them). ``velocity_decay`` [-]: v is multiplied by it after each substep (1: none; < 1
    only to relax a shape to rest).
    """
    nv = x.shape[0]
    n_planes = planes.shape[0]
    pf_sum = np.zeros((n_planes, 3))
    cf_sum = np.zeros(3)
    status = _total_force(
        x,
        v,
        dt,
        mass,
        gravity,
        stencil,
        faces,
        rest_inv,
        rest_b,
        rest_area,
        h,
        alpha,
        beta,
        with_bending,
        gas_law,
        p_gauge,
        v_ref,
        p_atm,
        gamma,
        planes,
        clamps,
        vertex_area,
        mean_area,
        k_contact,
        c_contact,
        collider,
        sample_idx,
        sample_w,
        sample_k,
        parallel,
        face_grad,
        face_energy,
        incidence_ptr,
        incidence,
        force,
        vgrad,
        plane_force,
        collider_force,
        out,
    )
    if status != OK:
        return status, 0
    # Trapezoidal averages of the contact forces: their impulse over the substeps done, divided by the time.
    pf_sum += 0.5 * plane_force
    cf_sum += 0.5 * collider_force
    for s in range(n_steps):
        for i in range(nv):
            half = 0.5 * dt / mass[i]
            v[i, 0] += half * force[i, 0]
            v[i, 1] += half * force[i, 1]
            v[i, 2] += half * force[i, 2]
            x[i, 0] += dt * v[i, 0]
            x[i, 1] += dt * v[i, 1]
            x[i, 2] += dt * v[i, 2]
        for c in range(3):  # the collider moves with its velocity
            collider[c] += dt * collider[7 + c]
            collider[3 + c] += dt * collider[7 + c]
        status = _total_force(
            x,
            v,
            dt,
            mass,
            gravity,
            stencil,
            faces,
            rest_inv,
            rest_b,
            rest_area,
            h,
            alpha,
            beta,
            with_bending,
            gas_law,
            p_gauge,
            v_ref,
            p_atm,
            gamma,
            planes,
            clamps,
            vertex_area,
            mean_area,
            k_contact,
            c_contact,
            collider,
            sample_idx,
            sample_w,
            sample_k,
            parallel,
            face_grad,
            face_energy,
            incidence_ptr,
            incidence,
            force,
            vgrad,
            plane_force,
            collider_force,
            out,
        )
        pf_sum += plane_force
        cf_sum += collider_force
        if status == OK and out[6] > tunnel_depth:
            status = TUNNELLED
        for i in range(nv):
            half = 0.5 * dt / mass[i]
            v[i, 0] = (v[i, 0] + half * force[i, 0]) * velocity_decay
            v[i, 1] = (v[i, 1] + half * force[i, 1]) * velocity_decay
            v[i, 2] = (v[i, 2] + half * force[i, 2]) * velocity_decay
        if status != OK or s == n_steps - 1:
            plane_force[:, :] = (pf_sum - 0.5 * plane_force) / (s + 1)
            collider_force[:] = (cf_sum - 0.5 * collider_force) / (s + 1)
            if status != OK:
                return status, s + 1
    return OK, n_steps
