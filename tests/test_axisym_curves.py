"""The batched curve API: balance, gas, convergence flags, errors, implicit gradients."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from shelljax.physics import IsothermalGas
import shelljax
from shelljax.axisym import Setup, indentation_curves, indentation_curves_raw
from shelljax.physics import ShellProperties

from _shells import shell

# batch_result's program (one Pezzi ball per call) is test_axisym_wrinkles.py's relaxed curve
SHARED_PROGRAMS = "axisym-pezzi-ball"

RADIUS = 0.13
PEZZI = [1300.0, 2.34e6, 9e-4, 0.4]  # P_g [Pa], E [Pa], h [m], ν
FORCES = (5.0, 20.0)  # −W(0) ≈ 2 (pre-onset) and ≈ 7.7 (post-onset) on the Pezzi ball
KW = dict(substeps=3)  # 15 N apart: three load steps per interval


@pytest.fixture(scope="module")
def batch_result():
    params = np.array([PEZZI, [1800.0, 3.0e6, 7e-4, 0.35]])
    return params, indentation_curves(shell(params), FORCES, radius=RADIUS, **KW)


def test_global_force_balance_and_monotone_curve(batch_result):
    _, res = batch_result
    assert bool(np.all(res.converged))
    # Ground reaction = indenter force (gas pressure integrates to zero on a closed surface).
    np.testing.assert_allclose(res.ground_reaction, res.force, rtol=1e-6)
    assert np.all(np.diff(res.w0, axis=1) > 0)
    assert np.all(res.travel > res.w0)  # travel includes the ground flattening
    # softer/lower-pressure ball indents more
    assert res.w0[0, -1] > res.w0[1, -1]


def test_batch_elements_are_independent(batch_result):
    params, res = batch_result
    swapped = indentation_curves(shell(params[::-1]), FORCES, radius=RADIUS, **KW)
    np.testing.assert_allclose(swapped.w0[::-1], res.w0, rtol=1e-8)


def test_one_curve_unbatched_is_its_row_of_a_vmapped_batch(batch_result):
    # a batch of one skips vmap: the same Newton iterations from the same start, so the same
    # equilibrium up to round-off (1e-8, as for the swapped batch above)
    params, res = batch_result
    alone = indentation_curves(shell(params[:1]), FORCES, radius=RADIUS, **KW)
    np.testing.assert_allclose(alone.w0, res.w0[:1], rtol=1e-8)
    np.testing.assert_allclose(alone.wrinkle_count, res.wrinkle_count[:1], rtol=1e-8)
    np.testing.assert_array_equal(alone.iterations, res.iterations[:1])


def test_uneven_chunks_match_one_vmapped_batch(batch_result):
    """3 curves in 2 lanes (the second padded with a copy of the Hilbert walk's last curve)
    against the fixture's one vmap of the first two: the padding must neither leak into the
    results, reorder them nor drop a curve."""
    params, res = batch_result
    three = np.vstack([params, [[1500.0, 2.6e6, 8e-4, 0.45]]])
    chunked = indentation_curves(shell(three), FORCES, radius=RADIUS, chunk=2, workers=1, **KW)
    assert chunked.w0.shape == (3, len(FORCES))
    np.testing.assert_allclose(chunked.w0[:2], res.w0, rtol=_NEWTON_RTOL)
    assert bool(np.all(chunked.converged[2]))
    np.testing.assert_allclose(chunked.ground_reaction[2], FORCES, rtol=1e-6)  # as in the balance test
    # plausibility: its P_g, E and h lie between the other two balls' (ν aside), and so does its
    # depth at 20 N (as measured; a reordered or leaked row would break the ordering)
    assert res.w0[1, -1] < chunked.w0[2, -1] < res.w0[0, -1]


def test_a_curve_the_walk_loses_is_solved_again_from_its_cold_start(batch_result, monkeypatch):
    """A walked lane that fails on a curve (a neighbour's equilibrium can mislead Newton) must not
    lose it: the curve is solved again alone. The walk's failure is simulated on the first curve."""
    from shelljax.axisym import _api

    params, res = batch_result
    three = np.vstack([params, [[1500.0, 2.6e6, 8e-4, 0.45]]])
    real = _api._curve_result  # what the checked API's every compiled call goes through
    losses = []

    def walk_loses_the_pezzi_ball(properties, forces, setup, chunk, physics, cold, program):
        out = real(properties, forces, setup, chunk, physics, cold, program)
        if chunk == 0 or cold:  # the walk only: the cold retry (the same program) solves it
            return out
        lost = jnp.all(_api._rows(properties) == jnp.asarray(PEZZI), axis=1)[:, None]
        losses.append(int(lost.sum()))
        return eqx.tree_at(
            lambda r: (r.converged, r.w0), out, (out.converged & ~lost, jnp.where(lost, jnp.nan, out.w0))
        )

    monkeypatch.setattr(_api, "_curve_result", walk_loses_the_pezzi_ball)
    walked = indentation_curves(shell(three), FORCES, radius=RADIUS, chunk=2, workers=1, **KW)
    assert losses == [1]  # not vacuous: the walk did lose the Pezzi ball
    assert bool(np.all(walked.converged))
    np.testing.assert_allclose(walked.w0[:2], res.w0, rtol=_NEWTON_RTOL)


# A walked batch starts each curve from its lane's previous one, so its equilibria agree with
# the cold ones to the Newton tolerance, not bitwise: max|∂E/∂y| ≤ 1e-7 N against a dimple
# stiffness ≳ 170 N/m leaves ≲ 6e-10 m on depths ≥ 20 mm, 3e-8 relative (the largest
# difference measured on 2048 curves). 1e-7 leaves room for that, not for another equilibrium.
_NEWTON_RTOL = 1e-7


@pytest.mark.slow  # compiles the walked batch and its derivative
def test_a_walked_batch_saves_iterations_and_differentiates_alike():
    rng = np.random.default_rng(3)
    params = np.asarray(PEZZI) * np.column_stack([rng.uniform(0.99, 1.01, size=(12, 3)), np.ones(12)])
    tangent = params * np.column_stack([rng.normal(size=(12, 3)), np.zeros(12)])
    setup = Setup(radius=RADIUS)
    forces = jnp.asarray([5.0, 7.5, 10.0])

    @jax.jit
    def curves(theta, cold):
        def depth(q):
            res = indentation_curves_raw(shell(q), forces, setup, 2, cold=cold)  # 2 lanes of 6
            return res.w0, res

        _, w0_dot, res = jax.jvp(depth, (theta,), (tangent,), has_aux=True)
        return res, w0_dot

    # The cold batch is the same compiled program with its traced ``cold`` flag: every guess
    # dropped, so each curve starts from the usual start and takes the unwalked solve's Newton
    # path step for step (NaN guesses are never taken: test_axisym_solver.py::
    # test_nearby_guesses_change_the_path_not_the_equilibrium), the same iterations and
    # equilibria as one vmapped batch (chunk 0), at half the compilation. That the walk keeps
    # every row in its place against unwalked solves is test_uneven_chunks_match_one_vmapped_batch.
    (cold, cold_dot), (walked, walked_dot) = curves(params, True), curves(params, False)
    assert bool(np.all(cold.converged)) and bool(np.all(walked.converged))
    np.testing.assert_allclose(walked.w0, cold.w0, rtol=_NEWTON_RTOL)
    np.testing.assert_allclose(walked.height, cold.height, rtol=_NEWTON_RTOL)
    # Implicit tangents at equilibria ≲ 3e-8 apart differ at that order too (measured 4e-9
    # relative here); 1e-6 passes that, not a tangent that lost a term (≥ 1e-3 off).
    np.testing.assert_allclose(walked_dot, cold_dot, rtol=1e-6, atol=1e-6 * np.max(np.abs(cold_dot)))
    # 10 of the 12 curves start from a neighbour 0.5–1 % away: ≈ 2 instead of 5–7 iterations a
    # level (measured 0.46 of the total); a broken walk (every curve from scratch) gives 1.
    assert int(walked.iterations.sum()) <= 0.65 * int(cold.iterations.sum())


def test_sealed_gas_conserves_pv(batch_result):
    params, pref = batch_result
    res = indentation_curves(shell(params), FORCES, radius=RADIUS, gas=IsothermalGas(), **KW)
    p_abs = np.asarray(res.pressure) + shelljax.physics.ATMOSPHERIC_PRESSURE
    v = np.asarray(res.volume)
    # Isothermal ideal gas: p·V is the same at every force level ...
    np.testing.assert_allclose(p_abs * v, np.broadcast_to(p_abs[:, :1] * v[:, :1], v.shape), rtol=1e-9)
    # ... and equals p₀V₀ of the inflated sphere (the inscribed polygon of revolution loses
    # ≈ Δθ²/12 ≈ 8e-4 of the volume at 61 elements, hence 2e-3)
    p0v0 = (shelljax.physics.ATMOSPHERIC_PRESSURE + params[:, 0]) * 4.0 / 3.0 * np.pi * RADIUS**3
    np.testing.assert_allclose(p_abs[:, 0] * v[:, 0], p0v0, rtol=2e-3)
    assert np.all(np.asarray(res.pressure) > params[:, :1])  # squeezing raises the pressure
    assert np.all(res.w0 < pref.w0)  # and stiffens the ball


def test_non_convergence_is_flagged_and_raised():
    res = indentation_curves(shell(PEZZI), FORCES, radius=RADIUS, max_steps=2, raise_on_failure=False, **KW)
    assert not bool(np.all(res.converged))
    with pytest.raises(shelljax.NoConvergenceError):
        indentation_curves(shell(PEZZI), FORCES, radius=RADIUS, max_steps=2, **KW)


@pytest.mark.parametrize(
    "params, forces",
    [
        ([1300.0, -1.0, 9e-4, 0.4], FORCES),
        ([1300.0, 2e6, 9e-4, 0.6], FORCES),
        (PEZZI, (10.0, 5.0)),
        ([[1300.0, 1300.0], [2e6, 2e6, 2e6], 9e-4, 0.4], FORCES),
        (PEZZI + [0.2], FORCES),
    ],
)
def test_invalid_input(params, forces):
    if len(params) == 4 and isinstance(params[1], list):  # fields of unequal batches
        properties = ShellProperties(
            **dict(zip(("gauge_pressure", "young_modulus", "thickness", "poisson_ratio"), params))
        )
    elif len(params) == 5:  # a radius that is not the one asked for
        properties = shell(params[:4], radius=params[4])
    else:
        properties = shell(params)
    with pytest.raises(shelljax.InvalidInputError):
        indentation_curves(properties, forces, radius=RADIUS)


def test_only_a_shell_properties_is_taken():
    with pytest.raises(shelljax.InvalidInputError, match="ShellProperties"):
        indentation_curves(np.asarray([PEZZI]), FORCES, radius=RADIUS)
    with pytest.raises(TypeError):  # keyword-only: a pressure and a modulus cannot swap places
        ShellProperties(*PEZZI)
    with pytest.raises(shelljax.InvalidInputError, match="radius"):
        indentation_curves(shell(PEZZI), FORCES)


def test_implicit_gradient_matches_central_differences():
    setup = Setup(radius=RADIUS, **KW)
    forces = jnp.asarray(FORCES)

    def outputs(theta):
        res = indentation_curves_raw(shell(theta[None]), forces, setup)
        return jnp.stack([jnp.sum(res.w0) + 0.1 * jnp.sum(res.height), res.wrinkle_count[0, 1]])

    jac = np.asarray(jax.jit(jax.jacrev(outputs))(jnp.asarray(PEZZI)))
    for j in range(3):  # P_g, E, h (ν enters the same way)
        step = 1e-4 * PEZZI[j]
        # θ ± step as one batch of two, as batch_result solves: its compiled program, not another
        pair = indentation_curves(
            shell(np.asarray(PEZZI) + np.outer([step, -step], np.eye(4)[j])), FORCES, radius=RADIUS, **KW
        )
        observed = np.stack([np.sum(pair.w0, axis=1) + 0.1 * np.sum(pair.height, axis=1), pair.wrinkle_count[:, 1]])
        fd = (observed[:, 0] - observed[:, 1]) / (2 * step)
        # curve observables: central differences are O(step²) ≈ 1e-8 accurate, plus single
        # nodes switching contact (penalty is C¹): measured < 1e-4 relative
        assert abs(jac[0, j] / fd[0] - 1.0) < 1e-3, (j, jac[0, j], fd[0])
        # wrinkle count: piecewise smooth (interpolated sign change of N_θ), measured ~1e-4
        assert abs(jac[1, j] / fd[1] - 1.0) < 1e-2, (j, jac[1, j], fd[1])


def test_walls_meeting_is_not_a_converged_state():
    # The Pezzi ball's top pole reaches the bottom wall between 40 and 45 N (docs/axisym.md); the
    # model has no self-contact, so past it the top passes through the bottom onto the ground and
    # w0 stalls at ≈ 217 mm. Such a level must never count as a solved ball.
    res = indentation_curves(shell(PEZZI), (20.0, 60.0), radius=RADIUS, raise_on_failure=False, **KW)
    gap = np.asarray(res.wall_gap)[0]
    assert gap[0] > 0.1 and bool(res.converged[0, 0])  # 20 N: the walls are ≈ 16 cm apart
    assert gap[1] < PEZZI[2] and not bool(res.converged[0, 1])
    with pytest.raises(shelljax.NoConvergenceError, match="top wall onto the bottom wall"):
        indentation_curves(shell(PEZZI), (20.0, 60.0), radius=RADIUS, **KW)
