"""The axisymmetric shell engine as the estimators' forward model: gradients, similarity, a fit."""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from shelljax.physics import IsothermalGas, PrescribedGas
from shelljax import InvalidInputError
from shelljax.estimate import AxisymForwardModel, fit_session
from shelljax.estimate._problem import jacobian
from shelljax.session import Session

SHARED_PROGRAMS = "bundled-session fits"  # one xdist worker for the files that fit alike (conftest.py)

FORCES = jnp.asarray(np.tile(np.arange(5.0, 20.01, 2.5), 3))
TRUTH = (1300.0, 2.34e6, 0.9e-3, 0.13)  # P_g [Pa], E [Pa], h [m], R [m]: the paper's Pezzi ball


# The default experiment's forward model (configs/paper.toml): its compiled fit is shared with the
# runner test on the bundled Pezzi sessions.
OPTIONS = dict(poisson_ratio=0.4, gas=IsothermalGas(), wrinkle_law="scaling")


@pytest.fixture(scope="module")
def model():
    return AxisymForwardModel.for_forces(0.13, FORCES, **OPTIONS)


def _depth(model, theta):
    """Depths [m] at FORCES through the engine call the fit's residuals make, so its compiled
    programs, plain and under ``jacfwd``, serve every test of this file and the fit's checks."""
    return model(theta[0], theta[1], theta[2], theta[3], FORCES).depth


@pytest.mark.slow  # central differences of the engine
def test_depth_gradient_matches_central_differences(model):
    theta = jnp.asarray(TRUTH)
    jac = jax.jacfwd(functools.partial(_depth, model))(theta)
    for k in range(4):
        step = 2.5e-5 * theta[k]
        fd = (_depth(model, theta.at[k].add(step)) - _depth(model, theta.at[k].add(-step))) / (2 * step)
        # Newton converges to 1e-7 N (docs/axisym.md), so depths are exact to ~1e-12 m; the central
        # difference's O(step²) truncation error is largest for R at the wrinkled 17.5–20 N levels:
        # measured 2.5e-5 relative at 1e-4 steps, 1.6e-6 at 2.5e-5 (≤ 6e-8 for P_g, E, h): 1e-5 holds
        np.testing.assert_allclose(np.asarray(jac[:, k]), np.asarray(fd), rtol=1e-5, atol=1e-12)


def test_similarity_in_radius(model):
    # A ball 4 % larger: exact length scaling except for the finger radius (kept at 8 mm), whose
    # effect on the dimple depth at these forces is below 1 %.
    direct = AxisymForwardModel.for_forces(0.1352, FORCES, **OPTIONS)
    p, e, h, _ = TRUTH
    scaled = _depth(model, jnp.asarray([p, e, h, 0.1352]))
    reference = _depth(direct, jnp.asarray([p, e, h, 0.1352]))
    np.testing.assert_allclose(np.asarray(scaled), np.asarray(reference), rtol=1e-2)


def test_both_gas_laws_run_one_program(model):
    # the gas law is the traced exponent κ of the engine's polytropic gas: same pytree structure
    # (static fields included), so the prescribed-pressure model runs the isothermal one's program
    prescribed = AxisymForwardModel.for_forces(0.13, FORCES, **{**OPTIONS, "gas": PrescribedGas()})
    assert jax.tree_util.tree_structure(prescribed) == jax.tree_util.tree_structure(model)
    assert (prescribed.gas_exponent, model.gas_exponent) == (0.0, 1.0)
    theta = jnp.asarray(TRUTH)
    free = np.asarray(_depth(prescribed, theta))
    # κ = 0 holds the pressure at P_g whatever volume the gas fills: the same Newton path, so the
    # same depths to round-off (measured 1e-14)
    np.testing.assert_allclose(_depth(dataclasses.replace(prescribed, gas_volume_ratio=3.0), theta), free, rtol=1e-12)
    # κ = 1: squeezing the sealed gas raises its pressure and stiffens the ball (measured 6 % less
    # depth at 5 N, 29 % at 20 N)
    assert np.all(np.asarray(_depth(model, theta)) < 0.97 * free)


@pytest.mark.slow  # fits through the engine
def test_fit_recovers_parameters_of_its_own_model(model):
    p, e, h, r = TRUTH
    pred = model(p, e, h, r, FORCES)
    rng = np.random.default_rng(0)
    counts = np.full(3, int(round(float(pred.wrinkle_count))))
    session = Session(
        source=Path("axisym-synthetic.toml"),
        object_name="synthetic",
        radius=r,
        radius_std=0.02 * r,
        thickness=h,
        thickness_std=0.05 * h,
        poisson_ratio=0.4,
        trial=np.repeat([1, 2, 3], 7),
        force=np.asarray(FORCES),
        depth=np.asarray(pred.depth) + rng.normal(0, 1e-3, FORCES.size),
        wrinkle_counts=counts,
    )
    result = fit_session(session, model)
    est = result.estimates["gauge_pressure"]
    # The truth must lie within the 95 % Laplace interval (a failure here is a 1-in-20 event only
    # if the errors are right). Width: in a sealed ball the F–w(0) slope moves only 0.42 % per 1 %
    # of P_g (the engine's k_s·P_g over the bundled Pezzi calibrations: 708 → 909 Pa for
    # 900 → 1650 Pa), so the 2 % radius prior alone leaves 2/0.42 ≈ 4.8 % on P_g, and 1 mm of
    # depth noise on 21 samples adds ≈ 1.5 %: the relative std must come out below 7 %, not ~1 %
    # as with a prescribed pressure.
    assert est.ci95[0] < p < est.ci95[1]
    assert est.std / est.value < 0.07
    # The recorded count is the truth's n rounded to an integer, so it pins E only to a band: E
    # also shapes the post-wrinkling depths, and least squares trades the count residual (σ = 1
    # wrinkle) against 21 depth residuals. The fitted n must lie inside the ±½ reading band of
    # the recorded count, and the true E inside its 95 % interval.
    assert abs(result.predicted_wrinkle_count - counts[0]) < 0.5
    modulus = result.estimates["young_modulus"]
    assert modulus.ci95[0] < e < modulus.ci95[1]
    # The fit reports what Levenberg–Marquardt linearised at the point it accepted last; recomputed
    # independently at the returned optimum (forward-mode Jacobian, a fresh forward solve) it must
    # be the same point. Two compiled programs differ by engine round-off (measured on a held-out
    # Pezzi session: Jacobian 4e-13, residuals 5e-12 relative), which (JᵀJ)⁻¹ amplifies by at most
    # its condition number: 1e-6 holds below 1e6. On that session the iterate before the optimum
    # (optimistix's sol.aux) gave depths 2.6e-10 relative off, which the 1e-10 check would catch.
    u = jnp.asarray(result.u)
    jac = np.asarray(jacobian(result.problem, u))
    np.testing.assert_allclose(result.covariance, np.linalg.inv(jac.T @ jac), rtol=1e-6)
    residual = np.asarray(result.problem.residuals(u))
    assert result.chi2 == pytest.approx(float(residual @ residual), rel=1e-9)
    np.testing.assert_allclose(result.predicted_depth, np.asarray(result.problem.predict(u)[0]), rtol=1e-10)


def test_sealed_gas_volume_comes_from_the_session_mesh():
    from shelljax.config import bundled_data_dir
    from shelljax.estimate import forward_model_for
    from shelljax.geometry import bundled_mesh_path, enclosed_volume, load_mesh
    from shelljax.session import load_session

    hammer = load_session(bundled_data_dir() / "sessions" / "hammer.toml")
    volume = enclosed_volume(load_mesh(bundled_mesh_path("hammer.stl")))
    assert hammer.enclosed_volume == pytest.approx(volume, rel=1e-12)
    sealed = forward_model_for(hammer, gas=IsothermalGas())
    # the hammer's head (R = 8 cm) belongs to a body of ≈ 2.9 spheres' volume
    assert sealed.gas_volume_ratio == pytest.approx(volume / (4 / 3 * np.pi * hammer.radius**3), rel=1e-12)
    assert 2.5 < sealed.gas_volume_ratio < 3.5
    assert forward_model_for(hammer, gas=PrescribedGas()).gas_volume_ratio == 1.0
    ball = load_session(bundled_data_dir() / "sessions" / "pezzi.toml")  # radius only: no mesh volume
    assert ball.enclosed_volume is None and forward_model_for(ball, gas=IsothermalGas()).gas_volume_ratio == 1.0
    with pytest.raises(InvalidInputError, match="gas_volume_ratio = -1.0 must be a positive number"):
        forward_model_for(ball, gas=IsothermalGas(), gas_volume_ratio=-1.0)
    open_scan = dataclasses.replace(hammer, enclosed_volume=None)  # a mesh that is not watertight
    with pytest.warns(UserWarning, match="not watertight"):
        assert forward_model_for(open_scan, gas=IsothermalGas()).gas_volume_ratio == 1.0
