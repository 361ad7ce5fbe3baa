"""Fit (optimistix LM + Laplace) and posterior (emcee) machinery on an exactly known forward model.

The scaling-law model is used here because its truth is exact; the shell-model forward solves are
tested with the engines.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from shelljax import InvalidInputError, NoConvergenceError
from shelljax.estimate import (
    ConvergenceWarning,
    Estimate,
    EstimatorOptions,
    Prediction,
    ScalingLawModel,
    fit_session,
    run_estimator,
    sample_posterior,
)
from shelljax.session import Session

FORCES = np.tile(np.arange(5.0, 20.01, 2.5), 3)
TRUTH = dict(gauge_pressure=1300.0, young_modulus=2.34e6, thickness=0.9e-3, radius=0.13)
MODEL = ScalingLawModel(poisson_ratio=0.4, k_s=0.64)


def synthetic(depth_noise=0.0, seed=0, counts=None, radius_std=0.0026, thickness_std=4.5e-5) -> Session:
    pred = MODEL(
        TRUTH["gauge_pressure"], TRUTH["young_modulus"], TRUTH["thickness"], TRUTH["radius"], jnp.asarray(FORCES)
    )
    rng = np.random.default_rng(seed)
    depth = (
        np.asarray(pred.depth) + rng.normal(0.0, depth_noise, FORCES.size) if depth_noise else np.asarray(pred.depth)
    )
    n = float(pred.wrinkle_count)
    return Session(
        source=Path(f"synthetic-{seed}.toml"),
        object_name="synthetic",
        radius=TRUTH["radius"],
        radius_std=radius_std,
        thickness=TRUTH["thickness"],
        thickness_std=thickness_std,
        poisson_ratio=0.4,
        trial=np.repeat([1, 2, 3], 7),
        force=FORCES.copy(),
        depth=depth,
        wrinkle_counts=np.array(counts if counts is not None else [round(n)] * 3),
    )


def test_fit_recovers_exact_pressure():
    s = synthetic(radius_std=0.0, thickness_std=0.0)
    result = fit_session(s, MODEL, depth_noise=1e-3)
    # noise-free depths from the same model: P_g is pinned by them up to solver tolerance
    assert result.estimates["gauge_pressure"].value == pytest.approx(TRUTH["gauge_pressure"], rel=1e-6)
    # E is pinned by the (rounded) counts: n_model must equal the recorded integer count
    assert result.predicted_wrinkle_count == pytest.approx(s.wrinkle_counts[0], abs=1e-4)


def test_fit_recovers_depth_offset():
    s = synthetic(radius_std=0.0, thickness_std=0.0)
    s = dataclasses.replace(s, depth=s.depth + 2e-3)
    result = fit_session(s, MODEL, depth_noise=1e-3, nuisance=("depth_offset",))
    assert result.estimates["depth_offset"].value == pytest.approx(2e-3, abs=1e-8)
    assert result.estimates["gauge_pressure"].value == pytest.approx(TRUTH["gauge_pressure"], rel=1e-6)


def test_laplace_and_mcmc_agree():
    s = synthetic(depth_noise=1e-3, seed=4)
    fit = fit_session(s, MODEL)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ConvergenceWarning)
        post = sample_posterior(fit, n_walkers=24, max_steps=6000, seed=1, progress=False)
    assert post.converged and post.effective_samples > 1000
    for name in ("gauge_pressure", "young_modulus"):
        f, b = fit.estimates[name], post.estimates[name]
        # two independent computations of one posterior; the posterior is near-Gaussian in log
        # space here, and the MCMC std carries ~3 % Monte-Carlo error at ESS > 1000: 25 % allows for
        # the Laplace approximation's neglect of skew (E ∝ n⁻² is skewed) and σ_w being sampled
        assert b.std / f.std == pytest.approx(1.0, abs=0.25), name
        assert abs(b.value - f.value) < 0.5 * f.std, name


def test_posterior_resumes_from_hdf5(tmp_path):
    s = synthetic(depth_noise=1e-3, seed=5)
    path = tmp_path / "chain.h5"
    fit = fit_session(s, MODEL)
    with pytest.warns(ConvergenceWarning, match="before convergence"):
        first = sample_posterior(fit, n_walkers=16, max_steps=300, check_every=100, backend_path=path, progress=False)
    assert first.n_steps == 300 and not first.converged
    with pytest.warns(ConvergenceWarning):
        second = sample_posterior(fit, n_walkers=16, max_steps=600, check_every=100, backend_path=path, progress=False)
    assert second.n_steps == 600
    # the first 300 steps of the resumed chain are the stored ones, untouched
    np.testing.assert_array_equal(second.chain[:300], first.chain)


def test_chain_file_is_the_chain_in_emcees_layout(tmp_path):
    import emcee

    fit = fit_session(synthetic(depth_noise=1e-3, seed=6), MODEL)
    path = tmp_path / "chain.h5"
    options = dict(
        n_walkers=16, max_steps=620, check_every=310, seed=3, progress=False
    )  # 620: not a multiple of the 250-step block
    with pytest.warns(ConvergenceWarning):
        in_memory = sample_posterior(fit, **options)
    with pytest.warns(ConvergenceWarning):
        on_file = sample_posterior(fit, backend_path=path, **options)
    np.testing.assert_array_equal(on_file.chain, in_memory.chain)
    # emcee's own reader sees every step, the acceptance counts and the sampler's last random state.
    stored = emcee.backends.HDFBackend(str(path), name="shelljax-" + fit.source.stem, read_only=True)
    assert stored.iteration == 620
    np.testing.assert_array_equal(stored.get_chain(), in_memory.chain)
    assert np.mean(stored.accepted) / 620 == pytest.approx(in_memory.acceptance_fraction, rel=1e-12)
    assert stored.random_state is not None


class _FailsAbovePressure(ScalingLawModel):
    limit: float = 1400.0

    def __call__(self, gauge_pressure, young_modulus, thickness, radius, forces):
        pred = super().__call__(gauge_pressure, young_modulus, thickness, radius, forces)
        return Prediction(pred.depth, pred.wrinkle_count, gauge_pressure < self.limit)


def test_failed_forward_solves_are_counted_not_fatal():
    s = synthetic(depth_noise=3e-3, seed=6)
    model = _FailsAbovePressure(poisson_ratio=0.4, k_s=0.64, limit=1.02 * TRUTH["gauge_pressure"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        post = sample_posterior(
            fit_session(s, model, raise_on_failure=False), n_walkers=16, max_steps=500, check_every=250, progress=False
        )
    assert post.failed_forward > 0
    assert np.all(post.samples["gauge_pressure"] < model.limit)


def test_fit_that_cannot_start_says_why():
    s = synthetic()
    model = _FailsAbovePressure(poisson_ratio=0.4, k_s=0.64, limit=1.0)
    with pytest.raises(NoConvergenceError, match="fails at the closed-form start"):
        fit_session(s, model)


def test_fit_blocked_by_failing_forward_solves_is_not_called_converged():
    # Data of k_s = 0.64 fitted with k_s = 0.64/1.3: the optimum is P_g = 1.3 × 1300 = 1690 Pa,
    # beyond a wall at 1600 Pa where the model fails. LM must push against the wall, have its steps
    # rejected (failed solves are large finite residuals), and report that it did not converge.
    s = synthetic(depth_noise=1e-3, seed=4)
    wall = _FailsAbovePressure(poisson_ratio=0.4, k_s=0.64 / 1.3, limit=1600.0)
    with pytest.raises(NoConvergenceError, match="would still remove"):
        fit_session(s, wall)
    last = fit_session(s, wall, raise_on_failure=False)
    assert not last.converged and last.estimates["gauge_pressure"].value < 1600.0
    # without the wall the same fit reaches the optimum
    free = fit_session(s, ScalingLawModel(poisson_ratio=0.4, k_s=0.64 / 1.3))
    # (1 mm depth noise on 21 samples pins P_g to ~1 %: 3 % is 3σ)
    assert free.converged and free.estimates["gauge_pressure"].value == pytest.approx(1690.0, rel=0.03)


def test_fit_without_wrinkles_is_a_clear_error():
    s = dataclasses.replace(synthetic(), wrinkle_counts=None)
    with pytest.raises(InvalidInputError, match="no \\[wrinkles\\] counts"):
        fit_session(s, MODEL)


def test_unknown_nuisance_is_rejected():
    with pytest.raises(InvalidInputError, match="unknown nuisance"):
        fit_session(synthetic(), MODEL, nuisance=("temperature",))


def test_fit_that_stops_short_raises_or_returns_its_last_iterate():
    # From the closed-form start (1300 Pa) to the optimum at 1690 Pa (k_s = 0.64 data fitted with
    # k_s = 0.64/1.3) takes LM more than one step: after one it is not at an optimum, and says so.
    s = synthetic(depth_noise=1e-3, seed=4)
    model = ScalingLawModel(poisson_ratio=0.4, k_s=0.64 / 1.3)
    with pytest.raises(NoConvergenceError, match="did not converge in 1 steps"):
        fit_session(s, model, max_steps=1)
    last = fit_session(s, model, max_steps=1, raise_on_failure=False)
    converged = fit_session(s, model)
    assert not last.converged and converged.converged
    assert abs(last.estimates["gauge_pressure"].value / converged.estimates["gauge_pressure"].value - 1) > 1e-3


def test_fit_out_of_steps_at_a_verified_optimum_is_converged():
    # rtol = atol = 0 can never be met: LM runs all its 200 steps. It does so at the optimum
    # (no χ² left for a Gauss–Newton step), so the fit is converged and equals the normal one.
    s = synthetic(depth_noise=1e-3, seed=2, radius_std=0.0, thickness_std=0.0)
    exhausted = fit_session(s, MODEL, rtol=0.0, atol=0.0)
    normal = fit_session(s, MODEL)
    assert exhausted.converged and exhausted.steps == 200
    assert exhausted.estimates["gauge_pressure"].value == pytest.approx(
        normal.estimates["gauge_pressure"].value, rel=1e-6
    )


def test_every_estimator_answers_in_one_protocol():
    s = synthetic(depth_noise=1e-3, seed=3)
    options = EstimatorOptions(forward_model="scaling", walkers=16, max_steps=300, bootstrap_samples=0)
    fit = run_estimator("fit", s, options)
    with pytest.warns(ConvergenceWarning):
        post = run_estimator("bayes", s, options, fit=fit)
    for result in (run_estimator("closed-form", s, options), fit, post):
        assert all(isinstance(e, Estimate) for e in result.estimates.values())
        record = result.to_dict()
        assert list(record["estimates"]) == list(result.estimates)
        assert record["estimates"]["gauge_pressure"]["unit"] == "Pa"
    with pytest.raises(InvalidInputError, match="unknown estimator"):
        run_estimator("magic", s, options)


def test_padded_log_posterior_is_the_posterior_of_the_session():
    # An independent computation (NumPy and SciPy) of the documented posterior, on a session whose
    # 21 samples and 3 counts are padded to 32 and 8, with the thickness fitted and the radius not.
    from scipy.stats import norm

    from shelljax.estimate import build_problem, padded_problem

    s = synthetic(depth_noise=1e-3, seed=7, radius_std=0.0)
    problem = build_problem(s, MODEL, start_pressure=1250.0, start_modulus=2.0e6, nuisance=("depth_offset",))
    padded, columns, _ = padded_problem(problem)
    rng = np.random.default_rng(0)
    for _ in range(3):
        u = np.zeros(7)
        u[columns] = 0.05 * rng.standard_normal(columns.size)
        u[-1] = math.log(8e-4)
        pressure, modulus = 1250.0 * math.exp(u[0]), 2.0e6 * math.exp(u[1])
        thickness, offset, noise = TRUTH["thickness"] * math.exp(u[2]), 1e-3 * u[4], math.exp(u[-1])
        pred = MODEL(pressure, modulus, thickness, TRUTH["radius"], jnp.asarray(s.force))
        depth = np.asarray(pred.depth) + offset
        n = float(pred.wrinkle_count)
        expected = (
            np.sum(norm.logpdf(s.depth, depth, noise))
            + 0.5 * s.depth.size * math.log(2 * math.pi)
            + np.sum(np.log(norm.cdf(s.wrinkle_counts + 0.5 - n) - norm.cdf(s.wrinkle_counts - 0.5 - n)))
            - 0.5 * ((thickness - s.thickness) / s.thickness_std) ** 2
        )
        log_p, converged = padded.log_posterior(jnp.asarray(u))
        # the same sums in another order: round-off only
        assert bool(converged) and float(log_p) == pytest.approx(expected, rel=1e-10, abs=1e-8)
    outside = np.zeros(7)
    outside[-1] = math.log(1e-6)  # σ_w below its prior's 10 µm
    assert float(padded.log_posterior(jnp.asarray(outside))[0]) == -np.inf


def test_stretch_moves_keep_unsampled_coordinates_and_sample_a_gaussian():
    # The scaling-law posterior in (log P_g, log E, log σ_w) with the rest fixed; the padded
    # coordinates must stay exactly 0, and the chain's moments match emcee's own sampler run on
    # the same log posterior (two independent samplers of one density).
    import emcee
    import jax

    from shelljax.estimate import build_problem, padded_problem
    from shelljax.estimate._ensemble import stretch_block

    s = synthetic(depth_noise=1e-3, seed=8, radius_std=0.0, thickness_std=0.0)
    problem = build_problem(s, MODEL, start_pressure=1300.0, start_modulus=2.34e6)
    padded, columns, _ = padded_problem(problem)
    free = np.zeros(7, bool)
    free[[*columns, 6]] = True
    rng = np.random.default_rng(1)
    walkers = np.zeros((16, 7))
    walkers[:, free] = 1e-3 * rng.standard_normal((16, 3)) + [0.0, 0.0, math.log(problem.depth_noise)]
    chains = []
    for block in range(8):
        out = stretch_block(padded, walkers, block, free, 500, 500)
        walkers = np.asarray(out["chain"])[-1]
        chains.append(np.asarray(out["chain"]))
    chain = np.concatenate(chains)[1000:]
    assert np.all(chain[:, :, ~free] == 0.0)
    log_prob = jax.jit(jax.vmap(lambda v: padded.log_posterior(jnp.zeros(7).at[free].set(v))[0]))
    reference = emcee.EnsembleSampler(16, 3, lambda c: np.asarray(log_prob(jnp.asarray(c))), vectorize=True)
    reference.run_mcmc(chain[-1][:, free], 3000, progress=False)
    ours, theirs = chain[:, :, free].reshape(-1, 3), reference.get_chain(discard=500, flat=True)
    # ~1000 effective samples each: means agree to a few Monte-Carlo standard errors (0.1 σ),
    # standard deviations to 15 %
    assert np.all(np.abs(ours.mean(0) - theirs.mean(0)) < 0.15 * theirs.std(0))
    np.testing.assert_allclose(ours.std(0), theirs.std(0), rtol=0.15)
