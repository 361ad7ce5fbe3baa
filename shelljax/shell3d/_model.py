"""The discrete shell model: energy, gradient and sparse Hessian of a pressurized closed shell.

Unknowns ``q`` (3V + 3,) [m]: the vertex positions x (V, 3) flattened, then the indenter center c
(3,). Total potential energy [J]:

    E(q) = Σ_faces A̅ (W_membrane + W_bending) + Π_gas(V(x)) + Σ_contacts φ(gap)
           + F_ind c_z − Σ_v f_v·x_v + m g Σ_v w_v z_v + Σ_planes Σ_v μ λ_pv f₀(‖P_p(x_v − x̂_v)‖)

with the gas energy Π from :mod:`shelljax.physics` (prescribed gauge pressure or a sealed ideal gas
at atmospheric pressure outside), contact potentials φ per vertex against a rigid sphere (the
indenter, radius r) and rigid planes (ground, walls), an optional downward force F_ind on the
indenter (force control; in displacement control c is prescribed), nodal forces f_v and the
weight of the shell (mass m spread by lumped rest area w_v). The last term is the optional
smoothed lagged Coulomb friction against the planes (:func:`shelljax.physics.friction_energy`):
μ [-] and the slip tolerance ε [m] of f₀ are set in :class:`ContactConfig`, the anchors x̂ and the
lagged normal forces λ are parameters; P_p = I − n nᵀ keeps the slip in the plane.

Parameters that can be differentiated live in a dict ``params`` (SI units):
``young_modulus`` [Pa], ``poisson_ratio`` [-], ``thickness`` [m], ``gauge_pressure`` [Pa]
(prescribed, or the sealed gas's gauge pressure at ``reference_volume`` [m³]),
``indenter_center`` (3,) [m], ``indenter_force`` [N], ``nodal_forces`` (V, 3) [N], ``mass`` [kg];
with friction (μ > 0 and planes) also ``friction_anchor`` (V, 3) [m] (lagged vertex positions, the
origin of the slip) and ``friction_normal_force`` (n_planes, V) [N] (lagged normal contact force
magnitude of every vertex on every plane, see :meth:`ShellModel.plane_normal_forces`), and
optionally ``friction_coefficient`` [-], which overrides the config's μ (differentiable; the host
functions of :class:`ShellModel` pass the config's μ this way, so that models differing only in
μ > 0 share one compilation).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._errors import InvalidInputError
from ..physics import (
    ATMOSPHERIC_PRESSURE,
    adiabatic_gas_energy,
    barrier_energy,
    friction_energy,
    isothermal_gas_energy,
    penalty_energy,
    plane_gap,
    prescribed_pressure_energy,
    sphere_gap,
)
from ..solve import SparseSolver, SparsityPattern, assemble_values, element_positions, newton
from ._energy import face_energy, face_volume, rest_geometry
from ._mesh import ShellMesh

GRAVITY = 9.81  # [m/s²]
GAS_MODELS = ("prescribed", "isothermal", "adiabatic")
# Barrier calibration: the IPC barrier's force at g = ĝ/10 is κ ĝ · 12.2 (φ(s) = 2(s−1)ln s +
# (s−1)²/s at s = 0.1), so κ = p_ref A_v / (12.2 ĝ) makes a vertex pressed with p_ref sit at ĝ/10.
_BARRIER_FORCE_AT_TENTH = 2.0 * 0.9 * np.log(10.0) + 0.81 / 0.1
# Default friction slip tolerance ε = ĝ/100 (4 µm for a 0.13 m-radius ball, whose Indentation ĝ
# is 0.4 mm). A sticking vertex creeps by up to ε per load step, so ε must sit well below the slip
# friction is meant to stop: such a ball poked 2 cm slides its ground contact by only ~65 µm in
# total, ~8 µm per continuation step. With ε = ĝ/10 the "sticking" creep (up to 8 steps × 40 µm)
# exceeds that, and μ = 0.5 removed only a third of the friction effect; ĝ/100, ĝ/400 and ĝ/800
# give the same slip, force and contact diameter to 5 digits (800 faces, μ = 0.5). The stick
# stiffness 2μλ/ε (~1e4–1e5 N/m per loaded vertex) stays within a few tens of the barrier's, which
# the sparse direct solve absorbs (Newton iterations per load step about double).
FRICTION_SLIP_FRACTION = 0.01


def _as_float(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


@dataclasses.dataclass(frozen=True)
class ContactConfig:
    """Static contact setup (hashable; part of the jit key).

    ``indenter_radius`` [m] or None; ``planes``: tuple of (point (3,), unit normal (3,)) [m];
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
    n_vertices: int
    gas: str = "prescribed"
    heat_capacity_ratio: float = 1.4
    contact: ContactConfig = ContactConfig()
    force_control: bool = False


class ShellGeometry(eqx.Module):
    """Per-face rest data and per-vertex weights (arrays; not part of the jit key)."""

    stencil: Int[Array, "F 6"]
    rest_metric: Float[Array, "F 2 2"]
    rest_curvature: Float[Array, "F 2 2"]
    rest_area: Float[Array, " F"]
    vertex_area: Float[Array, " V"]


def make_geometry(mesh: ShellMesh, rest_vertices) -> ShellGeometry:
    """Rest fundamental forms of ``mesh``'s topology at ``rest_vertices`` (V, 3) [m]."""
    stencil = jnp.asarray(mesh.stencil)
    rest = jnp.asarray(rest_vertices, dtype=jnp.float64)
    metric, curvature, area = rest_geometry(rest[stencil])
    vertex_area = jnp.zeros(mesh.n_vertices).at[stencil[:, :3]].add(area[:, None] / 3.0)
    return ShellGeometry(stencil, metric, curvature, area, vertex_area)


def _split(q, config: ModelConfig):
    n3 = 3 * config.n_vertices
    return q[:n3].reshape(-1, 3), q[n3:]


def volume(x: Float[Array, "V 3"], stencil) -> Float[Array, ""]:
    """Enclosed volume [m³] of the closed mesh at vertex positions x (V, 3) [m]."""
    return jnp.sum(jax.vmap(face_volume)(x[stencil[:, :3]]))


def gas_energy(vol, params, config: ModelConfig):
    """Gas potential Π(V) [J] (see :mod:`shelljax.physics._gas`)."""
    p_g = params["gauge_pressure"]
    if config.gas == "prescribed":
        return prescribed_pressure_energy(vol, p_g)
    p_atm = params.get("atmospheric_pressure", ATMOSPHERIC_PRESSURE)
    v0 = params["reference_volume"]
    if config.gas == "isothermal":
        return isothermal_gas_energy(vol, v0, p_g, atmospheric_pressure=p_atm)
    return adiabatic_gas_energy(vol, v0, p_g, config.heat_capacity_ratio, atmospheric_pressure=p_atm)


def gauge_pressure(q, params, geometry: ShellGeometry, config: ModelConfig):
    """Current gauge pressure −dΠ/dV [Pa] of the gas."""
    x, _ = _split(q, config)
    vol = volume(x, geometry.stencil)
    return -jax.grad(gas_energy)(vol, params, config)


def _contact_potential(gap, stiffness, contact: ContactConfig):
    if contact.kind == "barrier":
        return barrier_energy(gap, contact.activation_distance, stiffness)
    return penalty_energy(gap, stiffness)


def _contact_stiffness(geometry, contact: ContactConfig):
    """Per-vertex barrier κ [J/m²] or penalty k [N/m], scaled by lumped rest area."""
    force = contact.reference_pressure * geometry.vertex_area
    if contact.kind == "barrier":
        return force / (_BARRIER_FORCE_AT_TENTH * contact.activation_distance)
    return force / contact.activation_distance


def sphere_contact_energy(x, c, geometry, config):
    """Indenter contact energy [J] summed over vertices."""
    k = _contact_stiffness(geometry, config.contact)
    gap = sphere_gap(x, c, config.contact.indenter_radius)
    return jnp.sum(_contact_potential(gap, k, config.contact))


def plane_contact_energy(x, plane, geometry, config):
    """Contact energy [J] of all vertices against one plane (point, normal)."""
    k = _contact_stiffness(geometry, config.contact)
    gap = plane_gap(x, jnp.asarray(plane[0]), jnp.asarray(plane[1]))
    return jnp.sum(_contact_potential(gap, k, config.contact))


def plane_normal_forces(x, plane, geometry, config) -> Float[Array, " V"]:
    """Normal contact force magnitude λ = −dφ/dgap [N] (≥ 0) of every vertex on one plane."""
    k = _contact_stiffness(geometry, config.contact)
    gap = plane_gap(x, jnp.asarray(plane[0]), jnp.asarray(plane[1]))
    dphi = jax.vmap(jax.grad(_contact_potential), in_axes=(0, 0, None))(gap, k, config.contact)
    return -dphi


def _friction_data(params, config):
    keys = ("friction_anchor", "friction_normal_force")
    missing = [key for key in keys if key not in params]
    if missing:
        raise InvalidInputError(
            f"params: friction μ = {config.contact.friction} needs {missing} (lagged vertex positions "
            "(V, 3) [m] and normal forces (n_planes, V) [N]); Indentation sets them, or use μ = 0."
        )
    return params["friction_anchor"], params["friction_normal_force"]


def _vertex_friction(y, anchor, lam, normal, mu, contact: ContactConfig):
    """Friction potential [J] of vertex positions y (…, 3) on a plane of unit ``normal``."""
    d = y - anchor
    slip = d - (d @ normal)[..., None] * normal
    return friction_energy(slip, lam, mu, contact.friction_slip_tolerance)


_FRICTION_KEYS = ("friction_anchor", "friction_normal_force", "friction_coefficient")


def _friction_coefficient(params, config):
    return params.get("friction_coefficient", config.contact.friction)


def _jit_config(config: ModelConfig) -> ModelConfig:
    """``config`` with μ > 0 normalised to 1 (μ then travels in ``params``): the compile key."""
    if not config.contact.has_friction:
        return config
    contact = dataclasses.replace(
        config.contact, friction=1.0, slip_tolerance=config.contact.friction_slip_tolerance
    )
    return dataclasses.replace(config, contact=contact)


def friction_potential(x, params, config) -> Float[Array, ""]:
    """Lagged smoothed Coulomb friction energy [J] of all vertices on all planes (0 if μ = 0)."""
    if not config.contact.has_friction:
        return jnp.zeros(())
    anchor, lam = _friction_data(params, config)
    mu = _friction_coefficient(params, config)
    e = jnp.zeros(())
    for i, plane in enumerate(config.contact.planes):
        e = e + jnp.sum(_vertex_friction(x, anchor, lam[i], jnp.asarray(plane[1]), mu, config.contact))
    return e


def elastic_energy(x, params, geometry):
    """Membrane + bending energy [J] of the whole shell."""
    p = x[geometry.stencil]
    e = jax.vmap(face_energy, in_axes=(0, 0, 0, 0, None, None, None, None))(
        p, geometry.rest_metric, geometry.rest_curvature, geometry.rest_area,
        params["thickness"], params["young_modulus"], params["poisson_ratio"], 0.0,
    )
    return jnp.sum(e)


def total_energy(q, params, geometry: ShellGeometry, config: ModelConfig):
    """Total potential energy E(q) [J] (see the module docstring)."""
    x, c = _split(q, config)
    e = elastic_energy(x, params, geometry)
    e = e + gas_energy(volume(x, geometry.stencil), params, config)
    if config.contact.indenter_radius is not None:
        e = e + sphere_contact_energy(x, c, geometry, config)
    for plane in config.contact.planes:
        e = e + plane_contact_energy(x, plane, geometry, config)
    if config.contact.has_friction:
        e = e + friction_potential(x, params, config)
    if config.force_control:
        e = e + params["indenter_force"] * c[2]
    if "nodal_forces" in params:
        e = e - jnp.sum(params["nodal_forces"] * x)
    if "mass" in params:
        weights = geometry.vertex_area / jnp.sum(geometry.vertex_area)
        e = e + params["mass"] * GRAVITY * jnp.sum(weights * x[:, 2])
    return e


def min_gap(q, geometry, config):
    """Smallest contact gap [m] over all vertices and rigid bodies (+inf without contacts)."""
    x, c = _split(q, config)
    g = jnp.inf
    if config.contact.indenter_radius is not None:
        g = jnp.minimum(g, jnp.min(sphere_gap(x, c, config.contact.indenter_radius)))
    for plane in config.contact.planes:
        g = jnp.minimum(g, jnp.min(plane_gap(x, jnp.asarray(plane[0]), jnp.asarray(plane[1]))))
    return g


@functools.partial(jax.jit, static_argnames=("config",))
def _search_energy(q, params, geometry, config):
    e = total_energy(q, params, geometry, config)
    if config.contact.kind == "barrier":
        e = jnp.where(min_gap(q, geometry, config) > 0.0, e, jnp.inf)
    return jnp.where(jnp.isfinite(e), e, jnp.inf)


_gradient = jax.jit(jax.grad(total_energy), static_argnames=("config",))


@functools.partial(jax.jit, static_argnames=("config",))
def _linearized_gradient(q, params, geometry, config) -> tuple[Array, jax.tree_util.Partial]:
    """(∇E(q) [N], v ↦ H(q) v [N]): the gradient and the exact Hessian (sealed gas's rank-one part
    included) at q as a linear map, with the primal's intermediates computed once: each product
    then costs ≈ 13 ms at 20k faces instead of ≈ 35 ms for a jvp of the gradient, and the
    gradient comes with the linearization (≈ 7 ms at 20k faces, as much as the gradient alone)."""
    return jax.linearize(lambda y: jax.grad(total_energy)(y, params, geometry, config), q)


_apply_linear = jax.jit(lambda linear, v: linear(v))


@functools.partial(jax.jit, static_argnames=("config",))
def _hessian_vector_product(q, params, geometry, config, v):
    """H(q) v [N] by forward-over-reverse differentiation: nothing kept between products."""
    return jax.jvp(lambda y: jax.grad(total_energy)(y, params, geometry, config), (q,), (v,))[1]


#: Above this many faces the Hessian-vector products of Newton's CG are jvps (≈ 35 ms at 20k
#: faces) instead of products of a stored linearization (≈ 13 ms): the linearization keeps the
#: gradient's intermediates, ≈ 9 kB per face, and took the 80k-face benchmark from 1673 to
#: 2262 MiB peak RSS (docs/shell3d.md).
LINEARIZED_PRODUCT_MAX_FACES = 40_000


#: Faces per vectorized chunk of the element-Hessian kernel.
FACE_HESSIAN_CHUNK = 1024
#: Faces per chunk of the PSD-projected Hessian (its eigenvalue clamp runs on the host).
PROJECTION_CHUNK = 8192


def _face_hessian_kernel(q, params, geometry, config):
    """(face ↦ its 18×18 Hessian [N/m], the per-face inputs): the membrane, bending and
    pressure-follower energy of one face, differentiated twice (the gas pressure is fixed at the
    current volume's; the gas's rank-one term is :func:`_rank_one`)."""
    x, _ = _split(q, config)
    vol = volume(x, geometry.stencil)
    pressure = -jax.grad(gas_energy)(vol, params, config)
    face_hess = jax.hessian(lambda p, *rest: face_energy(p.reshape(6, 3), *rest))
    material = (params["thickness"], params["young_modulus"], params["poisson_ratio"], pressure)
    faces = (x[geometry.stencil].reshape(-1, 18), geometry.rest_metric, geometry.rest_curvature, geometry.rest_area)
    return (lambda face: face_hess(*face, *material)), faces


def _contact_hessians(q, params, geometry, config):
    """Per-vertex contact (and friction) Hessian blocks [N/m], one (V, k, k) array per contact
    family (indenter, then each plane), in the order of :class:`ShellModel`'s pattern."""
    x, c = _split(q, config)
    blocks = []
    k = _contact_stiffness(geometry, config.contact)
    if config.contact.indenter_radius is not None:
        def pair(y, kv):
            gap = sphere_gap(y[:3], y[3:], config.contact.indenter_radius)
            return _contact_potential(gap, kv, config.contact)

        cc = jnp.broadcast_to(c, x.shape)
        blocks.append(jax.vmap(jax.hessian(pair))(jnp.concatenate([x, cc], axis=1), k))
    friction = config.contact.has_friction
    if friction:
        anchor, lam = _friction_data(params, config)
        mu = _friction_coefficient(params, config)
    for i, plane in enumerate(config.contact.planes):
        # The friction of a vertex on a plane involves only that vertex: it shares the plane's
        # per-vertex 3×3 block (same sparsity pattern with or without friction).
        def single(y, kv, y_hat, lam_v, plane=plane):
            gap = plane_gap(y, jnp.asarray(plane[0]), jnp.asarray(plane[1]))
            e = _contact_potential(gap, kv, config.contact)
            if friction:
                e = e + _vertex_friction(y, y_hat, lam_v, jnp.asarray(plane[1]), mu, config.contact)
            return e

        y_hat = anchor if friction else x
        lam_i = lam[i] if friction else jnp.zeros_like(k)
        blocks.append(jax.vmap(jax.hessian(single))(x, k, y_hat, lam_i))
    return blocks


#: Smallest factor on a barrier's stiffness along its gap gradient in Newton's matrix
#: (:func:`_barrier_softening`). A vertex that nothing presses (λ̂ ≤ 0) gets it; where the barrier
#: alone holds a rigid mode (the ball's vertical translation in force control), Newton's step in
#: that mode is then at most 1/floor too long for the line search. With 1e-4 the force-controlled
#: 2000-face poke of tests/test_axisym_vs_shell3d.py stalled on its first level (residual 0.625 N,
#: the indenter force, for 60 iterations).
BARRIER_SOFTENING_FLOOR = 1e-2


@functools.partial(jax.jit, static_argnames=("config",))
def _barrier_softening(q, gradient, geometry, config) -> Float[Array, "V 3 3"]:
    """Per vertex, the 3×3 correction [N/m] that turns the Hessian into Newton's matrix: the
    planes' barrier stiffness φ'' n nᵀ scaled down; ``gradient`` [N] is ∇E at q.

    A log barrier pressing a vertex harder than its load needs (gap far below equilibrium) has a
    stiffness φ'' ≈ λ_b / gap, with λ_b = −φ' its force, so a Newton step can at most double the
    gap: from 0.04 µm to 36 µm took 11 iterations on the first load step of the 20k-face curve.
    The primal–dual remedy of interior-point methods scales φ'' by λ̂ / λ_b, where λ̂ = λ_b + n·∇E
    is the force the rest of the model presses the vertex with (the dual estimate that balances
    it). With φ'' ≈ λ_b / gap this is λ̂ / gap, and the step of a vertex under a fixed load reaches
    its equilibrium gap in one go. The factor is clipped to [``BARRIER_SOFTENING_FLOOR``, 1]: a
    barrier is never stiffened, and at equilibrium (∇E = 0 on free dofs) the factor is 1, so the
    converged state and Newton's final rate are those of the true Hessian. A softer barrier keeps
    the matrix positive definite wherever the true one is, so the steps still descend the energy.

    Planes only: softening the indenter's barrier too made the first load step of the 20k-face
    curve slower (25 against 16 Newton iterations; its steps were cut 8–64× by the line search),
    where the planes alone brought it to 13–14 (docs/shell3d.md).
    """
    x, _ = _split(q, config)
    vertex_gradient = gradient[: x.size].reshape(x.shape)
    k = _contact_stiffness(geometry, config.contact)
    slope = jax.vmap(jax.grad(_contact_potential), in_axes=(0, 0, None))
    curvature = jax.vmap(jax.grad(jax.grad(_contact_potential)), in_axes=(0, 0, None))
    blocks = jnp.zeros((config.n_vertices, 3, 3))
    for point, normal in config.contact.planes:
        normal = jnp.asarray(normal)
        gap = plane_gap(x, jnp.asarray(point), normal)
        push = -slope(gap, k, config.contact)
        pressed = push > 0.0
        ratio = 1.0 + (vertex_gradient @ normal) / jnp.where(pressed, push, 1.0)
        factor = jnp.where(pressed, jnp.clip(ratio, BARRIER_SOFTENING_FLOOR, 1.0), 1.0)
        blocks = blocks + ((factor - 1.0) * curvature(gap, k, config.contact))[:, None, None] * jnp.outer(normal, normal)
    return blocks


def _softens(config: ModelConfig) -> bool:
    """Whether Newton's matrix differs from the Hessian (:func:`_barrier_softening`)."""
    return config.contact.kind == "barrier" and bool(config.contact.planes)


def _softened_contact_hessians(q, params, geometry, config, gradient=None):
    """:func:`_contact_hessians`, with :func:`_barrier_softening` at ``gradient`` [N] unless None."""
    blocks = _contact_hessians(q, params, geometry, config)
    if gradient is not None and _softens(config):
        # Each plane's block is its vertex's own 3×3: the first one takes the corrections of all.
        first = len(blocks) - len(config.contact.planes)
        blocks[first] = blocks[first] + _barrier_softening(q, gradient, geometry, config)
    return blocks


def _plus_vertex_blocks(product, blocks, v):
    """product + the (V, 3, 3) vertex ``blocks`` applied to v (3V + 3,) (the indenter dofs untouched)."""
    vertex = jnp.einsum("vij,vj->vi", blocks, v[:-3].reshape(-1, 3))
    return product + jnp.concatenate([vertex.reshape(-1), jnp.zeros(3)])


_apply_linear_softened = jax.jit(lambda linear, blocks, v: _plus_vertex_blocks(linear(v), blocks, v))


def _balanced_chunk(n: int, most: int) -> int:
    """Chunk size ≤ ``most`` that covers ``n`` items in the fewest chunks, the last one
    overlapping the one before it by fewer than the number of chunks."""
    return -(-n // -(-n // most))


def _face_chunk(kernel, faces, start, size):
    """(Hessians of ``size`` consecutive faces from ``start``, the start used): a chunk that would
    overrun is shifted back to end at the last face, and the caller drops the overlap."""
    start = jnp.minimum(start, faces[0].shape[0] - size)
    return jax.vmap(kernel)([jax.lax.dynamic_slice_in_dim(a, start, size) for a in faces]), start


@functools.partial(jax.jit, static_argnames=("config", "size"))
def _face_hessians(q, params, geometry, config, start, size):
    """The 18×18 Hessians [N/m] of ``size`` faces from face ``start`` (see :func:`_face_chunk`)."""
    return _face_chunk(*_face_hessian_kernel(q, params, geometry, config), start, size)[0]


_contact_hessians_jit = jax.jit(_softened_contact_hessians, static_argnames=("config",))


@functools.partial(jax.jit, static_argnames=("config", "nnz"))
def _hessian_values(q, params, geometry, config, maps, nnz, gradient=None):
    """CSR values of the exact Hessian [N/m] (a pattern's ``maps`` and ``nnz``), element blocks
    summed inside one XLA program; with ``gradient`` [N] at q, Newton's matrix
    (:func:`_barrier_softening`).

    The face Hessians are computed in balanced chunks of at most ``FACE_HESSIAN_CHUNK`` faces and
    each chunk is scattered at once: the (F, 18, 18) array of all of them (207 MB at 80k faces)
    never exists, the autodiff intermediates stay small, and chunks that fit in cache are faster
    too (0.72 → 0.52 s at 20k faces on 2 cores against one vmap over all faces).
    """
    data = assemble_values(maps[1:], nnz, _softened_contact_hessians(q, params, geometry, config, gradient))
    kernel, faces = _face_hessian_kernel(q, params, geometry, config)
    n_faces = faces[0].shape[0]
    chunk = _balanced_chunk(n_faces, FACE_HESSIAN_CHUNK)
    n_chunks = -(-n_faces // chunk)
    face_base, face_stride = maps[0]

    def add_chunk(k, data):
        hessians, start = _face_chunk(kernel, faces, k * chunk, chunk)
        fresh = start + jnp.arange(chunk) >= k * chunk  # rows an earlier chunk did not add
        hessians = jnp.where(fresh[:, None, None], hessians, 0.0)
        rows = element_positions(
            jax.lax.dynamic_slice_in_dim(face_base, start, chunk),
            jax.lax.dynamic_slice_in_dim(face_stride, start, chunk),
            hessians.shape[-1],
        )
        return data.at[rows.reshape(-1)].add(hessians.reshape(-1))

    return jax.lax.fori_loop(0, n_chunks, add_chunk, data)


@functools.partial(jax.jit, static_argnames=("config",))
def _plane_normal_forces(q, geometry, config):
    x, _ = _split(q, config)
    forces = [plane_normal_forces(x, plane, geometry, config) for plane in config.contact.planes]
    return jnp.stack(forces) if forces else jnp.zeros((0, config.n_vertices))


@functools.partial(jax.jit, static_argnames=("config",))
def _friction_forces(q, params, config):
    x, _ = _split(q, config)
    if not config.contact.has_friction:
        return jnp.zeros((len(config.contact.planes),) + x.shape)
    anchor, lam = _friction_data(params, config)
    mu = _friction_coefficient(params, config)
    out = []
    for i, plane in enumerate(config.contact.planes):
        e = lambda y, i=i, plane=plane: jnp.sum(  # noqa: E731
            _vertex_friction(y, anchor, lam[i], jnp.asarray(plane[1]), mu, config.contact)
        )
        out.append(-jax.grad(e)(x))
    return jnp.stack(out)


@functools.partial(jax.jit, static_argnames=("config",))
def _rank_one(q, params, geometry, config):
    """(Π''(V), ∇_q V) for the dense rank-one part of a sealed gas's Hessian."""
    x, _ = _split(q, config)
    vol_fn = lambda y: volume(y.reshape(-1, 3), geometry.stencil)  # noqa: E731
    vol, dvol = jax.value_and_grad(vol_fn)(x.reshape(-1))
    c2 = jax.grad(jax.grad(gas_energy), argnums=0)(vol, params, config)
    return c2, jnp.concatenate([dvol, jnp.zeros(3)])


#: The line search's projection (:meth:`ShellModel.feasible_trial`) keeps at least this fraction
#: of its gap to a body for every vertex within the barrier's range. A log barrier's Newton model
#: overshoots wherever a vertex starts far above its equilibrium gap, and halving the whole step
#: until no vertex crossed made the first 2–10 iterations of every load step take 1/4 … 1/64
#: steps. On the 20k-face curve 0.3 took 42 Newton iterations and 183 CG products against 55 and
#: 265 without; 0.1 made more factorizations (12 against 5) and 0.5 more products (201)
#: (docs/shell3d.md, *Benchmark*).
BARRIER_STEP_FRACTION = 0.3


def _body_gap_and_normal(x, c, config: ModelConfig, body: int):
    """Gap [m] (V,) of every vertex to rigid body ``body`` (0: the indenter, if any, then the
    planes in order) and the unit direction (V, 3) in which it grows (host arrays)."""
    contact = config.contact
    if contact.indenter_radius is not None:
        if body == 0:
            offset = x - c
            distance = np.linalg.norm(offset, axis=1)
            return distance - contact.indenter_radius, offset / distance[:, None]
        body -= 1
    point, normal = (np.asarray(a, dtype=np.float64) for a in contact.planes[body])
    return (x - point) @ normal, np.broadcast_to(normal, x.shape)


def n_bodies(config: ModelConfig) -> int:
    """Number of rigid bodies (indenter and planes) the shell can touch."""
    return (config.contact.indenter_radius is not None) + len(config.contact.planes)


def place_at_gaps(q, config: ModelConfig, target) -> np.ndarray:
    """A copy of state ``q`` [m] with vertices moved along the bodies' normals to the gaps
    ``target(body, gap)`` [m] (NaN where a vertex stays), body after body (host)."""
    q = np.array(q, dtype=np.float64)
    x, c = q[: 3 * config.n_vertices].reshape(-1, 3), q[3 * config.n_vertices :]
    for body in range(n_bodies(config)):
        gap, normal = _body_gap_and_normal(x, c, config, body)
        goal = target(body, gap)
        moved = np.isfinite(goal)
        x[moved] += (goal[moved] - gap[moved])[:, None] * normal[moved]
    return q


def body_gaps(q, config: ModelConfig) -> list:
    """Gaps [m] (V,) of every vertex to each rigid body (:func:`_body_gap_and_normal`'s order)."""
    q = np.asarray(q, dtype=np.float64)
    x, c = q[: 3 * config.n_vertices].reshape(-1, 3), q[3 * config.n_vertices :]
    return [_body_gap_and_normal(x, c, config, body)[0] for body in range(n_bodies(config))]


def _check_config(config: ModelConfig) -> None:
    if config.gas not in GAS_MODELS:
        raise InvalidInputError(f"gas: unknown model {config.gas!r}; use one of {GAS_MODELS}.")
    if config.contact.kind not in ("barrier", "penalty"):
        raise InvalidInputError(
            f"contact: unknown kind {config.contact.kind!r}; use 'barrier' or 'penalty'."
        )


class ShellModel:
    """A discrete shell on a closed mesh with gas, contacts and pins; Newton-ready.

    ``mesh``: topology; ``rest_vertices`` (V, 3) [m]: stress-free shape; ``config``: static setup;
    ``fixed``: (3V + 3,) bool mask of pinned dofs (pins remove rigid-body modes; see
    :func:`rigid_mode_pins`).
    """

    def __init__(self, mesh: ShellMesh, rest_vertices, config: ModelConfig, fixed):
        _check_config(config)
        self.mesh = mesh
        self.config = config
        self._jit_config = _jit_config(config)
        self.rest_vertices = np.asarray(rest_vertices, dtype=np.float64)
        self.geometry = make_geometry(mesh, self.rest_vertices)
        self.n_dofs = 3 * mesh.n_vertices + 3
        self.free = ~np.asarray(fixed, dtype=bool)
        blocks = [(3 * mesh.stencil[:, :, None] + np.arange(3)).reshape(-1, 18)]
        vdofs = 3 * np.arange(mesh.n_vertices)[:, None] + np.arange(3)
        if config.contact.indenter_radius is not None:
            cdofs = np.broadcast_to(3 * mesh.n_vertices + np.arange(3), vdofs.shape)
            blocks.append(np.concatenate([vdofs, cdofs], axis=1))
        for _ in config.contact.planes:
            blocks.append(vdofs)
        self.pattern = SparsityPattern.from_elements(blocks, self.n_dofs, self.free)

    def with_rest(self, rest_vertices) -> "ShellModel":
        """Same model with another rest shape (reuses the sparsity pattern and compiled code)."""
        other = object.__new__(ShellModel)
        other.__dict__.update(self.__dict__)
        other.rest_vertices = np.asarray(rest_vertices, dtype=np.float64)
        other.geometry = make_geometry(self.mesh, other.rest_vertices)
        return other

    def with_config(self, config: ModelConfig, fixed=None) -> "ShellModel":
        """Same mesh and rest shape with another static setup (new pattern if contacts change)."""
        old = self.config.contact
        new = config.contact
        same_blocks = (
            fixed is None
            and config.n_vertices == self.config.n_vertices
            and (old.indenter_radius is None) == (new.indenter_radius is None)
            and len(old.planes) == len(new.planes)
        )
        if not same_blocks:
            return ShellModel(self.mesh, self.rest_vertices, config, ~self.free if fixed is None else fixed)
        # Same element families (e.g. only friction, gas or contact constants changed): keep the
        # sparsity pattern (and the geometry), validate the new setup the same way.
        _check_config(config)
        other = object.__new__(ShellModel)
        other.__dict__.update(self.__dict__)
        other.config = config
        other._jit_config = _jit_config(config)
        return other

    # --- JAX functions (traceable) -------------------------------------------------------------
    def energy(self, q, params):
        """Total energy [J]."""
        return total_energy(q, params, self.geometry, self.config)

    def gradient(self, q, params):
        """Energy gradient [N] (unmasked), traceable."""
        return jax.grad(total_energy)(q, params, self.geometry, self.config)

    def volume(self, q):
        """Enclosed volume [m³]."""
        return volume(_split(q, self.config)[0], self.geometry.stencil)

    def gauge_pressure(self, q, params):
        """Current gas gauge pressure [Pa]."""
        return gauge_pressure(q, params, self.geometry, self.config)

    def plane_normal_forces(self, q) -> np.ndarray:
        """(n_planes, V) normal contact force magnitudes λ = −dφ/dgap [N] at state q (host)."""
        return np.asarray(_plane_normal_forces(jnp.asarray(q), self.geometry, self._jit_config))

    def friction_forces(self, q, params) -> np.ndarray:
        """(n_planes, V, 3) friction forces −∂D/∂x_v [N] of each plane on each vertex (host; 0
        without friction). Tangential to the plane, magnitude μ λ f₁(‖slip‖) ≤ μ λ."""
        return np.asarray(_friction_forces(jnp.asarray(q), self._host_params(params), self._jit_config))

    # --- host functions for Newton --------------------------------------------------------------
    def _host_params(self, params):
        """``params`` as arrays, with the config's μ as a traced value (see :func:`_jit_config`).

        Without friction the friction entries are dropped: they are unused, and leaving them in
        would change the pytree and so recompile the frictionless functions.
        """
        params = jax.tree_util.tree_map(jnp.asarray, params)
        if not self.config.contact.has_friction:
            return {k: v for k, v in params.items() if k not in _FRICTION_KEYS}
        if "friction_coefficient" not in params:
            params = {**params, "friction_coefficient": jnp.asarray(self.config.contact.friction)}
        return params

    def host_energy(self, q, params) -> float:
        return float(_search_energy(jnp.asarray(q), self._host_params(params), self.geometry, self._jit_config))

    def host_gradient(self, q, params) -> np.ndarray:
        return np.asarray(_gradient(jnp.asarray(q), self._host_params(params), self.geometry, self._jit_config))

    def _linearizes(self) -> bool:
        return self.mesh.n_faces <= LINEARIZED_PRODUCT_MAX_FACES

    def host_gradient_linearized(self, q, params):
        """(gradient [N] as a host array, its linearization for :meth:`host_hessian_operator`)."""
        gradient, linear = _linearized_gradient(jnp.asarray(q), self._host_params(params), self.geometry, self._jit_config)
        return np.asarray(gradient), linear

    def host_hessian_operator(self, q, params, gradient=None, linear=None):
        """v ↦ H(q) v [N] (host arrays; unmasked, exact) for displacements v (3V + 3,) [m]; with
        the ``gradient`` [N] at q, Newton's matrix (:func:`_barrier_softening`) instead of H.
        ``linear``: the linearization at q from :meth:`host_gradient_linearized`, if at hand."""
        q, params = jnp.asarray(q), self._host_params(params)
        blocks = None
        if gradient is not None and _softens(self.config):
            blocks = _barrier_softening(q, jnp.asarray(gradient), self.geometry, self._jit_config)
        if not self._linearizes():
            def product(v):
                hv = _hessian_vector_product(q, params, self.geometry, self._jit_config, v)
                return hv if blocks is None else _plus_vertex_blocks(hv, blocks, v)
        else:
            if linear is None:
                linear = _linearized_gradient(q, params, self.geometry, self._jit_config)[1]
            if blocks is None:
                product = lambda v: _apply_linear(linear, v)  # noqa: E731
            else:
                product = lambda v: _apply_linear_softened(linear, blocks, v)  # noqa: E731
        return lambda v: np.asarray(product(jnp.asarray(v)))

    def host_hessian(self, q, params, project: bool = False, gradient=None):
        """(CSR Hessian with pins folded in, rank-one part or None); with the ``gradient`` [N] at
        q, Newton's matrix (:func:`_barrier_softening`) instead of the Hessian."""
        q = jnp.asarray(q)
        params = self._host_params(params)
        gradient = None if gradient is None else jnp.asarray(gradient)
        if project:
            # The eigenvalue clamp runs in NumPy: a vmapped jnp.linalg.eigh (a LAPACK custom call)
            # inside this XLA:CPU program never returned on 2-core machines (see docs/shell3d.md).
            n_faces = self.mesh.n_faces
            size = _balanced_chunk(n_faces, FACE_HESSIAN_CHUNK)

            def face_chunks():
                # JAX computes FACE_HESSIAN_CHUNK faces at a time (its autodiff intermediates for
                # 8192 faces took 0.4 GiB at 80k faces); the host clamps batches of PROJECTION_CHUNK.
                batch, count = [], 0
                for start in range(0, n_faces, size):
                    chunk = _face_hessians(q, params, self.geometry, self._jit_config, start, size)
                    batch.append(np.asarray(chunk)[start - min(start, n_faces - size) :])
                    count += len(batch[-1])
                    if count >= PROJECTION_CHUNK or start + size >= n_faces:
                        yield np.concatenate(batch)
                        batch, count = [], 0

            contact = _contact_hessians_jit(q, params, self.geometry, self._jit_config, gradient)
            data = self.pattern.assemble_projected([face_chunks()] + [np.asarray(b) for b in contact])
        else:
            data = _hessian_values(q, params, self.geometry, self._jit_config, self.pattern.maps, self.pattern.nnz, gradient)
        mat = self.pattern.matrix(data)
        rank_one = None
        if self.config.gas != "prescribed":
            c2, u = _rank_one(q, params, self.geometry, self._jit_config)
            rank_one = (float(c2), np.where(self.free, np.asarray(u), 0.0))
        return mat, rank_one

    def solve(self, q0, params, *, atol: float, max_iter: int = 60, factorization=None, name: str = "shell Newton"):
        """Newton equilibrium from ``q0`` with max |free force| ≤ ``atol`` [N]; NewtonResult.

        Steps are inexact Newton steps (CG on exact Hessian-vector products) preconditioned by a
        kept factorization, ``factorization`` (e.g. the previous load step's
        ``last_factorization``) first: :func:`shelljax.solve.newton`. Newton's matrix is the
        Hessian with the planes' barriers softened where they press harder than the load
        (:func:`_barrier_softening`); it equals the Hessian at equilibrium."""
        params = self._host_params(params)
        # Newton's matrix needs the gradient at the iterate (barrier softening) and CG its
        # linearization, which computes the gradient anyway: keep the last of both.
        last = {}

        def gradient(q):
            if self._linearizes():
                last["q"], (last["g"], last["linear"]) = q, self.host_gradient_linearized(q, params)
            else:
                last["q"], last["g"] = q, self.host_gradient(q, params)
            return last["g"]

        def gradient_at(q):
            return last["g"] if last.get("q") is q else self.host_gradient(q, params)

        def hessian_operator(q):
            linear = last.get("linear") if last.get("q") is q else None
            return self.host_hessian_operator(q, params, gradient_at(q), linear)

        barrier = self.config.contact.kind == "barrier" and n_bodies(self.config) > 0
        return newton(
            lambda q: self.host_energy(q, params),
            gradient,
            lambda q, project: self.host_hessian(q, params, project, gradient_at(q)),
            q0,
            self.free,
            atol=atol,
            max_iter=max_iter,
            hessian_operator=hessian_operator,
            factorization=factorization,
            project=self.feasible_trial if barrier else None,
            name=name,
        )

    def feasible_trial(self, q, q_trial) -> np.ndarray:
        """``q_trial`` [m] with every vertex whose gap to a body would fall below
        ``BARRIER_STEP_FRACTION`` of its gap at ``q`` (and below the barrier's range ĝ) put at that
        fraction, along the body's normal; pinned dofs as in ``q_trial``. Newton's line search
        projection with barrier contact: the vertices the step would drive into (or nearly
        into) a body stop short, everything else moves the whole way."""
        config = self.config
        start_gaps = body_gaps(q, config)

        def target(body, gap):
            floor = BARRIER_STEP_FRACTION * start_gaps[body]
            return np.where((gap < floor) & (gap < config.contact.activation_distance), floor, np.nan)

        return np.where(self.free, place_at_gaps(q_trial, config, target), q_trial)

    def linear_response(self, q, params, load) -> np.ndarray:
        """Displacement [m] solving H u = load [N] at state q (exact Hessian; pins held)."""
        params = jax.tree_util.tree_map(jnp.asarray, params)
        mat, rank_one = self.host_hessian(q, params, project=False)
        return SparseSolver(mat, rank_one, symmetric=True).solve(np.where(self.free, load, 0.0))


def rigid_mode_pins(vertices, n_extra: int = 3, fixed_extra=(True, True, True)) -> np.ndarray:
    """Pins removing the horizontal rigid modes of a shell about the vertical (z) axis.

    Fixes x and y of the top (max z) and bottom (min z) vertices, and the y of the vertex with the
    largest x: this removes the x/y translations and the three rotations, none of which an
    axisymmetric load resists. For a load symmetric about the z axis through the two pinned
    vertices, the pins carry no reaction (checked in the tests by the global force balance). The
    vertical translation is left free (ground/indenter contacts or a pin added by the caller fix
    it). Returns the (3V + n_extra,) fixed-dof mask; ``fixed_extra`` for the indenter dofs.
    """
    v = np.asarray(vertices)
    fixed = np.zeros(3 * len(v) + n_extra, dtype=bool)
    top, bottom, side = int(np.argmax(v[:, 2])), int(np.argmin(v[:, 2])), int(np.argmax(v[:, 0]))
    fixed[[3 * top, 3 * top + 1, 3 * bottom, 3 * bottom + 1, 3 * side + 1]] = True
    fixed[3 * len(v) :] = np.asarray(fixed_extra, dtype=bool)
    return fixed


def _face_energy_from_rest(p, rest_p, thickness, young_modulus, poisson_ratio):
    metric, curvature, area = rest_geometry(rest_p[None])
    return face_energy(p, metric[0], curvature[0], area[0], thickness, young_modulus, poisson_ratio, 0.0)


@jax.jit
def _rest_jacobian_blocks(x, rest, stencil, thickness, young_modulus, poisson_ratio):
    jac = jax.jacfwd(jax.grad(_face_energy_from_rest, argnums=0), argnums=1)
    blocks = jax.vmap(jac, in_axes=(0, 0, None, None, None))(
        x[stencil], rest[stencil], thickness, young_modulus, poisson_ratio
    )
    return blocks.reshape(-1, 18, 18)


def rest_jacobian_values(x, rest, stencil, params, pattern):
    """CSR values of ∂(∇ₓE)/∂X [N/m]: the forces' sensitivity to the rest vertices X (V, 3).

    The per-face blocks are summed on the host: fusing the scatter into the same
    XLA program as the batched jacfwd deadlocked XLA:CPU (jaxlib 0.10.2) on meshes of ~2k faces.
    """
    blocks = np.asarray(
        _rest_jacobian_blocks(x, rest, stencil, params["thickness"], params["young_modulus"], params["poisson_ratio"])
    )
    return pattern.assemble_host(0, blocks)
