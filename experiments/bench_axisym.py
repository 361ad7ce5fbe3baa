"""Benchmark of the axisymmetric engine.

Measures, after compilation, medians over repeats of:
  1. one full 7-level F–w(0) curve (the paper's 5–20 N protocol),
  2. a vmapped batch of 64 parameter sets, on one host thread and split over every CPU core
     (``shelljax.axisym.map_batch``: XLA runs this kind of computation on one core),
  3. a large batch (default 1024, all cores) whose per-curve time is extrapolated to 10⁵ curves
     (the size of a posterior run) — labelled as an extrapolation in the table unless
     ``--large 100000`` times all of them. Batches are walked in ``--chunk`` lanes per thread
     (``indentation_curves_raw``): a denser batch has closer neighbours and fewer Newton
     iterations a curve, so a smaller ``--large`` overstates the time per curve.
Prints a table and writes JSON (``--out``), naming the machine.

    python experiments/bench_axisym.py --out bench_axisym.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import jax
import numpy as np

import shelljax  # noqa: F401  (x64)
from shelljax.axisym import Setup, cpu_workers, indentation_curves_raw, map_batch
from shelljax.paper import DEFAULT_POISSON_RATIO, PAPER_FORCES
from shelljax.physics import ShellProperties


def _params(n, seed=0):
    rng = np.random.default_rng(seed)
    base = np.array([1300.0, 2.34e6, 9e-4, DEFAULT_POISSON_RATIO])
    return base * rng.uniform(0.85, 1.15, size=(n, 4)) * np.array([1, 1, 1, 0]) + np.array(
        [0, 0, 0, DEFAULT_POISSON_RATIO]
    )


def _shell(rows):
    """The rows (n, 4) of P_g [Pa], E [Pa], h [m], ν [-] as the engine's ShellProperties."""
    return ShellProperties(
        gauge_pressure=rows[:, 0], young_modulus=rows[:, 1], thickness=rows[:, 2], poisson_ratio=rows[:, 3]
    )


def _work(result):
    """(fraction of curves converged at every level [-], median Newton iterations per curve [-])."""
    return (float(np.mean(np.all(result.converged, axis=1))), float(np.median(np.sum(result.iterations, axis=1))))


def _time(fn, repeats):
    out = fn()
    jax.block_until_ready(out)  # compile + warm
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="bench_axisym.json")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--large", type=int, default=1024, help="batch size timed for the 1e5 estimate")
    ap.add_argument("--n-elements", type=int, default=101)
    ap.add_argument("--chunk", type=int, default=8, help="vmapped lanes (0: the whole batch at once)")
    ap.add_argument(
        "--workers", type=int, default=None, help="host threads for the batches (default: every CPU core; 1 on a GPU)"
    )
    args = ap.parse_args(argv)

    setup = Setup(radius=0.13, n_elements=args.n_elements)
    forces = np.asarray(PAPER_FORCES)
    rows = []

    one = _params(1)
    t1, r1 = _time(lambda: indentation_curves_raw(_shell(one), forces, setup), args.repeats)
    rows.append(("single 7-level curve", 1, t1, t1, *_work(r1), "< 0.020 s"))

    workers = cpu_workers() if args.workers is None else args.workers

    def batch(params, n_workers):
        return map_batch(
            lambda rows: indentation_curves_raw(_shell(rows), forces, setup, args.chunk), params, n_workers
        )

    b64 = _params(64, 1)
    t64_one, r64 = _time(lambda: batch(b64, 1), args.repeats)
    rows.append(("vmapped batch, 1 thread", 64, t64_one, t64_one / 64, *_work(r64), ""))
    t64, r64 = _time(lambda: batch(b64, workers), args.repeats)
    rows.append((f"vmapped batch, {workers} threads", 64, t64, t64 / 64, *_work(r64), "< 0.5 s"))

    big = _params(args.large, 2)
    tl, rl = _time(lambda: batch(big, workers), max(1, args.repeats // 3))
    rows.append((f"large batch, {workers} threads", args.large, tl, tl / args.large, *_work(rl), ""))
    t_1e5 = tl / args.large * 1e5
    how = "timed" if args.large == 100000 else f"extrapolated from {args.large}"
    rows.append((f"1e5 curves ({how})", 100000, t_1e5, tl / args.large, None, None, "< 120 s"))

    device = jax.devices()[0]
    machine = dict(
        platform=platform.platform(),
        processor=platform.processor(),
        cpu_count=os.cpu_count(),
        jax=jax.__version__,
        device=str(device.device_kind),
        backend=jax.default_backend(),
        n_elements=args.n_elements,
        chunk=args.chunk,
        workers=workers,
    )
    print(f"machine: {machine}")
    print(
        f"{'case':34s} {'batch':>7s} {'median [s]':>11s} {'per curve [ms]':>15s} "
        f"{'conv. frac':>10s} {'Newton its/curve':>16s} {'target':>10s}"
    )
    for name, n, t, per, conv, its, target in rows:
        print(
            f"{name:34s} {n:7d} {t:11.4f} {per * 1e3:15.3f} {'' if conv is None else f'{conv:.3f}':>10s} "
            f"{'' if its is None else f'{its:g}':>16s} {target:>10s}"
        )
    with open(args.out, "w") as fh:
        json.dump(
            dict(
                machine=machine,
                rows=[
                    dict(
                        case=a,
                        batch=b,
                        median_s=c,
                        per_curve_s=d,
                        converged=e,
                        median_newton_iterations_per_curve=f,
                        target=g,
                    )
                    for a, b, c, d, e, f, g in rows
                ],
            ),
            fh,
            indent=2,
        )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
