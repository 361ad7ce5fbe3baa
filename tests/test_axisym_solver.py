"""Newton safeguards of the axisymmetric engine: they change the path, never the equilibrium."""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from shelljax.physics import IsothermalGas, PrescribedGas, gas_law
import shelljax.axisym._newton as newton
from shelljax.axisym import CurvePhysics, Setup
from shelljax.axisym._energy import Config, constrained_mask, enclosed_volume, split, total_energy
from shelljax.axisym._hessian import hessian_at
from shelljax.axisym._linalg import StructuredHessian, _inverse_4x4, structured_solve
from shelljax.axisym._model import _params, curve_single, inflate

from _shells import shell


def test_closed_form_block_inverse_matches_lapack():
    rng = np.random.default_rng(3)
    blocks = rng.normal(size=(50, 4, 4)) + 4.0 * np.eye(4)  # condition numbers ~1–10
    # float64 closed form vs LAPACK: agreement to a few hundred ulps of the inverse's size
    np.testing.assert_allclose(np.asarray(_inverse_4x4(blocks)), np.linalg.inv(blocks), rtol=0, atol=1e-13)


@pytest.mark.parametrize("blocks", [1, 6, 51])
def test_structured_solve_equals_a_dense_solve(blocks):
    # H = [[A + σ g gᵀ, b], [bᵀ, c]], A symmetric block tridiagonal with diagonally dominant blocks
    # (condition number ~10): the block-Thomas + Sherman–Morrison + Schur solve against LAPACK on
    # the dense matrix, to a few hundred ulps.
    rng = np.random.default_rng(blocks)
    n = 4 * blocks
    a = np.zeros((n, n))
    for b in range(blocks):
        block = rng.normal(size=(4, 4))
        a[4 * b : 4 * b + 4, 4 * b : 4 * b + 4] = block @ block.T + 8.0 * np.eye(4)
    for b in range(blocks - 1):
        a[4 * b : 4 * b + 4, 4 * b + 4 : 4 * b + 8] = rng.normal(size=(4, 4))
        a[4 * b + 4 : 4 * b + 8, 4 * b : 4 * b + 4] = a[4 * b : 4 * b + 4, 4 * b + 4 : 4 * b + 8].T
    gas_grad, arrow = rng.normal(size=n), rng.normal(size=n)
    hess = StructuredHessian(
        tuple(tuple(jnp.asarray(a[i::4, j::4].diagonal()) for j in range(4)) for i in range(4)),
        tuple(tuple(jnp.asarray(a[i::4, j::4].diagonal(1)) for j in range(4)) for i in range(4)),
        jnp.asarray(arrow),
        jnp.asarray(50.0),
        jnp.asarray(0.3),
        jnp.asarray(gas_grad),
    )
    dense = np.zeros((n + 1, n + 1))
    dense[:n, :n] = a + 0.3 * np.outer(gas_grad, gas_grad)
    dense[:n, n] = dense[n, :n] = arrow
    dense[n, n] = 50.0
    rhs = rng.normal(size=n + 1)
    solution = np.asarray(structured_solve(hess, jnp.asarray(rhs)))
    np.testing.assert_allclose(solution, np.linalg.solve(dense, rhs), rtol=0, atol=1e-13 * np.max(np.abs(solution)))


def _dense(hess, mask):
    """The structured Hessian as a dense matrix (fixed dofs: identity rows and columns)."""
    diag = np.moveaxis(np.asarray(hess.diag), -1, 0)  # entry-wise (4, 4, m) → blocks (m, 4, 4)
    upper = np.moveaxis(np.asarray(hess.upper), -1, 0)
    m = diag.shape[0]
    n_x = 4 * m
    dense = np.zeros((n_x + 1, n_x + 1))
    for b in range(m):
        dense[4 * b : 4 * b + 4, 4 * b : 4 * b + 4] = diag[b]
    for b in range(m - 1):
        dense[4 * b : 4 * b + 4, 4 * b + 4 : 4 * b + 8] = upper[b]
        dense[4 * b + 4 : 4 * b + 8, 4 * b : 4 * b + 4] = upper[b].T
    free_x = ~mask[:-1]
    gas = float(hess.gas_sigma) * np.outer(hess.gas_grad, hess.gas_grad)
    dense[:n_x, :n_x] += gas * np.outer(free_x, free_x)
    dense[:n_x, -1] = dense[-1, :n_x] = hess.arrow
    dense[-1, -1] = hess.corner
    return dense


PEZZI = np.array([1300.0, 2.34e6, 9e-4, 0.4])  # P_g [Pa], E [Pa], h [m], ν [-]
FORCES = np.array([5.0, 10.0, 15.0])  # [N]


def _cold_curve(setup):
    """curve_single from its usual start, jitted anew (Newton constants are read at trace time)."""
    return jax.jit(lambda theta: curve_single(setup, shell(theta), FORCES, return_states=True))


@functools.lru_cache(maxsize=None)
def _indented_curve(setup):
    return _cold_curve(setup)(PEZZI)


def _indented_states(setup):
    return _indented_curve(setup)["state"]


# the indented states the Hessians are compared at (21 elements, sealed gas)
STATES_SETUP = Setup(radius=0.13, n_elements=21, gas=IsothermalGas())

# Jitted: run op by op, the dense autodiff Hessian compiled ≈ 900 single-operation programs
# (≈ 45 s of the suite's time from an empty compilation cache).
_dense_autodiff_hessian = jax.jit(jax.hessian(total_energy), static_argnums=1)
_assembled_hessian = jax.jit(hessian_at, static_argnums=1)


@pytest.mark.parametrize(
    ("loading", "gas"),
    [("sphere", "isothermal"), ("sphere", "prescribed"), ("point", "prescribed"), ("none", "isothermal")],
)
def test_assembled_hessian_equals_the_dense_autodiff_hessian(gas, loading):
    # A wrinkled, indented state (15 N, both contacts active, relaxed hoop stress in the dimple)
    # with a random perturbation, so that every term has a non-zero gradient and curvature. The
    # state is only where both Hessians are evaluated: every case takes the sealed-gas curve's
    # (one compiled curve, shared with the inflation test below), whatever its own gas, and its
    # inflated state and rest radius (the inflation is the same for every gas: the sealed gas
    # is off while inflating, test_the_curves_inflation_is_the_equilibrium_of_the_plain_inflation_problem).
    setup = Setup(radius=0.13, n_elements=21, gas=gas_law(gas))
    curve = _indented_curve(STATES_SETUP)
    states, r0 = curve["state"], curve["rest_radius"]
    x_inflated, _ = split(states[0], len(setup.theta()))
    cfg = Config(
        theta=setup.theta(),
        gas=gas_law(gas),
        loading=loading,
        ground=loading != "none",
        pin_bottom=loading == "none",
        relax=True,
        hoop_capacity=setup.hoop_capacity,
    )
    p = _params(
        2.34e6,
        9e-4,
        0.4,
        r0,
        1300.0,
        setup,
        force=15.0,
        ref_volume=enclosed_volume(x_inflated),
        ground_z=x_inflated[0, 1],
    )
    y = states[-1] + 1e-4 * jnp.asarray(np.random.default_rng(0).normal(size=states[-1].shape))
    mask = constrained_mask(cfg)
    reference = np.array(_dense_autodiff_hessian(y, cfg, p))
    reference[mask, :] = 0.0
    reference[:, mask] = 0.0
    reference[mask, mask] = 1.0
    assembled = _dense(jax.tree_util.tree_map(np.asarray, _assembled_hessian(y, cfg, p)), mask)
    # Both are exact second derivatives evaluated in float64 by different operation orders: entries
    # span 1e-3 … 1e9 N/m (contact penalty), so compare to round-off of the largest entry.
    np.testing.assert_allclose(assembled, reference, rtol=0, atol=1e-12 * np.max(np.abs(reference)))
    # not vacuous: the bending hinges fill the second-neighbour node blocks (a 10-wide band)
    second_neighbour = [reference[2 * i : 2 * i + 2, 2 * i + 4 : 2 * i + 6] for i in range(2, len(y) // 2 - 4)]
    assert all(np.any(block != 0.0) for block in second_neighbour)


def test_contact_springs_model_the_penalty_of_a_node_entering_contact():
    # The active-set model of a node predicted in contact with the indenter is the exact Hessian
    # of k/2 (gap linearised)²: compare to the dense Hessian of that quadratic in (x_i, z_c).
    # (the zeroed Hessian only gives the block structure of 21 elements: it comes from the
    # Hessian test's compiled sphere-prescribed program; the model and the springs are jitted,
    # one program each instead of hundreds of single operations)
    setup = Setup(radius=0.13, n_elements=21)
    cfg = Config(
        theta=setup.theta(),
        gas=PrescribedGas(),
        loading="sphere",
        ground=True,
        pin_bottom=False,
        relax=True,
        hoop_capacity=setup.hoop_capacity,
    )
    n = cfg.n_nodes
    hess = jax.tree_util.tree_map(
        jnp.zeros_like,
        _assembled_hessian(
            jnp.concatenate([jnp.ones(2 * n), jnp.zeros(1)]),
            cfg,
            _params(2.34e6, 9e-4, 0.4, 0.13, 1300.0, setup, ground_z=-1.0),
        ),
    )
    rng = np.random.default_rng(1)
    normal = rng.normal(size=(n, 2))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    k_indenter, k_ground = rng.uniform(0, 1, n), rng.uniform(0, 1, n)
    springs = jax.jit(newton._add_contact_springs)(
        hess, jnp.asarray(k_ground), jnp.asarray(k_indenter), jnp.asarray(normal)
    )

    def model(v):  # Σ k/2 (n·Δx − n_z Δz_c)² + Σ k_g/2 Δz²
        dx, dzc = split(v, n)
        return 0.5 * jnp.sum(
            k_indenter * (jnp.sum(normal * dx, -1) - normal[:, 1] * dzc) ** 2 + k_ground * dx[:, 1] ** 2
        )

    reference = np.asarray(jax.jit(jax.hessian(model))(jnp.zeros(2 * n + 1)))
    springs = eqx.tree_at(lambda h: h.gas_grad, springs, jnp.zeros_like(springs.gas_grad))
    np.testing.assert_allclose(
        _dense(jax.tree_util.tree_map(np.asarray, springs), np.zeros(2 * n + 1, bool)), reference, rtol=0, atol=1e-14
    )


def test_step_cap_limits_motion_relative_to_the_indenter():
    # A ball of R = 0.13 m touched at its top pole by the 8 mm indenter (gap 0 there). Moving
    # shell and indenter together must not be cut (the old per-coordinate cap of 8 mm cut this
    # 20 mm step to 0.4); moving the indenter alone 20 mm into the shell must be cut to the
    # indenter radius at the touching pole: α = 8 / 20 (far nodes have gaps > 20 mm).
    setup = Setup(radius=0.13, n_elements=21)
    cfg = Config(theta=setup.theta(), loading="sphere", ground=True, pin_bottom=False)
    theta = np.asarray(setup.theta())
    x = 0.13 * np.stack([np.sin(theta), -np.cos(theta)], -1)
    p = _params(2.34e6, 9e-4, 0.4, 0.13, 1300.0, setup, ground_z=-0.13)
    y = jnp.asarray(np.concatenate([x.ravel(), [0.13 + setup.indenter_radius]]))
    together = jnp.asarray(np.concatenate([np.tile([0.0, -0.02], len(theta)), [-0.02]]))
    indenter_only = jnp.zeros_like(y).at[-1].set(-0.02)
    assert float(newton._step_cap(together, y, cfg, p, setup.indenter_radius)) == 1.0
    np.testing.assert_allclose(
        float(newton._step_cap(indenter_only, y, cfg, p, setup.indenter_radius)),
        setup.indenter_radius / 0.02,
        rtol=1e-12,
    )
    # under a point load (no indenter) the cap stays on the largest coordinate change
    plane = Config(theta=setup.theta(), loading="point", ground=True, pin_bottom=False)
    np.testing.assert_allclose(
        float(newton._step_cap(together, y, plane, p, setup.indenter_radius)), setup.indenter_radius / 0.02, rtol=1e-12
    )


def _curve(setup):
    # the same program as the cold curve below: compiled once, read back from the persistent cache
    return _cold_curve(setup)(PEZZI)


def test_ground_active_set_prediction_keeps_the_equilibrium_and_saves_iterations(monkeypatch):
    setup = Setup(radius=0.13, n_elements=61)
    predicted = _curve(setup)
    monkeypatch.setattr(newton, "ACTIVE_SET_PASSES", 0)  # plain Newton direction (read at trace time)
    plain = _curve(setup)
    for out in (predicted, plain):
        assert np.all(np.asarray(out["residual"]) <= setup.atol)
    # Both satisfy max|∂E/∂y| ≤ 1e-7 N; with a dimple stiffness of ~250 N/m that pins w0 to well
    # below 1e-9 m, so 1e-8 relative on 20–55 mm depths only allows round-off.
    np.testing.assert_allclose(np.asarray(predicted["w0"]), np.asarray(plain["w0"]), rtol=1e-8)
    np.testing.assert_allclose(
        np.asarray(predicted["contact_diameter"]), np.asarray(plain["contact_diameter"]), rtol=1e-7
    )
    # Measured on this ball: 19 vs 50 iterations over the three levels (the plain step crawls each
    # time the ground disc grows by a node). Iteration counts can move by one or two with another
    # CPU's rounding, so require a clear saving (≥ 15 %), not the exact count.
    assert float(predicted["iterations"].sum()) <= 0.85 * float(plain["iterations"].sum())


def test_nearby_guesses_change_the_path_not_the_equilibrium():
    setup = Setup(radius=0.13, n_elements=61)
    cold = _cold_curve(setup)
    warm = jax.jit(lambda theta, guesses: curve_single(setup, shell(theta), FORCES, nearby_guesses=guesses))
    alone = cold(PEZZI)
    neighbour = cold(PEZZI * np.array([1.004, 0.995, 1.003, 1.0]))  # P_g, E, h within 0.5 %
    missing = jnp.full_like(neighbour["state"], jnp.nan)
    # two guesses in every call below (a NaN one never taken): one compiled program serves them all
    started_near = warm(PEZZI, jnp.stack([neighbour["state"], missing], axis=1))
    # Both satisfy max|∂E/∂y| ≤ 1e-7 N; with a dimple stiffness of ~250 N/m that pins w0 to
    # ≈ 4e-10 m of its 20–45 mm, ≈ 2e-8 relative: 1e-7 leaves room for the two Newton paths'
    # own rounding without letting any other equilibrium pass.
    np.testing.assert_allclose(np.asarray(started_near["w0"]), np.asarray(alone["w0"]), rtol=1e-7)
    # 5–7 Newton iterations a level from the previous level, 2 from the neighbour (measured)
    assert float(started_near["iterations"].sum()) <= 0.6 * float(alone["iterations"].sum())
    # The lowest-energy guess wins: the equilibrium itself needs no iteration ...
    at_rest = warm(PEZZI, jnp.stack([neighbour["state"], alone["state"]], axis=1))
    assert np.all(np.asarray(at_rest["iterations"]) == 0)
    # ... and a missing one (NaN) is never taken: the usual path, step for step.
    unknown = warm(PEZZI, jnp.stack([missing, missing], axis=1))
    np.testing.assert_array_equal(np.asarray(unknown["iterations"]), np.asarray(alone["iterations"]))
    np.testing.assert_allclose(np.asarray(unknown["w0"]), np.asarray(alone["w0"]), rtol=1e-12)


def test_a_node_hovering_over_the_ground_does_not_freeze_newton(monkeypatch):
    # A hammer surrogate node (sealed gas, E ≈ 198 MPa, τ ≈ 9): at the fourth level a ground node
    # hovers 4 nm above the plane, where the contact-predicted model's pull k·gap cancels its
    # true load and the predicted step vanished (1e-17 m): Newton repeated it until max_steps.
    # (found with c_w = 2.5, the default then: with other c_w the Newton path misses that state)
    setup = Setup(radius=0.08, gas=IsothermalGas(), hoop_capacity=2.5)
    physics = CurvePhysics(gas_volume_ratio=2.936825663641749)
    forces = np.array([5.192942604266566, 7.838569549712717, 10.484196495158868, 13.12982344060502])
    params = (4322.770123333427, 197785522.1706926, 0.00030831352398951936, 0.4)

    def residuals():
        return np.asarray(jax.jit(lambda: curve_single(setup, shell(params), forces, physics=physics))()["residual"])

    assert np.all(residuals() <= setup.atol)
    monkeypatch.setattr(newton, "MIN_DESCENT_FRACTION", 0.0)  # the former rule (read at trace time)
    assert residuals()[-1] > 1e-2  # stuck at ≈ 0.14 N


def test_tied_loop_carries_let_vmap_batch_a_loop_body_once():
    # vmap batches a while_loop body until the set of batched carries stops growing; nested loops
    # multiply those passes (docs/axisym.md, *Solver*). Tied to a batched value, a counter is
    # batched from the start and the body is batched once, with the same result. A custom_vmap
    # rule inside the body counts the passes.
    from shelljax.axisym._tracing import tied_to

    def run(tie):
        passes = []

        @jax.custom_batching.custom_vmap
        def halve(x):
            return 0.5 * x

        @halve.def_vmap
        def _(axis_size, in_batched, x):
            passes.append(in_batched)
            return 0.5 * x, in_batched[0]

        def halve_below_one(x):
            k = tied_to(x, jnp.asarray(0)) if tie else jnp.asarray(0)
            return jax.lax.while_loop(lambda s: s[0] > 1.0, lambda s: (halve(s[0]), s[1] + 1), (x, k))

        out = jax.vmap(halve_below_one)(jnp.asarray([3.0, 40.0]))
        return len(passes), out

    (untied, out_untied), (tied, out_tied) = run(False), run(True)
    assert (untied, tied) == (2, 1)
    np.testing.assert_array_equal(out_tied[0], out_untied[0])
    np.testing.assert_array_equal(out_tied[1], [2, 6])


def test_the_curves_inflation_is_the_equilibrium_of_the_plain_inflation_problem():
    # A curve's first Newton solve is the inflation in the indentation's configuration, with
    # Params.inflating switching the sealed gas, the relaxation, the contacts, the load and the
    # weight off (one solver program for both). The state must be the equilibrium of the plain
    # inflation problem: prescribed gauge pressure, nothing touching, unrelaxed wall, bottom pinned.
    setup = STATES_SETUP
    # jitted: op by op, its hundreds of single operations each compile a program of their own
    r0, y, res, _ = jax.jit(lambda theta: inflate(setup, shell(theta)))(PEZZI)
    # the same solve, inside the curve's program and in a program of its own here: equal to round-off
    np.testing.assert_allclose(np.asarray(_indented_states(setup)[0]), np.asarray(y), rtol=0, atol=1e-14)
    assert float(res) <= setup.atol
    plain = Config(theta=setup.theta(), gas=PrescribedGas(), loading="none", ground=False, pin_bottom=True, relax=False)
    p = _params(*PEZZI[1:], r0, PEZZI[0], setup)
    force = jax.jit(newton.residual, static_argnums=1)
    # The plain problem's out-of-balance force at the state is the curve's own residual (2.7e-8 N
    # measured, bit for bit: the switched-off terms add exact zeros) up to the round-off of forces
    # of P_g × element area ≈ 30 N per node (1e-14 N), so 1e-6 relative.
    assert float(jnp.max(jnp.abs(force(y, plain, p)))) == pytest.approx(float(res), rel=1e-6)
    # not vacuous: with a sealed gas that is at P_g only at 90 % of this volume, the same state is
    # far out of balance (285 N measured)
    sealed = _params(*PEZZI[1:], r0, PEZZI[0], setup, ref_volume=0.9 * enclosed_volume(split(y, 21)[0]))
    assert (
        float(
            jnp.max(
                jnp.abs(
                    force(y, Config(theta=setup.theta(), gas=IsothermalGas(), loading="none", pin_bottom=True), sealed)
                )
            )
        )
        > 1.0
    )
