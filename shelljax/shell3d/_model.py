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

Parameters that can be differentiated are a :class:`ShellParams` (SI units).
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._config import ModelConfig, check_config, jit_config, split_dofs
from ._contact import BARRIER_STEP_FRACTION, body_gaps, n_bodies, place_at_gaps
from ._contact import stacked_friction_forces, stacked_plane_normal_forces
from ._energy import ShellGeometry, energy_gradient, gauge_pressure, make_geometry, search_energy, total_energy, volume
from ._hessian import (
    apply_linear,
    apply_linear_softened,
    barrier_softening,
    hessian_values,
    hessian_vector_product,
    linearized_gradient,
    linearizes,
    plus_vertex_blocks,
    projected_hessian_values,
    rank_one,
    softens,
)
from ._krylov import SparseOperator, krylov_layout, sparse_operator
from ._linear import AbstractLinearSolver
from ._mesh import ShellMesh
from .._solution import Solution
from ._newton import AbstractEnergyProblem, newton
from ._params import FRICTION_FIELDS, ShellParams
from ._sparse import SparseSolver, SparsityPattern


def _pattern(mesh: ShellMesh, config: ModelConfig, free: np.ndarray) -> SparsityPattern:
    """Sparsity of the faces' 18-dof blocks and of each contact family's per-vertex blocks."""
    blocks = [(3 * mesh.stencil[:, :, None] + np.arange(3)).reshape(-1, 18)]
    vdofs = 3 * np.arange(mesh.n_vertices)[:, None] + np.arange(3)
    if config.contact.indenter_radius is not None:
        cdofs = np.broadcast_to(3 * mesh.n_vertices + np.arange(3), vdofs.shape)
        blocks.append(np.concatenate([vdofs, cdofs], axis=1))
    for _ in config.contact.planes:
        blocks.append(vdofs)
    return SparsityPattern.from_elements(blocks, 3 * mesh.n_vertices + 3, free)


class ShellModel(eqx.Module):
    """A discrete shell on a closed mesh with gas, contacts and pins; Newton-ready.

    ``mesh``: topology; ``rest_vertices`` (V, 3) [m]: stress-free shape; ``config``: static setup;
    ``fixed``: (3V + 3,) bool mask of pinned dofs (pins remove rigid-body modes; see
    :func:`rigid_mode_pins`).
    """

    mesh: ShellMesh
    config: ModelConfig
    rest_vertices: np.ndarray
    geometry: ShellGeometry
    free: np.ndarray
    pattern: SparsityPattern

    def __init__(self, mesh: ShellMesh, rest_vertices, config: ModelConfig, fixed):
        check_config(config)
        self.mesh = mesh
        self.config = config
        self.rest_vertices = np.asarray(rest_vertices, dtype=np.float64)
        self.geometry = make_geometry(mesh, self.rest_vertices)
        self.free = ~np.asarray(fixed, dtype=bool)
        self.pattern = _pattern(mesh, config, self.free)

    @property
    def n_dofs(self) -> int:
        """Number of unknowns: 3 per vertex and 3 for the indenter center."""
        return 3 * self.mesh.n_vertices + 3

    @property
    def jit_config(self) -> ModelConfig:
        """The compile key: ``config`` with μ > 0 normalised (μ travels in the parameters)."""
        return jit_config(self.config)

    def with_rest(self, rest_vertices) -> "ShellModel":
        """Same model with another rest shape (reuses the sparsity pattern and compiled code)."""
        rest = np.asarray(rest_vertices, dtype=np.float64)
        return eqx.tree_at(lambda m: (m.rest_vertices, m.geometry), self, (rest, make_geometry(self.mesh, rest)))

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
        # Same element families: keep the sparsity pattern and the geometry.
        check_config(config)
        return eqx.tree_at(lambda m: m.config, self, config)

    # --- JAX functions (traceable) -------------------------------------------------------------
    def energy(self, q, params):
        """Total energy [J]."""
        return total_energy(q, params, self.geometry, self.config)

    def gradient(self, q, params):
        """Energy gradient [N] (unmasked), traceable."""
        return jax.grad(total_energy)(q, params, self.geometry, self.config)

    def volume(self, q):
        """Enclosed volume [m³]."""
        return volume(split_dofs(q, self.config)[0], self.geometry.stencil)

    def gauge_pressure(self, q, params):
        """Current gas gauge pressure [Pa]."""
        return gauge_pressure(q, params, self.geometry, self.config)

    def plane_normal_forces(self, q) -> np.ndarray:
        """(n_planes, V) normal contact force magnitudes λ = −dφ/dgap [N] at state q (host)."""
        return np.asarray(stacked_plane_normal_forces(jnp.asarray(q), self.geometry, self.jit_config))

    def friction_forces(self, q, params) -> np.ndarray:
        """(n_planes, V, 3) friction forces −∂D/∂x_v [N] of each plane on each vertex (host; 0
        without friction). Tangential to the plane, magnitude μ λ f₁(‖slip‖) ≤ μ λ."""
        return np.asarray(stacked_friction_forces(jnp.asarray(q), self.host_params(params), self.jit_config))

    # --- host functions for Newton --------------------------------------------------------------
    def host_params(self, params: ShellParams) -> ShellParams:
        """``params`` as arrays, with the config's μ as a traced value (see :func:`jit_config`):
        what the compiled host functions take.

        Without friction the friction entries are dropped: they are unused, and leaving them in
        would change the pytree and so recompile the frictionless functions.
        """
        params = jax.tree_util.tree_map(jnp.asarray, params)
        if not self.config.contact.has_friction:
            return params.replace(**dict.fromkeys(FRICTION_FIELDS))
        if params.friction_coefficient is None:
            params = params.replace(friction_coefficient=self.config.contact.friction)
        return params

    def host_energy(self, q, params) -> float:
        """Energy [J] for Newton's line search (+inf where infeasible)."""
        return float(search_energy(jnp.asarray(q), self.host_params(params), self.geometry, self.jit_config))

    def host_gradient(self, q, params) -> np.ndarray:
        """Energy gradient [N] (unmasked) as a host array."""
        return np.asarray(energy_gradient(jnp.asarray(q), self.host_params(params), self.geometry, self.jit_config))

    def host_gradient_linearized(self, q, params):
        """(gradient [N] as a host array, its linearization for :meth:`host_hessian_operator`)."""
        gradient, linear = linearized_gradient(jnp.asarray(q), self.host_params(params), self.geometry, self.jit_config)
        return np.asarray(gradient), linear

    def host_hessian_operator(self, q, params, gradient=None, linear=None):
        """v ↦ H(q) v [N] (host arrays; unmasked, exact) for displacements v (3V + 3,) [m]; with
        the ``gradient`` [N] at q, Newton's matrix (:func:`barrier_softening`) instead of H.
        ``linear``: the linearization at q from :meth:`host_gradient_linearized`, if at hand."""
        q, params = jnp.asarray(q), self.host_params(params)
        config = self.jit_config
        blocks = None
        if gradient is not None and softens(self.config):
            blocks = barrier_softening(q, jnp.asarray(gradient), self.geometry, config)
        if not linearizes(self.mesh.n_faces):

            def product(v):
                hv = hessian_vector_product(q, params, self.geometry, config, v)
                return hv if blocks is None else plus_vertex_blocks(hv, blocks, v)
        else:
            if linear is None:
                linear = linearized_gradient(q, params, self.geometry, config)[1]
            if blocks is None:
                product = lambda v: apply_linear(linear, v)  # noqa: E731
            else:
                product = lambda v: apply_linear_softened(linear, blocks, v)  # noqa: E731
        return lambda v: np.asarray(product(jnp.asarray(v)))

    def hessian_values(self, q, params, gradient=None) -> np.ndarray:
        """CSR values (host) of the exact Hessian [N/m] on :attr:`pattern`, unfolded; with the
        ``gradient`` [N] at q, Newton's matrix (:func:`barrier_softening`)."""
        q, params = jnp.asarray(q), self.host_params(params)
        gradient = None if gradient is None else jnp.asarray(gradient)
        return hessian_values(q, params, self.geometry, self.jit_config, self.pattern.maps, self.pattern.nnz, gradient)

    def host_hessian(self, q, params, project: bool = False, gradient=None):
        """(CSR Hessian with pins folded in, rank-one part or None); with the ``gradient`` [N] at
        q, Newton's matrix (:func:`barrier_softening`) instead of the Hessian."""
        if project:
            q, hp = jnp.asarray(q), self.host_params(params)
            gradient = None if gradient is None else jnp.asarray(gradient)
            data = projected_hessian_values(q, hp, self.geometry, self.jit_config, self.pattern, gradient)
        else:
            data = self.hessian_values(q, params, gradient)
        mat = self.pattern.matrix(data)
        rank = None
        if self.config.gas.sealed:
            c2, u = rank_one(jnp.asarray(q), self.host_params(params), self.geometry, self.jit_config)
            rank = (float(c2), np.where(self.free, np.asarray(u), 0.0))
        return mat, rank

    def device_operator(self, q, params, project: bool = False, gradient=None) -> SparseOperator:
        """:meth:`host_hessian` as a JAX :class:`SparseOperator` (pins and the sealed gas's
        rank-one term included), for a :class:`KrylovSolver`; traceable unless ``project`` (the
        PSD projection's eigenvalue clamp runs on the host, then the values move to the device)."""
        q, params = jnp.asarray(q), self.host_params(params)
        gradient = None if gradient is None else jnp.asarray(gradient)
        if project:
            data = projected_hessian_values(q, params, self.geometry, self.jit_config, self.pattern, gradient)
            data = jnp.asarray(data)
        else:
            data = hessian_values(
                q, params, self.geometry, self.jit_config, self.pattern.maps, self.pattern.nnz, gradient
            )
        layout = krylov_layout(self.pattern)
        if not self.config.gas.sealed:
            return sparse_operator(layout, data)
        c2, u = rank_one(q, params, self.geometry, self.jit_config)
        return sparse_operator(layout, data, columns=u[None, :], coeffs=jnp.reshape(c2, (1,)))

    def equilibrium(
        self,
        q0,
        params,
        *,
        atol: float,
        max_steps: int = 60,
        factorization=None,
        name: str = "shell Newton",
        barrier_aids: bool = True,
        linear_solver: AbstractLinearSolver | None = None,
    ) -> Solution:
        """Newton equilibrium from ``q0`` with max |free force| ≤ ``atol`` [N]: a
        :class:`shelljax.Solution` (raises NoConvergenceError where Newton fails).

        Steps are inexact Newton steps (CG on exact Hessian-vector products) preconditioned by a
        kept factorization, ``factorization`` (e.g. the previous load step's
        ``Solution.state``) first: :func:`newton` on :class:`EquilibriumProblem`. With
        ``barrier_aids``, Newton's matrix is the Hessian with the planes' barriers softened where
        they press harder than the load (:func:`barrier_softening`; it equals the Hessian at
        equilibrium), and the line search keeps the vertices out of the bodies
        (:meth:`EquilibriumProblem.feasible_trial`). ``linear_solver``: where Newton's steps solve
        (:class:`DirectSolver` by default, or :class:`KrylovSolver`)."""
        problem = EquilibriumProblem(self, self.host_params(params), barrier_aids)
        return newton(
            problem,
            q0,
            atol=atol,
            max_steps=max_steps,
            factorization=factorization,
            name=name,
            linear_solver=linear_solver,
        )

    def linear_response(self, q, params, load) -> np.ndarray:
        """Displacement [m] solving H u = load [N] at state q (exact Hessian; pins held)."""
        params = jax.tree_util.tree_map(jnp.asarray, params)
        mat, rank = self.host_hessian(q, params, project=False)
        return SparseSolver(mat, rank, symmetric=True).apply_inverse(np.where(self.free, load, 0.0))


class EquilibriumProblem(AbstractEnergyProblem):
    """The energy of ``model`` at fixed parameters ``params`` (host form), for :func:`newton`.

    The gradient comes with the linearization of the gradient map (meshes up to
    ``LINEARIZED_PRODUCT_MAX_FACES``), which CG's Hessian-vector products at the same state reuse.
    With ``barrier_aids`` (barrier contact), Newton's matrix softens the planes' barriers
    (:func:`barrier_softening`) and the line search projects onto feasible states.
    """

    model: ShellModel
    params: ShellParams
    barrier_aids: bool
    free: np.ndarray

    def __init__(self, model: ShellModel, params: ShellParams, barrier_aids: bool = True):
        self.model, self.params, self.barrier_aids = model, params, barrier_aids
        self.free = model.free

    def energy(self, x) -> float:
        return self.model.host_energy(x, self.params)

    def gradient(self, x) -> tuple[np.ndarray, Any]:
        if linearizes(self.model.mesh.n_faces):
            return self.model.host_gradient_linearized(x, self.params)
        return self.model.host_gradient(x, self.params), None

    def hessian(self, x, gradient, project: bool):
        return self.model.host_hessian(x, self.params, project, gradient[0] if self.barrier_aids else None)

    def device_operator(self, x, gradient, project: bool) -> SparseOperator:
        """Newton's matrix at x as a JAX operator (:meth:`ShellModel.device_operator`)."""
        return self.model.device_operator(x, self.params, project, gradient[0] if self.barrier_aids else None)

    def hessian_operator(self, x, gradient):
        """v ↦ Newton's matrix times v [N] at x, from the linearization kept with ``gradient``."""
        return self.model.host_hessian_operator(x, self.params, gradient[0] if self.barrier_aids else None, gradient[1])

    def feasible_trial(self, q, q_trial):
        """``q_trial`` [m] with every vertex whose gap to a body would fall below
        ``BARRIER_STEP_FRACTION`` of its gap at ``q`` (and below the barrier's range ĝ) put at that
        fraction, along the body's normal; pinned dofs as in ``q_trial``: the vertices the step
        would drive into (or nearly into) a body stop short, everything else moves the whole way.
        None without barrier contact (nothing to project) or without ``barrier_aids``."""
        config = self.model.config
        if not (self.barrier_aids and config.contact.kind == "barrier" and n_bodies(config) > 0):
            return None
        start_gaps = body_gaps(q, config)

        def target(body, gap):
            floor = BARRIER_STEP_FRACTION * start_gaps[body]
            return np.where((gap < floor) & (gap < config.contact.activation_distance), floor, np.nan)

        return np.where(self.free, place_at_gaps(q_trial, config, target), q_trial)


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
