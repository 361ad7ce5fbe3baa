"""Newton safeguards of the axisymmetric engine: they change the path, never the equilibrium."""

from __future__ import annotations

import jax
import numpy as np

import shelljax.axisym._newton as newton
from shelljax.axisym import Setup
from shelljax.axisym._linalg import _inverse_4x4
from shelljax.axisym._model import curve_single


def test_closed_form_block_inverse_matches_lapack():
    rng = np.random.default_rng(3)
    blocks = rng.normal(size=(50, 4, 4)) + 4.0 * np.eye(4)  # condition numbers ~1–10
    # float64 closed form vs LAPACK: agreement to a few hundred ulps of the inverse's size
    np.testing.assert_allclose(np.asarray(_inverse_4x4(blocks)), np.linalg.inv(blocks), rtol=0, atol=1e-13)


def _curve(setup):
    return jax.jit(lambda: curve_single(setup, 1300.0, 2.34e6, 9e-4, 0.4, np.array([5.0, 10.0, 15.0])))()


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
    np.testing.assert_allclose(np.asarray(predicted["contact_diameter"]), np.asarray(plain["contact_diameter"]), rtol=1e-7)
    # Measured on this ball: 38 vs 51 iterations over the three levels (the plain step crawls each
    # time the ground disc grows by a node). Iteration counts can move by one or two with another
    # CPU's rounding, so require a clear saving (≥ 15 %), not the exact count.
    assert float(predicted["iterations"].sum()) <= 0.85 * float(plain["iterations"].sum())


def test_a_node_hovering_over_the_ground_does_not_freeze_newton(monkeypatch):
    # A hammer surrogate node (sealed gas, E ≈ 198 MPa, τ ≈ 9): at the fourth level a ground node
    # hovers 4 nm above the plane, where the contact-predicted model's pull k·gap cancels its
    # true load and the predicted step vanished (1e-17 m): Newton repeated it until max_iter.
    setup = Setup(radius=0.08, gas="isothermal", gas_volume_ratio=2.936825663641749)
    forces = np.array([5.192942604266566, 7.838569549712717, 10.484196495158868, 13.12982344060502])
    params = (4322.770123333427, 197785522.1706926, 0.00030831352398951936, 0.4)

    def residuals():
        return np.asarray(jax.jit(lambda: curve_single(setup, *params, forces))()["residual"])

    assert np.all(residuals() <= setup.atol)
    monkeypatch.setattr(newton, "MIN_DESCENT_FRACTION", 0.0)  # the former rule (read at trace time)
    assert residuals()[-1] > 1e-2  # stuck at ≈ 0.14 N
