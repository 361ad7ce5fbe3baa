"""The JAX Krylov solve (shell3d.KrylovSolver, dynamics.KrylovNewton) against the host direct path.

Small meshes keep every test to seconds; the wall times are experiments/bench_device_solve.py's.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse.linalg as spla

import shelljax.shell3d as s3
from shelljax import InvalidInputError, NoConvergenceError
from shelljax import dynamics as d
from shelljax.physics import IsothermalGas, ShellProperties
from shelljax.shell3d.internal import krylov_layout, krylov_solve, sparse_operator

pytestmark = pytest.mark.slow  # 3D solves and dynamics runs

PEZZI = ShellProperties(gauge_pressure=1300.0, young_modulus=2.34e6, thickness=0.9e-3, poisson_ratio=0.4)
DEPTHS = [0.005, 0.01]  # one continuation sub-step each (at most 2 % of the 0.26 m ball)


def _sim(linear_solver, n_triangles=300):
    ball = s3.ball(radius=0.13, thickness=PEZZI.thickness, n_triangles=n_triangles)
    # Newton's tolerance 1e-4 of the default (1e-12 E h L ≈ 5e-10 N): two converged states then differ
    # by H⁻¹ × that residual, ~1e-12 m, so the comparisons below test the linear solves, not Newton's stop.
    atol = 1e-12 * PEZZI.young_modulus * PEZZI.thickness * 0.26
    return s3.Indentation(
        ball,
        PEZZI,
        gas=IsothermalGas(),
        indenter_radius=0.008,
        force_tolerance=atol,
        progress=False,
        linear_solver=linear_solver,
    )


@pytest.fixture(scope="module")
def sims():
    direct = _sim(s3.DirectSolver())
    return {"direct": direct, "krylov": direct.with_linear_solver(s3.KrylovSolver())}


def test_operator_solve_matches_a_sparse_direct_solve_with_pins_and_the_gas_rank_one_term(sims):
    sim = sims["direct"]
    model = sim.model
    q = sim.q_reference
    params = sim.params_at(q)
    mat, (c2, u) = model.host_hessian(q, params)
    rhs = np.where(model.free, np.random.default_rng(0).normal(size=model.n_dofs), 0.0)
    dense = mat.toarray() + c2 * np.outer(u, u)
    expected = np.linalg.solve(dense, rhs)
    operator = model.device_operator(q, params)
    # The operator is the folded matrix plus the rank-one term: its product agrees to round-off.
    product = np.asarray(operator.mv(jnp.asarray(rhs)))
    assert np.max(np.abs(product - dense @ rhs)) <= 1e-12 * np.max(np.abs(dense)) * np.max(np.abs(rhs))
    x, iterations, status = krylov_solve(operator, jnp.asarray(rhs), 1e-12, 5000)
    assert int(status) == 0 and 0 < int(iterations) < 5000
    # A relative residual of 1e-12 bounds the relative error by cond(H) 1e-12; cond ≈ 1e5 on this mesh.
    assert np.max(np.abs(np.asarray(x) - expected)) <= 1e-6 * np.max(np.abs(expected))
    assert np.all(np.asarray(x)[~model.free] == 0.0)
    # Newton's fallback: the PSD-projected Hessian moved to the device is the host's matrix.
    projected, _ = model.host_hessian(q, params, project=True)
    product = np.asarray(model.device_operator(q, params, project=True).mv(jnp.asarray(rhs)))
    expected = projected @ rhs + c2 * u * (u @ rhs)
    assert np.max(np.abs(product - expected)) <= 1e-12 * np.max(np.abs(dense)) * np.max(np.abs(rhs))


def test_block_jacobi_takes_fewer_iterations_than_point_jacobi(sims):
    sim = sims["direct"]
    model = sim.model
    operator = model.device_operator(sim.q_reference, sim.params_at(sim.q_reference))
    rhs = jnp.asarray(np.where(model.free, 1.0, 0.0))
    _, block, _ = krylov_solve(operator, rhs, 1e-10, 5000, nodal=True)
    _, point, _ = krylov_solve(operator, rhs, 1e-10, 5000, nodal=False)
    # The 3×3 nodal blocks carry the strong in-surface membrane coupling that point Jacobi drops.
    assert int(block) < int(point)


def test_indentation_force_and_displacement_agree_with_the_direct_solver(sims):
    direct = sims["direct"].curve(DEPTHS)
    krylov = sims["krylov"].curve(DEPTHS)
    for a, b in zip(direct, krylov):
        fa, fb = a.observables()["force"], b.observables()["force"]
        # Both states meet |free force| ≤ 5e-10 N (fixture): any difference is the solves', ≪ 1e-6.
        assert abs(fa - fb) <= 1e-6 * abs(fa)
        displacement = a.q - a.sim.q_reference
        assert np.max(np.abs(b.q - a.q)) <= 1e-6 * np.max(np.abs(displacement))
    assert krylov[-1].factorizations > 0


def test_implicit_gradient_through_the_krylov_tangent_agrees_with_the_direct_one(sims):
    theta = {"gauge_pressure": 1300.0, "young_modulus": 2.34e6}
    grads = {}
    for name, sim in sims.items():
        force = sim.force_function(DEPTHS[0])
        grads[name] = jax.grad(force)(theta)
    for key in theta:
        g_direct, g_krylov = float(grads["direct"][key]), float(grads["krylov"][key])
        # The tangent solves stop at a relative residual of 1e-10; cond(H) ≈ 1e5 leaves ≤ 1e-5 relative.
        assert g_krylov == pytest.approx(g_direct, rel=1e-5)
        assert g_direct != 0.0


def test_a_krylov_failure_is_reported_not_silent(sims):
    model = sims["direct"].model
    operator = model.device_operator(sims["direct"].q_reference, sims["direct"].params_at(sims["direct"].q_reference))
    rhs = jnp.asarray(np.where(model.free, 1.0, 0.0))
    _, iterations, status = krylov_solve(operator, rhs, 1e-10, 1)
    assert int(status) == 1 and int(iterations) == 1  # not converged within one CG iteration
    # Negative curvature: the same matrix, negated on the free dofs, is detected at the first direction.
    negative = sparse_operator(krylov_layout(model.pattern), -operator.values)
    assert int(krylov_solve(negative, rhs, 1e-10, 100)[2]) == 2
    # In Newton: every fallback fails, and the error says why and what to do.
    sim = sims["direct"].with_linear_solver(s3.KrylovSolver(max_steps=1))
    with pytest.raises(NoConvergenceError, match="no convergence within max_steps.*KrylovSolver"):
        sim.solve(depth=DEPTHS[0])
    with pytest.raises(InvalidInputError, match="rtol"):
        s3.KrylovSolver(rtol=0.0)
    with pytest.raises(InvalidInputError, match="linear_solver"):
        sims["direct"].with_linear_solver("krylov")


# --- the dynamics ----------------------------------------------------------------------------------

RADIUS, THICKNESS, MASS, GHAT = 0.05, 0.5e-3, 0.1, 5e-4
BALL = ShellProperties(gauge_pressure=5000.0, young_modulus=2e6, thickness=THICKNESS, poisson_ratio=0.4)


@pytest.fixture(scope="module")
def system():
    shell = s3.ball(RADIUS, THICKNESS, n_triangles=200)
    ground = d.Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], d.BarrierContact(GHAT, 1e3), damping=2.0, name="ground")
    return d.shell_system(shell, BALL, gas=IsothermalGas(), mass=MASS, planes=[ground])


def test_krylov_newton_drop_matches_sparse_newton(system):
    # Just above the ground at 0.6 m/s: contact, the gas's rank-one term and the dashpot within 6 steps.
    state = d.drop_state(system, system.inflated, 2 * GHAT, velocity=[0.0, 0.0, -0.6])
    runs = {
        name: d.simulate(system, state, 1e-3, 6e-3, minimiser=m, progress=False, chunk=6)
        for name, m in (("sparse", d.SparseNewton()), ("krylov", d.KrylovNewton()))
    }
    a, b = runs["sparse"]["position_m"], runs["krylov"]["position_m"]
    assert np.min(runs["sparse"]["min_gap_m"]) < GHAT  # the ball touched the ground
    # Same Newton, same kept matrices: the steps differ by the solves' 1e-10 relative residuals, far
    # below Newton's 1e-10 m step tolerance; 1e-6 relative to the travel leaves round-off room.
    travel = np.max(np.abs(a - a[0]))
    assert np.max(np.abs(a - b)) <= 1e-6 * travel
    np.testing.assert_array_equal(runs["sparse"]["newton_matrices"], runs["krylov"]["newton_matrices"])


def test_krylov_newton_adjoint_solve_matches_the_sparse_one_and_fails_loudly(system):
    state = d.drop_state(system, system.inflated, 2 * GHAT, velocity=[0.0, 0.0, -0.6])
    potential = d.incremental_potential(system, d.BackwardEuler(), state, 1e-3)
    y = potential.free(state.position)
    rhs = jnp.asarray(np.random.default_rng(1).normal(size=y.shape))
    direct = np.asarray(d.SparseNewton().linear_solve(potential, y, rhs))
    krylov = np.asarray(d.KrylovNewton().linear_solve(potential, y, rhs))
    # Inertia dominates this matrix (cond ≈ 1e2): a 1e-10 relative residual is ≤ 1e-8 relative error.
    assert np.max(np.abs(krylov - direct)) <= 1e-8 * np.max(np.abs(direct))
    with pytest.raises(Exception, match="KrylovNewton: the implicit derivative's CG solve failed"):
        jax.block_until_ready(d.KrylovNewton(krylov_max_steps=1).linear_solve(potential, y, rhs))
    assert math.isfinite(float(jnp.sum(krylov)))
