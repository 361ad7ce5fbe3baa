"""Sparse assembly, sparse solves with a rank-one update, Newton and implicit differentiation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from shelljax import RESULTS, NoConvergenceError
from shelljax.shell3d import (
    kept_factorization,
    AbstractEnergyProblem,
    SparseSolver,
    SparsityPattern,
    implicit_equilibrium,
    newton,
    release_factorizations,
)
from shelljax.shell3d._sparse import element_positions


class _Direct(AbstractEnergyProblem):
    """A test problem from plain functions energy(x), grad(x), hess(x, project), and optionally a
    feasibility projection project(x, x_trial); Newton's steps are direct solves."""

    free: np.ndarray
    energy_fn: object
    grad_fn: object
    hess_fn: object
    project_fn: object = None

    def energy(self, x):
        return self.energy_fn(x)

    def gradient(self, x):
        return self.grad_fn(x), None

    def hessian(self, x, gradient, project):
        return self.hess_fn(x, project)

    def feasible_trial(self, x, x_trial):
        return None if self.project_fn is None else self.project_fn(x, x_trial)


class _Inexact(_Direct):
    """:class:`_Direct` with Hessian-vector products operator(x): Newton's steps are CG solves."""

    operator_fn: object = None

    def hessian_operator(self, x, gradient):
        return self.operator_fn(x)


def _problem(energy, grad, hess, free, hessian_operator=None, project=None):
    free = np.asarray(free, dtype=bool)
    if hessian_operator is None:
        return _Direct(free, energy, grad, hess, project)
    return _Inexact(free, energy, grad, hess, project, hessian_operator)


def test_pattern_assembles_the_dense_sum_and_folds_pins(monkeypatch):
    import shelljax.shell3d._sparse as sparse_module

    rng = np.random.default_rng(0)
    n = 7
    blocks = [rng.integers(0, n, size=(5, 3)), rng.integers(0, n, size=(4, 2))]
    blocks = [np.stack([rng.permutation(n)[: b.shape[1]] for _ in b]) for b in blocks]
    values = [rng.normal(size=(b.shape[0], b.shape[1], b.shape[1])) for b in blocks]
    free = np.ones(n, dtype=bool)
    free[2] = False
    pattern = SparsityPattern.from_elements(blocks, n, free)
    mat = pattern.matrix(pattern.assemble_values([jnp.asarray(v) for v in values])).toarray()
    dense = np.zeros((n, n))
    for b, v in zip(blocks, values):
        for e in range(b.shape[0]):
            dense[np.ix_(b[e], b[e])] += v[e]
    dense[2, :] = 0.0
    dense[:, 2] = 0.0
    dense[2, 2] = 1.0
    np.testing.assert_allclose(mat, dense, rtol=1e-13, atol=1e-13)
    monkeypatch.setattr(sparse_module, "_PROJECTION_CHUNK", 2)  # the host sum, in uneven chunks
    host = sum(pattern.assemble_host(i, v) for i, v in enumerate(values))
    np.testing.assert_allclose(pattern.matrix(host).toarray(), dense, rtol=1e-13, atol=1e-13)


def test_projected_assembly_sums_clamped_element_matrices(monkeypatch):
    """Independent computation: clamp each symmetric element matrix through its own eigen-
    decomposition (np.linalg.eig, unsorted, general solver) and sum densely."""
    import shelljax.shell3d._sparse as sparse_module

    monkeypatch.setattr(sparse_module, "_PROJECTION_CHUNK", 4)  # 6 elements: two chunks
    rng = np.random.default_rng(7)
    n = 9
    blocks = [np.stack([rng.permutation(n)[:4] for _ in range(6)])]
    values = rng.normal(size=(6, 4, 4))
    values = values + np.swapaxes(values, 1, 2)  # symmetric, indefinite
    pattern = SparsityPattern.from_elements(blocks, n, np.ones(n, dtype=bool))
    mat = pattern.matrix(pattern.assemble_projected([values])).toarray()
    dense = np.zeros((n, n))
    for b, v in zip(blocks[0], values):
        w, vec = np.linalg.eig(v)
        dense[np.ix_(b, b)] += np.real(vec @ np.diag(np.maximum(np.real(w), 0.0)) @ vec.T)
    np.testing.assert_allclose(mat, dense, rtol=1e-12, atol=1e-12)
    assert np.linalg.eigvalsh(mat).min() > -1e-12  # a sum of PSD matrices is PSD
    streamed = pattern.assemble_projected([iter([values[:1], values[1:5], values[5:]])])
    np.testing.assert_allclose(pattern.matrix(streamed).toarray(), dense, rtol=1e-12, atol=1e-12)
    # PSD elements pass through unchanged
    spd = np.einsum("eij,ekj->eik", values, values)
    exact = pattern.matrix(pattern.assemble_values([jnp.asarray(spd)])).toarray()
    np.testing.assert_allclose(
        pattern.matrix(pattern.assemble_projected([spd])).toarray(), exact, rtol=1e-10, atol=1e-9
    )


def test_sherman_morrison_matches_dense_solve():
    import scipy.sparse as sp

    rng = np.random.default_rng(1)
    n = 30
    a = sp.random(n, n, density=0.2, random_state=2) + 10 * sp.identity(n)
    a = (a + a.T).tocsr()
    u = rng.normal(size=n)
    c = 3.7
    b = rng.normal(size=n)
    x = SparseSolver(a, (c, u)).apply_inverse(b)
    np.testing.assert_allclose(x, np.linalg.solve(a.toarray() + c * np.outer(u, u), b), rtol=1e-10)


def _quartic_problem(n=12):
    """E(x) = ½ xᵀ L x + Σ x⁴/4 − bᵀx with L a 1D Laplacian + identity (strictly convex)."""
    import scipy.sparse as sp

    lap = sp.diags([-1.0, 2.5, -1.0], [-1, 0, 1], shape=(n, n)).tocsr()
    b = np.linspace(1.0, 3.0, n)

    def energy(x):
        return 0.5 * x @ (lap @ x) + np.sum(x**4) / 4 - b @ x

    def grad(x):
        return lap @ x + x**3 - b

    def hess(x, project):
        return (lap + sp.diags(3 * x**2)).tocsr(), None

    return energy, grad, hess, b


def test_newton_converges_in_force_units_and_reports_failure():
    energy, grad, hess, b = _quartic_problem()
    free = np.ones(b.size, dtype=bool)
    res = newton(_problem(energy, grad, hess, free), np.zeros(b.size), atol=1e-12, reuse_factorization=False)
    assert np.max(np.abs(grad(res.value))) <= 1e-12
    # Quadratic convergence: the last residuals drop super-linearly.
    h = res.history
    assert h[-1] < 1e-3 * h[-2] or h[-1] < 1e-14
    assert res.stats["factorizations"] == res.iterations
    with pytest.raises(NoConvergenceError) as err:
        newton(_problem(energy, grad, hess, free), np.zeros(b.size), atol=1e-12, max_steps=2)
    assert len(err.value.history) == 3 and "residual history" in str(err.value)
    # Without throw, the same failure is the Solution's result code (the raise above comes from it).
    flagged = newton(_problem(energy, grad, hess, free), np.zeros(b.size), atol=1e-12, max_steps=2, throw=False)
    assert flagged.result == RESULTS.max_steps_reached and not bool(flagged.converged)
    assert flagged.history == err.value.history and flagged.iterations == 2
    assert bool(res.converged) and res.result == RESULTS.successful
    infeasible = newton(_problem(lambda x: np.inf, grad, hess, free), np.zeros(b.size), atol=1e-12, throw=False)
    assert infeasible.result == RESULTS.infeasible_start


def test_newton_reuses_factorizations_only_while_they_contract():
    from shelljax.shell3d._newton import REUSE_CONTRACTION

    energy, grad, hess, b = _quartic_problem(40)
    free = np.ones(b.size, dtype=bool)
    factorized = []

    def counting_hess(x, project):
        factorized.append(len(factorized))
        return hess(x, project)

    exact = newton(_problem(energy, grad, hess, free), np.zeros(b.size), atol=1e-12, reuse_factorization=False)
    lagged = newton(_problem(energy, grad, counting_hess, free), np.zeros(b.size), atol=1e-12)
    assert np.max(np.abs(grad(lagged.value))) <= 1e-12
    assert lagged.stats["factorizations"] == len(factorized) < exact.stats["factorizations"]
    # Strictly convex (Hessian ≥ 0.5 I): both minimisers lie within |∇E| / 0.5 of the unique one.
    np.testing.assert_allclose(lagged.value, exact.value, atol=2 * np.sqrt(b.size) * 1e-12 / 0.5)
    # Every lagged step but the last (which may stop early at the tolerance) contracted enough to
    # be followed by another lagged step; all other steps were fresh factorizations.
    h = lagged.history
    reused_steps = lagged.iterations - lagged.stats["factorizations"]
    assert reused_steps > 0
    ratios = np.array(h[:-1]) / np.array(h[1:])
    assert np.sum(ratios >= REUSE_CONTRACTION) >= reused_steps - 1


def test_preconditioned_inexact_newton_keeps_one_factorization_and_reaches_the_same_minimum():
    energy, grad, hess, b = _quartic_problem(40)
    free = np.ones(b.size, dtype=bool)

    def operator(x):
        matrix = hess(x, False)[0]
        return lambda v: matrix @ v

    exact = newton(_problem(energy, grad, hess, free), np.zeros(b.size), atol=1e-12, reuse_factorization=False)
    inexact = newton(_problem(energy, grad, hess, free, hessian_operator=operator), np.zeros(b.size), atol=1e-12)
    assert np.max(np.abs(grad(inexact.value))) <= 1e-12
    # Strictly convex (Hessian ≥ 0.5 I): both minimisers lie within |∇E| / 0.5 of the unique one.
    np.testing.assert_allclose(inexact.value, exact.value, atol=2 * np.sqrt(b.size) * 1e-12 / 0.5)
    # A factorization preconditions the steps after it while CG converges on it: fewer are made.
    assert inexact.stats["factorizations"] < exact.stats["factorizations"]
    assert inexact.stats["products"] >= inexact.iterations - inexact.stats["factorizations"] > 0
    # Handed to a nearby problem (5 % more load), it is all that problem needs either.
    shifted = lambda x: grad(x) - 0.05 * b  # noqa: E731
    energy_shifted = lambda x: energy(x) - 0.05 * b @ x  # noqa: E731
    again = newton(
        _problem(energy_shifted, shifted, hess, free, hessian_operator=operator),
        inexact.value,
        atol=1e-12,
        factorization=inexact.state,
    )
    assert np.max(np.abs(shifted(again.value))) <= 1e-12
    assert again.stats["factorizations"] == 0 and again.state is inexact.state


def test_newton_line_search_projection_keeps_trial_points_feasible_and_the_minimum():
    """A spring chain x₀…x₄ pushed toward a wall by a force on x₄, its first bead on a log
    barrier (x₀ > 0), started far above the equilibrium gap μ/push. Newton's quadratic model of
    the barrier overshoots into x₀ < 0, so the plain line search meets infeasible trial points
    and halves; with a projection that keeps x₀ ≥ 30 % of its value, no trial point is
    infeasible and Newton reaches the same minimum."""
    import scipy.sparse as sp

    n, stiffness, mu, push = 5, 10.0, 1e-6, 1.0
    infeasible = []

    def energy(x):
        if x[0] <= 0.0:
            infeasible.append(x.copy())
            return np.inf
        springs = np.diff(x) - 0.1
        return 0.5 * stiffness * springs @ springs - mu * np.log(x[0]) + push * x[-1]

    def grad(x):
        tension = stiffness * (np.diff(x) - 0.1)
        g = np.zeros(n)
        g[:-1] -= tension
        g[1:] += tension
        g[0] -= mu / x[0]
        g[-1] += push
        return g

    def hess(x, project):
        main = np.full(n, 2 * stiffness)
        main[0] = main[-1] = stiffness
        main[0] += mu / x[0] ** 2
        off = -stiffness * np.ones(n - 1)
        return sp.diags([off, main, off], [-1, 0, 1], format="csr"), None

    trials = []

    def keep_gap(x, x_trial):
        out = x_trial.copy()
        out[0] = max(x_trial[0], 0.3 * x[0])
        trials.append(out)
        return out

    start = 0.1 * np.arange(n) + 0.5
    free = np.ones(n, dtype=bool)
    plain = newton(_problem(energy, grad, hess, free), start, atol=1e-10, reuse_factorization=False)
    assert len(infeasible) > 0
    infeasible.clear()
    projected = newton(
        _problem(energy, grad, hess, free, project=keep_gap), start, atol=1e-10, reuse_factorization=False
    )
    assert infeasible == [] and len(trials) >= projected.iterations
    for res in (plain, projected):
        assert np.max(np.abs(grad(res.value))) <= 1e-10
    # At the minimum every spring carries the push, compressed by its whole rest length 0.1, so
    # all beads sit at x₀ = μ/push. The barrier (μ/x₀² = 1e6 N/m) holds x₀; the rest is a
    # fixed–free chain of 4 springs, smallest eigenvalue 4k sin²(π/18) ≈ 1.2 N/m, so
    # |x − x*| ≤ √5 · 1e-10 N / 1.2 N/m ≈ 2e-10 m.
    np.testing.assert_allclose(projected.value, mu / push, atol=5e-10)
    np.testing.assert_allclose(plain.value, mu / push, atol=5e-10)


def test_preconditioned_cg_gives_up_on_a_poor_preconditioner_or_negative_curvature():
    from shelljax.shell3d._newton import CG_EXTRAPOLATE_AFTER, CG_MAX_ITERATIONS, _preconditioned_cg

    rng = np.random.default_rng(3)
    spectrum = np.logspace(0, 6, 200)  # condition number 1e6: unpreconditioned CG needs far more steps
    g = rng.normal(size=spectrum.size)
    d, used = _preconditioned_cg(lambda v: spectrum * v, lambda r: r, g, 1e-8)
    # hopeless at its rate so far: given up at the first extrapolation, not after the whole budget
    assert d is None and used == CG_EXTRAPOLATE_AFTER < CG_MAX_ITERATIONS
    # A preconditioned spectrum in [1, 2.25] contracts CG's residual by ≈ (√2.25 − 1)/(√2.25 + 1)
    # = 0.2 a product: on course for 1e-4 within the budget, so it is not given up on.
    mild = np.linspace(1.0, 2.25, spectrum.size)
    d, used = _preconditioned_cg(lambda v: mild * spectrum * v, lambda r: r / spectrum, g, 1e-4)
    assert CG_EXTRAPOLATE_AFTER < used <= CG_MAX_ITERATIONS
    # the error of the step is at most the relative residual 1e-4 over the smallest eigenvalue 1 (scaled)
    np.testing.assert_allclose(d, -g / (mild * spectrum), atol=1e-4 * np.linalg.norm(g))
    d, used = _preconditioned_cg(lambda v: spectrum * v, lambda r: r / spectrum, g, 1e-8)
    np.testing.assert_allclose(d, -g / spectrum, rtol=1e-10)  # exact preconditioner: one product
    assert used == 1
    # A gradient along a direction of negative curvature: no CG step, a factorization decides.
    indefinite = np.where(np.arange(spectrum.size) == 7, -1.0, spectrum)
    along = np.where(np.arange(spectrum.size) == 7, 1.0, 0.0)
    d, used = _preconditioned_cg(lambda v: indefinite * v, lambda r: r / np.abs(indefinite), along, 1e-8)
    assert d is None and used == 1


def test_cholesky_and_lu_paths_agree_with_dense_solves():
    import scipy.sparse as sp

    rng = np.random.default_rng(3)
    n = 40
    a = sp.random(n, n, density=0.15, random_state=4)
    spd = (a @ a.T + sp.identity(n)).tocsr()
    indefinite = (a + a.T - 0.5 * sp.identity(n)).tocsr()
    nonsymmetric = (a + 3 * sp.identity(n)).tocsr()
    b = rng.normal(size=(n, 2))
    first = SparseSolver(spd, symmetric=True)
    assert first.method == "cholesky"
    np.testing.assert_allclose(first.apply_inverse(b), np.linalg.solve(spd.toarray(), b), rtol=1e-10)
    # Same pattern, other values: the second factorization reuses the first's symbolic analysis,
    # and the first solver must still solve its own matrix afterwards.
    other = (spd + sp.diags(np.linspace(1.0, 5.0, n))).tocsr()
    second = SparseSolver(other, symmetric=True)
    np.testing.assert_allclose(second.apply_inverse(b[:, 0]), np.linalg.solve(other.toarray(), b[:, 0]), rtol=1e-10)
    np.testing.assert_allclose(first.apply_inverse(b[:, 0]), np.linalg.solve(spd.toarray(), b[:, 0]), rtol=1e-10)
    fallback = SparseSolver(indefinite, symmetric=True)
    assert fallback.method == "lu"  # not positive definite
    np.testing.assert_allclose(fallback.apply_inverse(b), np.linalg.solve(indefinite.toarray(), b), rtol=1e-8)
    lu = SparseSolver(nonsymmetric)  # the default never assumes symmetry
    assert lu.method == "lu"
    np.testing.assert_allclose(lu.apply_inverse(b), np.linalg.solve(nonsymmetric.toarray(), b), rtol=1e-10)


def test_an_evicted_cholesky_analysis_is_freed_without_the_cycle_collector():
    """Only the latest pattern keeps its CHOLMOD analysis (its factor is 0.46 GiB at 80k faces);
    the evicted one must be freed as soon as nothing uses it, not when Python's cycle collector
    happens to run (a factor ↔ analysis reference cycle once kept it alive)."""
    import gc
    import weakref

    import scipy.sparse as sp

    import shelljax.shell3d._sparse as sparse_module

    def spd(n, seed):
        a = sp.random(n, n, density=0.2, random_state=seed)
        return (a @ a.T + sp.identity(n)).tocsr()

    first, second = spd(30, 1), spd(31, 2)  # two patterns
    solver = SparseSolver(first, symmetric=True)
    analysis = weakref.ref(sparse_module._nested_dissection(first)._cholesky[0])
    del solver
    gc.disable()
    try:
        SparseSolver(second, symmetric=True)  # evicts the first pattern's analysis
        assert analysis() is None
    finally:
        gc.enable()
    # The first pattern still solves (its analysis is rebuilt).
    b = np.ones(30)
    np.testing.assert_allclose(
        SparseSolver(first, symmetric=True).apply_inverse(b), np.linalg.solve(first.toarray(), b), rtol=1e-10
    )
    # release_factorizations frees the kept analysis too (the 3D engine calls it once its free
    # shell is solved); a solver made before still solves, and a new one rebuilds the analysis.
    kept = SparseSolver(second, symmetric=True)
    analysis = weakref.ref(sparse_module._nested_dissection(second)._cholesky[0])
    release_factorizations()
    assert not sparse_module._ANALYSED and not sparse_module._nested_dissection(second)._cholesky
    b = np.arange(31.0)
    np.testing.assert_allclose(kept.apply_inverse(b), np.linalg.solve(second.toarray(), b), rtol=1e-10)
    del kept
    assert analysis() is None
    np.testing.assert_allclose(
        SparseSolver(second, symmetric=True).apply_inverse(b), np.linalg.solve(second.toarray(), b), rtol=1e-10
    )


def test_one_call_releases_every_kept_factorization():
    # The factorizations kept by content (the dynamics' kept Newton matrices) live in the same
    # module as the Cholesky analyses, so release_factorizations frees both.
    import shelljax.shell3d._sparse as sparse_module

    made = []
    first = kept_factorization(("test", 1), lambda: made.append(1) or "factor")
    assert kept_factorization(("test", 1), lambda: made.append(2) or "other") == first == "factor" and made == [1]
    release_factorizations(keep_analyses=True)
    assert not sparse_module._KEPT
    assert kept_factorization(("test", 1), lambda: made.append(3) or "again") == "again" and made == [1, 3]
    release_factorizations()
    assert not sparse_module._KEPT and not sparse_module._ANALYSED


def test_nodal_pattern_build_equals_the_entrywise_one():
    """The shell models' patterns are built from node pairs; the entrywise build is the reference."""
    from shelljax.shell3d._sparse import _dof_pattern, _nodal_blocks, _nodal_pattern

    rng = np.random.default_rng(5)
    n_nodes = 30
    faces = np.stack([rng.permutation(n_nodes)[:6] for _ in range(25)])
    pairs = np.stack([rng.permutation(n_nodes)[:2] for _ in range(10)])
    blocks = [(3 * nodes[:, :, None] + np.arange(3)).reshape(len(nodes), -1) for nodes in (faces, pairs)]
    n_dofs = 3 * n_nodes
    nodal = _nodal_blocks(blocks, n_dofs)
    assert nodal is not None and _nodal_blocks([blocks[0][:, ::-1]], n_dofs) is None
    reference, built = _dof_pattern(blocks, n_dofs), _nodal_pattern(nodal, n_nodes)
    for ref, new in zip(reference[:3], built[:3]):
        np.testing.assert_array_equal(ref, new)
    # The compact maps (3 × 3 node blocks, one stride per row node) expand to the entrywise ones.
    for blk, ref, new in zip(blocks, reference[3], built[3]):
        k = blk.shape[1]
        np.testing.assert_array_equal(element_positions(*ref, k), element_positions(*new, k))
        assert ref[0].shape == (len(blk), k, k) and new[0].shape == (len(blk), k // 3, k // 3)
        np.testing.assert_array_equal(
            np.asarray(element_positions(*map(jnp.asarray, new), k)), element_positions(*new, k)
        )
    # A node in no element (here the last one, pinned) still gets its unit pivots.
    free = np.ones(n_dofs + 3, dtype=bool)
    free[-3:] = False
    pattern = SparsityPattern.from_elements(blocks, n_dofs + 3, free)
    values = [jnp.ones((len(b), b.shape[1], b.shape[1])) for b in blocks]
    np.testing.assert_array_equal(pattern.matrix(pattern.assemble_values(values)).toarray()[-3:, -3:], np.eye(3))


def test_implicit_equilibrium_forward_and_reverse_match_finite_differences():
    """x*(θ) minimises ½xᵀLx + Σx⁴/4 − θ₀ bᵀx − θ₁ Σx: gradients vs central differences."""
    import scipy.sparse as sp

    energy, grad, hess, b = _quartic_problem()
    n = b.size
    lap = hess(np.zeros(n), False)[0]
    lap_j = jnp.asarray(lap.toarray())  # only used by the JAX residual of this tiny test
    free = np.ones(n, dtype=bool)
    free[0] = False  # a pinned dof stays at 0

    def residual(x, th):
        return lap_j @ x + x**3 - th["a"] * jnp.asarray(b) - th["c"]

    def minimise_at(th):
        a, c = float(th["a"]), float(th["c"])
        return newton(
            _problem(
                lambda x: 0.5 * x @ (lap @ x) + np.sum(x**4) / 4 - a * b @ x - c * x.sum(),
                lambda x: np.where(free, lap @ x + x**3 - a * b - c, 0.0),
                lambda x, p: _fold(lap + sp.diags(3 * x**2), free),
                free,
            ),
            np.zeros(n),
            atol=1e-13,
        ).value

    def hessian_host(x, th):
        return _fold(lap + sp.diags(3 * x**2), free)

    eq = implicit_equilibrium(minimise_at, residual, hessian_host, free, n)
    theta = {"a": jnp.asarray(1.3), "c": jnp.asarray(0.4)}
    f = lambda th: jnp.sum(eq(th) ** 2)  # noqa: E731
    g = jax.grad(f)(theta)
    for k in theta:
        eps = 1e-6
        tp = dict(theta, **{k: theta[k] + eps})
        tm = dict(theta, **{k: theta[k] - eps})
        fd = (f(tp) - f(tm)) / (2 * eps)
        # Central differences of a 1e-13-converged solve: error O(eps²) + 1e-13/eps ≈ 1e-7 relative.
        np.testing.assert_allclose(g[k], fd, rtol=1e-6)
        _, jvp = jax.jvp(f, (theta,), ({kk: jnp.asarray(float(kk == k)) for kk in theta},))
        np.testing.assert_allclose(jvp, fd, rtol=1e-6)
    assert float(eq(theta)[0]) == 0.0


def _fold(mat, free):
    import scipy.sparse as sp

    d = sp.diags(free.astype(float))
    out = (d @ mat @ d + sp.diags((~free).astype(float))).tocsr()
    return out, None


def test_newton_runs_with_single_threaded_blas_and_restores_it():
    # OpenBLAS threads spinning after CG's dot products slowed the XLA work between them 1.6×
    # (shell3d/_newton.py): inside the loop NumPy's BLAS must run on one thread, outside as before.
    from threadpoolctl import threadpool_info

    def blas_threads():
        return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]

    before = blas_threads()
    energy, grad, hess, b = _quartic_problem(10)
    seen = []

    def watched_energy(x):
        seen.append(blas_threads())
        return energy(x)

    result = newton(_problem(watched_energy, grad, hess, np.ones(b.size, dtype=bool)), np.zeros(b.size), atol=1e-10)
    assert np.max(np.abs(grad(result.value))) <= 1e-10
    assert seen and all(threads and max(threads) == 1 for threads in seen)
    assert blas_threads() == before
