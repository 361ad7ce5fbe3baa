"""The real-time shell: explicit velocity-Verlet stepping of the 3D engine's physics (SI units).

A :class:`RealtimeShell` holds the state (positions x (V, 3) [m], velocities v (V, 3) [m/s]) and
the constant data of one object: the rest geometry of :mod:`shelljax.shell3d` (rest metric,
curvature and area per face), E [Pa], ν [-], h [m], the gas law and its reference volume, the
lumped vertex masses [kg] of :func:`shelljax.dynamics.shell_system` (the mass spread by rest area),
gravity, the planes and a moving collider (sphere or capsule: the user's hand).

Each substep (velocity Verlet, symplectic and second order, Δt [s]):

    F(x, v) = −∇(E_membrane + E_bending)(x) + P(V) ∂V/∂x + m g + F_contact(x, v)
    v ← v + Δt/2 M⁻¹F;  x ← x + Δt v;  F ← F(x, v);  v ← v + Δt/2 M⁻¹F

``frame(dt_frame)`` runs ⌈dt_frame / Δt_stable⌉ substeps of equal length in one compiled call.
The stable Δt is estimated when the object loads (:meth:`RealtimeShell.stable_dt_estimate`), and
every frame is checked by the blow-up guard (:class:`BlowUpError`).
"""

from __future__ import annotations

import dataclasses
import math
import time as _time

import numpy as np

from .._errors import InvalidInputError
from ..physics import ATMOSPHERIC_PRESSURE, STANDARD_GRAVITY, AdiabaticGas
from . import _kernels as K
from ._checks import _check, _planes_array
from ._contact import plane_clamps, planes_energy
from ._embedding import DisplayEmbedding
from ._errors import BlowUpError
from ._loading import _Loading
from ._stable import BENDING_CONSTANT, CONTACT_FRACTION, StableStep, _StableTimeStep

__all__ = ["BENDING_CONSTANT", "CONTACT_FRACTION", "SAFETY", "Collider", "Frame", "RealtimeShell", "StableStep"]

#: Default safety factor on the stable Δt [-].
SAFETY = 0.9


@dataclasses.dataclass(frozen=True)
class Collider:
    """A moving rigid capsule (the user's hand or finger): the segment from ``a`` (3,) [m] to ``b``
    (3,) [m] swept by a sphere of ``radius`` [m] (a = b: a sphere), moving at ``velocity`` (3,)
    [m/s], with Coulomb friction ``friction`` μ [-]. It moves with its velocity during a frame;
    place it anew (or change its velocity) between frames with :meth:`RealtimeShell.set_collider`."""

    a: tuple
    b: tuple | None = None
    radius: float = 0.01
    velocity: tuple = (0.0, 0.0, 0.0)
    friction: float = 0.0

    def packed(self) -> np.ndarray:
        a = np.asarray(self.a, dtype=float).reshape(-1)
        b = a if self.b is None else np.asarray(self.b, dtype=float).reshape(-1)
        vel = np.asarray(self.velocity, dtype=float).reshape(-1)
        for name, value in (("a", a), ("b", b), ("velocity", vel)):
            if value.shape != (3,) or not np.all(np.isfinite(value)):
                raise InvalidInputError(
                    f"Collider.{name}: expected a finite 3-vector [m or m/s]; got {value.tolist()}."
                )
        if not (np.isfinite(self.radius) and self.radius > 0.0):
            raise InvalidInputError(f"Collider.radius: must be a positive length in m; got {self.radius}.")
        if not (np.isfinite(self.friction) and self.friction >= 0.0):
            raise InvalidInputError(f"Collider.friction: μ must be ≥ 0; got {self.friction}.")
        return np.concatenate([a, b, [self.radius], vel, [self.friction]])


def _sphere(center, radius, velocity=(0.0, 0.0, 0.0), friction=0.0) -> Collider:
    return Collider(a=tuple(center), b=None, radius=radius, velocity=tuple(velocity), friction=friction)


Collider.sphere = staticmethod(_sphere)


@dataclasses.dataclass(frozen=True)
class Frame:
    """What one frame did: simulated ``time_s`` [s] at its end, ``substeps`` and their ``dt_s`` [s],
    ``wall_s`` [s] its wall-clock cost, ``plane_forces_N`` (P, 3) and ``collider_force_N`` (3,)
    [N] (on the shell, averaged over the frame's substeps), ``gauge_pressure_Pa``, ``volume_m3``,
    ``energies_J`` (kinetic, elastic, gas, gravity, contact, total) and the centre of mass
    ``com_m`` (3,) [m] and its velocity ``com_velocity_m_per_s`` (3,); ``refinements``: how many times
    the frame was redone at half its substep after a blow-up (0: none)."""

    time_s: float
    substeps: int
    dt_s: float
    wall_s: float
    plane_forces_N: np.ndarray
    collider_force_N: np.ndarray
    gauge_pressure_Pa: float
    volume_m3: float
    energies_J: dict
    com_m: np.ndarray
    com_velocity_m_per_s: np.ndarray
    refinements: int = 0


class RealtimeShell(_Loading, _StableTimeStep):
    """A shell stepped explicitly in real time; see the module docstring.

    Build one with :meth:`from_system` (a :class:`shelljax.dynamics.ShellDynamicSystem`: the same
    rest geometry, masses and gas as the implicit reference), :meth:`ball`, :meth:`from_shell`,
    :meth:`from_session` or :meth:`from_replica`.

    Arguments: ``stencil`` (F, 6) int, ``rest_metric`` (F, 2, 2) [m²], ``rest_curvature`` (F, 2, 2)
    [m], ``rest_area`` (F,) [m²], ``vertex_area`` (V,) [m²], ``positions`` (V, 3) [m] (the start,
    e.g. the inflated equilibrium), ``masses`` (V,) [kg], ``young_modulus`` E [Pa],
    ``poisson_ratio`` ν [-], ``thickness`` h [m], ``gas`` (a ``physics.PrescribedGas``,
    ``IsothermalGas`` or ``AdiabaticGas``, with its γ [-]), ``gauge_pressure`` P_g [Pa] (prescribed,
    or the sealed gas's at ``reference_volume`` [m³]), ``planes`` (``physics.Plane``s or scenario
    plane specs: point, normal, friction μ, damping c [N·s/m], the centre-of-mass dashpot of the reference),
    ``gravity`` [m/s²] (g down, or a 3-vector), ``contact_stiffness`` k [N/m] per vertex (default:
    k_i = 0.25 m_i ω_max², ω_max the stiffest internal mode: it shortens the stable Δt by 11 %),
    ``contact_damping_ratio`` ζ [-] of each vertex's normal damper c_i = 2ζ√(k m_i) (default 0: the
    plane's ``damping`` c, the centre-of-mass dashpot, is the physical dissipation, as in the reference),
    ``slip_velocity`` v_ε [m/s] of the regularised Coulomb friction, ``safety`` [-] on the stable
    Δt, ``bending`` (False: membrane only), ``parallel`` (Numba threads over faces),
    ``tunnel_depth`` [m] (a vertex deeper behind a plane is a blow-up; default half the mean edge),
    ``energy_growth`` [-] (the guard's bound on the growth of the total energy, as a fraction of
    the energy scale m g L + kinetic + elastic, L the object's size), ``max_refinements`` (a frame
    that trips the guard is redone from its start at half the substep, up to this many times,
    before :class:`BlowUpError` is raised: a hard impact can stiffen the shell past the stable Δt
    estimated at rest; 0: raise at once).
    """

    def __init__(
        self,
        *,
        stencil,
        rest_metric,
        rest_curvature,
        rest_area,
        vertex_area,
        positions,
        masses,
        young_modulus,
        poisson_ratio,
        thickness,
        gas=AdiabaticGas(),
        gauge_pressure,
        reference_volume=None,
        atmospheric_pressure=ATMOSPHERIC_PRESSURE,
        planes=(),
        gravity=STANDARD_GRAVITY,
        contact_stiffness=None,
        contact_damping_ratio=0.0,
        slip_velocity=1e-2,
        safety=SAFETY,
        bending=True,
        parallel=False,
        tunnel_depth=None,
        energy_growth=0.5,
        max_refinements=3,
        velocities=None,
        dt_method="spectral",
    ):
        self._set_material(gas, young_modulus, poisson_ratio, thickness, gauge_pressure, atmospheric_pressure, safety)
        self._set_rest_geometry(stencil, rest_metric, rest_curvature, rest_area, vertex_area)
        self._set_bodies(positions, velocities, masses, gravity)
        self.slip_velocity = _check("slip_velocity [m/s]", slip_velocity)
        self.planes, self.plane_names = _planes_array(planes, self.slip_velocity)
        self.with_bending = bool(bending)
        self.parallel = bool(parallel)
        self.energy_growth = _check("energy_growth [-]", energy_growth)
        if (
            isinstance(max_refinements, bool)
            or not isinstance(max_refinements, (int, np.integer))
            or max_refinements < 0
        ):
            raise InvalidInputError(
                f"max_refinements: expected an integer ≥ 0 (0: no redone frames); got {max_refinements!r}."
            )
        self.max_refinements = int(max_refinements)
        self._set_gas_and_sizes(reference_volume, tunnel_depth)
        self._allocate_buffers()
        self._set_contact_and_dt(contact_stiffness, contact_damping_ratio, dt_method)
        self._collider_samples()
        self.time = 0.0
        self.collider_work = 0.0
        self._energy_scale = None
        self._energy_start = None

    def _set_material(
        self, gas, young_modulus, poisson_ratio, thickness, gauge_pressure, atmospheric_pressure, safety
    ) -> None:
        """E [Pa], ν [-], h [m], the gas and its pressures [Pa], the Lamé-like α, β [Pa] and the Δt safety."""
        if type(gas) not in K.GAS_CODES:
            laws = ", ".join(f"physics.{law.__name__}" for law in K.GAS_CODES)
            raise InvalidInputError(f"gas: expected one of {laws}; got {gas!r}.")
        self.E = _check("young_modulus [Pa]", young_modulus)
        self.nu = _check("poisson_ratio [-]", poisson_ratio, positive=False)
        if not self.nu < 0.5:
            raise InvalidInputError(f"poisson_ratio [-]: must be in [0, 0.5); got {poisson_ratio!r}.")
        self.h = _check("thickness [m]", thickness)
        self.p_gauge = _check("gauge_pressure [Pa]", gauge_pressure, positive=False)
        self.gamma = float(gas.exponent)  # read by the adiabatic law's kernel only
        self.p_atm = _check("atmospheric_pressure [Pa]", atmospheric_pressure)
        self.safety = _check("safety [-]", safety)
        self.gas = gas
        self.alpha = self.E * self.nu / (1.0 - self.nu**2)
        self.beta = self.E / (2.0 * (1.0 + self.nu))

    def _set_rest_geometry(self, stencil, rest_metric, rest_curvature, rest_area, vertex_area) -> None:
        """The stencils, the faces and the rest geometry per face, packed for the kernels."""
        self.stencil = np.ascontiguousarray(stencil, dtype=np.int64)
        self.faces = np.ascontiguousarray(self.stencil[:, :3])
        n_faces = self.stencil.shape[0]
        metric = np.asarray(rest_metric, dtype=float).reshape(n_faces, 2, 2)
        inv = np.linalg.inv(metric)
        self.rest_inv = np.ascontiguousarray(np.stack([inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]], axis=1))
        curvature = np.asarray(rest_curvature, dtype=float).reshape(n_faces, 2, 2)
        self.rest_b = np.ascontiguousarray(
            np.stack([curvature[:, 0, 0], curvature[:, 0, 1], curvature[:, 1, 1]], axis=1)
        )
        self.rest_area = np.ascontiguousarray(rest_area, dtype=float).reshape(n_faces)
        self.vertex_area = np.ascontiguousarray(vertex_area, dtype=float).reshape(-1)

    def _set_bodies(self, positions, velocities, masses, gravity) -> None:
        """Positions [m], velocities [m/s], vertex masses [kg] and gravity [m/s²], checked."""
        self.x = np.array(positions, dtype=float).reshape(-1, 3)
        n = self.x.shape[0]
        if not np.all(np.isfinite(self.x)):
            raise InvalidInputError("positions [m]: contain NaN or inf.")
        self.v = np.zeros_like(self.x) if velocities is None else np.array(velocities, dtype=float).reshape(n, 3)
        self.masses = np.ascontiguousarray(masses, dtype=float).reshape(-1)
        if self.masses.shape != (n,) or not np.all(np.isfinite(self.masses)) or np.any(self.masses <= 0):
            raise InvalidInputError(f"masses [kg]: expected {n} positive vertex masses; got shape {self.masses.shape}.")
        g = np.asarray(gravity, dtype=float)
        self.gravity = np.array([0.0, 0.0, -float(g)]) if g.ndim == 0 else g.reshape(3).copy()
        if not np.all(np.isfinite(self.gravity)):
            raise InvalidInputError(f"gravity [m/s²]: must be finite; got {gravity!r}.")

    def _set_gas_and_sizes(self, reference_volume, tunnel_depth) -> None:
        """The gas's reference volume [m³], the mean edge [m], the tunnelling depth [m] and the mean vertex area [m²]."""
        volume_grad = np.zeros_like(self.x)
        volume = K.volume_and_gradient(self.x, self.faces, volume_grad)
        if not self.gas.sealed:
            self.v_ref = volume
        else:
            self.v_ref = volume if reference_volume is None else _check("reference_volume [m³]", reference_volume)
        edges = np.linalg.norm(self.x[self.faces[:, [1, 2, 0]]] - self.x[self.faces], axis=2)
        self.mean_edge = float(edges.mean())
        self.tunnel_depth = 0.5 * self.mean_edge if tunnel_depth is None else _check("tunnel_depth [m]", tunnel_depth)
        self.mean_area = float(self.vertex_area.mean())

    def _allocate_buffers(self) -> None:
        """The kernels' work buffers, the vertex → face-slot incidence (CSR) and the collider (none)."""
        n, n_faces = self.x.shape[0], self.stencil.shape[0]
        self._force = np.zeros_like(self.x)
        self._vgrad = np.zeros_like(self.x)
        self._face_grad = np.zeros((n_faces, 6, 3))
        self._face_energy = np.zeros(n_faces)
        slots = self.stencil.ravel()
        order = np.argsort(slots, kind="stable")
        self._incidence = np.ascontiguousarray(order.astype(np.int64))
        self._incidence_ptr = np.concatenate([[0], np.cumsum(np.bincount(slots, minlength=n))]).astype(np.int64)
        self._plane_force = np.zeros((self.planes.shape[0], 3))
        self._collider_force = np.zeros(3)
        self._out = np.zeros(8)
        self.collider = np.zeros(11)  # radius 0: none

    def _set_contact_and_dt(self, contact_stiffness, contact_damping_ratio, dt_method) -> None:
        """The contact springs k_i [N/m] and dampers c_i [N·s/m], and the stable Δt."""
        if dt_method not in ("spectral", "element"):
            raise InvalidInputError(f"dt_method: expected 'spectral' or 'element'; got {dt_method!r}.")
        self.dt_method = dt_method
        self.omega_internal = self._largest_frequency() if dt_method == "spectral" else 2.0 / self._element_parts()[3]
        if contact_stiffness is None:
            self.k_contact = CONTACT_FRACTION * self.masses * self.omega_internal**2
        else:
            self.k_contact = np.full(self.x.shape[0], _check("contact_stiffness [N/m]", contact_stiffness))
        zeta = _check("contact_damping_ratio [-]", contact_damping_ratio, positive=False)
        self.c_contact = 2.0 * zeta * np.sqrt(self.k_contact * self.masses)
        self._clamps = plane_clamps(self.planes, self.k_contact)
        self.stable = self.stable_dt_estimate()

    def _collider_samples(self) -> None:
        """The collider's contact points: vertices, edge midpoints and face centroids (barycentric
        indices (S, 3) and weights (S, 3)), each with a spring of a third of its vertices' mean k
        [N/m], so that a vertex's springs from all the points around it sum to about its own k."""
        n = self.x.shape[0]
        f = self.faces
        edges = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
        idx = np.concatenate([np.stack([np.arange(n)] * 3, axis=1), np.column_stack([edges, edges[:, 0]]), f])
        w = np.concatenate(
            [
                np.tile([1.0, 0.0, 0.0], (n, 1)),
                np.tile([0.5, 0.5, 0.0], (len(edges), 1)),
                np.full((len(f), 3), 1.0 / 3.0),
            ]
        )
        self._sample_idx = np.ascontiguousarray(idx, dtype=np.int64)
        self._sample_w = np.ascontiguousarray(w)
        self._sample_k = np.ascontiguousarray((w * self.k_contact[idx]).sum(axis=1) / 3.0)

    # ------------------------------------------------------------------ forces and energies
    def elastic_forces(self, x=None, *, parallel=False, with_energy=True, out=None) -> tuple[float, np.ndarray]:
        """(membrane + bending energy [J], −∇ of it (V, 3) [N]) at x [m] (default: the state), by the
        serial kernel or (``parallel``) the threaded one; the energy is 0 unless ``with_energy``;
        ``out`` (V, 3) float64, C-contiguous: the force's buffer (default: a new array)."""
        x = self.x if x is None else np.ascontiguousarray(x, dtype=float).reshape(-1, 3)
        force = np.zeros_like(x) if out is None else out
        args = (
            x,
            self.stencil,
            self.rest_inv,
            self.rest_b,
            self.rest_area,
            self.h,
            self.alpha,
            self.beta,
            self.with_bending,
            force,
        )
        if parallel:
            e = K.elastic_forces_parallel(
                *args, self._face_grad, self._face_energy, self._incidence_ptr, self._incidence, with_energy
            )
        else:
            e = K.elastic_forces_serial(*args, with_energy)
        return e, force

    def gas_state(self, x=None) -> tuple[float, float, np.ndarray]:
        """(gauge pressure [Pa], volume [m³], pressure force P ∂V/∂x (V, 3) [N]) at x [m]."""
        x = self.x if x is None else np.ascontiguousarray(x, dtype=float).reshape(-1, 3)
        grad = np.zeros_like(x)
        vol = K.volume_and_gradient(x, self.faces, grad)
        pressure, _ = K.gas_pressure_energy(
            vol, K.GAS_CODES[type(self.gas)], self.p_gauge, self.v_ref, self.p_atm, self.gamma
        )
        return float(pressure), float(vol), pressure * grad

    def internal_forces(self, x) -> np.ndarray:
        """Elastic + gas forces (V, 3) [N] at x [m] (no gravity, no contact)."""
        _, f = self.elastic_forces(x)
        return f + self.gas_state(x)[2]

    def energies(self) -> dict:
        """Kinetic, elastic, gas, gravity and plane-contact energies and their total [J] now."""
        e_el, _ = self.elastic_forces()
        grad = np.zeros_like(self.x)
        vol = K.volume_and_gradient(self.x, self.faces, grad)
        _, e_gas = K.gas_pressure_energy(
            vol, K.GAS_CODES[type(self.gas)], self.p_gauge, self.v_ref, self.p_atm, self.gamma
        )
        e_grav = float(-np.sum(self.masses * (self.x @ self.gravity)))
        e_con = float(planes_energy(self.x, self.planes, self._clamps, self.k_contact))
        out = {
            "kinetic": float(K.kinetic_energy(self.v, self.masses)),
            "elastic": float(e_el),
            "gas": float(e_gas),
            "gravity": e_grav,
            "contact": e_con,
        }
        out["total"] = sum(out.values())
        return out

    @property
    def total_mass(self) -> float:
        """Mass [kg]."""
        return float(self.masses.sum())

    def com(self) -> tuple[np.ndarray, np.ndarray]:
        """Centre of mass (3,) [m] and its velocity (3,) [m/s]."""
        m = self.masses[:, None]
        return (m * self.x).sum(0) / self.total_mass, (m * self.v).sum(0) / self.total_mass

    # ------------------------------------------------------------------ state
    def set_state(self, positions, velocities=None, time=0.0) -> None:
        """Positions (V, 3) [m], velocities (V, 3) [m/s] (or a (3,) rigid velocity), time [s]."""
        x = np.array(positions, dtype=float).reshape(self.x.shape)
        if not np.all(np.isfinite(x)):
            raise InvalidInputError("positions [m]: contain NaN or inf.")
        v = (
            np.zeros_like(x)
            if velocities is None
            else np.broadcast_to(np.asarray(velocities, dtype=float), x.shape).copy()
        )
        self.x, self.v, self.time = x, v, float(time)
        self.collider_work = 0.0
        self._energy_start = None

    def drop(self, height: float, velocity=(0.0, 0.0, 0.0), plane: int = 0, centre_xy=None) -> None:
        """Move the shell so that its lowest vertex is ``height`` [m] above plane ``plane``, at rest
        or moving rigidly at ``velocity`` (3,) [m/s] (as :func:`shelljax.dynamics.drop_state`)."""
        h = _check("height [m]", height, positive=False)
        if self.planes.shape[0] <= plane:
            raise InvalidInputError(
                f"plane: no plane {plane} to drop onto ({self.planes.shape[0]} planes); add the ground."
            )
        row = self.planes[plane]
        x = self.x.copy()
        if centre_xy is not None:
            com, _ = self.com()
            x[:, :2] += np.asarray(centre_xy, dtype=float) - com[:2]
        gap = (x - row[:3]) @ row[3:6]
        x += (h - gap.min()) * row[3:6]
        self.set_state(x, np.asarray(velocity, dtype=float))

    def embed(self, vertices, faces=None) -> DisplayEmbedding:
        """A finer display mesh (``vertices`` (N, 3) [m] in the shell's current frame, e.g. the
        scan at the inflated state; optional ``faces`` (M, 3)) embedded on this simulation mesh at
        its current positions: ``.positions(shell.x)`` places it each frame (:class:`DisplayEmbedding`)."""
        return DisplayEmbedding(self.x, self.faces, vertices, faces)

    def set_collider(self, collider: Collider | None) -> None:
        """Place (or remove, None) the moving collider for the next frames; it then moves with its
        velocity (``self.collider`` holds its current segment ends [m])."""
        self.collider = np.zeros(11) if collider is None else collider.packed()

    def set_planes(self, planes) -> None:
        """Replace the planes (``physics.Plane``s or scenario plane specs, as the constructor's
        ``planes``; () for none) for the next frames; the contact springs are kept."""
        self.planes, self.plane_names = _planes_array(planes, self.slip_velocity)
        self._clamps = plane_clamps(self.planes, self.k_contact)
        self._plane_force = np.zeros((self.planes.shape[0], 3))

    # ------------------------------------------------------------------ stepping
    def substeps_for(self, frame_dt: float) -> int:
        """Substeps of one frame of ``frame_dt`` [s]: ⌈frame_dt / Δt_stable⌉."""
        return max(1, math.ceil(frame_dt / self.stable.dt_s - 1e-12))

    def _scale(self) -> float:
        size = float(np.ptp(self.x, axis=0).max())
        e = self.energies()
        return self.total_mass * float(np.linalg.norm(self.gravity)) * size + e["kinetic"] + abs(e["elastic"]) + 1e-12

    def advance(self, n_substeps: int, dt: float, velocity_decay: float = 1.0) -> tuple[int, int]:
        """Run ``n_substeps`` of ``dt`` [s] (no guard on energy); returns (status, substeps done)."""
        status, done = K.advance(
            self.x,
            self.v,
            int(n_substeps),
            float(dt),
            self.masses,
            self.gravity,
            self.stencil,
            self.faces,
            self.rest_inv,
            self.rest_b,
            self.rest_area,
            self.h,
            self.alpha,
            self.beta,
            self.with_bending,
            K.GAS_CODES[type(self.gas)],
            self.p_gauge,
            self.v_ref,
            self.p_atm,
            self.gamma,
            self.planes,
            self._clamps,
            self.vertex_area,
            self.mean_area,
            self.k_contact,
            self.c_contact,
            self.collider,
            self._sample_idx,
            self._sample_w,
            self._sample_k,
            self.tunnel_depth,
            self.parallel,
            self._face_grad,
            self._face_energy,
            self._incidence_ptr,
            self._incidence,
            self._force,
            self._vgrad,
            self._plane_force,
            self._collider_force,
            self._out,
            float(velocity_decay),
        )
        self.time += done * dt
        if self.collider[6] > 0.0:  # the collider's work on the shell [J]: its force on it × its velocity
            self.collider_work += float(self._collider_force @ self.collider[7:10]) * done * dt
        return int(status), int(done)

    def contact_forces(self) -> tuple[np.ndarray, np.ndarray]:
        """The contact forces on the shell now, without stepping: per plane (P, 3) [N] and the
        collider's (3,) [N] (e.g. a static reading after :meth:`relax`)."""
        self.advance(0, self.stable.dt_s)  # zero substeps: the forces at the current state only
        return self._plane_force.copy(), self._collider_force.copy()

    def relax(self, duration: float, rate: float | None = None) -> float:
        """Settle the shell towards rest (gravity and contacts as set) for ``duration`` [s] of
        simulated time at half the stable Δt with a velocity decay of ``rate`` [1/s] (default:
        4/duration, so the slowest motions also die out); then re-estimates the stable Δt at the
        settled shape (:meth:`reestimate_dt`, the contact springs kept) and zeroes the velocities.
        Returns the kinetic energy [J] before zeroing. Resets the time to 0."""
        duration = _check("duration [s]", duration)
        rate = 4.0 / duration if rate is None else _check("rate [1/s]", rate)
        dt = 0.5 * self.stable.dt_s  # a start far from equilibrium deforms the elements: half the step
        n = max(1, math.ceil(duration / dt))
        status, _ = self.advance(n, dt, math.exp(-rate * dt))
        if status != K.OK:
            raise BlowUpError(
                f"relax: the stepping blew up (status {status}) at Δt = {dt:.3g} s. Fix: lower `safety`.",
                reason="not finite" if status == K.NOT_FINITE else "tunnelled",
                time_s=self.time,
                dt_s=dt,
            )
        kinetic = float(K.kinetic_energy(self.v, self.masses))
        self.reestimate_dt()
        self.v[:] = 0.0
        self.time = 0.0
        self._energy_start = None
        return kinetic

    def frame(self, frame_dt: float = 1.0 / 60.0, substeps: int | None = None) -> Frame:
        """Advance one frame of ``frame_dt`` [s] in ``substeps`` equal substeps (default
        :meth:`substeps_for`). A frame that trips the guard is redone from its start with twice the
        substeps, up to ``max_refinements`` times (``Frame.refinements`` says how often); then
        :class:`BlowUpError` is raised."""
        frame_dt = _check("frame_dt [s]", frame_dt)
        n = self.substeps_for(frame_dt) if substeps is None else int(_check("substeps", substeps))
        if self._energy_start is None:
            self._energy_start = self.energies()["total"]
            self._energy_scale = self._scale()
        saved = (self.x.copy(), self.v.copy(), self.collider.copy(), self.time, self.collider_work)
        start = _time.perf_counter()
        for refinements in range(self.max_refinements + 1):
            if refinements:
                x, v, collider, self.time, self.collider_work = saved
                self.x[:], self.v[:], self.collider[:] = x, v, collider
            substeps_done = n * 2**refinements
            dt = frame_dt / substeps_done
            status, done = self.advance(substeps_done, dt)
            energies = self.energies() if status == K.OK else None  # at the frame's end: x and v of one instant
            error = self._blow_up(status, dt, energies)
            if error is None:
                break
        if error is not None:
            raise error
        wall = _time.perf_counter() - start
        com, vcom = self.com()
        pressure, volume, _ = self.gas_state()
        return Frame(
            self.time,
            done,
            dt,
            wall,
            self._plane_force.copy(),
            self._collider_force.copy(),
            pressure,
            volume,
            energies,
            com,
            vcom,
            refinements,
        )

    def _blow_up(self, status: int, dt: float, energies: dict | None) -> BlowUpError | None:
        """The guard's verdict on the frame just stepped at ``dt`` [s]: a :class:`BlowUpError` to
        raise (a failed substep, or the total energy grown past its bound), or None."""
        o = self._out
        if status != K.OK:
            reason = "not finite" if status == K.NOT_FINITE else "tunnelled"
            detail = (
                "a force or the volume became NaN/inf"
                if status == K.NOT_FINITE
                else f"a vertex is {o[6]:.3g} m behind a plane (tunnel depth {self.tunnel_depth:.3g} m)"
            )
            return BlowUpError(
                f"realtime step blew up at t = {self.time:.6g} s ({reason}: {detail}) with Δt = {dt:.3g} s. "
                f"Fix: step at or below the stable Δt {self.stable.dt_s:.3g} s, or lower the contact stiffness.",
                reason=reason,
                time_s=self.time,
                dt_s=dt,
            )
        growth = energies["total"] - self._energy_start - self.collider_work
        if not math.isfinite(energies["kinetic"]) or growth > self.energy_growth * self._energy_scale:
            return BlowUpError(
                f"realtime step blew up at t = {self.time:.6g} s (energy growth: the total energy rose by "
                f"{growth:.3g} J, past the bound {self.energy_growth * self._energy_scale:.3g} J) with Δt = {dt:.3g} s. "
                f"Fix: step at or below the stable Δt {self.stable.dt_s:.3g} s.",
                reason="energy growth",
                time_s=self.time,
                dt_s=dt,
            )
        return None

    def run(self, duration: float, frame_dt: float = 1.0 / 60.0, substeps: int | None = None) -> dict:
        """Frames over ``duration`` [s]: a dict of per-frame arrays (time_s, wall_s, com_m, ...)."""
        duration = _check("duration [s]", duration)
        frames = [self.frame(frame_dt, substeps) for _ in range(max(1, round(duration / frame_dt)))]
        out = {
            "time_s": np.array([f.time_s for f in frames]),
            "wall_s": np.array([f.wall_s for f in frames]),
            "substeps": np.array([f.substeps for f in frames]),
            "com_m": np.array([f.com_m for f in frames]),
            "com_velocity_m_per_s": np.array([f.com_velocity_m_per_s for f in frames]),
            "plane_forces_N": np.array([f.plane_forces_N for f in frames]),
            "collider_force_N": np.array([f.collider_force_N for f in frames]),
            "gauge_pressure_Pa": np.array([f.gauge_pressure_Pa for f in frames]),
            "volume_m3": np.array([f.volume_m3 for f in frames]),
            "total_energy_J": np.array([f.energies_J["total"] for f in frames]),
        }
        return out
