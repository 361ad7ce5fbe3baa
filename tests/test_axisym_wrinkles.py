"""Tension-field relaxation past the onset and the mechanics-based wrinkle count."""

import jax.numpy as jnp
import numpy as np

from shelljax.axisym import Setup, indentation_curves_raw, vella_wrinkle_count

RADIUS = 0.13
PEZZI = jnp.asarray([1300.0, 2.34e6, 9e-4, 0.4])  # τ ≈ 37
FORCES = jnp.asarray([5.0, 20.0])  # −W(0) ≈ 1.6 (pre-onset) and ≈ 6 (post-onset)


def test_relaxation_only_acts_past_the_onset():
    relaxed = indentation_curves_raw(PEZZI[None], FORCES, Setup(radius=RADIUS, substeps=3))
    plain = indentation_curves_raw(PEZZI[None], FORCES, Setup(radius=RADIUS, substeps=3, relax=False))
    assert bool(np.all(relaxed.converged)) and bool(np.all(plain.converged))
    # Before the onset the hoop stress is tensile everywhere: relaxation must change nothing
    # (up to the 1e-3 smoothing width of the switch, an O(1e-4) effect on w0).
    assert float(plain.min_hoop_tension[0, 0]) > 0
    np.testing.assert_allclose(relaxed.w0[0, 0], plain.w0[0, 0], rtol=1e-3)
    # Past it the unrelaxed shell carries hoop compression a wrinkled shell cannot: relaxing
    # it makes the dimple deeper.
    assert float(plain.min_hoop_tension[0, 1]) < 0
    assert float(relaxed.w0[0, 1]) > 1.01 * float(plain.w0[0, 1])


def test_wrinkle_count_near_paper_law():
    res = indentation_curves_raw(PEZZI[None], FORCES, Setup(radius=RADIUS, substeps=3))
    n_pre, n_post = np.asarray(res.wrinkle_count[0])
    n_paper = float(vella_wrinkle_count(*PEZZI, RADIUS))
    assert n_pre == 0.0  # no compressive annulus before the onset
    # A local wavelength model, not a fit: the report shows n / (1.33 τ^½) ≈ 0.6–0.85 over
    # τ = 10…100 at −W(0) = 4…6, rising with depth; here (τ ≈ 37, −W(0) ≈ 7.7) measured 0.94.
    assert 0.75 < n_post / n_paper < 1.25
    # the derivative of n is checked with the curve gradients in test_axisym_curves.py
