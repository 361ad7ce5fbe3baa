"""The real-time runtime's records: what a :class:`RealtimeShell` is built from (its
:class:`RestShape` and :class:`RealtimeOptions`), the moving :class:`Collider` and what one
:class:`Frame` did (SI units)."""

from __future__ import annotations

import dataclasses

import numpy as np

from .._errors import InvalidInputError
from ..physics import STANDARD_GRAVITY

#: Default safety factor on the stable Δt [-].
SAFETY = 0.9


@dataclasses.dataclass(frozen=True)
class RestShape:
    """The mesh at rest, as :mod:`shelljax.shell3d` describes it: ``stencil`` (F, 6) int (face,
    then its flap vertices), ``rest_metric`` (F, 2, 2) [m²], ``rest_curvature`` (F, 2, 2) [m],
    ``rest_area`` (F,) [m²] and ``vertex_area`` (V,) [m²]."""

    stencil: np.ndarray
    rest_metric: np.ndarray
    rest_curvature: np.ndarray
    rest_area: np.ndarray
    vertex_area: np.ndarray


@dataclasses.dataclass(frozen=True)
class RealtimeOptions:
    """How a :class:`RealtimeShell` steps: ``gravity`` [m/s²] (g down, or a 3-vector),
    ``contact_stiffness`` k [N/m] per vertex (default: k_i = 0.25 m_i ω_max², ω_max the stiffest
    internal mode: it shortens the stable Δt by 11 %), ``contact_damping_ratio`` ζ [-] of each
    vertex's normal damper c_i = 2ζ√(k m_i) (default 0: the plane's ``damping`` c, the
    centre-of-mass dashpot, is the physical dissipation, as in the reference), ``slip_velocity``
    v_ε [m/s] of the regularised Coulomb friction, ``safety`` [-] on the stable Δt, ``bending``
    (False: membrane only), ``parallel`` (Numba threads over faces), ``tunnel_depth`` [m] (a vertex
    deeper behind a plane is a blow-up; default half the mean edge), ``energy_growth`` [-] (the
    guard's bound on the growth of the total energy, as a fraction of the energy scale
    m g L + kinetic + elastic, L the object's size), ``max_refinements`` (a frame that trips the
    guard is redone from its start at half the substep, up to this many times, before
    :class:`BlowUpError` is raised: a hard impact can stiffen the shell past the stable Δt
    estimated at rest; 0: raise at once) and ``dt_method`` (``"spectral"``: Lanczos on the
    stiffness, or ``"element"``: the stiffest element's bounds)."""

    gravity: float | tuple = STANDARD_GRAVITY
    contact_stiffness: float | None = None
    contact_damping_ratio: float = 0.0
    slip_velocity: float = 1e-2
    safety: float = SAFETY
    bending: bool = True
    parallel: bool = False
    tunnel_depth: float | None = None
    energy_growth: float = 0.5
    max_refinements: int = 3
    dt_method: str = "spectral"

    @classmethod
    def of(cls, options: dict) -> RealtimeOptions:
        """The options from keywords (a constructor's ``**options``), each name checked."""
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(options) - set(names))
        if unknown:
            raise InvalidInputError(f"{unknown[0]}: not an option of the realtime shell; expected one of {names}.")
        return cls(**options)


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
