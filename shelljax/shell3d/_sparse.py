"""Sparse assembly of per-element Hessians and host-side sparse direct solves.

The element Hessians are computed in JAX (vmapped over elements) and summed into the values of a
CSR matrix by a precomputed scatter map, so only ``nnz`` numbers cross to the host. The matrix is
never densified. The linear solve runs on the host on a METIS nested-dissection ordering (pymetis)
computed once per sparsity pattern: a supernodal CHOLMOD Cholesky (through cvxopt, symbolic
analysis once per pattern) for symmetric positive definite matrices, SciPy's SuperLU
(``scipy.sparse.linalg.splu``) for indefinite or nonsymmetric ones.
A dense rank-one term (sealed gas: Π''(V) ∇V ∇Vᵀ) is handled by Sherman–Morrison on top of the
sparse factorization.

Fixed degrees of freedom (pins that remove rigid-body modes) are folded into the matrix: their
rows and columns are zeroed and their diagonal set to one, so a right-hand side that is zero on
them gives a solution that is zero on them.
"""

from __future__ import annotations

import ctypes
import dataclasses
import weakref
import zlib

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .._errors import NoConvergenceError


_PROJECTION_CHUNK = 8192  # elements per host batch (eigenvalue clamp, host sum)


@dataclasses.dataclass(frozen=True, eq=False)
class SparsityPattern:
    """CSR pattern of a sum of element matrices, with the scatter map from element entries.

    Built once per mesh topology (the symbolic part); every Newton iteration only recomputes the
    ``nnz`` values. ``blocks`` are the element dof index arrays, one ``(n_elements, k)`` int array
    per element family; ``maps[i]`` sends the ``(n_elements, k, k)`` values of family ``i`` to
    positions in the CSR data array, in the compact form of :func:`element_positions`.
    """

    n_dofs: int
    indptr: np.ndarray
    indices: np.ndarray
    maps: tuple
    fixed_entries: np.ndarray  # CSR positions in a row or column of a fixed dof
    fixed_diagonal: np.ndarray  # CSR positions of the diagonal of fixed dofs
    free: np.ndarray  # (n_dofs,) bool

    @staticmethod
    def from_elements(blocks, n_dofs: int, free) -> "SparsityPattern":
        """Pattern from element dof blocks (list of (n_e, k) int arrays) and a free-dof mask."""
        free = np.asarray(free, dtype=bool)
        blocks = [np.asarray(blk, dtype=np.int64) for blk in blocks]
        nodal = _nodal_blocks(blocks, n_dofs)
        if nodal is not None:
            indptr, indices, rows, maps = _nodal_pattern(nodal, n_dofs // 3)
        else:
            indptr, indices, rows, maps = _dof_pattern(blocks, n_dofs)
        cols = indices
        fixed_entries = np.nonzero(~free[rows] | ~free[cols])[0]
        fixed_diagonal = np.nonzero((rows == cols) & ~free[rows])[0]
        return SparsityPattern(
            n_dofs=n_dofs,
            indptr=indptr,
            indices=indices.astype(np.int32),
            maps=tuple((jnp.asarray(base), jnp.asarray(stride)) for base, stride in maps),
            fixed_entries=fixed_entries,
            fixed_diagonal=fixed_diagonal,
            free=free,
        )

    @property
    def nnz(self) -> int:
        return int(self.indices.size)

    def assemble_values(self, element_matrices) -> jax.Array:
        """CSR values (JAX, traceable) from element matrices, one (n_e, k, k) array per family."""
        return assemble_values(self.maps, self.nnz, element_matrices)

    def assemble_projected(self, element_matrices) -> np.ndarray:
        """CSR values (host) of the sum of the nearest positive semi-definite element matrices.

        Each symmetric element matrix has its negative eigenvalues clamped to zero before the
        sum, so the assembled matrix is PSD: Newton's fallback when the exact Hessian gives no
        descent direction. ``element_matrices``: one entry per family, an (n_e, k, k) NumPy array
        or an iterable of its consecutive row chunks (so that a caller can stream them).
        """
        data = np.zeros(self.nnz)
        for family_map, family in zip(self.maps, element_matrices):
            chunks = family
            if isinstance(family, np.ndarray):
                # eigh and its products hold ~5 copies of what they are given: bound them.
                chunks = (family[i : i + _PROJECTION_CHUNK] for i in range(0, len(family), _PROJECTION_CHUNK))
            start = 0
            for chunk in chunks:
                sym = 0.5 * (chunk + np.swapaxes(chunk, -1, -2))
                w, v = np.linalg.eigh(sym)
                clamped = (v * np.maximum(w, 0.0)[..., None, :]) @ np.swapaxes(v, -1, -2)
                self._add_host(data, family_map, start, clamped)
                start += len(chunk)
        return data

    def assemble_host(self, family: int, element_matrices: np.ndarray) -> np.ndarray:
        """CSR values (host) of the (n_e, k, k) element matrices of family ``family`` alone,
        summed in chunks, without ever expanding the whole family's map."""
        data = np.zeros(self.nnz)
        for start in range(0, len(element_matrices), _PROJECTION_CHUNK):
            self._add_host(data, self.maps[family], start, element_matrices[start : start + _PROJECTION_CHUNK])
        return data

    def _add_host(self, data: np.ndarray, family_map, start: int, chunk: np.ndarray) -> None:
        """data += the element matrices ``chunk`` of elements start, start + 1, … of a family."""
        base, stride = (np.asarray(a)[start : start + len(chunk)] for a in family_map)
        rows = element_positions(base, stride, chunk.shape[-1])
        data += np.bincount(rows.ravel(), weights=chunk.ravel(), minlength=self.nnz)

    def matrix(self, data) -> sp.csr_matrix:
        """Host CSR matrix with the fixed dofs folded in (zero rows/cols, unit diagonal)."""
        data = np.array(data, dtype=np.float64)
        data[self.fixed_entries] = 0.0
        data[self.fixed_diagonal] = 1.0
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.n_dofs, self.n_dofs))


def assemble_values(maps, nnz: int, element_matrices) -> jax.Array:
    """CSR values (JAX, traceable): the element matrices (one (n_e, k, k) array per family)
    scattered through a pattern's ``maps`` into ``nnz`` entries.

    Inside a jitted function, pass ``maps`` as an argument rather than closing over a pattern:
    captured, they become constants of the XLA program, copied by the compiler and into the
    compilation cache, which slows the assembly (docs/shell3d.md, *Benchmark*).
    """
    data = jnp.zeros(nnz, dtype=jnp.float64)
    for (base, stride), values in zip(maps, element_matrices):
        data = data.at[element_positions(base, stride, values.shape[-1]).reshape(-1)].add(values.reshape(-1))
    return data


def element_positions(base, stride, size: int):
    """CSR positions (n_e, k, k) of the entries of ``k = size`` × ``k`` element matrices, from a
    pattern's compact map of their family (NumPy or JAX arrays).

    A map stores, per element, the position ``base`` (n_e, m, m) of entry (0, 0) of each of its
    m × m node-pair blocks of b × b dofs (b = k / m: 3 for the shell models' nodal patterns, 1
    otherwise) and the ``stride`` (n_e, m) between that block's rows (a CSR row's length):
    entry (b i + r, b j + c) sits at base[i, j] + r stride[i] + c. The expanded map (k² integers
    per element) exists only chunk by chunk.
    """
    n, m = base.shape[0], base.shape[1]
    block = size // m
    r = np.arange(block, dtype=np.int32)
    positions = base[:, :, None, :, None] + stride[:, :, None, None, None] * r[:, None, None] + r
    return positions.reshape(n, size, size)


def _index_dtype(size: int):
    return np.int32 if size < 2**31 else np.int64


def _dof_pattern(blocks, n_dofs: int):
    """CSR (indptr, indices, row of each entry, per-family scatter maps) by deduplicating every
    (row, column) key of every element entry."""
    keys = []
    for blk in blocks:
        rows = np.broadcast_to(blk[:, :, None], blk.shape + (blk.shape[1],))
        cols = np.broadcast_to(blk[:, None, :], blk.shape + (blk.shape[1],))
        keys.append((rows * n_dofs + cols).ravel())
    # The diagonal is always present so that fixed dofs can carry their unit pivot.
    diag = np.arange(n_dofs, dtype=np.int64) * (n_dofs + 1)
    unique, inverse = np.unique(np.concatenate(keys + [diag]), return_inverse=True)
    rows = unique // n_dofs
    indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=n_dofs))])
    maps, start = [], 0
    dtype = _index_dtype(unique.size)
    for blk, k in zip(blocks, keys):
        positions = inverse[start : start + k.size].astype(dtype).reshape(blk.shape[0], blk.shape[1], blk.shape[1])
        maps.append((positions, np.zeros(blk.shape, dtype=dtype)))  # 1 × 1 blocks: no stride
        start += k.size
    return indptr, unique % n_dofs, rows, maps


def _nodal_blocks(blocks, n_dofs: int):
    """Node index blocks (n_e, m) if every dof block lists whole nodes (dofs 3v, 3v+1, 3v+2 in
    order, as the shell models' are), else None."""
    if n_dofs % 3:
        return None
    nodal = []
    for blk in blocks:
        if blk.shape[1] % 3:
            return None
        nodes = blk[:, 0::3] // 3
        if not np.array_equal(blk, (3 * nodes[:, :, None] + np.arange(3)).reshape(blk.shape)):
            return None
        nodal.append(nodes)
    return nodal


def _nodal_pattern(nodal, n_nodes: int):
    """The dof pattern of :func:`_dof_pattern` built from node pairs (9× fewer keys to sort).

    Each node pair (I, J) owns a 3×3 block; row 3I+a lists the blocks of node I's neighbours J in
    increasing order, so entry (3I+a, 3J+b) sits at 9·ptr(I) + 3a·count(I) + 3·rank(J) + b, with
    ptr(I) the number of pairs of the nodes before I and rank(J) J's place among I's neighbours.
    It sorts 9× fewer keys, which bounds the build's peak memory on fine meshes.
    """
    keys = [(blk[:, :, None] * n_nodes + blk[:, None, :]).ravel() for blk in nodal]
    diag = np.arange(n_nodes, dtype=np.int64) * (n_nodes + 1)  # unit pivots of fixed dofs
    unique, inverse = np.unique(np.concatenate(keys + [diag]), return_inverse=True)
    first, second = unique // n_nodes, unique % n_nodes
    count = np.bincount(first, minlength=n_nodes)
    ptr = np.concatenate([[0], np.cumsum(count)])
    rank = np.arange(unique.size) - ptr[first]
    nnz = 9 * unique.size
    dtype = _index_dtype(nnz)
    # Rows 3I+a start at 9 ptr(I) + 3a count(I).
    indptr = (9 * ptr[:-1, None] + 3 * np.arange(3) * count[:, None]).ravel()
    indptr = np.concatenate([indptr, [nnz]])
    # Entries in CSR order: node I's rows a = 0, 1, 2, each listing 3J+b over its neighbours J.
    row_node = np.repeat(np.arange(n_nodes), 3 * count)  # the node of each (row a, pair) slot
    slot = np.arange(3 * unique.size) - np.repeat(3 * ptr[:-1], 3 * count)
    pair = ptr[row_node] + slot % np.maximum(count[row_node], 1)
    indices = (3 * second[pair][:, None] + np.arange(3)).ravel()
    rows = np.repeat(3 * row_node + slot // np.maximum(count[row_node], 1), 3)
    maps, start = [], 0
    for blk, k in zip(nodal, keys):
        p = inverse[start : start + k.size].reshape(blk.shape[0], blk.shape[1], blk.shape[1])
        start += k.size
        base = (9 * ptr[first[p]] + 3 * rank[p]).astype(dtype)  # (n_e, m, m): row a = 0, col b = 0
        stride = (3 * count[blk]).astype(dtype)  # (n_e, m): row length of node blk[e, i]'s rows
        maps.append((base, stride))
    return indptr, indices, rows, maps


class SparseSolver:
    """Factorization of K + c u uᵀ (K sparse, u dense, c scalar) for repeated solves.

    ``symmetric=True`` (the caller guarantees K = Kᵀ; Newton, implicit differentiation): a
    supernodal CHOLMOD Cholesky (cvxopt) on the METIS ordering, whose symbolic analysis is done
    once per sparsity pattern; if K is not positive definite, SuperLU in symmetric mode, or, with
    ``definite=True`` (Newton's steps, which need a positive definite model), a
    :class:`NoConvergenceError`. Otherwise (e.g. the rest-shape Jacobian): SuperLU. The rank-one
    part by Sherman–Morrison, never densified. Raises :class:`NoConvergenceError` when K is
    numerically singular.
    """

    def __init__(self, matrix: sp.csr_matrix, rank_one=None, *, symmetric: bool = False, definite: bool = False):
        matrix = sp.csr_matrix(matrix, dtype=np.float64)
        matrix.sum_duplicates()  # canonical CSR (sorted, unique): the ordering cache relies on it
        ordering = _nested_dissection(matrix)
        self._perm = ordering.perm
        self._cholesky = None
        if symmetric:
            # Cholesky is several times faster than LU on the same ordering (docs/shell3d.md).
            self._cholesky = _Cholesky.factorize(matrix, ordering)
        if self._cholesky is None and definite:
            raise NoConvergenceError(
                f"sparse Hessian ({matrix.shape[0]} dofs) is not positive definite (Cholesky failed)."
            )
        if self._cholesky is None:
            self._lu = _superlu(ordering.permute(matrix))
        if matrix.nnz >= _TRIM_MIN_NNZ:
            _return_free_heap()
        self._rank_one = None
        if rank_one is not None:
            c, u = rank_one
            u = np.asarray(u, dtype=np.float64)
            c = float(c)
            if c != 0.0:
                z = self._solve_sparse(u)
                self._rank_one = (c, u, z, 1.0 + c * float(u @ z))

    @property
    def method(self) -> str:
        """ "cholesky" or "lu": which factorization holds K."""
        return "lu" if self._cholesky is None else "cholesky"

    def apply_inverse(self, rhs) -> np.ndarray:
        """x = (K + c u uᵀ)⁻¹ rhs by back-substitution; rhs (n,) or (n, m)."""
        y = self._solve_sparse(np.asarray(rhs, dtype=np.float64))
        if self._rank_one is not None:
            c, u, z, denom = self._rank_one
            coef = c * (u @ y) / denom
            y = y - (np.multiply.outer(z, coef) if y.ndim == 2 else z * coef)
        return y

    def _solve_sparse(self, rhs: np.ndarray) -> np.ndarray:
        """K⁻¹ rhs through the factorization."""
        if self._cholesky is not None:
            return self._cholesky.apply_inverse(rhs)
        # SuperLU holds P K Pᵀ: solve (P K Pᵀ) (P x) = P rhs.
        out = np.empty_like(rhs)
        out[self._perm] = self._lu.solve(np.ascontiguousarray(rhs[self._perm]))
        return out


#: Matrices from this many nonzeros on (≈ 10k shell faces) hand the allocator's free memory back
#: to the OS after their factorization; below, the few ms it takes would be felt per iteration.
_TRIM_MIN_NNZ = 1_000_000


def _return_free_heap() -> None:
    """glibc's ``malloc_trim(0)``: give the free pages inside the heap back to the OS.

    Each Newton iteration allocates and frees tens of MB (CSR values, CHOLMOD's permuted copy and
    workspace, the projection's batches); glibc keeps what it cannot return from the top of its
    heaps, so the resident size would creep up over a long curve. A no-op where there is no glibc.
    """
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def _superlu(permuted: sp.csc_matrix):
    """SuperLU of an already permuted matrix (NoConvergenceError if singular)."""
    try:
        # Symmetric mode (diagonal pivots) on the METIS ordering has the least fill; if the
        # diagonal pivots lose accuracy (indefinite or nonsymmetric matrix), threshold pivoting.
        lu = spla.splu(permuted, permc_spec="NATURAL", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        probe = np.ones(permuted.shape[0])
        residual = np.linalg.norm(permuted @ lu.solve(probe) - probe) / np.sqrt(permuted.shape[0])
        if not residual < 1e-8:
            lu = spla.splu(permuted, permc_spec="NATURAL")
        return lu
    except RuntimeError as err:  # SuperLU: "Factor is exactly singular"
        raise NoConvergenceError(
            f"sparse Hessian ({permuted.shape[0]} dofs) is singular: {err}. An unconstrained "
            "rigid-body mode or a collapsed element; check the pins and the load."
        ) from err


class _Cholesky:
    """A numeric CHOLMOD factor of one matrix, on the symbolic analysis shared by its pattern.

    The symbolic factor of a pattern is one mutable CHOLMOD object: a solver whose numbers were
    overwritten by a later factorization of the same pattern refactorizes before solving.
    """

    def __init__(self, analysis: "_CholeskyAnalysis", values):
        self._analysis = analysis
        self._values = values

    @staticmethod
    def factorize(matrix: sp.csr_matrix, ordering: "_Ordering") -> "_Cholesky | None":
        """The Cholesky factor of ``matrix``, or None if it is not (numerically) positive definite."""
        analysis = ordering.cholesky_analysis(matrix)
        factor = _Cholesky(analysis, analysis.values_of(matrix))
        return factor if factor._refactorize() else None

    def _refactorize(self) -> bool:
        from cvxopt import cholmod

        analysis = self._analysis
        analysis.template.V = self._values
        try:
            cholmod.numeric(analysis.template, analysis.symbolic)
        except ArithmeticError:  # not positive definite (CHOLMOD reports the failing column)
            analysis.owner = None
            return False
        # Weak: a cycle (factor ↔ analysis) would keep an evicted analysis alive until the GC runs.
        analysis.owner = weakref.ref(self)
        return True

    def apply_inverse(self, rhs: np.ndarray) -> np.ndarray:
        import cvxopt
        from cvxopt import cholmod

        if self._analysis.owner is None or self._analysis.owner() is not self:
            self._refactorize()
        b = cvxopt.matrix(np.asfortranarray(rhs.reshape(rhs.shape[0], -1)))
        cholmod.solve(self._analysis.symbolic, b)
        return np.array(b).reshape(rhs.shape)


@dataclasses.dataclass(eq=False)
class _CholeskyAnalysis:
    """Lower-triangle template (cvxopt CCS), CSR→CCS value map and CHOLMOD symbolic factor."""

    template: object
    lower_map: np.ndarray  # CCS values of the lower triangle = csr.data[lower_map]
    symbolic: object
    owner: object = None  # weak reference to the _Cholesky whose numbers the factor holds

    def values_of(self, matrix: sp.csr_matrix):
        import cvxopt

        return cvxopt.matrix(matrix.data[self.lower_map])

    @staticmethod
    def build(matrix: sp.csr_matrix, perm: np.ndarray) -> "_CholeskyAnalysis":
        import cvxopt
        from cvxopt import cholmod

        cholmod.options["supernodal"] = 2  # always supernodal (BLAS-3): simplicial is far slower here
        n = matrix.shape[0]
        positions = sp.csr_matrix(
            (np.arange(1, matrix.nnz + 1, dtype=np.float64), matrix.indices, matrix.indptr), shape=(n, n)
        )
        lower = sp.tril(positions, format="csc")
        lower.sort_indices()
        lower_map = lower.data.astype(np.int64) - 1
        columns = np.repeat(np.arange(n), np.diff(lower.indptr))
        template = cvxopt.spmatrix(matrix.data[lower_map], lower.indices.astype(int), columns.astype(int), (n, n))
        symbolic = cholmod.symbolic(template, p=cvxopt.matrix(perm.astype(int)))
        return _CholeskyAnalysis(template=template, lower_map=lower_map, symbolic=symbolic)


@dataclasses.dataclass(frozen=True, eq=False)
class _Ordering:
    """A symmetric permutation of one sparsity pattern (and its Cholesky analysis, once built)."""

    perm: np.ndarray  # new position k holds old index perm[k]
    _cholesky: list = dataclasses.field(default_factory=list)  # lazily built _CholeskyAnalysis

    def permute(self, matrix: sp.csr_matrix) -> sp.csc_matrix:
        """P A Pᵀ in CSC form for SuperLU (built per call: no scatter map kept per ordering)."""
        permuted = matrix[self.perm][:, self.perm].tocsc()
        permuted.sort_indices()
        return permuted

    def cholesky_analysis(self, matrix: sp.csr_matrix) -> _CholeskyAnalysis:
        """CHOLMOD's symbolic analysis of this pattern on this ordering (built on first use).

        An analysis holds its pattern's factor storage, so only the ``_CHOLESKY_KEPT`` most
        recently analysed patterns keep theirs: the free shell's of the rest-shape solve is
        dropped once the contact model factorizes (switching back costs one symbolic analysis).
        """
        if not self._cholesky:
            while len(_ANALYSED) >= _CHOLESKY_KEPT:  # drop before building: never two at once
                _ANALYSED.pop(0)._cholesky.clear()
            self._cholesky.append(_CholeskyAnalysis.build(matrix, self.perm))
            _ANALYSED.append(self)
        return self._cholesky[0]


_CHOLESKY_KEPT = 1
_ANALYSED: list = []  # orderings holding a Cholesky analysis, oldest first


#: Host data kept by content, oldest first: factorizations by a fingerprint of their matrix (the
#: dynamics' kept Newton matrix is factorized once however many steps it serves) and the dynamics'
#: assemblies of a pattern's matrix on its free dofs. This module owns every host cache of the
#: package, so that one call releases them all.
_KEPT: dict = {}
_ASSEMBLIES: dict = {}


def _kept(store: dict, key, make, keep: int):
    """``store[key]``, made by ``make()`` and kept among the ``keep`` newest if it is not there yet."""
    if key in store:
        return store[key]
    value = make()
    if len(store) >= keep:
        store.pop(next(iter(store)))
    store[key] = value
    return value


def kept_factorization(fingerprint, factorize, keep: int = 4):
    """The factorization (whatever ``factorize()`` returns) kept under the hashable
    ``fingerprint``, made and kept among the ``keep`` newest if it is not there yet."""
    return _kept(_KEPT, fingerprint, factorize, keep)


def kept_assembly(key, assemble, keep: int = 8):
    """The symbolic assembly of a pattern's matrix (whatever ``assemble()`` returns: index maps,
    no values) kept under the hashable ``key``, made and kept among the ``keep`` newest if it is
    not there yet."""
    return _kept(_ASSEMBLIES, key, assemble, keep)


def release_factorizations(keep_analyses: bool = False) -> None:
    """Free every cached factorization: the factorizations kept by content, and unless
    ``keep_analyses`` the Cholesky analyses (and with them their factor storage) and the kept
    assemblies.

    For a caller done with a sparsity pattern: a later factorization of that pattern redoes its
    symbolic analysis (orderings, a permutation per pattern and 16 at most, stay cached).
    ``keep_analyses``: only the numeric factorizations go (e.g. to time a numeric factorization on
    its own).
    """
    _KEPT.clear()
    if not keep_analyses:
        _ASSEMBLIES.clear()
    while _ANALYSED and not keep_analyses:
        _ANALYSED.pop(0)._cholesky.clear()


_ORDERINGS: dict = {}


def _nested_dissection(matrix: sp.csr_matrix) -> _Ordering:
    """METIS nested-dissection ordering of the graph of A + Aᵀ (A in canonical CSR), cached per
    sparsity pattern.

    The key is the pattern's checksum (a few ms against a factorization of seconds), so every
    Newton iteration on one mesh reuses the ordering (and its Cholesky analysis) from its first.
    """
    import pymetis

    n = matrix.shape[0]
    key = (n, matrix.nnz, zlib.crc32(matrix.indptr.tobytes()), zlib.crc32(matrix.indices.tobytes()))
    if key in _ORDERINGS:
        return _ORDERINGS[key]
    pattern = sp.csr_matrix((np.ones(matrix.nnz), matrix.indices, matrix.indptr), shape=(n, n))
    graph = (pattern + pattern.T).tocsr()
    graph.setdiag(0.0)
    graph.eliminate_zeros()
    if graph.nnz == 0:  # diagonal matrix: nothing to reorder
        perm = np.arange(n)
    else:
        perm, _ = pymetis.nested_dissection(pymetis.CSRAdjacency(graph.indptr, graph.indices))
        perm = np.asarray(perm, dtype=np.int64)
    ordering = _Ordering(perm=perm)
    if len(_ORDERINGS) >= 16:
        _ORDERINGS.pop(next(iter(_ORDERINGS)))
    _ORDERINGS[key] = ordering
    return ordering
