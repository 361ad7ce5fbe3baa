"""Benchmark and check of ``shelljax.diagnose`` on a 4-session study (the bundled Pezzi calibration).

1. Time: the diagnosis against every candidate of the library, in a fresh process with an empty
   compilation cache (cold) and again in the same process (warm); medians over ``--repeats``.
2. Accuracy of the linearised leave-one-trial-out score: for each trial, the model is refitted
   without it, and the trial's held-out log predictive density at that refit (Gaussian with the
   refit's Laplace covariance) is compared with the linearised one the diagnosis uses.

Prints a table and writes JSON (default docs/bench/diagnose-cpu-2core.json).
Run:  python experiments/bench_diagnose.py --repeats 3
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from shelljax.config import bundled_data_dir

ROOT = Path(__file__).resolve().parents[1]
SESSIONS = sorted(str(p) for p in (bundled_data_dir() / "sessions").glob("calib_pezzi_*.toml"))[:4]


def _timed_diagnosis() -> dict:
    from shelljax.diagnose import EFFECTS, diagnose

    start = time.perf_counter()
    result = diagnose(SESSIONS, progress=False)
    return {"seconds": time.perf_counter() - start, "candidates": len(EFFECTS), "verdict": result.verdict}


def _cold(repeats: int) -> list[float]:
    """Fresh processes, each with its own empty compilation cache."""
    times = []
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as cache:
            env = {**os.environ, "SHELLJAX_CACHE_DIR": cache}
            start = time.perf_counter()
            subprocess.run([sys.executable, __file__, "--one"], check=True, env=env, capture_output=True)
            times.append(time.perf_counter() - start)
    return times


def _without_trial(session, trial):
    keep = session.trial != trial
    counts = session.wrinkle_counts[session.trial_ids != trial]
    return dataclasses.replace(
        session, trial=session.trial[keep], force=session.force[keep], depth=session.depth[keep], wrinkle_counts=counts
    )


def loo_check() -> dict:
    """Linearised vs refitted held-out log density of every trial of the baseline."""
    import jax
    import jax.numpy as jnp

    from shelljax.diagnose import (
        JointProblem,
        build_study,
        candidate_data,
        fit_candidate,
        loo_score,
        study_arrays,
        unit_log_jacobian,
    )
    from shelljax.session import load_session

    sessions = [load_session(p) for p in SESSIONS]
    free = ("young_modulus", "thickness", "radius")
    study = build_study(sessions)
    data = candidate_data(study_arrays(study), None, free)
    fit = fit_candidate(data, "scaling", np.zeros(data.free.shape[0]))
    linear = loo_score(fit).elpd
    problem = JointProblem(data, "scaling")
    jac_fn = jax.jit(jax.jacfwd(lambda u: problem.residuals_and_prediction(u)[0]))
    units = np.concatenate([np.asarray(data.depth_unit), np.asarray(data.count_unit)])
    mask = np.asarray(data.free)
    log_jac = unit_log_jacobian(data)
    refit = []
    for i, (s, trial) in enumerate(study.units):
        reduced = [(_without_trial(x, trial) if k == s else x) for k, x in enumerate(sessions)]
        sub_study = build_study(reduced, noise=(study.trial_offset_std, study.depth_noise))
        sub = candidate_data(study_arrays(sub_study), None, free)
        sub_fit = fit_candidate(sub, "scaling", fit.u)
        rows = np.flatnonzero(units == i)
        r = np.asarray(problem.residuals_and_prediction(jnp.asarray(sub_fit.u))[0])[rows]
        j = np.asarray(jac_fn(jnp.asarray(sub_fit.u)))[rows][:, mask]
        cov = np.eye(rows.size) + j @ sub_fit.covariance @ j.T
        chol = np.linalg.cholesky(cov)
        white = np.linalg.solve(chol, r)
        refit.append(float(-0.5 * white @ white - np.sum(np.log(np.diag(chol))) + log_jac[i]))
    refit = np.array(refit)
    return {
        "linearised": linear.tolist(),
        "refitted": refit.tolist(),
        "max_abs_difference_nats": float(np.max(np.abs(linear - refit))),
        "total_linearised": float(linear.sum()),
        "total_refitted": float(refit.sum()),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--out", default=str(ROOT / "docs" / "bench" / "diagnose-cpu-2core.json"))
    args = parser.parse_args()
    if args.one:
        print(json.dumps(_timed_diagnosis()))
        return
    cold = _cold(args.repeats)
    warm = [_timed_diagnosis() for _ in range(args.repeats + 1)][1:]
    check = loo_check()
    result = {
        "machine": f"{platform.machine()} {os.cpu_count()} cores, {platform.python_version()}",
        "sessions": [Path(p).name for p in SESSIONS],
        "candidates": warm[0]["candidates"],
        "verdict": warm[0]["verdict"],
        "cold_seconds": cold,
        "cold_median_seconds": statistics.median(cold),
        "warm_seconds": [w["seconds"] for w in warm],
        "warm_median_seconds": statistics.median(w["seconds"] for w in warm),
        "loo_check": check,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1))
    print(f"{'measure':<52s} {'value':>10s}")
    print(
        f"{'diagnosis, 4 sessions x %d candidates, cold (process, empty cache)' % result['candidates']:<52s} "
        f"{result['cold_median_seconds']:9.1f} s"
    )
    print(f"{'same, warm (same process)':<52s} {result['warm_median_seconds']:9.1f} s")
    print(f"{'linearised vs refitted LOO, largest |Δ| per trial':<52s} {check['max_abs_difference_nats']:9.3f} nats")
    print(f"{'total elpd, linearised / refitted':<52s} {check['total_linearised']:.2f} / {check['total_refitted']:.2f}")


if __name__ == "__main__":
    main()
