"""Compiled (Numba) penalty contact of the real-time runtime (float64, SI units): the planes
(the reference's barrier or a spring, dampers, regularised Coulomb friction and the centre-of-mass
dashpot) and the friction law they share with the collider (:mod:`._hand`). ``contact_forces`` is
the planes' entry point (:mod:`._kernels` calls it once per force evaluation); ``plane_clamps``
sets up the plane law per vertex."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _friction(tx, ty, tz, fn, mu, veps, mass, dt):
    """Regularised Coulomb friction [N] against the slip velocity (tx, ty, tz) [m/s] under the
    normal force ``fn`` [N]: −μ f_n t/√(|t|² + v_ε²), capped at ``mass`` |t|/Δt ([kg]: the least
    mass it moves) so that one substep cannot reverse the slip."""
    vt = math.sqrt(tx * tx + ty * ty + tz * tz)
    if mu <= 0.0 or vt == 0.0:
        return 0.0, 0.0, 0.0
    ft = min(mu * fn * vt / math.sqrt(vt * vt + veps * veps), mass * vt / dt)
    return -ft * tx / vt, -ft * ty / vt, -ft * tz / vt


# half the spring: clamped at k_i itself, hard impacts outran the stable Δt (docs/realtime.md, *The model*)
BARRIER_CLAMP_FRACTION = 0.5


def _barrier_stiffness(s, kappa):
    """d²/dg² [N/m] of the IPC barrier −κ (g − ĝ)² ln(g/ĝ) at s = g/ĝ ∈ (0, 1] (it does not depend on
    ĝ); it falls monotonically from +∞ at s → 0 to 0 at s = 1."""
    return kappa * (-2.0 * np.log(s) - 4.0 * (s - 1.0) / s + (s - 1.0) ** 2 / s**2)


def plane_clamps(planes, k_contact) -> np.ndarray:
    """(P, V, 3) per plane (``planes``: :class:`._parts.Planes`) and vertex: the clamp gap g_c [m], the barrier's force [N] and energy [J]
    there. A plane with a barrier (ĝ, κ) pushes a vertex at gap g by the reference's barrier force
    −d/dg[−κ (g − ĝ)² ln(g/ĝ)] for g_c ≤ g < ĝ and continues it linearly with the vertex's contact
    stiffness k_i [N/m] below g_c, where the barrier's stiffness reaches ``BARRIER_CLAMP_FRACTION``
    k_i: the reference's force law wherever it is that soft, and never stiffer than the stable Δt
    allows. A plane without a barrier has g_c = 0 and no force at g_c: the spring k_i δ behind it."""
    clamps = np.zeros((planes.point.shape[0], k_contact.shape[0], 3))
    for p, (reach, kappa) in enumerate(zip(planes.barrier_reach, planes.barrier_stiffness)):
        if reach <= 0.0:
            continue
        lo, hi = np.full(k_contact.shape, 1e-12), np.ones(k_contact.shape)
        for _ in range(80):  # bisection on s = g_c/ĝ: the barrier's stiffness is monotonic in s
            mid = 0.5 * (lo + hi)
            softer = _barrier_stiffness(mid, kappa) < BARRIER_CLAMP_FRACTION * k_contact
            hi = np.where(softer, mid, hi)
            lo = np.where(softer, lo, mid)
        s = hi
        clamps[p, :, 0] = s * reach
        clamps[p, :, 1] = kappa * reach * (2.0 * (s - 1.0) * np.log(s) + (s - 1.0) ** 2 / s)
        clamps[p, :, 2] = -kappa * reach**2 * (s - 1.0) ** 2 * np.log(s)
    return clamps


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _plane_law(gap, k, reach, kappa, clamp):
    """(normal force [N], energy [J]) of a vertex at ``gap`` [m] < max(ĝ, 0) from a plane: the barrier
    of reach ĝ = ``reach`` [m] and stiffness ``kappa`` [J/m²] above the clamp gap, its linear
    continuation with stiffness ``k`` [N/m] below (``clamp``: g_c, force and energy there; see
    ``plane_clamps``)."""
    if gap < clamp[0]:
        d = clamp[0] - gap
        return clamp[1] + k * d, clamp[2] + clamp[1] * d + 0.5 * k * d * d
    s = gap / reach
    return kappa * reach * (2.0 * (s - 1.0) * math.log(s) + (s - 1.0) ** 2 / s), -kappa * reach * reach * (
        s - 1.0
    ) ** 2 * math.log(s)


@njit(cache=True, fastmath=False, error_model="numpy")
def planes_energy(x, planes, clamps, k_contact):
    """The planes' contact energy [J] at positions x (V, 3) [m] (see ``plane_clamps``)."""
    energy = 0.0
    for p in range(planes.point.shape[0]):
        reach = max(planes.barrier_reach[p], 0.0)
        for i in range(x.shape[0]):
            gap = (
                (x[i, 0] - planes.point[p, 0]) * planes.normal[p, 0]
                + (x[i, 1] - planes.point[p, 1]) * planes.normal[p, 1]
                + (x[i, 2] - planes.point[p, 2]) * planes.normal[p, 2]
            )
            if gap < reach:
                energy += _plane_law(
                    gap, k_contact[i], planes.barrier_reach[p], planes.barrier_stiffness[p], clamps[p, i]
                )[1]
    return energy


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _plane_contact(x, v, dt, p, body, geometry, contact, buffers, depth, energy):
    """Plane p's contact law, dampers and friction and its centre-of-mass dashpot (see
    ``contact_forces``), added to ``buffers.force`` and ``buffers.plane_force[p]``; ``depth[p]`` ←
    its deepest penetration [m]. Returns ``energy`` [J] plus its contact energy."""
    mass, force, plane_force = body.masses, buffers.force, buffers.plane_force
    planes, clamps, k_contact, c_contact = contact.planes, contact.clamps, contact.stiffness, contact.damping
    nv = x.shape[0]
    ox, oy, oz = planes.point[p, 0], planes.point[p, 1], planes.point[p, 2]
    nx, ny, nz = planes.normal[p, 0], planes.normal[p, 1], planes.normal[p, 2]
    mu = planes.friction[p]
    veps = planes.slip_velocity[p]
    cbody = planes.damping[p]
    reach = max(planes.barrier_reach[p], 0.0)
    touching_area = 0.0
    for i in range(nv):
        gap = (x[i, 0] - ox) * nx + (x[i, 1] - oy) * ny + (x[i, 2] - oz) * nz
        if gap >= reach:
            continue
        depth[p] = max(depth[p], -gap)
        # the reference's lagged weight of a barrier contact, (1 − g/ĝ)², 1 behind the plane
        touching_area += geometry.vertex_area[i] * (1.0 if gap <= 0.0 else (1.0 - gap / reach) ** 2)
        vn = v[i, 0] * nx + v[i, 1] * ny + v[i, 2] * nz
        fn, e = _plane_law(gap, k_contact[i], planes.barrier_reach[p], planes.barrier_stiffness[p], clamps[p, i])
        fn -= c_contact[i] * vn
        energy += e
        if fn <= 0.0:
            continue
        gx, gy, gz = _friction(v[i, 0] - vn * nx, v[i, 1] - vn * ny, v[i, 2] - vn * nz, fn, mu, veps, mass[i], dt)
        fx, fy, fz = fn * nx + gx, fn * ny + gy, fn * nz + gz
        force[i, 0] += fx
        force[i, 1] += fy
        force[i, 2] += fz
        plane_force[p, 0] += fx
        plane_force[p, 1] += fy
        plane_force[p, 2] += fz
    if cbody > 0.0 and touching_area > 0.0:
        _body_dashpot(v, p, cbody * min(1.0, touching_area / geometry.mean_area), body, planes, force, plane_force)
    return energy


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _body_dashpot(v, p, c, body, planes, force, plane_force):
    """Plane p's centre-of-mass dashpot −c (v_com·n) n with c = c_plane W [N·s/m], spread over the
    vertices by mass, added to ``force`` and ``plane_force[p]``."""
    nx, ny, nz = planes.normal[p, 0], planes.normal[p, 1], planes.normal[p, 2]
    nv = v.shape[0]
    mass, total_mass = body.masses, body.total_mass
    vcx = 0.0
    vcy = 0.0
    vcz = 0.0
    for i in range(nv):
        vcx += mass[i] * v[i, 0]
        vcy += mass[i] * v[i, 1]
        vcz += mass[i] * v[i, 2]
    vcn = (vcx * nx + vcy * ny + vcz * nz) / total_mass
    fb = -c * vcn
    for i in range(nv):
        s = fb * mass[i] / total_mass
        force[i, 0] += s * nx
        force[i, 1] += s * ny
        force[i, 2] += s * nz
    plane_force[p, 0] += fb * nx
    plane_force[p, 1] += fb * ny
    plane_force[p, 2] += fb * nz


@njit(cache=True, fastmath=False, error_model="numpy")
def mass_sum(masses):
    """Σ m [kg] as the kernels sum it (in order: the body's total mass, summed once)."""
    return masses.sum()


@njit(cache=True, fastmath=False, error_model="numpy")
def contact_forces(x, v, dt, body, geometry, contact, buffers):
    """Add the planes' contact forces [N] to ``buffers.force``; return (energy [J], deepest
    penetration [m] per plane, then a 0 for the collider's (:func:`._hand.collider_contact` fills it)).

    ``contact.planes`` (:class:`._parts.Planes`): point [m], unit normal, μ [-], slip velocity v_ε
    [m/s], body damping c [N·s/m], barrier reach ĝ [m] and stiffness κ [J/m²] (0, 0: a spring
    behind the plane); ``contact.clamps`` (P, V, 3) from ``plane_clamps``. A vertex at gap
    g < max(ĝ, 0) feels the plane's law f(g) (the barrier, or its linear continuation with
    per-vertex stiffness ``contact.stiffness`` (V,) [N/m]; without a barrier k δ, δ = −g) less
    c_v v_n (clamped ≥ 0) along the normal, c_v = ``contact.damping`` (V,) [N·s/m], and regularised
    Coulomb friction −μ f_n v_t / √(|v_t|² + v_ε²), capped so that one substep of it cannot reverse
    v_t. The plane's c is the centre-of-mass dashpot of :mod:`shelljax.dynamics._shell`:
    −c W (v_com·n) spread over the vertices by mass, W = min(1, Σ_j w_j A_j / Ā),
    w_j = (1 − g_j/ĝ)² within the barrier's reach, 1 behind the plane. ``buffers.plane_force``
    (P, 3) ← the forces on the shell [N].
    """
    n_planes = contact.planes.point.shape[0]
    energy = 0.0
    depth = np.zeros(n_planes + 1)
    buffers.plane_force[:, :] = 0.0
    for p in range(n_planes):
        energy = _plane_contact(x, v, dt, p, body, geometry, contact, buffers, depth, energy)
    return energy, depth
