"""The stable time step of the real-time runtime: the element bounds (membrane wave, bending
wave, contact spring) and the spectral one (the largest eigenvalue of M⁻¹K by Lanczos), mixed into
:class:`shelljax.realtime.RealtimeShell` (see :class:`StableStep`)."""

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


class _StableTimeStep:
    """The stable-Δt methods of :class:`shelljax.realtime.RealtimeShell` (it holds the state)."""

    def _element_parts(self):
        """(membrane, bending, contact-free combined) element Δt [s] at the current positions, and
        the combined one again: the stiffest element's bounds (see :class:`StableStep`)."""
        x, f = self.x, self.faces
        e = x[f[:, [1, 2, 0]]] - x[f]
        lengths = np.linalg.norm(e, axis=2)
        area = 0.5 * np.linalg.norm(np.cross(e[:, 0], -e[:, 2]), axis=1)
        altitude = 2.0 * area / lengths.max(axis=1)
        # Areal density of each face: its vertices' lightest mass per vertex area [kg/m²].
        rho = (self.masses / self.vertex_area)[f].min(axis=1)
        c_p = np.sqrt((self.alpha + 2.0 * self.beta) * self.h / rho)
        dt_m = float(np.min(altitude / c_p))
        dt_b = math.inf
        if self.with_bending:
            bend = self.E * self.h**3 / (12.0 * (1.0 - self.nu**2))
            dt_b = float(np.min(altitude**2 / (BENDING_CONSTANT * np.sqrt(bend / rho))))
        combined = 1.0 / math.sqrt(1.0 / dt_m**2 + 1.0 / dt_b**2)
        return dt_m, dt_b, combined, combined

    def _largest_frequency(self, tol=1e-6) -> float:
        """ω_max [rad/s]: the largest eigenvalue of M⁻¹K (elastic + gas, no contact) at the current
        positions, by Lanczos (scipy ``eigsh``) on M^-½ K M^-½ with K u from central differences of
        the compiled forces."""
        from scipy.sparse.linalg import LinearOperator, eigsh

        x0 = self.x.copy()
        scale = 1.0 / np.sqrt(np.repeat(self.masses, 3))
        eps = 1e-6 * self.mean_edge

        def matvec(u):
            w = (scale * np.ravel(u)).reshape(-1, 3)
            norm = float(np.abs(w).max()) or 1.0
            ku = (
                -(self.internal_forces(x0 + eps * w / norm) - self.internal_forces(x0 - eps * w / norm))
                * norm
                / (2 * eps)
            )
            return scale * ku.ravel()

        n = x0.size
        op = LinearOperator((n, n), matvec=matvec, dtype=float)
        v0 = np.random.default_rng(0).standard_normal(n)
        lam = eigsh(op, k=1, which="LA", tol=tol, v0=v0, maxiter=2000, return_eigenvectors=False)[0]
        return math.sqrt(max(float(lam), 0.0))

    def reestimate_dt(self) -> StableStep:
        """Re-estimate the stable Δt at the current positions (``dt_method``; contact springs kept)."""
        if self.dt_method == "spectral":
            self.omega_internal = self._largest_frequency()
        else:
            self.omega_internal = 2.0 / self._element_parts()[3]
        self.stable = self.stable_dt_estimate()
        return self.stable

    def stable_dt_estimate(self, safety=None) -> StableStep:
        """The stable substep [s]: see :class:`StableStep`. Velocity Verlet on a mode of frequency
        ω is stable for ω Δt < 2; a vertex on its contact spring k_i [N/m] adds k_i/m_i to ω²."""
        dt_m, dt_b, element, _ = self._element_parts()
        contact_omega2 = float(np.max(self.k_contact / self.masses))
        dt_c = 2.0 / math.sqrt(contact_omega2)
        element_total = 1.0 / math.sqrt(1.0 / element**2 + 1.0 / dt_c**2)
        spectral = 2.0 / math.sqrt(self.omega_internal**2 + contact_omega2)
        critical = spectral if self.dt_method == "spectral" else element_total
        s = self.safety if safety is None else safety
        return StableStep(dt_m, dt_b, dt_c, element_total, spectral, critical, s, s * critical)
