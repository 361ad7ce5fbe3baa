"""Second derivatives of the shell energy: sparse Hessian assembly and Hessian-vector products.

The face Hessians (18×18, by autodiff of :func:`face_energy`) and the per-vertex contact blocks are
scattered into the CSR values of a :class:`SparsityPattern`; a sealed gas adds the dense rank-one
term Π''(V) ∇V ∇Vᵀ (:func:`rank_one`), which the factorization handles by Sherman–Morrison.
Newton's matrix is the Hessian with the planes' barriers softened (:func:`barrier_softening`).
Units: N/m for Hessian entries, N for products with displacements in m.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..physics import sphere_gap
from ._config import ModelConfig, split_dofs
from ._contact import contact_potential, contact_stiffness, friction_coefficient, friction_data, vertex_friction
from ._energy import face_energy, gas_energy, rest_geometry, total_energy, volume
from ._sparse import assemble_values, element_positions


@functools.partial(jax.jit, static_argnames=("config",))
def linearized_gradient(q, params, geometry, config) -> tuple[Array, jax.tree_util.Partial]:
    """(∇E(q) [N], v ↦ H(q) v [N]): the gradient and the exact Hessian (sealed gas's rank-one part
    included) at q as a linear map, with the primal's intermediates computed once, so that each
    product is cheaper than a jvp of the gradient (docs/shell3d.md, *Benchmark*)."""
    return jax.linearize(lambda y: jax.grad(total_energy)(y, params, geometry, config), q)


apply_linear = jax.jit(lambda linear, v: linear(v))


@functools.partial(jax.jit, static_argnames=("config",))
def hessian_vector_product(q, params, geometry, config, v):
    """H(q) v [N] by forward-over-reverse differentiation: nothing kept between products."""
    return jax.jvp(lambda y: jax.grad(total_energy)(y, params, geometry, config), (q,), (v,))[1]


#: Above this many faces the Hessian-vector products of Newton's CG are jvps instead of products
#: of a stored linearization, whose kept intermediates (≈ 9 kB per face) cost too much memory.
LINEARIZED_PRODUCT_MAX_FACES = 40_000


#: Faces per vectorized chunk of the element-Hessian kernel.
FACE_HESSIAN_CHUNK = 1024
#: Faces per chunk of the PSD-projected Hessian (its eigenvalue clamp runs on the host).
PROJECTION_CHUNK = 8192


def _face_hessian_kernel(q, params, geometry, config):
    """(face ↦ its 18×18 Hessian [N/m], the per-face inputs): the membrane, bending and
    pressure-follower energy of one face, differentiated twice (the gas pressure is fixed at the
    current volume's; the gas's rank-one term is :func:`rank_one`)."""
    x, _ = split_dofs(q, config)
    vol = volume(x, geometry.stencil)
    pressure = -jax.grad(gas_energy)(vol, params, config)
    face_hess = jax.hessian(lambda p, *rest: face_energy(p.reshape(6, 3), *rest))
    material = (params.thickness, params.young_modulus, params.poisson_ratio, pressure)
    faces = (x[geometry.stencil].reshape(-1, 18), geometry.rest_metric, geometry.rest_curvature, geometry.rest_area)
    return (lambda face: face_hess(*face, *material)), faces


def _contact_hessians(q, params, geometry, config):
    """Per-vertex contact (and friction) Hessian blocks [N/m], one (V, k, k) array per contact
    family (indenter, then each plane), in the order of :class:`ShellModel`'s pattern."""
    x, c = split_dofs(q, config)
    blocks = []
    k = contact_stiffness(geometry, config.contact)
    if config.contact.indenter_radius is not None:

        def pair(y, kv):
            gap = sphere_gap(y[:3], y[3:], config.contact.indenter_radius)
            return contact_potential(gap, kv, config.contact)

        cc = jnp.broadcast_to(c, x.shape)
        blocks.append(jax.vmap(jax.hessian(pair))(jnp.concatenate([x, cc], axis=1), k))
    friction = config.contact.has_friction
    if friction:
        anchor, lam = friction_data(params, config)
        mu = friction_coefficient(params, config)
    for i, plane in enumerate(config.contact.planes):
        # The friction of a vertex on a plane involves only that vertex: it shares the plane's
        # per-vertex 3×3 block (same sparsity pattern with or without friction).
        def single(y, kv, y_hat, lam_v, plane=plane):
            gap = plane.gap(y)
            e = contact_potential(gap, kv, config.contact)
            if friction:
                e = e + vertex_friction(y, y_hat, lam_v, plane.normal, mu, config.contact)
            return e

        y_hat = anchor if friction else x
        lam_i = lam[i] if friction else jnp.zeros_like(k)
        blocks.append(jax.vmap(jax.hessian(single))(x, k, y_hat, lam_i))
    return blocks


#: Smallest factor on a barrier's stiffness along its gap gradient in Newton's matrix
#: (:func:`barrier_softening`). A vertex that nothing presses (λ̂ ≤ 0) gets it; where the barrier
#: alone holds a rigid mode (the ball's vertical translation in force control), Newton's step in
#: that mode is then at most 1/floor too long for the line search (smaller floors stall there).
BARRIER_SOFTENING_FLOOR = 1e-2


@functools.partial(jax.jit, static_argnames=("config",))
def barrier_softening(q, gradient, geometry, config) -> Float[Array, "V 3 3"]:
    """Per vertex, the 3×3 correction [N/m] that turns the Hessian into Newton's matrix: the
    planes' barrier stiffness φ'' n nᵀ scaled down; ``gradient`` [N] is ∇E at q.

    A log barrier pressing a vertex harder than its load needs (gap far below equilibrium) has a
    stiffness φ'' ≈ λ_b / gap, with λ_b = −φ' its force, so a Newton step can at most double the
    gap.
    The primal–dual remedy of interior-point methods scales φ'' by λ̂ / λ_b, where λ̂ = λ_b + n·∇E
    is the force the rest of the model presses the vertex with (the dual estimate that balances
    it). With φ'' ≈ λ_b / gap this is λ̂ / gap, and the step of a vertex under a fixed load reaches
    its equilibrium gap in one go. The factor is clipped to [``BARRIER_SOFTENING_FLOOR``, 1]: a
    barrier is never stiffened, and at equilibrium (∇E = 0 on free dofs) the factor is 1, so the
    converged state and Newton's final rate are those of the true Hessian. A softer barrier keeps
    the matrix positive definite wherever the true one is, so the steps still descend the energy.

    Planes only: softening the indenter's barrier too made the line search cut its steps
    (docs/shell3d.md, *Benchmark*).
    """
    x, _ = split_dofs(q, config)
    vertex_gradient = gradient[: x.size].reshape(x.shape)
    k = contact_stiffness(geometry, config.contact)
    slope = jax.vmap(jax.grad(contact_potential), in_axes=(0, 0, None))
    curvature = jax.vmap(jax.grad(jax.grad(contact_potential)), in_axes=(0, 0, None))
    blocks = jnp.zeros((config.n_vertices, 3, 3))
    for plane in config.contact.planes:
        normal = plane.normal
        gap = plane.gap(x)
        push = -slope(gap, k, config.contact)
        pressed = push > 0.0
        ratio = 1.0 + (vertex_gradient @ normal) / jnp.where(pressed, push, 1.0)
        factor = jnp.where(pressed, jnp.clip(ratio, BARRIER_SOFTENING_FLOOR, 1.0), 1.0)
        blocks = blocks + ((factor - 1.0) * curvature(gap, k, config.contact))[:, None, None] * jnp.outer(
            normal, normal
        )
    return blocks


def softens(config: ModelConfig) -> bool:
    """Whether Newton's matrix differs from the Hessian (:func:`barrier_softening`)."""
    return config.contact.kind == "barrier" and bool(config.contact.planes)


def _softened_contact_hessians(q, params, geometry, config, gradient=None):
    """:func:`_contact_hessians`, with :func:`barrier_softening` at ``gradient`` [N] unless None."""
    blocks = _contact_hessians(q, params, geometry, config)
    if gradient is not None and softens(config):
        # Each plane's block is its vertex's own 3×3: the first one takes the corrections of all.
        first = len(blocks) - len(config.contact.planes)
        blocks[first] = blocks[first] + barrier_softening(q, gradient, geometry, config)
    return blocks


def plus_vertex_blocks(product, blocks, v):
    """product + the (V, 3, 3) vertex ``blocks`` applied to v (3V + 3,) (the indenter dofs untouched)."""
    vertex = jnp.einsum("vij,vj->vi", blocks, v[:-3].reshape(-1, 3))
    return product + jnp.concatenate([vertex.reshape(-1), jnp.zeros(3)])


apply_linear_softened = jax.jit(lambda linear, blocks, v: plus_vertex_blocks(linear(v), blocks, v))


def balanced_chunk(n: int, most: int) -> int:
    """Chunk size ≤ ``most`` that covers ``n`` items in the fewest chunks, the last one
    overlapping the one before it by fewer than the number of chunks."""
    return -(-n // -(-n // most))


def _face_chunk(kernel, faces, start, size):
    """(Hessians of ``size`` consecutive faces from ``start``, the start used): a chunk that would
    overrun is shifted back to end at the last face, and the caller drops the overlap."""
    start = jnp.minimum(start, faces[0].shape[0] - size)
    return jax.vmap(kernel)([jax.lax.dynamic_slice_in_dim(a, start, size) for a in faces]), start


@functools.partial(jax.jit, static_argnames=("config", "size"))
def face_hessians(q, params, geometry, config, start, size):
    """The 18×18 Hessians [N/m] of ``size`` faces from face ``start`` (see :func:`_face_chunk`)."""
    return _face_chunk(*_face_hessian_kernel(q, params, geometry, config), start, size)[0]


contact_hessians = jax.jit(_softened_contact_hessians, static_argnames=("config",))


@functools.partial(jax.jit, static_argnames=("config", "nnz"))
def hessian_values(q, params, geometry, config, maps, nnz, gradient=None):
    """CSR values of the exact Hessian [N/m] (a pattern's ``maps`` and ``nnz``), element blocks
    summed inside one XLA program; with ``gradient`` [N] at q, Newton's matrix
    (:func:`barrier_softening`).

    The face Hessians are computed in balanced chunks of at most ``FACE_HESSIAN_CHUNK`` faces and
    each chunk is scattered at once: the (F, 18, 18) array of all of them never exists, the
    autodiff intermediates stay small, and chunks that fit in cache are faster too.
    """
    data = assemble_values(maps[1:], nnz, _softened_contact_hessians(q, params, geometry, config, gradient))
    kernel, faces = _face_hessian_kernel(q, params, geometry, config)
    n_faces = faces[0].shape[0]
    chunk = balanced_chunk(n_faces, FACE_HESSIAN_CHUNK)
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
def rank_one(q, params, geometry, config):
    """(Π''(V), ∇_q V) for the dense rank-one part of a sealed gas's Hessian."""
    x, _ = split_dofs(q, config)
    vol_fn = lambda y: volume(y.reshape(-1, 3), geometry.stencil)  # noqa: E731
    vol, dvol = jax.value_and_grad(vol_fn)(x.reshape(-1))
    c2 = jax.grad(jax.grad(gas_energy), argnums=0)(vol, params, config)
    return c2, jnp.concatenate([dvol, jnp.zeros(3)])


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

    The per-face blocks are summed on the host: fused into the batched jacfwd's XLA program, the
    scatter deadlocked XLA:CPU (docs/shell3d.md, *XLA:CPU hangs*).
    """
    blocks = np.asarray(
        _rest_jacobian_blocks(x, rest, stencil, params.thickness, params.young_modulus, params.poisson_ratio)
    )
    return pattern.assemble_host(0, blocks)


def linearizes(n_faces: int) -> bool:
    """Whether CG's products on a mesh of ``n_faces`` come from a stored linearization."""
    return n_faces <= LINEARIZED_PRODUCT_MAX_FACES


def projected_hessian_values(q, params, geometry, config, pattern, gradient=None) -> np.ndarray:
    """CSR values (host) of the per-element PSD-projected Hessian [N/m] (Newton's fallback).

    The eigenvalue clamp runs in NumPy: a vmapped jnp.linalg.eigh inside this XLA:CPU program
    never returned on 2-core machines (docs/shell3d.md, *XLA:CPU hangs*). JAX computes
    ``FACE_HESSIAN_CHUNK`` faces at a time; the host clamps batches of ``PROJECTION_CHUNK``.
    """
    n_faces = int(geometry.stencil.shape[0])
    size = balanced_chunk(n_faces, FACE_HESSIAN_CHUNK)

    def face_chunks():
        batch, count = [], 0
        for start in range(0, n_faces, size):
            chunk = face_hessians(q, params, geometry, config, start, size)
            batch.append(np.asarray(chunk)[start - min(start, n_faces - size) :])
            count += len(batch[-1])
            if count >= PROJECTION_CHUNK or start + size >= n_faces:
                yield np.concatenate(batch)
                batch, count = [], 0

    contact = contact_hessians(q, params, geometry, config, gradient)
    return pattern.assemble_projected([face_chunks()] + [np.asarray(b) for b in contact])
