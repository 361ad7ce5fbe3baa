"""The Chebyshev surrogate that bayes samples through (shelljax.estimate._surrogate)."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from shelljax import InvalidInputError
from shelljax.estimate import ScalingLawModel, build_surrogate, surrogate_error
from shelljax.estimate._forward import AxisymForwardModel
from shelljax.estimate._surrogate import node_axes, surrogate_from_values

# one xdist worker for the files that fit alike (conftest.py): the engine check's 128-curve
# program is the posterior's surrogate program of the default experiment's runs
SHARED_PROGRAMS = "bundled-session fits"

CENTER = {"gauge_pressure": 1300.0, "young_modulus": 2.34e6, "thickness": 9e-4, "radius": 0.13}
FORCES = np.linspace(5.0, 20.0, 7)


def _analytic_surrogate(half_width, nodes):
    """Surrogate of the paper's scaling laws, whose exact values are known everywhere."""
    law = ScalingLawModel(poisson_ratio=0.4)
    axes, lower, upper = node_axes(CENTER, half_width, nodes)
    mesh = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    flat = np.exp(mesh.reshape(-1, 4))
    out = jax.vmap(lambda q: law(q[0], q[1], q[2], q[3], jnp.asarray(FORCES)))(jnp.asarray(flat))
    values = np.concatenate([np.asarray(out.depth), np.asarray(out.wrinkle_count)[:, None]], axis=1)
    surrogate = surrogate_from_values(values.reshape(mesh.shape[:-1] + (-1,)), lower, upper, FORCES, 0.4)
    return law, surrogate, flat, values, (lower, upper)


def test_surrogate_reproduces_an_analytic_model_to_spectral_accuracy():
    half = {"gauge_pressure": 0.2, "young_modulus": 0.5, "thickness": 0.3, "radius": 0.1}
    law, surrogate, nodes, node_values, (lower, upper) = _analytic_surrogate(half, (7, 7, 5, 3))
    evaluate = jax.jit(jax.vmap(lambda q, f: surrogate(q[0], q[1], q[2], q[3], f)))
    # through the nodes exactly (interpolation), up to round-off in the 4-fold transform
    at_nodes = evaluate(jnp.asarray(nodes), jnp.broadcast_to(jnp.asarray(FORCES), (len(nodes), FORCES.size)))
    np.testing.assert_allclose(np.asarray(at_nodes.depth), node_values[:, :-1], rtol=1e-11)
    # Between nodes: the scaling laws are exponentials exp(a·z) of the log parameters z, with
    # |a| ≤ 1 per axis (depth ∝ 1/(P_g R), n ∝ P_g^½ R / (E^½ h)). Chebyshev interpolation on n
    # nodes over z ± w errs by at most (a w)^n e^(a w) / (2^(n−1) n!) relative per axis
    # (dominated here by R: 3 nodes over ±0.1, 4.6e-5); the tensor product multiplies each
    # axis's error by at most the Lebesgue constant of the others (< 2.3 for ≤ 7 nodes).
    bound = 2.3 * sum(
        (w**n) * math.exp(w) / (2 ** (n - 1) * math.factorial(n)) for w, n in zip(half.values(), (7, 7, 5, 3))
    )
    rng = np.random.default_rng(0)
    points = np.exp(rng.uniform(lower, upper, size=(64, 4)))
    forces = rng.uniform(5.0, 20.0, size=(64, FORCES.size))
    got = evaluate(jnp.asarray(points), jnp.asarray(forces))
    want = jax.vmap(lambda q, f: law(q[0], q[1], q[2], q[3], f))(jnp.asarray(points), jnp.asarray(forces))
    assert bool(jnp.all(got.converged))
    np.testing.assert_allclose(np.asarray(got.depth), np.asarray(want.depth), rtol=bound)
    np.testing.assert_allclose(np.asarray(got.wrinkle_count), np.asarray(want.wrinkle_count), rtol=bound)
    assert bound < 2e-4  # the check is tight enough to catch a wrong transform
    # outside the box it reports a failed forward solve (bayes maps it to log p = −∞)
    outside = surrogate(
        CENTER["gauge_pressure"] * 1.3,
        CENTER["young_modulus"],
        CENTER["thickness"],
        CENTER["radius"],
        jnp.asarray(FORCES),
    )
    assert not bool(outside.converged)


def test_fixed_axes_and_gradients():
    # thickness and radius fixed: one node each, any value on those axes is accepted as the centre
    half = {"gauge_pressure": 0.2, "young_modulus": 0.5}
    law, surrogate, *_ = _analytic_surrogate(half, (7, 7, 5, 3))
    assert surrogate.coefficients.shape[2:4] == (1, 1)

    def depth(log_p):
        return surrogate(jnp.exp(log_p), 2.0e6, CENTER["thickness"], CENTER["radius"], jnp.asarray([10.0])).depth[0]

    # the law's depth ∝ 1/P_g: d depth / d log P_g = −depth (independent check of the gradient)
    log_p = jnp.log(1250.0)
    assert float(jax.grad(depth)(log_p)) == pytest.approx(-float(depth(log_p)), rel=1e-6)


def test_surrogate_matches_the_engine_between_nodes():
    # The estimators' engine (101 elements) on a 3 × 3 box in (P_g, E): the check the posterior
    # relies on. Its engine program is bayes's own (the same Setup and 128-curve calls), shipped
    # with the package and compiled once for the suite's posteriors too. Measured at these two
    # points: 2.5e-5 m and 0.04 wrinkles (3.4e-5 m over 64 points). Coarser engines are worse
    # between nodes: at 31 elements the wrinkling relaxation switches Gauss point by Gauss point
    # and w0(P_g, E) carries 0.1 mm bumps (measured 1.02e-4 m at 31, 3.2e-5 m at 61).
    model = AxisymForwardModel.for_forces(0.13, FORCES)
    half = {"gauge_pressure": 0.05, "young_modulus": 0.1}
    surrogate = build_surrogate(model, CENTER, half, nodes=(3, 3, 1, 1), progress=False)
    rng = np.random.default_rng(1)
    axes_lo, axes_hi = np.asarray(surrogate.log_lower), np.asarray(surrogate.log_upper)
    points = np.exp(rng.uniform(axes_lo, axes_hi, size=(2, 4)))
    error = surrogate_error(surrogate, model, points, FORCES)
    # Depths are ~20–80 mm; bayes warns past 0.2 σ_w, and the smallest depth noise of the virtual
    # sessions is σ_w = 0.5 mm: 0.1 mm. A quadratic interpolant over ±5 % / ±10 % of the nearly
    # 1/P_g-shaped curve is expected to be ~10× better than that.
    assert error["depth"] < 1e-4, error
    assert error["wrinkle_count"] < 0.2, error


def test_surrogate_needs_the_engine_model():
    with pytest.raises(InvalidInputError, match="axisymmetric engine model"):
        build_surrogate(ScalingLawModel(), CENTER, {"gauge_pressure": 0.1})
