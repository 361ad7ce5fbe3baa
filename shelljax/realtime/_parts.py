"""The named structures the real-time kernels receive (Numba-compatible named tuples of float64
and int64 arrays and scalars, SI units): the mesh's :class:`Geometry`, the :class:`Body`'s masses
and gravity, the wall's and gas's :class:`Material`, the :class:`Contact` (its :class:`Planes`,
per-vertex springs and the collider) and the work :class:`Buffers`. :class:`RealtimeShell` builds
them once; a kernel takes a few of them instead of dozens of loose arrays."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._errors import InvalidInputError
from ._checks import _check


class Planes(NamedTuple):
    """P rigid planes, one row each: ``point`` (P, 3) [m], unit ``normal`` (P, 3), Coulomb
    ``friction`` μ (P,) [-], ``slip_velocity`` v_ε (P,) [m/s] of the regularised friction, the
    centre-of-mass dashpot's ``damping`` c (P,) [N·s/m], the IPC barrier's ``barrier_reach`` ĝ (P,)
    [m] and ``barrier_stiffness`` κ (P,) [J/m²] (0, 0: a spring behind the plane)."""

    point: np.ndarray
    normal: np.ndarray
    friction: np.ndarray
    slip_velocity: np.ndarray
    damping: np.ndarray
    barrier_reach: np.ndarray
    barrier_stiffness: np.ndarray

    @property
    def count(self) -> int:
        """P, the number of planes."""
        return self.point.shape[0]


class Geometry(NamedTuple):
    """The mesh and its rest state: ``stencil`` (F, 6) int (face, then its flap vertices), ``faces``
    (F, 3) int, the rest metric's inverse ``rest_inv`` (F, 3) [1/m²] and curvature ``rest_b`` (F, 3)
    [m] (entries 00, 01, 11), ``rest_area`` (F,) [m²], ``vertex_area`` (V,) [m²] and its mean
    ``mean_area`` [m²], and the vertex → face-slot incidence (CSR ``incidence_ptr`` (V + 1,),
    ``incidence`` (6F,) = 6 f + k) the threaded kernel gathers with."""

    stencil: np.ndarray
    faces: np.ndarray
    rest_inv: np.ndarray
    rest_b: np.ndarray
    rest_area: np.ndarray
    vertex_area: np.ndarray
    mean_area: float
    incidence_ptr: np.ndarray
    incidence: np.ndarray


class Body(NamedTuple):
    """The lumped vertex ``masses`` (V,) [kg], the ``gravity`` vector (3,) [m/s²] and the
    ``total_mass`` [kg] (``_contact.mass_sum`` of the masses)."""

    masses: np.ndarray
    gravity: np.ndarray
    total_mass: float


class Material(NamedTuple):
    """The wall and the gas: ``thickness`` h [m], the Lamé-like ``alpha`` = Eν/(1 − ν²) and ``beta``
    = E/(2(1 + ν)) [Pa], ``bending`` (False: membrane only), the gas law's kernel code
    ``gas_law``, ``gauge_pressure`` [Pa] (prescribed, or at ``reference_volume`` [m³]),
    ``atmospheric_pressure`` [Pa] and ``heat_capacity_ratio`` γ [-]."""

    thickness: float
    alpha: float
    beta: float
    bending: bool
    gas_law: int
    gauge_pressure: float
    reference_volume: float
    atmospheric_pressure: float
    heat_capacity_ratio: float


class Contact(NamedTuple):
    """The contacts: the :class:`Planes`, their ``clamps`` (P, V, 3) (``_contact.plane_clamps``), the
    per-vertex spring ``stiffness`` k (V,) [N/m] and normal ``damping`` c (V,) [N·s/m], the
    ``collider`` (11,) (segment ends a, b [m], radius [m] (0: none), velocity (3) [m/s], μ [-];
    moved in place as it travels; felt by the vertices and, as a backstop, the triangles, :mod:`._hand`), the ``valence``
    (V,) [-] (faces around each vertex, which share its spring in the collider's contact), and the
    ``tunnel_depth`` [m] past which a vertex behind a plane is a blow-up."""

    planes: Planes
    clamps: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    collider: np.ndarray
    valence: np.ndarray
    tunnel_depth: float


class Buffers(NamedTuple):
    """The kernels' work arrays, overwritten each force evaluation: ``force`` (V, 3) [N],
    ``volume_gradient`` (V, 3) [m²], the threaded kernel's ``face_grad`` (F, 6, 3) [N] and
    ``face_energy`` (F,) [J], ``plane_force`` (P, 3) and ``collider_force`` (3,) [N], ``out`` (8,)
    (see ``_kernels.advance``), and ``parallel`` (Numba threads over faces)."""

    force: np.ndarray
    volume_gradient: np.ndarray
    face_grad: np.ndarray
    face_energy: np.ndarray
    plane_force: np.ndarray
    collider_force: np.ndarray
    out: np.ndarray
    parallel: bool


def _barrier(plane) -> tuple[float, float]:
    """(ĝ [m], κ [J/m²]) of a plane's IPC log barrier (a ``dynamics.BarrierContact`` law or a scenario
    PlaneSpec's), or (0, 0) for a plane without one (the runtime's penalty spring from g = 0)."""
    law = getattr(plane, "law", None)
    if law is not None and hasattr(law, "activation_distance") and hasattr(law, "stiffness"):
        return float(np.asarray(law.activation_distance)), float(np.asarray(law.stiffness))
    if hasattr(plane, "activation_distance") and hasattr(plane, "barrier_stiffness"):
        return float(plane.activation_distance), float(plane.barrier_stiffness)
    return 0.0, 0.0


def planes_table(planes, slip_velocity: float) -> tuple[Planes, tuple[str, ...]]:
    """The kernels' :class:`Planes` and the planes' names, from physics.Plane objects or scenario
    PlaneSpecs (point, normal, friction μ, damping c [N·s/m], an optional barrier); every plane's
    v_ε is ``slip_velocity`` [m/s]."""
    rows, names = [], []
    for i, p in enumerate(planes):
        point = np.asarray(p.point, dtype=float).reshape(-1)
        normal = np.asarray(p.normal, dtype=float).reshape(-1)
        name = str(getattr(p, "name", f"plane{i}"))
        if (
            point.shape != (3,)
            or normal.shape != (3,)
            or not np.all(np.isfinite(point))
            or not np.linalg.norm(normal) > 0
        ):
            raise InvalidInputError(
                f"planes[{i}] ({name!r}): point and normal must be finite 3-vectors, normal nonzero; "
                f"got point {point.tolist()}, normal {normal.tolist()}."
            )
        mu = _check(f"planes[{i}] ({name!r}).friction", np.asarray(getattr(p, "friction", 0.0)), positive=False)
        damping = _check(
            f"planes[{i}] ({name!r}).damping [N·s/m]", np.asarray(getattr(p, "damping", 0.0)), positive=False
        )
        reach, kappa = _barrier(p)
        _check(f"planes[{i}] ({name!r}) barrier activation distance ĝ [m]", reach, positive=False)
        _check(f"planes[{i}] ({name!r}) barrier stiffness κ [J/m²]", kappa, positive=reach > 0.0)
        rows.append([*point, *(normal / np.linalg.norm(normal)), mu, slip_velocity, damping, reach, kappa])
        names.append(name)
    table = np.asarray(rows, dtype=float).reshape(-1, 11)
    columns = (
        np.ascontiguousarray(table[:, 0:3]),
        np.ascontiguousarray(table[:, 3:6]),
        *(np.ascontiguousarray(table[:, c]) for c in range(6, 11)),
    )
    return Planes(*columns), tuple(names)
