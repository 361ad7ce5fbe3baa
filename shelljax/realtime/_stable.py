"""The stable time step of the real-time runtime: the element bounds (membrane wave, bending
wave, contact spring) and the spectral one (the largest eigenvalue of M⁻¹K by Lanczos) that
:class:`shelljax.realtime.RealtimeShell` estimates (see :class:`StableStep`)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

#: The bending element's Δt constant [-] in altitude² / (C √(B/ρ_A)).
BENDING_CONSTANT = 4.0
#: The default contact spring's share of the stiffest internal mode: k_i = 0.25 m_i ω_max² [N/m],
#: which shortens the stable Δt by 1/√1.25 (−11 %).
CONTACT_FRACTION = 0.25


@dataclasses.dataclass(frozen=True)
class StableStep:
    """The stable-Δt estimate [s] and its parts. From the stiffest element: ``membrane_s`` (its
    shortest altitude over the membrane P-wave speed √((α + 2β) h / ρ_A), ρ_A [kg/m²] the lumped
    areal density), ``bending_s`` (altitude² / (4 √(B/ρ_A)), B = E h³/(12(1 − ν²))),
    ``contact_s`` (2 √(m_i/k_i), the stiffest vertex spring) and ``element_s`` (the three combined
    as 1/Δt² = Σ 1/Δtᵢ²). ``spectral_s`` = 2/√(ω_max² + max k_i/m_i), ω_max² the largest
    eigenvalue of M⁻¹K of the elastic and gas forces at load (Lanczos). ``critical_s`` is the one
    of the two the shell's ``dt_method`` names, and ``dt_s`` = ``safety`` × critical."""

    membrane_s: float
    bending_s: float
    contact_s: float
    element_s: float
    spectral_s: float
    critical_s: float
    safety: float
    dt_s: float


def element_steps(x, faces, masses, vertex_area, material, bending_stiffness) -> tuple[float, float, float]:
    """(membrane, bending, combined) element Δt [s] at positions x (V, 3) [m]: the stiffest element's
    bounds (see :class:`StableStep`) for the lumped ``masses`` (V,) [kg] over ``vertex_area`` (V,)
    [m²], the :class:`._parts.Material` and the flexural rigidity ``bending_stiffness`` B [N·m]."""
    e = x[faces[:, [1, 2, 0]]] - x[faces]
    lengths = np.linalg.norm(e, axis=2)
    area = 0.5 * np.linalg.norm(np.cross(e[:, 0], -e[:, 2]), axis=1)
    altitude = 2.0 * area / lengths.max(axis=1)
    # Areal density of each face: its vertices' lightest mass per vertex area [kg/m²].
    rho = (masses / vertex_area)[faces].min(axis=1)
    c_p = np.sqrt((material.alpha + 2.0 * material.beta) * material.thickness / rho)
    dt_m = float(np.min(altitude / c_p))
    dt_b = math.inf
    if material.bending:
        dt_b = float(np.min(altitude**2 / (BENDING_CONSTANT * np.sqrt(bending_stiffness / rho))))
    return dt_m, dt_b, 1.0 / math.sqrt(1.0 / dt_m**2 + 1.0 / dt_b**2)


def largest_frequency(internal_forces, x0, masses, mean_edge, tol=1e-6) -> float:
    """ω_max [rad/s]: the largest eigenvalue of M⁻¹K (K the Jacobian of ``internal_forces(x)`` (V, 3)
    [N], elastic + gas, no contact) at positions ``x0`` [m], by Lanczos (scipy ``eigsh``) on
    M^-½ K M^-½ with K u from central differences of step 10⁻⁶ ``mean_edge`` [m]."""
    from scipy.sparse.linalg import LinearOperator, eigsh

    x0 = x0.copy()
    scale = 1.0 / np.sqrt(np.repeat(masses, 3))
    eps = 1e-6 * mean_edge

    def matvec(u):
        w = (scale * np.ravel(u)).reshape(-1, 3)
        norm = float(np.abs(w).max()) or 1.0
        ku = -(internal_forces(x0 + eps * w / norm) - internal_forces(x0 - eps * w / norm)) * norm / (2 * eps)
        return scale * ku.ravel()

    n = x0.size
    op = LinearOperator((n, n), matvec=matvec, dtype=float)
    v0 = np.random.default_rng(0).standard_normal(n)
    lam = eigsh(op, k=1, which="LA", tol=tol, v0=v0, maxiter=2000, return_eigenvectors=False)[0]
    return math.sqrt(max(float(lam), 0.0))


def stable_step(element, omega_internal, contact_omega2, dt_method, safety) -> StableStep:
    """The stable substep [s] (see :class:`StableStep`) from the ``element`` bounds (membrane,
    bending, combined) [s], the internal ω_max [rad/s] and the stiffest contact spring's
    max k_i/m_i [1/s²]. Velocity Verlet on a mode of frequency ω is stable for ω Δt < 2; a vertex on
    its contact spring adds k_i/m_i to ω²."""
    dt_m, dt_b, combined = element
    dt_c = 2.0 / math.sqrt(contact_omega2)
    element_total = 1.0 / math.sqrt(1.0 / combined**2 + 1.0 / dt_c**2)
    spectral = 2.0 / math.sqrt(omega_internal**2 + contact_omega2)
    critical = spectral if dt_method == "spectral" else element_total
    return StableStep(dt_m, dt_b, dt_c, element_total, spectral, critical, safety, safety * critical)
