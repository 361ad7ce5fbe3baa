"""``SparseNewton``: the step minimiser of the 3D shell, on the engine's sparse factorisation.

Newton's loop is the simplified one of ``_minimise`` (traceable: it runs inside ``jit`` and
``lax.scan``), or with ``reuse_matrix=False`` the dense minimiser's; only the linear solve
differs. The Hessian of the incremental potential is assembled without ever being densified,

    ∇²Φ_inc = diag(inertia_weight [+ α M/Δt]) + K_shell(x) [+ β K_shell(xₙ)/Δt] + blockdiag(point blocks)
              + c u uᵀ + Σ_planes (c_p Wⁿ_p / Δt) v_p v_pᵀ,

K_shell the shell's sparse Hessian (membrane, bending and the gas's per-face part, on the
engine's sparsity pattern), the point blocks the planes' contact, damping and friction 3×3 blocks
at every vertex, c u uᵀ the sealed gas's rank-one term (Sherman–Morrison) and v_p = (mᵢ/M) n_p the
centre-of-mass dashpots' (Woodbury, one column per plane). The values are
computed in JAX; the factorisation (CHOLMOD through :class:`shelljax.shell3d.SparseSolver`, its
symbolic analysis cached per pattern) runs on the host through ``jax.pure_callback``. The implicit
derivative of a step solves with the same assembly, so ``jax.grad`` through a roll-out stays sparse.
Newton's matrix is kept across iterations and steps while it contracts (``reuse_matrix``,
:func:`simplified_newton_loop`); the host keeps recent factorisations by content and the
assembly of each pattern's free-dof matrix (:func:`shelljax.shell3d.kept_factorization` and
:func:`shelljax.shell3d.kept_assembly`: ``shell3d`` owns every host cache, and
:func:`shelljax.shell3d.release_factorizations` frees them).
Newton's step shifts a Hessian that is not positive definite by a multiple of its mean diagonal;
the implicit derivative's solve is never shifted.
β's gas rank-one term at xₙ is left out of Newton's matrix (an approximation of its step only).
"""

from __future__ import annotations

import dataclasses
import functools
import zlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp

from .._errors import InvalidInputError, NoConvergenceError
from ..shell3d import SparseSolver, kept_assembly, kept_factorization
from ._minimise import AbstractMinimiser, KeptMatrix, newton_loop, simplified_newton_loop
from ._shell import KeyedPattern, ShellDynamicSystem


def _woodbury(solver, columns, coeffs):
    """rhs ↦ (A + U D Uᵀ)⁻¹ rhs from a solver of A: y − Z D (I + Uᵀ Z D)⁻¹ Uᵀ y, Z = A⁻¹U (U: the columns)."""
    if not np.any(coeffs):
        return solver.apply_inverse
    z = solver.apply_inverse(columns.T) * coeffs[None, :]
    small = np.eye(len(coeffs)) + columns @ z

    def apply(rhs):
        y = solver.apply_inverse(rhs)
        return y - z @ np.linalg.solve(small, columns @ y)

    return apply


@dataclasses.dataclass(frozen=True, eq=False)
class _FreeAssembly:
    """Where Newton's matrix on the free dofs takes its values from (host, built once per pattern
    and free set): its CSR entry e is K's entry ``source[e]``, plus the point block entry
    ``block_source[j]`` at ``block_target[j]``, plus the diagonal of free dof i at ``diagonal[i]``.
    """

    indptr: np.ndarray
    indices: np.ndarray
    source: np.ndarray
    block_target: np.ndarray
    block_source: np.ndarray
    diagonal: np.ndarray
    fixed_zero: np.ndarray  # entries in a row or column of a dof the pattern fixes
    fixed_unit: np.ndarray  # and its diagonal

    @staticmethod
    def build(pattern, n: int, free: np.ndarray) -> "_FreeAssembly":
        """From the shell's pattern (its first ``n`` dofs the vertices') and the free dof indices."""
        positions = sp.csr_matrix(
            (np.arange(1.0, pattern.nnz + 1.0), pattern.indices, pattern.indptr), shape=(pattern.n_dofs,) * 2
        )
        sub = positions[:n, :n][free][:, free]
        sub.sort_indices()
        m = free.size
        keys = np.repeat(np.arange(m), np.diff(sub.indptr)) * m + sub.indices

        def find(rows, cols):  # CSR positions of (row, col) entries of the sub-matrix
            at = np.searchsorted(keys, rows * m + cols)
            if np.any(at >= keys.size) or np.any(keys[np.minimum(at, keys.size - 1)] != rows * m + cols):
                raise InvalidInputError("the shell's sparsity pattern lacks a vertex's own 3×3 block.")
            return at

        source = sub.data.astype(np.int64) - 1
        local = np.full(n, -1)
        local[free] = np.arange(m)
        v = n // 3
        base = 3 * np.arange(v)[:, None, None]
        row, col = (
            np.broadcast_to(base + np.arange(3)[:, None], (v, 3, 3)),
            np.broadcast_to(base + np.arange(3), (v, 3, 3)),
        )
        kept = (local[row] >= 0) & (local[col] >= 0)
        return _FreeAssembly(
            indptr=sub.indptr,
            indices=sub.indices,
            source=source,
            block_target=find(local[row][kept], local[col][kept]),
            block_source=np.flatnonzero(kept.ravel()),
            diagonal=find(np.arange(m), np.arange(m)),
            fixed_zero=np.flatnonzero(np.isin(source, pattern.fixed_entries)),
            fixed_unit=np.flatnonzero(np.isin(source, pattern.fixed_diagonal)),
        )

    def values(self, data, blocks, diag) -> np.ndarray:
        """CSR values of K (its fixed dofs folded in) + blockdiag(blocks) + diag(diag) on the free dofs."""
        out = data[self.source]
        out[self.fixed_zero] = 0.0
        out[self.fixed_unit] = 1.0
        out[self.block_target] += blocks.reshape(-1)[self.block_source]  # the targets are distinct
        out[self.diagonal] += diag
        return out

    def matrix(self, values) -> sp.csr_matrix:
        m = self.indptr.size - 1
        return sp.csr_matrix((values, self.indices, self.indptr), shape=(m, m))


def _free_assembly(sparsity: KeyedPattern, n: int, free: np.ndarray) -> _FreeAssembly:
    """The :class:`_FreeAssembly` of ``sparsity`` and these free dofs, kept by ``shell3d``."""
    key = (sparsity.key, n, zlib.crc32(free.tobytes()))
    return kept_assembly(key, lambda: _FreeAssembly.build(sparsity.pattern, n, free))


def _factorised(sparsity, shift, data, blocks, diag, c2, u, columns, coeffs, free):
    """rhs ↦ (K + blockdiag + diag + c u uᵀ + Σ_p d_p v_p v_pᵀ)⁻¹ rhs on the free dofs (host; None if not
    positive definite); v_p = ``columns`` (P, n), d_p = ``coeffs`` (P,): the body dashpots.

    With ``shift``, a matrix that is not positive definite is shifted by 1e-2, 1e-1, 1 times its
    mean diagonal until it is (Newton's step then is a descent direction)."""
    arrays = [np.asarray(a, dtype=np.float64) for a in (data, blocks, diag, c2, u, coeffs, columns)]
    free = np.asarray(free, dtype=np.int64)
    fingerprint = (sparsity.key, bool(shift), free.size, hash(b"".join(a.tobytes() for a in arrays) + free.tobytes()))
    return kept_factorization(fingerprint, lambda: _factorise(sparsity, shift, *arrays, free))


def _factorise(sparsity, shift, data, blocks, diag, c2, u, coeffs, columns, free):
    """The solve of :func:`_factorised`, made afresh."""
    assembly = _free_assembly(sparsity, blocks.shape[0] * 3, free)
    values = assembly.values(data, blocks, diag[free])
    rank = (float(c2), u[free]) if float(c2) != 0.0 else None
    mean = float(np.mean(np.abs(values[assembly.diagonal])))
    apply = None
    for factor in (0.0, 1e-2, 1e-1, 1.0) if shift else (0.0,):
        shifted = values
        if factor:
            shifted = values.copy()
            shifted[assembly.diagonal] += factor * mean
        try:
            solver = SparseSolver(assembly.matrix(shifted), rank, symmetric=True, definite=True)
        except NoConvergenceError:
            continue
        apply = _woodbury(solver, columns[:, free], coeffs)
        break
    return apply


def _host_solve(sparsity, shift, data, blocks, diag, c2, u, columns, coeffs, free, rhs):
    """The solve of :func:`_factorised` applied to ``rhs`` (NaN where the matrix is not positive definite)."""
    apply = _factorised(sparsity, shift, data, blocks, diag, c2, u, columns, coeffs, free)
    if apply is None:
        return np.full(rhs.shape, np.nan)
    return np.asarray(apply(np.asarray(rhs)), dtype=np.float64)


def rayleigh_values(potential):
    """CSR values [N/m] of Rayleigh β's β K(xₙ)/Δt (None without Rayleigh): fixed over a step."""
    if potential.rayleigh is None:
        return None
    return potential.rayleigh.stiffness_coefficient / potential.dt * potential.system.hessian_parts(potential.x_prev)[0]


def newton_matrix(potential, y, rayleigh, minimiser: str = "SparseNewton"):
    """Newton's matrix of a shell step at y [m] as its parts (data, blocks, diag, c2, u, columns,
    coeffs): the shell's CSR values [N/m] (with Rayleigh β's ``rayleigh`` values added), the point
    blocks (V, 3, 3) [N/m], the diagonal (3V,) [N/m], the gas's rank-one (c2, u) and the
    dashpots' columns (P, 3V) with coefficients (P,) (module doc)."""
    system = potential.system
    if not isinstance(system, ShellDynamicSystem):
        raise InvalidInputError(
            f"{minimiser} needs a ShellDynamicSystem; got {type(system).__name__}. Use DenseNewton for small systems."
        )
    x = potential.full(y)
    data, c2, u = system.hessian_parts(x)
    diag = potential.inertia_weight
    if potential.rayleigh is not None:
        diag = diag + potential.rayleigh.mass_coefficient * system.lumped_mass() / potential.dt
        data = data + rayleigh
    blocks = potential.point_hessian_blocks(x)
    share = jnp.repeat(system.node_masses / jnp.sum(system.node_masses), 3)
    columns = (
        jnp.stack([share * jnp.tile(p.normal, system.node_masses.shape[0]) for p in system.planes])
        if system.planes
        else jnp.zeros((0, x.shape[0]))
    )
    coeffs = (
        jnp.stack([p.damping for p in system.planes]) * potential.body_damping_prev / potential.dt
        if system.planes
        else jnp.zeros((0,))
    )
    return data, blocks, diag, c2, u, columns, coeffs


class SparseNewton(AbstractMinimiser):
    """Newton's method on a :class:`ShellDynamicSystem` step with the sparse Hessian (module doc).

    Converged when the Newton step's largest component is below ``step_tolerance`` [m];
    ``max_steps`` bounds the iterations and ``max_halvings`` the feasibility-keeping line search.
    With ``reuse_matrix`` (default) it is the simplified Newton of :func:`simplified_newton_loop`:
    Newton's matrix and its factorisation are kept across iterations and steps while its steps
    contract; otherwise the matrix is assembled and factorised at every iteration.
    """

    step_tolerance: float = eqx.field(static=True, default=1e-10)
    max_steps: int = eqx.field(static=True, default=50)
    max_halvings: int = eqx.field(static=True, default=40)
    reuse_matrix: bool = eqx.field(static=True, default=True)

    def linear_solve(self, potential, y, rhs):
        return self._apply(potential, newton_matrix(potential, y, rayleigh_values(potential)), rhs, False)

    def _apply(self, potential, matrix, rhs, shift: bool):
        out = jax.ShapeDtypeStruct(rhs.shape, rhs.dtype)
        solve = functools.partial(_host_solve, potential.system.sparsity, shift)
        data, blocks, diag, c2, u, columns, coeffs = matrix
        return jax.pure_callback(
            solve, out, data, blocks, diag, c2, u, columns, coeffs, potential.free_dofs, rhs, vmap_method="sequential"
        )

    def _direction(self, potential, matrix, g):
        p = self._apply(potential, matrix, -g, True)
        # Only a failed shift gives NaN: fall back to descent scaled by the inertia.
        ok = jnp.all(jnp.isfinite(p)) & (g @ p < 0.0)
        return jnp.where(ok, p, -g / jnp.max(potential.inertia_weight))

    def initial_memory(self, potential, y0):
        if not self.reuse_matrix:
            return None
        shapes = jax.eval_shape(lambda y: newton_matrix(potential, y, rayleigh_values(potential)), y0)
        return KeptMatrix(jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype), shapes), jnp.asarray(True))

    def minimise(self, potential, y0, memory=None):
        # K(xₙ) of Rayleigh β is the same in every iteration of the step: assembled once, before the loop.
        rayleigh = rayleigh_values(potential)

        def assemble(y):
            return newton_matrix(potential, y, rayleigh)

        if not self.reuse_matrix:
            return newton_loop(self, potential, y0, lambda y, g: self._direction(potential, assemble(y), g))
        memory = self.initial_memory(potential, y0) if memory is None else memory
        return simplified_newton_loop(
            self, potential, y0, assemble, lambda values, g: self._direction(potential, values, g), memory
        )
