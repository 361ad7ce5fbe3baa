"""Static setup of a shell model (hashable: part of the jit key) and the layout of its unknowns."""

from __future__ import annotations

import dataclasses
import math

from .._errors import InvalidInputError
from ..physics import AbstractGasLaw, Plane, PrescribedGas

#: Default friction slip tolerance ε = ĝ/100: well below the slip friction is meant to stop
#: (docs/shell3d.md, *Model*, ground friction).
FRICTION_SLIP_FRACTION = 0.01


def _as_float(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def _static_plane(plane, index: int) -> Plane:
    """``plane`` as a :class:`Plane` of the static setup (a (point, normal) pair becomes one)."""
    if not isinstance(plane, Plane):
        point, normal = plane
        plane = Plane(point, normal, name="ground" if index == 0 else f"plane {index}")
    own = plane.law is not None or float(plane.friction) != 0.0 or float(plane.damping) != 0.0
    if own:
        raise InvalidInputError(
            f"planes[{index}] ({plane.name!r}) has its own contact law, friction or damping; the 3D engine's "
            "planes take theirs from ContactConfig (kind, friction): give the plane's point and normal only."
        )
    return plane


@dataclasses.dataclass(frozen=True)
class ContactConfig:
    """Static contact setup (hashable; part of the jit key).

    ``indenter_radius`` [m] or None; ``planes``: tuple of :class:`shelljax.physics.Plane` (or of
    (point (3,) [m], unit normal (3,)) pairs, made planes) without a law, friction or damping of
    their own: this setup's ``kind`` and ``friction`` apply to all of them;
    ``kind``: "barrier" (IPC log barrier, no penetration, surface stops within
    ``activation_distance`` ĝ [m] of the body) or "penalty" (quadratic; a vertex pressed by the
    reference pressure penetrates by ``activation_distance``).

    ``friction`` μ [-] ≥ 0: Coulomb coefficient between the shell and the planes (0: frictionless,
    the default; the indenter stays frictionless). ``slip_tolerance`` ε [m] > 0: slip below which a
    vertex counts as sticking (None: ``FRICTION_SLIP_FRACTION`` × ``activation_distance``, see
    :attr:`friction_slip_tolerance`). With μ = 0, ε is dropped so that every frictionless config
    compares (and hashes, i.e. jit-keys) equal to the one without friction fields set.
    """

    indenter_radius: float | None = None
    planes: tuple = ()
    kind: str = "barrier"
    activation_distance: float = 2e-4
    reference_pressure: float = 1e3
    friction: float = 0.0
    slip_tolerance: float | None = None

    def __post_init__(self):
        mu = _as_float(self.friction)
        if not (math.isfinite(mu) and mu >= 0):
            raise InvalidInputError(
                f"friction: the Coulomb coefficient μ must be a finite number ≥ 0, got {self.friction!r}; "
                "use 0 for frictionless contact."
            )
        eps = None if self.slip_tolerance is None else _as_float(self.slip_tolerance)
        if eps is not None and not (math.isfinite(eps) and eps > 0):
            raise InvalidInputError(
                f"slip_tolerance: must be a positive length in m, got {self.slip_tolerance!r}; use None for the "
                f"default {FRICTION_SLIP_FRACTION} × activation_distance."
            )
        object.__setattr__(self, "friction", mu)
        object.__setattr__(self, "slip_tolerance", None if mu == 0 else eps)
        object.__setattr__(self, "planes", tuple(_static_plane(p, i) for i, p in enumerate(self.planes)))

    @property
    def has_friction(self) -> bool:
        """Whether the plane contacts carry friction (μ > 0 and at least one plane)."""
        return self.friction > 0 and bool(self.planes)

    @property
    def friction_slip_tolerance(self) -> float:
        """Slip tolerance ε [m] of the friction mollifier (explicit or the default)."""
        if self.slip_tolerance is not None:
            return self.slip_tolerance
        return FRICTION_SLIP_FRACTION * self.activation_distance


@dataclasses.dataclass(frozen=True)
class ModelConfig:
    """Static model setup (hashable; the jit key): vertex count, gas law (a
    ``physics.AbstractGasLaw``, e.g. ``PrescribedGas()``, ``IsothermalGas()`` or ``AdiabaticGas(γ)``),
    contacts, and whether the indenter height is an unknown under a prescribed force (force control)."""

    n_vertices: int
    gas: AbstractGasLaw = PrescribedGas()
    contact: ContactConfig = ContactConfig()
    force_control: bool = False


def split_dofs(q, config: ModelConfig):
    """(vertex positions (V, 3), indenter center (3,)) [m] of the unknowns q (3V + 3,)."""
    n3 = 3 * config.n_vertices
    return q[:n3].reshape(-1, 3), q[n3:]


def jit_config(config: ModelConfig) -> ModelConfig:
    """``config`` with μ > 0 normalised to 1 (μ then travels in ``params``): the compile key."""
    if not config.contact.has_friction:
        return config
    contact = dataclasses.replace(config.contact, friction=1.0, slip_tolerance=config.contact.friction_slip_tolerance)
    return dataclasses.replace(config, contact=contact)


def check_config(config: ModelConfig) -> None:
    """Raise InvalidInputError for a gas that is no gas law or an unknown contact kind."""
    if not isinstance(config.gas, AbstractGasLaw):
        raise InvalidInputError(
            f"gas: {config.gas!r} is no gas law. Fix: pass a physics.AbstractGasLaw, e.g. physics.IsothermalGas()"
        )
    if config.contact.kind not in ("barrier", "penalty"):
        raise InvalidInputError(f"contact: unknown kind {config.contact.kind!r}; use 'barrier' or 'penalty'.")
