"""The real-time shell: explicit velocity-Verlet stepping of the 3D engine's physics (SI units).

A :class:`RealtimeShell` holds the state (positions x (V, 3) [m], velocities v (V, 3) [m/s]) and
the constant data of one object, as the named structures the kernels take (:mod:`._parts`): the
rest ``geometry`` of :mod:`shelljax.shell3d` (rest metric, curvature and area per face), the
``body`` (the lumped vertex masses [kg] of :func:`shelljax.dynamics.shell_system`, the mass spread
by rest area, and gravity), the ``material`` (from the ``properties``: E [Pa], ν [-], h [m]; the
gas law and its reference volume) and the ``contact`` (the planes, the per-vertex springs and a
moving collider: sphere or capsule, the user's hand).

Each substep (velocity Verlet, symplectic and second order, Δt [s]):

    F(x, v) = −∇(E_membrane + E_bending)(x) + P(V) ∂V/∂x + m g + F_contact(x, v)
    v ← v + Δt/2 M⁻¹F;  x ← x + Δt v;  F ← F(x, v);  v ← v + Δt/2 M⁻¹F

``frame(dt_frame)`` runs ⌈dt_frame / Δt_stable⌉ substeps of equal length in one compiled call.
The stable Δt is estimated when the object loads (:meth:`RealtimeShell.stable_dt_estimate`), and
every frame is checked by the blow-up guard (:class:`BlowUpError`).
"""

from __future__ import annotations

import math
import time as _time

import numpy as np

from .._errors import InvalidInputError
from ..physics import ATMOSPHERIC_PRESSURE, AdiabaticGas, ShellProperties, bending_stiffness
from . import _kernels as K
from . import _loading
from ._checks import _check
from ._contact import mass_sum, plane_clamps, planes_energy
from ._elastic import elastic_forces_parallel, elastic_forces_serial
from ._embedding import DisplayEmbedding
from ._errors import BlowUpError
from ._parts import Body, Buffers, Contact, Geometry, Material, planes_table
from ._records import Collider, Frame, RealtimeOptions, RestShape
from ._stable import CONTACT_FRACTION, StableStep, element_steps, largest_frequency, stable_step

__all__ = ["RealtimeShell"]


def _material(properties: ShellProperties, gas, reference_volume, atmospheric_pressure, bending):
    """The kernels' :class:`Material` from the checked ``properties`` and the gas law (the reference
    volume [m³] is set once the volume is known)."""
    if type(gas) not in K.GAS_CODES:
        laws = ", ".join(f"physics.{law.__name__}" for law in K.GAS_CODES)
        raise InvalidInputError(f"gas: expected one of {laws}; got {gas!r}.")
    if not isinstance(properties, ShellProperties):
        raise InvalidInputError(f"properties: expected a physics.ShellProperties; got {type(properties).__name__}.")
    e = _check("properties.young_modulus [Pa]", properties.young_modulus)
    nu = _check("properties.poisson_ratio [-]", properties.poisson_ratio, positive=False)
    if not nu < 0.5:
        raise InvalidInputError(f"properties.poisson_ratio [-]: must be in [0, 0.5); got {properties.poisson_ratio!r}.")
    return Material(
        thickness=_check("properties.thickness [m]", properties.thickness),
        alpha=e * nu / (1.0 - nu**2),
        beta=e / (2.0 * (1.0 + nu)),
        bending=bool(bending),
        gas_law=K.GAS_CODES[type(gas)],
        gauge_pressure=_check("properties.gauge_pressure [Pa]", properties.gauge_pressure, positive=False),
        reference_volume=math.nan if reference_volume is None else reference_volume,
        atmospheric_pressure=_check("atmospheric_pressure [Pa]", atmospheric_pressure),
        heat_capacity_ratio=float(gas.exponent),  # read by the adiabatic law's kernel only
    )


def _geometry(rest: RestShape) -> Geometry:
    """The kernels' :class:`Geometry`: the stencils, the faces, the rest geometry per face and the
    vertex → face-slot incidence (CSR)."""
    stencil = np.ascontiguousarray(rest.stencil, dtype=np.int64)
    n_faces = stencil.shape[0]
    inv = np.linalg.inv(np.asarray(rest.rest_metric, dtype=float).reshape(n_faces, 2, 2))
    curvature = np.asarray(rest.rest_curvature, dtype=float).reshape(n_faces, 2, 2)
    vertex_area = np.ascontiguousarray(rest.vertex_area, dtype=float).reshape(-1)
    slots = stencil.ravel()
    order = np.argsort(slots, kind="stable")
    return Geometry(
        stencil=stencil,
        faces=np.ascontiguousarray(stencil[:, :3]),
        rest_inv=np.ascontiguousarray(np.stack([inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]], axis=1)),
        rest_b=np.ascontiguousarray(np.stack([curvature[:, 0, 0], curvature[:, 0, 1], curvature[:, 1, 1]], axis=1)),
        rest_area=np.ascontiguousarray(rest.rest_area, dtype=float).reshape(n_faces),
        vertex_area=vertex_area,
        mean_area=float(vertex_area.mean()),
        incidence_ptr=np.concatenate([[0], np.cumsum(np.bincount(slots, minlength=vertex_area.shape[0]))]).astype(
            np.int64
        ),
        incidence=np.ascontiguousarray(order.astype(np.int64)),
    )


def _body(positions, masses, gravity) -> tuple[np.ndarray, Body]:
    """The positions (V, 3) [m] and the :class:`Body` (vertex masses [kg], gravity [m/s²]), checked."""
    x = np.array(positions, dtype=float).reshape(-1, 3)
    n = x.shape[0]
    if not np.all(np.isfinite(x)):
        raise InvalidInputError("positions [m]: contain NaN or inf.")
    masses = np.ascontiguousarray(masses, dtype=float).reshape(-1)
    if masses.shape != (n,) or not np.all(np.isfinite(masses)) or np.any(masses <= 0):
        raise InvalidInputError(f"masses [kg]: expected {n} positive vertex masses; got shape {masses.shape}.")
    g = np.asarray(gravity, dtype=float)
    g = np.array([0.0, 0.0, -float(g)]) if g.ndim == 0 else g.reshape(3).copy()
    if not np.all(np.isfinite(g)):
        raise InvalidInputError(f"gravity [m/s²]: must be finite; got {gravity!r}.")
    return x, Body(masses=masses, gravity=g, total_mass=float(mass_sum(masses)))


class RealtimeShell:
    """A shell stepped explicitly in real time; see the module docstring.

    Build one with :meth:`from_system` (a :class:`shelljax.dynamics.ShellDynamicSystem`: the same
    rest geometry, masses and gas as the implicit reference), :meth:`ball`, :meth:`from_shell`,
    :meth:`from_session` or :meth:`from_replica`.

    Arguments: the :class:`RestShape` ``rest``, the ``properties`` (a ``physics.ShellProperties``:
    P_g [Pa] (prescribed, or the sealed gas's at ``reference_volume`` [m³]), E [Pa], h [m], ν [-]),
    ``positions`` (V, 3) [m] (the start, e.g. the inflated equilibrium), ``masses`` (V,) [kg],
    ``gas`` (a ``physics.PrescribedGas``, ``IsothermalGas`` or ``AdiabaticGas``, with its γ [-]),
    ``atmospheric_pressure`` [Pa], ``planes`` (``physics.Plane``s or scenario plane specs: point,
    normal, friction μ, damping c [N·s/m], the centre-of-mass dashpot of the reference) and the
    :class:`RealtimeOptions` ``options``.

    State: ``x``, ``v`` (V, 3) [m], [m/s], ``time`` [s], ``collider_work`` [J] (the collider's
    work on the shell since the energy reference), ``stable`` (:class:`StableStep`) and
    ``omega_internal`` [rad/s]; constant: ``properties``, ``gas``, ``options``, ``geometry``,
    ``body``, ``material``, ``contact`` (its planes and collider replaced by :meth:`set_planes`,
    :meth:`set_collider`), ``plane_names``, ``mean_edge`` [m].
    """

    from_system = classmethod(_loading.from_system)
    from_shell = classmethod(_loading.from_shell)
    ball = classmethod(_loading.ball)
    from_session = classmethod(_loading.from_session)
    from_replica = classmethod(_loading.from_replica)

    def __init__(
        self,
        rest: RestShape,
        properties: ShellProperties,
        *,
        positions,
        masses,
        gas=AdiabaticGas(),
        reference_volume=None,
        atmospheric_pressure=ATMOSPHERIC_PRESSURE,
        planes=(),
        options: RealtimeOptions = RealtimeOptions(),
    ):
        o = options
        self.options = o
        self.gas = gas
        self.properties = properties
        self.material = _material(properties, gas, None, atmospheric_pressure, o.bending)
        self.geometry = _geometry(rest)
        self.x, self.body = _body(positions, masses, o.gravity)
        self.v = np.zeros_like(self.x)
        _check("slip_velocity [m/s]", o.slip_velocity)
        _check("safety [-]", o.safety)
        _check("energy_growth [-]", o.energy_growth)
        if (
            isinstance(o.max_refinements, bool)
            or not isinstance(o.max_refinements, (int, np.integer))
            or o.max_refinements < 0
        ):
            raise InvalidInputError(
                f"max_refinements: expected an integer ≥ 0 (0: no redone frames); got {o.max_refinements!r}."
            )
        if o.dt_method not in ("spectral", "element"):
            raise InvalidInputError(f"dt_method: expected 'spectral' or 'element'; got {o.dt_method!r}.")
        planes, self.plane_names = planes_table(planes, float(o.slip_velocity))
        volume = K.volume_and_gradient(self.x, self.geometry.faces, np.zeros_like(self.x))
        if gas.sealed and reference_volume is not None:
            volume = _check("reference_volume [m³]", reference_volume)
        self.material = self.material._replace(reference_volume=volume)
        faces = self.geometry.faces
        self.mean_edge = float(np.linalg.norm(self.x[faces[:, [1, 2, 0]]] - self.x[faces], axis=2).mean())
        self.omega_internal = self._internal_frequency()
        self.contact = self._contact(planes, o)
        self._buffers = Buffers(
            force=np.zeros_like(self.x),
            volume_gradient=np.zeros_like(self.x),
            face_grad=np.zeros((faces.shape[0], 6, 3)),
            face_energy=np.zeros(faces.shape[0]),
            plane_force=np.zeros((planes.count, 3)),
            collider_force=np.zeros(3),
            out=np.zeros(8),
            parallel=bool(o.parallel),
        )
        self.stable = self.stable_dt_estimate()
        self.time = 0.0
        self.collider_work = 0.0
        self._energy_scale = None
        self._energy_start = None

    def _contact(self, planes, o: RealtimeOptions) -> Contact:
        """The contact springs k_i [N/m] and dampers c_i [N·s/m], the planes' clamps, no collider."""
        masses = self.body.masses
        if o.contact_stiffness is None:
            k_contact = CONTACT_FRACTION * masses * self.omega_internal**2
        else:
            k_contact = np.full(self.x.shape[0], _check("contact_stiffness [N/m]", o.contact_stiffness))
        zeta = _check("contact_damping_ratio [-]", o.contact_damping_ratio, positive=False)
        tunnel = 0.5 * self.mean_edge if o.tunnel_depth is None else _check("tunnel_depth [m]", o.tunnel_depth)
        return Contact(
            planes=planes,
            clamps=plane_clamps(planes, k_contact),
            stiffness=k_contact,
            damping=2.0 * zeta * np.sqrt(k_contact * masses),
            collider=np.zeros(11),  # radius 0: none
            valence=np.bincount(self.geometry.faces.ravel(), minlength=masses.shape[0]).astype(float),
            tunnel_depth=tunnel,
        )

    # ------------------------------------------------------------------ stable Δt
    def _element_steps(self) -> tuple[float, float, float]:
        p = self.properties
        b = bending_stiffness(float(p.young_modulus), self.material.thickness, float(p.poisson_ratio))
        return element_steps(self.x, self.geometry.faces, self.body.masses, self.geometry.vertex_area, self.material, b)

    def _internal_frequency(self) -> float:
        """ω_max [rad/s] of the elastic and gas forces now, by the shell's ``dt_method``."""
        if self.options.dt_method == "spectral":
            return largest_frequency(self.internal_forces, self.x, self.body.masses, self.mean_edge)
        return 2.0 / self._element_steps()[2]

    def reestimate_dt(self) -> StableStep:
        """Re-estimate the stable Δt at the current positions (``dt_method``; contact springs kept)."""
        self.omega_internal = self._internal_frequency()
        self.stable = self.stable_dt_estimate()
        return self.stable

    def stable_dt_estimate(self, safety=None) -> StableStep:
        """The stable substep [s]: see :class:`StableStep`."""
        contact_omega2 = float(np.max(self.contact.stiffness / self.body.masses))
        s = self.options.safety if safety is None else safety
        return stable_step(self._element_steps(), self.omega_internal, contact_omega2, self.options.dt_method, s)

    # ------------------------------------------------------------------ forces and energies
    def elastic_forces(self, x=None, *, parallel=False, with_energy=True, out=None) -> tuple[float, np.ndarray]:
        """(membrane + bending energy [J], −∇ of it (V, 3) [N]) at x [m] (default: the state), by the
        serial kernel or (``parallel``) the threaded one; the energy is 0 unless ``with_energy``;
        ``out`` (V, 3) float64, C-contiguous: the force's buffer (default: a new array)."""
        x = self.x if x is None else np.ascontiguousarray(x, dtype=float).reshape(-1, 3)
        force = np.zeros_like(x) if out is None else out
        if parallel:
            b = self._buffers
            e = elastic_forces_parallel(x, self.geometry, self.material, force, b.face_grad, b.face_energy, with_energy)
        else:
            e = elastic_forces_serial(x, self.geometry, self.material, force, with_energy)
        return e, force

    def gas_state(self, x=None) -> tuple[float, float, np.ndarray]:
        """(gauge pressure [Pa], volume [m³], pressure force P ∂V/∂x (V, 3) [N]) at x [m]."""
        x = self.x if x is None else np.ascontiguousarray(x, dtype=float).reshape(-1, 3)
        grad = np.zeros_like(x)
        vol = K.volume_and_gradient(x, self.geometry.faces, grad)
        pressure, _ = K.gas_pressure_energy(vol, self.material)
        return float(pressure), float(vol), pressure * grad

    def internal_forces(self, x) -> np.ndarray:
        """Elastic + gas forces (V, 3) [N] at x [m] (no gravity, no contact)."""
        _, f = self.elastic_forces(x)
        return f + self.gas_state(x)[2]

    def energies(self) -> dict:
        """Kinetic, elastic, gas, gravity and plane-contact energies and their total [J] now."""
        e_el, _ = self.elastic_forces()
        vol = K.volume_and_gradient(self.x, self.geometry.faces, np.zeros_like(self.x))
        _, e_gas = K.gas_pressure_energy(vol, self.material)
        c = self.contact
        out = {
            "kinetic": float(K.kinetic_energy(self.v, self.body.masses)),
            "elastic": float(e_el),
            "gas": float(e_gas),
            "gravity": float(-np.sum(self.body.masses * (self.x @ self.body.gravity))),
            "contact": float(planes_energy(self.x, c.planes, c.clamps, c.stiffness)),
        }
        out["total"] = sum(out.values())
        return out

    @property
    def total_mass(self) -> float:
        """Mass [kg]."""
        return float(self.body.masses.sum())

    def com(self) -> tuple[np.ndarray, np.ndarray]:
        """Centre of mass (3,) [m] and its velocity (3,) [m/s]."""
        m = self.body.masses[:, None]
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
        planes = self.contact.planes
        if planes.count <= plane:
            raise InvalidInputError(f"plane: no plane {plane} to drop onto ({planes.count} planes); add the ground.")
        point, normal = planes.point[plane], planes.normal[plane]
        x = self.x.copy()
        if centre_xy is not None:
            com, _ = self.com()
            x[:, :2] += np.asarray(centre_xy, dtype=float) - com[:2]
        gap = (x - point) @ normal
        x += (h - gap.min()) * normal
        self.set_state(x, np.asarray(velocity, dtype=float))

    def embed(self, vertices, faces=None) -> DisplayEmbedding:
        """A finer display mesh (``vertices`` (N, 3) [m] in the shell's current frame, e.g. the
        scan at the inflated state; optional ``faces`` (M, 3)) embedded on this simulation mesh at
        its current positions: ``.positions(shell.x)`` places it each frame (:class:`DisplayEmbedding`)."""
        return DisplayEmbedding(self.x, self.geometry.faces, vertices, faces)

    def set_collider(self, collider: Collider | None) -> None:
        """Place (or remove, None) the moving collider for the next frames; it then moves with its
        velocity (``self.contact.collider`` holds its current segment ends [m])."""
        packed = np.zeros(11) if collider is None else collider.packed()
        self.contact = self.contact._replace(collider=packed)

    def set_planes(self, planes) -> None:
        """Replace the planes (``physics.Plane``s or scenario plane specs, as the constructor's
        ``planes``; () for none) for the next frames; the contact springs are kept."""
        table, self.plane_names = planes_table(planes, float(self.options.slip_velocity))
        self.contact = self.contact._replace(planes=table, clamps=plane_clamps(table, self.contact.stiffness))
        self._buffers = self._buffers._replace(plane_force=np.zeros((table.count, 3)))

    # ------------------------------------------------------------------ stepping
    def substeps_for(self, frame_dt: float) -> int:
        """Substeps of one frame of ``frame_dt`` [s]: ⌈frame_dt / Δt_stable⌉."""
        return max(1, math.ceil(frame_dt / self.stable.dt_s - 1e-12))

    def _scale(self) -> float:
        size = float(np.ptp(self.x, axis=0).max())
        e = self.energies()
        return (
            self.total_mass * float(np.linalg.norm(self.body.gravity)) * size + e["kinetic"] + abs(e["elastic"]) + 1e-12
        )

    def advance(self, n_substeps: int, dt: float, velocity_decay: float = 1.0) -> tuple[int, int]:
        """Run ``n_substeps`` of ``dt`` [s] (no guard on energy); returns (status, substeps done)."""
        c = self.contact
        status, done = K.advance(
            self.x,
            self.v,
            int(n_substeps),
            float(dt),
            float(velocity_decay),
            self.body,
            self.geometry,
            self.material,
            c,
            self._buffers,
        )
        self.time += done * dt
        if c.collider[6] > 0.0:  # the collider's work on the shell [J]: its force on it × its velocity
            self.collider_work += float(self._buffers.collider_force @ c.collider[7:10]) * done * dt
        return int(status), int(done)

    def contact_forces(self) -> tuple[np.ndarray, np.ndarray]:
        """The contact forces on the shell now, without stepping: per plane (P, 3) [N] and the
        collider's (3,) [N] (e.g. a static reading after :meth:`relax`)."""
        self.advance(0, self.stable.dt_s)  # zero substeps: the forces at the current state only
        return self._buffers.plane_force.copy(), self._buffers.collider_force.copy()

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
        kinetic = float(K.kinetic_energy(self.v, self.body.masses))
        self.reestimate_dt()
        self.v[:] = 0.0
        self.time = 0.0
        self._energy_start = None
        return kinetic

    def frame(self, frame_dt: float = 1.0 / 60.0, substeps: int | None = None) -> Frame:
        """Advance one frame of ``frame_dt`` [s] in ``substeps`` equal substeps (default
        :meth:`substeps_for`). A frame that trips the guard is redone from its start with twice the
        substeps, up to the options' ``max_refinements`` times (``Frame.refinements`` says how often); then
        :class:`BlowUpError` is raised."""
        frame_dt = _check("frame_dt [s]", frame_dt)
        n = self.substeps_for(frame_dt) if substeps is None else int(_check("substeps", substeps))
        if self._energy_start is None:
            self._energy_start = self.energies()["total"]
            self._energy_scale = self._scale()
        collider = self.contact.collider
        saved = (self.x.copy(), self.v.copy(), collider.copy(), self.time, self.collider_work)
        start = _time.perf_counter()
        for refinements in range(self.options.max_refinements + 1):
            if refinements:
                x, v, start_collider, self.time, self.collider_work = saved
                self.x[:], self.v[:], collider[:] = x, v, start_collider
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
            self._buffers.plane_force.copy(),
            self._buffers.collider_force.copy(),
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
        o = self._buffers.out
        if status != K.OK:
            reason = "not finite" if status == K.NOT_FINITE else "tunnelled"
            detail = (
                "a force or the volume became NaN/inf"
                if status == K.NOT_FINITE
                else f"a vertex is {o[6]:.3g} m behind a plane (tunnel depth {self.contact.tunnel_depth:.3g} m)"
            )
            return BlowUpError(
                f"realtime step blew up at t = {self.time:.6g} s ({reason}: {detail}) with Δt = {dt:.3g} s. "
                f"Fix: step at or below the stable Δt {self.stable.dt_s:.3g} s, or lower the contact stiffness.",
                reason=reason,
                time_s=self.time,
                dt_s=dt,
            )
        growth = energies["total"] - self._energy_start - self.collider_work
        if not math.isfinite(energies["kinetic"]) or growth > self.options.energy_growth * self._energy_scale:
            return BlowUpError(
                f"realtime step blew up at t = {self.time:.6g} s (energy growth: the total energy rose by "
                f"{growth:.3g} J, past the bound {self.options.energy_growth * self._energy_scale:.3g} J) with Δt = {dt:.3g} s. "
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
