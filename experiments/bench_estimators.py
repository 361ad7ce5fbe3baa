"""Benchmark of the simulation-based estimators: table + JSON.

* fit: wall time of ``fit_session`` after compilation, median over repeats; and summed over every
  bundled session (one session's time depends on how many steps round-off lets Levenberg–Marquardt
  take near its optimum, which any change of compiled arithmetic redraws);
* bayes: wall time of ``sample_posterior`` after compilation (with the default surrogate: the
  least-squares fit, the surrogate's engine solves and check, and the chain until its
  autocorrelation criterion holds), its effective samples and the time to 1000 effective samples;
* the exact-engine log posterior: seconds per walker evaluation, and what a chain of the same
  length would take through the engine (an extrapolation, labelled as such).

Usage: python experiments/bench_estimators.py [--repeats 5] [--model axisym] [--out bench_estimators.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
import warnings

import jax
import numpy as np

import shelljax
from shelljax.config import bundled_data_dir
from shelljax.estimate import ConvergenceWarning, fit_session, forward_model_for, padded_problem, sample_posterior
from shelljax.physics import gas_law
from shelljax.session import load_session


def _exact_seconds_per_evaluation(fit, walkers, repeats=3):
    """Median seconds per walker of the exact (engine) vectorized log posterior, after compiling."""
    problem = fit.problem
    padded, columns, _ = padded_problem(problem)
    batched = jax.jit(jax.vmap(padded.log_posterior))
    rng = np.random.default_rng(0)
    u = np.zeros((walkers, padded.free.size))
    u[:, columns] = 1e-2 * rng.standard_normal((walkers, problem.ndim))
    coords = np.concatenate([u, np.full((walkers, 1), np.log(problem.depth_noise))], axis=1)
    log_prob = lambda c: jax.block_until_ready(batched(c))  # noqa: E731
    log_prob(coords)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        log_prob(coords)
        times.append(time.perf_counter() - t)
    return statistics.median(times) / walkers


def _fit_every_bundled_session(model_name, options, repeats=3):
    """(sum over the bundled sessions of the median warm fit time [s], their Levenberg–Marquardt
    steps): one session's fit time depends on where round-off stops LM near the optimum."""
    seconds, steps = 0.0, 0
    for path in sorted((bundled_data_dir() / "sessions").glob("*.toml")):
        session = load_session(path)
        model = forward_model_for(session, model_name, **options)
        fit = fit_session(session, model)
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            fit_session(session, model)
            times.append(time.perf_counter() - t)
        seconds, steps = seconds + statistics.median(times), steps + fit.steps
    return seconds, steps


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--session", default=str(bundled_data_dir() / "sessions" / "pezzi.toml"))
    parser.add_argument("--model", default="axisym", choices=["axisym", "scaling"])
    # defaults: the forward model of the default experiment (configs/paper.toml)
    parser.add_argument("--gas", default="isothermal", choices=["prescribed", "isothermal"])
    parser.add_argument("--wrinkle-law", default="scaling", choices=["mechanics", "scaling"])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--walkers", type=int, default=32)
    parser.add_argument("--no-surrogate", action="store_true", help="bayes through the engine itself")
    parser.add_argument("--out", default="bench_estimators.json")
    args = parser.parse_args(argv)
    session = load_session(args.session)
    option_names = {"gas": args.gas, "wrinkle_law": args.wrinkle_law} if args.model == "axisym" else {}
    options = {**option_names, "gas": gas_law(args.gas)} if option_names else {}
    model = forward_model_for(session, args.model, **options)

    t0 = time.perf_counter()
    fit_session(session, model)
    fit_first = time.perf_counter() - t0
    fit_times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        fit_session(session, model)
        fit_times.append(time.perf_counter() - t0)

    fit_every_s, fit_every_steps = _fit_every_bundled_session(args.model, options)

    def posterior():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            t = time.perf_counter()
            fit = fit_session(session, model, raise_on_failure=False)
            post = sample_posterior(
                fit, n_walkers=args.walkers, max_steps=20_000, progress=False, surrogate=not args.no_surrogate
            )
            return time.perf_counter() - t, post, fit

    bayes_first, _, fit = posterior()
    runs = [posterior() for _ in range(max(1, args.repeats // 2))]
    times = [t for t, _, _ in runs]
    ess = [p.effective_samples for _, p, _ in runs]
    rate = [e / t for t, e in zip(times, ess)]
    steps = statistics.median(p.n_steps for _, p, _ in runs)
    exact_per_eval = _exact_seconds_per_evaluation(fit, args.walkers) if args.model == "axisym" else None
    surrogate = runs[-1][1].surrogate
    rows = [
        ("fit, first call (compile + solve)", f"{fit_first:.2f} s"),
        (f"fit after compilation (median of {args.repeats})", f"{statistics.median(fit_times):.3f} s"),
        ("fit of every bundled session (sum of medians of 3)", f"{fit_every_s:.2f} s, {fit_every_steps} LM steps"),
        ("bayes, first call (compile + sample)", f"{bayes_first:.1f} s"),
        (f"bayes after compilation (median of {len(runs)})", f"{statistics.median(times):.1f} s"),
        ("bayes effective samples (median)", f"{statistics.median(ess):.0f}"),
        ("bayes time to 1000 effective samples", f"{1000 / statistics.median(rate):.1f} s"),
        ("bayes chain length (median)", f"{steps:.0f} steps x {args.walkers} walkers"),
    ]
    if surrogate is not None:
        rows += [
            ("surrogate: engine curves solved", f"{surrogate['curves']} + {surrogate['check_points']} checks"),
            ("surrogate: max depth error / sigma_w", f"{surrogate['depth_error_in_noise']:.3f}"),
            ("surrogate: max wrinkle-count error", f"{surrogate['wrinkle_count_error']:.3f}"),
        ]
    if exact_per_eval is not None:
        rows += [
            ("exact engine: s per walker evaluation", f"{exact_per_eval * 1e3:.1f} ms"),
            ("exact engine: same chain (extrapolated)", f"{exact_per_eval * steps * args.walkers:.0f} s"),
        ]
    print(
        f"session {session.source.name}, model {args.model} {option_names}, machine: {platform.platform()}, {os.cpu_count()} CPUs"
    )
    width = max(len(r[0]) for r in rows)
    for name, value in rows:
        print(f"  {name:<{width}}  {value}")
    result = {
        "machine": f"{platform.platform()}, {os.cpu_count()} CPUs",
        "session": str(session.source),
        "model": args.model,
        "model_options": option_names,
        "fit_first_s": fit_first,
        "fit_s": fit_times,
        "fit_median_s": statistics.median(fit_times),
        "fit_every_bundled_session_s": fit_every_s,
        "fit_every_bundled_session_steps": fit_every_steps,
        "bayes_first_s": bayes_first,
        "bayes_s": times,
        "bayes_effective_samples": ess,
        "bayes_seconds_per_1000_effective": 1000 / statistics.median(rate),
        "walkers": args.walkers,
        "bayes_steps_median": steps,
        "surrogate": surrogate,
        "exact_seconds_per_walker_evaluation": exact_per_eval,
        "shelljax_version": shelljax.__version__,
    }
    with open(args.out, "w") as handle:
        json.dump(result, handle, indent=2)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
