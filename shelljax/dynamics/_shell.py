"""The 3D shell engine in motion: ``ShellDynamicSystem``, an ``AbstractDynamicSystem`` on its energies.

Degrees of freedom are the shell's vertex positions x (3V,) [m]. The internal energies are the
engine's own (:mod:`shelljax.shell3d`): Neo-Hookean membrane and bending relative to the rest
shape, the gas (prescribed gauge pressure, or a sealed ideal gas, isothermal or adiabatic, holding
P_g at the inflated volume), and gravity on the lumped vertex masses. Contact, damping and friction
are the dynamics core's planes, with every vertex a contact point.

``shell_system`` builds one from a :class:`shelljax.shell3d.Shell`: the rest shape comes from the
engine's rest-shape solve (:func:`shelljax.shell3d.inflated_reference`, in the mesh's own frame), so the
inflated shell ``inflated`` is in equilibrium at t = 0.

Prescribed motion: ``prescribed_vertices`` (static indices) follow ``prescribed``, a
:class:`PrescribedRotation` of their positions (e.g. a hand holding the hammer's handle and
swinging it); the integrator eliminates their degrees of freedom. ``with_prescribed`` sets both.

Contact damping is mesh independent: it is one dashpot c [N·s/m] on the centre of mass's velocity
along each plane's normal, the paper's 1-DOF dashpot, (c / 2Δt) W ((x_com − x_comⁿ)·n)², weighted
by W = min(1, Σⱼ wⱼ Aⱼ / Ā) from the vertices' lagged law weights wⱼ, rest areas Aⱼ and mean area
Ā: 0 off contact, 1 once about one vertex's area touches. A dashpot on the touching vertices
themselves would do nothing: held by the barrier, they hardly move along the normal.
"""

from __future__ import annotations

import dataclasses
import hashlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._errors import InvalidInputError
from ..physics import ATMOSPHERIC_PRESSURE, STANDARD_GRAVITY, AbstractGasLaw, IsothermalGas, ShellProperties
from ..shell3d import (
    ModelConfig,
    Shell,
    ShellGeometry,
    ShellMesh,
    ShellModel,
    ShellParams,
    elastic_energy,
    enclosed_volume,
    gas_energy,
    gas_rank_one,
    hessian_values,
    inflated_reference,
)
from ..physics import Plane
from ..physics.internal import check_positive
from ._system import AbstractDynamicSystem, PrescribedRotation, gravity_vector


def _pattern_key(pattern) -> int:
    """A key equal for equal patterns: systems on one mesh topology share the compiled step programs."""
    digest = hashlib.sha256()
    arrays = (
        pattern.indptr,
        pattern.indices,
        pattern.fixed_entries,
        pattern.fixed_diagonal,
        pattern.free,
        *(np.asarray(part) for pair in pattern.maps for part in pair),
    )
    for array in arrays:
        digest.update(f"{array.dtype}{array.shape}".encode() + np.ascontiguousarray(array).tobytes())
    return int.from_bytes(digest.digest()[:8], "little")


class KeyedPattern:
    """The host sparsity ``pattern`` of a shell's Hessian with its content ``key``: a system's
    static field, equal and hashed by the key, so systems on one mesh topology share the compiled
    step programs, and the host solve reads the pattern from the system it serves."""

    def __init__(self, pattern):
        self.pattern = pattern
        self.key = _pattern_key(pattern)

    def __eq__(self, other) -> bool:
        return isinstance(other, KeyedPattern) and other.key == self.key

    def __hash__(self) -> int:
        return hash(self.key)


class ShellDynamicSystem(AbstractDynamicSystem):
    """A closed Neo-Hookean shell with gas, gravity and planes (see the module docstring).

    ``params``: the engine's :class:`ShellParams` (E [Pa], ν, h [m], P_g [Pa], the sealed gas's
    reference volume [m³]); ``geometry``: rest data; ``config``: the engine's static setup (gas
    model, γ); ``node_masses`` (V,) [kg]; ``faces`` (F, 3); ``inflated`` (3V,) [m]: the pressurized
    equilibrium at rest; ``maps``, ``nnz``, ``sparsity``: the sparse Hessian's pattern;
    ``prescribed_vertices`` (static indices) and ``prescribed``: held vertices and their motion.
    """

    params: ShellParams
    geometry: ShellGeometry
    config: ModelConfig = eqx.field(static=True)
    node_masses: Float[Array, " V"]
    faces: Int[Array, "F 3"]
    inflated: Float[Array, " n"]
    planes: tuple[Plane, ...]
    gravity: Float[Array, "3"]
    maps: tuple
    nnz: int = eqx.field(static=True)
    sparsity: KeyedPattern = eqx.field(static=True)
    prescribed_vertices: tuple[int, ...] = eqx.field(static=True, default=())
    prescribed: PrescribedRotation | None = None

    def lumped_mass(self):
        return jnp.repeat(self.node_masses, 3)

    def _q(self, x):
        return jnp.concatenate([x, jnp.zeros(3, dtype=x.dtype)])

    def volume(self, x: Float[Array, " n"]) -> Float[Array, ""]:
        """Enclosed volume [m³] at positions x [m]."""
        return enclosed_volume(x.reshape(-1, 3), self.geometry.stencil)

    def internal_energies(self, x, t):
        nodes = x.reshape(-1, 3)
        return {
            "elastic": elastic_energy(nodes, self.params, self.geometry),
            "gas": gas_energy(self.volume(x), self.params, self.config),
            "gravity": -jnp.sum(self.node_masses * (nodes @ self.gravity)),
        }

    def gas_state(self, x):
        v = self.volume(x)
        return -jax.grad(gas_energy)(v, self.params, self.config), v

    def damping_weights(self, weights):
        # A touching vertex hardly moves along the normal: the dashpot acts on the centre of mass instead.
        return jnp.zeros_like(weights)

    def body_damping_weights(self, weights):
        area = self.geometry.vertex_area
        return jnp.minimum(jnp.sum(weights * area) / jnp.mean(area), 1.0)

    def surface_faces(self):
        return np.asarray(self.faces)

    def prescribed_dofs(self):
        return tuple(3 * i + k for i in self.prescribed_vertices for k in range(3))

    def prescribed_positions(self, t):
        if self.prescribed is None:
            return jnp.zeros((0,))
        return self.prescribed.positions(t).reshape(-1)

    def with_prescribed(
        self, vertices, axis_point, axis_direction, times, angles, reference=None
    ) -> "ShellDynamicSystem":
        """The same system with ``vertices`` (indices) held and turned rigidly about the axis through
        ``axis_point`` (3,) [m] along ``axis_direction`` (3,) by ``angles`` (K,) [rad] at ``times``
        (K,) [s] (:class:`PrescribedRotation`), from their positions in ``reference`` (3V,) [m]
        (default: ``inflated``). The held vertices' start must be the schedule's position at t = 0:
        use :meth:`posed` for the whole body's start.
        """
        idx = np.asarray(vertices, dtype=int).reshape(-1)
        n = self.node_masses.shape[0]
        if idx.size == 0 or idx.min() < 0 or idx.max() >= n or np.unique(idx).size != idx.size:
            raise InvalidInputError(
                f"prescribed vertices must be distinct indices in [0, {n}); got {idx.size} of them. Select at least one vertex of the mesh."
            )
        t, a = np.asarray(times, dtype=float).reshape(-1), np.asarray(angles, dtype=float).reshape(-1)
        if t.size < 2 or t.size != a.size or np.any(np.diff(t) <= 0.0):
            raise InvalidInputError(
                f"the rotation schedule needs ≥ 2 strictly increasing times [s] and as many angles [rad]; got {t.size} times and {a.size} angles."
            )
        direction = np.asarray(axis_direction, dtype=float)
        if direction.shape != (3,) or not np.linalg.norm(direction) > 0.0:
            raise InvalidInputError(f"axis_direction must be a nonzero 3-vector; got {direction.tolist()}.")
        x = np.asarray(self.inflated if reference is None else reference, dtype=float).reshape(-1, 3)
        rotation = PrescribedRotation(x[idx], np.asarray(axis_point, dtype=float), direction, t, a)
        return dataclasses.replace(self, prescribed_vertices=tuple(int(i) for i in idx), prescribed=rotation)

    def posed(self, t: float = 0.0, reference=None) -> Float[Array, " n"]:
        """Every vertex of ``reference`` (default ``inflated``) [m] turned rigidly as the held ones are at time t [s]."""
        x = jnp.asarray(self.inflated if reference is None else reference).reshape(-1, 3)
        if self.prescribed is None:
            return x.reshape(-1)
        whole = eqx.tree_at(lambda r: r.rest_positions, self.prescribed, x)
        return whole.positions(jnp.asarray(t)).reshape(-1)

    def hessian_parts(self, x: Float[Array, " n"]):
        """The internal energy's Hessian at x [m]: CSR values [N/m] on the pattern (faces and the
        gas's per-face part; 3 trailing pinned dofs) and the sealed gas's rank-one c u uᵀ (c, u)."""
        q = self._q(x)
        data = hessian_values(q, self.params, self.geometry, self.config, self.maps, self.nnz)
        if not self.config.gas.sealed:
            return data, jnp.asarray(0.0), jnp.zeros_like(x)
        c2, u = gas_rank_one(q, self.params, self.geometry, self.config)
        return data, c2, u[:-3]

    def with_parameters(self, **changes) -> "ShellDynamicSystem":
        """The same system with :class:`ShellParams` entries replaced (e.g. ``young_modulus``)."""
        return eqx.tree_at(lambda s: s.params, self, self.params.replace(**changes))

    def with_planes(self, planes) -> "ShellDynamicSystem":
        """The same system against other planes."""
        return eqx.tree_at(lambda s: s.planes, self, tuple(planes))


def _node_masses(model: ShellModel, mass, wall_density, thickness) -> np.ndarray:
    area = np.asarray(model.geometry.vertex_area)
    if mass is None and wall_density is None:
        raise InvalidInputError(
            "the shell's mass is missing: give `mass` [kg] (a session's `mass`) or `wall_density` [kg/m³]."
        )
    if mass is not None and wall_density is not None:
        raise InvalidInputError("give either `mass` [kg] or `wall_density` [kg/m³], not both.")
    if mass is not None:
        check_positive("mass [kg]", mass, "Give the object's mass, e.g. the session's `mass`.")
        return float(mass) * area / area.sum()
    check_positive("wall_density [kg/m³]", wall_density, "Give the wall material's density, e.g. 1100 kg/m³.")
    return float(wall_density) * float(thickness) * area


def shell_system(
    shell: Shell,
    properties: ShellProperties,
    *,
    gas: AbstractGasLaw = IsothermalGas(),
    mass: float | None = None,
    wall_density: float | None = None,
    planes=(),
    gravity=STANDARD_GRAVITY,
) -> ShellDynamicSystem:
    """A :class:`ShellDynamicSystem` of ``shell`` (its mesh the inflated shape [m]) with the E [Pa],
    ν [-] and gauge pressure P_g [Pa] of ``properties`` (a ``physics.ShellProperties`` whose
    thickness is the shell's; its radius is not read), ``gas`` (a ``physics.AbstractGasLaw``:
    ``PrescribedGas()``, ``IsothermalGas()`` or ``AdiabaticGas(γ)``), the mass
    from ``mass`` [kg] (spread by rest area) or ``wall_density`` [kg/m³] × h × area, ``planes``
    and ``gravity`` (g [m/s²] down, or a 3-vector). Its ``inflated`` state is in equilibrium, in the
    mesh's frame (its lowest vertex where the mesh has it).
    """
    if not isinstance(properties, ShellProperties) or float(properties.thickness) != float(shell.thickness):
        raise InvalidInputError(
            f"shell_system: expected a physics.ShellProperties whose thickness is the shell's {shell.thickness!r} m, "
            f"got {properties!r}. Fix: ShellProperties(gauge_pressure=…, young_modulus=…, thickness=shell.thickness, "
            "poisson_ratio=…)"
        )
    params = ShellParams(
        young_modulus=float(properties.young_modulus),
        poisson_ratio=float(properties.poisson_ratio),
        thickness=float(shell.thickness),
        gauge_pressure=float(properties.gauge_pressure),
    )
    reference = inflated_reference(shell, params)
    inflated = reference.inflated.reshape(-1)
    n = shell.mesh.n_vertices
    config = ModelConfig(n, gas=gas)
    fixed = np.zeros(3 * n + 3, dtype=bool)
    fixed[-3:] = True
    model = ShellModel(shell.mesh, reference.rest, config, fixed)
    if gas.sealed:
        params = params.replace(reference_volume=reference.reference_volume, atmospheric_pressure=ATMOSPHERIC_PRESSURE)
    return ShellDynamicSystem(
        params=params,
        geometry=model.geometry,
        config=config,
        node_masses=jnp.asarray(_node_masses(model, mass, wall_density, shell.thickness)),
        faces=jnp.asarray(shell.mesh.faces),
        inflated=jnp.asarray(inflated),
        planes=tuple(planes),
        gravity=gravity_vector(gravity),
        maps=model.pattern.maps,
        nnz=model.pattern.nnz,
        sparsity=KeyedPattern(model.pattern),
    )


def remeshed(shell: Shell, n_faces: int) -> Shell:
    """``shell`` with its edges split until it has about ``n_faces`` triangles (within 10 %), its
    thickness [m] kept: long, thin triangles (a capsule's sides) become rows of short ones that
    can bend. Only refines (manifold3d's ``refine_to_length``): the vertices stay on the mesh's
    surface and no triangle gets a smaller angle. Coarsening by edge collapse folded faces onto
    their neighbours, which the rest-shape solve cannot start from; give a coarser mesh instead.
    """
    import manifold3d

    mesh = shell.mesh
    if n_faces < mesh.n_faces:
        raise InvalidInputError(
            f"mesh_faces = {n_faces}: the mesh {mesh.name} has {mesh.n_faces} faces and can only be refined; "
            f'give mesh_faces ≥ {mesh.n_faces}, or a coarser mesh (e.g. object.mesh = "bundled:meshes/hammer-coarse.stl").'
        )
    solid = manifold3d.Manifold(
        manifold3d.Mesh(np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.uint32))
    )
    low, high = 1e-6 * float(np.ptp(mesh.vertices, axis=0).max()), float(np.ptp(mesh.vertices, axis=0).max())
    for _ in range(40):  # bisection on the edge length [m]: the face count falls as it grows
        length = float(np.sqrt(low * high))
        fine = solid.refine_to_length(length)
        if abs(fine.num_tri() - n_faces) < 0.1 * n_faces or high / low < 1.001:
            break
        low, high = (length, high) if fine.num_tri() > n_faces else (low, length)
    out = fine.to_mesh()
    vertices = np.asarray(out.vert_properties[:, :3], dtype=float)
    return Shell(
        mesh=ShellMesh.from_arrays(
            vertices, np.asarray(out.tri_verts, dtype=int), name=f"{mesh.name} refined to {fine.num_tri()} faces"
        ),
        thickness=shell.thickness,
    )
