"""Compiled (Numba) stepping of the real-time runtime (float64, SI units).

The elastic forces are :mod:`._elastic`'s. The gas enters through the enclosed volume
V = Σ_f x₀·(x₁ × x₂)/6 [m³] and its gradient; the gauge pressure P(V) [Pa] follows the law
(prescribed, isothermal, adiabatic), and the pressure force on the vertices is P ∂V/∂x [N].

``advance`` runs n velocity-Verlet substeps (kick Δt/2, drift Δt, force, kick Δt/2) in one
compiled call, with penalty contact against planes (:mod:`._contact`) and a moving sphere/capsule (:mod:`._hand`),
and stops at the first substep that fails the blow-up guard (NaN/inf, or a vertex deeper than the
tunnelling depth behind a plane), returning a status code for the Python layer to raise. The
kernels take the named structures of :mod:`._parts` (geometry, body, material, contact, buffers).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..physics import AdiabaticGas, IsothermalGas, PrescribedGas
from ._contact import contact_forces
from ._elastic import elastic_forces_parallel, elastic_forces_serial
from ._hand import collider_contact

# Status codes of ``advance``.
OK = 0
NOT_FINITE = 1
TUNNELLED = 2

# Gas laws, as integers for the kernels (``gas_pressure_energy``): the code of each law's class.
GAS_CODES = {PrescribedGas: 0, IsothermalGas: 1, AdiabaticGas: 2}


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
def gas_pressure_energy(vol, material):
    """(gauge pressure [Pa], gas energy [J]) at volume ``vol`` [m³] (physics._gas's formulas) of the
    :class:`Material`'s gas."""
    law, p_gauge, v_ref = material.gas_law, material.gauge_pressure, material.reference_volume
    p_atm, gamma = material.atmospheric_pressure, material.heat_capacity_ratio
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
def _total_force(x, v, dt, body, geometry, material, contact, buffers):
    """``buffers.force`` (V, 3) [N] ← elastic + gas + gravity + contact at (x, v); ``buffers.out``
    as in ``advance``. Returns the status."""
    force, vgrad, out = buffers.force, buffers.volume_gradient, buffers.out
    mass, gravity = body.masses, body.gravity
    if buffers.parallel:
        e_el = elastic_forces_parallel(x, geometry, material, force, buffers.face_grad, buffers.face_energy, False)
    else:
        e_el = elastic_forces_serial(x, geometry, material, force, False)
    vol = volume_and_gradient(x, geometry.faces, vgrad)
    pres, e_gas = gas_pressure_energy(vol, material)
    nv = x.shape[0]
    finite = math.isfinite(vol)
    for i in range(nv):
        force[i, 0] += pres * vgrad[i, 0] + mass[i] * gravity[0]
        force[i, 1] += pres * vgrad[i, 1] + mass[i] * gravity[1]
        force[i, 2] += pres * vgrad[i, 2] + mass[i] * gravity[2]
        if not (math.isfinite(force[i, 0]) and math.isfinite(force[i, 1]) and math.isfinite(force[i, 2])):
            finite = False
    e_con, depth = contact_forces(x, v, dt, body, geometry, contact, buffers)
    n_planes = contact.planes.point.shape[0]
    e_con = collider_contact(x, v, dt, body, geometry, contact, buffers, depth, n_planes, e_con)
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


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _kick_drift(x, v, dt, mass, force):
    """The first half-kick and the drift of a substep: v ← v + Δt/2 M⁻¹F; x ← x + Δt v."""
    for i in range(x.shape[0]):
        half = 0.5 * dt / mass[i]
        v[i, 0] += half * force[i, 0]
        v[i, 1] += half * force[i, 1]
        v[i, 2] += half * force[i, 2]
        x[i, 0] += dt * v[i, 0]
        x[i, 1] += dt * v[i, 1]
        x[i, 2] += dt * v[i, 2]


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _kick(v, dt, mass, force, velocity_decay):
    """The second half-kick of a substep, then the decay: v ← (v + Δt/2 M⁻¹F) × decay."""
    for i in range(v.shape[0]):
        half = 0.5 * dt / mass[i]
        v[i, 0] = (v[i, 0] + half * force[i, 0]) * velocity_decay
        v[i, 1] = (v[i, 1] + half * force[i, 1]) * velocity_decay
        v[i, 2] = (v[i, 2] + half * force[i, 2]) * velocity_decay


@njit(cache=True, fastmath=False, error_model="numpy")
def advance(x, v, n_steps, dt, velocity_decay, body, geometry, material, contact, buffers):
    """``n_steps`` velocity-Verlet substeps of Δt = ``dt`` [s] in place on x, v (V, 3) [m], [m/s]:

        v ← v + Δt/2 M⁻¹F;  x ← x + Δt v;  F ← F(x, v);  v ← v + Δt/2 M⁻¹F

    (the velocity-dependent contact dampers and friction see the half-step velocity). The force at
    the start is evaluated once per call; the collider's ends move with its velocity (in place in
    ``contact.collider``). Returns (status, steps done). ``buffers.out`` (8,) ← elastic (not
    evaluated: 0), gas, −, contact energy [J], volume [m³], gauge pressure [Pa], deepest plane
    penetration [m], deepest collider penetration [m] at the last force evaluation.
    ``buffers.plane_force`` (P, 3), ``buffers.collider_force`` (3,) [N]: the contact forces
    averaged over the substeps done (trapezoidal: their impulse divided by the time, as the kicks
    apply them). ``velocity_decay`` [-]: v is multiplied by it after each substep (1: none; < 1
    only to relax a shape to rest).
    """
    plane_force, collider_force, collider = buffers.plane_force, buffers.collider_force, contact.collider
    pf_sum = np.zeros((plane_force.shape[0], 3))
    cf_sum = np.zeros(3)
    status = _total_force(x, v, dt, body, geometry, material, contact, buffers)
    if status != OK:
        return status, 0
    # Trapezoidal averages of the contact forces: their impulse over the substeps done, divided by the time.
    pf_sum += 0.5 * plane_force
    cf_sum += 0.5 * collider_force
    for s in range(n_steps):
        _kick_drift(x, v, dt, body.masses, buffers.force)
        for c in range(3):  # the collider moves with its velocity
            collider[c] += dt * collider[7 + c]
            collider[3 + c] += dt * collider[7 + c]
        status = _total_force(x, v, dt, body, geometry, material, contact, buffers)
        pf_sum += plane_force
        cf_sum += collider_force
        if status == OK and buffers.out[6] > contact.tunnel_depth:
            status = TUNNELLED
        _kick(v, dt, body.masses, buffers.force, velocity_decay)
        if status != OK or s == n_steps - 1:
            plane_force[:, :] = (pf_sum - 0.5 * plane_force) / (s + 1)
            collider_force[:] = (cf_sum - 0.5 * collider_force) / (s + 1)
            if status != OK:
                return status, s + 1
    return OK, n_steps
