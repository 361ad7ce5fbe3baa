"""Command line: ``shelljax run``, ``estimate``, ``validate``, and the sensor commands ``acquire``,
``sensor-calibrate``, ``sensor-emulator`` (see docs/sensing.md)."""

from __future__ import annotations

import argparse
import json
import sys

from ._errors import ShelljaxError


def _cmd_run(args) -> int:
    from .runner import run_experiment, summary_table

    run_dir = run_experiment(args.config, output_dir=args.out, progress=None if not args.quiet else False)
    print(summary_table(json.loads((run_dir / "results.json").read_text())))
    print(f"results: {run_dir / 'results.json'}")
    return 0


def _cmd_estimate(args) -> int:
    from .estimate import Estimate, estimate_session, fit_session, forward_model_for, sample_posterior
    from .session import load_session

    session = load_session(args.session)
    out = {"session": str(session.source), "object": session.object_name, "method": args.method}
    if args.method == "closed-form":
        k_s = None
        if args.k_s is not None:
            if args.k_s <= 0 or args.k_s_std < 0:
                raise ShelljaxError(f"--k-s {args.k_s} / --k-s-std {args.k_s_std}: k_s must be > 0 and its std >= 0")
            k_s = Estimate.lognormal(args.k_s, args.k_s_std / args.k_s, "1", "given on the command line")
        result = estimate_session(session, k_s=k_s, bootstrap_samples=args.bootstrap, seed=args.seed)
        estimates = result.estimates()
        out["bootstrap"] = {k: v.to_dict() for k, v in result.bootstrap.items()}
    else:
        options = {"gas": args.gas, "wrinkle_law": args.wrinkle_law} if args.model == "axisym" else {}
        model = forward_model_for(session, args.model, **options)
        nuisance = tuple(args.nuisance or ())
        if args.method == "fit":
            result = fit_session(session, model, nuisance=nuisance)
            estimates = result.estimates
            out.update(chi2=result.chi2, dof=result.dof, iterations=result.steps)
        else:
            result = sample_posterior(session, model, nuisance=nuisance, n_walkers=args.walkers,
                                      max_steps=args.max_steps, backend_path=args.chain, seed=args.seed,
                                      surrogate=not args.no_surrogate)  # fmt: skip
            estimates = result.estimates
            out.update(converged=result.converged, steps=result.n_steps, effective_samples=result.effective_samples,
                       failed_forward_solves=result.failed_forward, surrogate=result.surrogate)  # fmt: skip
        out["forward_model"] = args.model
    out["estimates"] = {k: v.to_dict() for k, v in estimates.items()}
    if args.json:
        json.dump(out, sys.stdout, indent=2)
        print()
    else:
        for name, est in estimates.items():
            unit = "" if est.unit == "1" else f" {est.unit}"
            print(f"{name:>24s} = {est.value:.5g} ± {est.std:.2g}{unit}  "
                  f"(95 %: {est.ci95[0]:.5g} … {est.ci95[1]:.5g}){'  [' + est.note.split(':')[0] + ']' if est.note else ''}")  # fmt: skip
    return 0


def _cmd_validate(args) -> int:
    from .session import load_session

    for path in args.sessions:
        s = load_session(path)
        print(f"ok: {path}: {s.object_name}, {s.force.size} samples in {s.trial_ids.size} trials, R = {s.radius:.4g} m")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argparse parser of the ``shelljax`` command."""
    parser = argparse.ArgumentParser(prog="shelljax", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run an experiment config into a fresh run directory")
    run.add_argument("config", help="experiment config TOML, e.g. configs/paper.toml")
    run.add_argument("--out", default=None, help="parent directory of the run directory (default: the config's output_dir)")
    run.add_argument("--quiet", action="store_true", help="no progress bars")
    run.set_defaults(func=_cmd_run)

    est = sub.add_parser("estimate", help="estimate P_g and E of one session")
    est.add_argument("session", help="session TOML file")
    est.add_argument("--method", choices=["closed-form", "fit", "bayes"], default="closed-form",
                     help="closed-form: the paper's Procedures 2-3; fit: least squares through a shell model; "
                     "bayes: MCMC posterior through a shell model")
    est.add_argument("--json", action="store_true", help="print JSON on stdout")
    est.add_argument("--k-s", type=float, default=None, help="k_s [-] (default: the paper's 0.64)")
    est.add_argument("--k-s-std", type=float, default=0.0, help="standard deviation of --k-s [-]")
    est.add_argument("--bootstrap", type=int, default=2000, help="bootstrap resamples (0 disables)")
    est.add_argument("--seed", type=int, default=0)
    est.add_argument("--model", choices=["axisym", "scaling"], default="axisym",
                     help="forward model of fit/bayes (default: the axisymmetric shell engine)")
    est.add_argument("--gas", choices=["prescribed", "isothermal"], default="prescribed", help="gas model of the axisym engine")
    est.add_argument("--wrinkle-law", choices=["mechanics", "scaling"], default="mechanics",
                     help="wrinkle count of the axisym model: the engine's (mechanics) or n = 1.33 tau^1/2 (scaling)")
    est.add_argument("--nuisance", nargs="*", choices=["depth_offset", "force_gain"], help="extra fitted parameters")
    est.add_argument("--walkers", type=int, default=32, help="bayes: emcee walkers")
    est.add_argument("--max-steps", type=int, default=20_000, help="bayes: most MCMC steps")
    est.add_argument("--chain", default=None, help="bayes: HDF5 file for the chain (resumed if it exists)")
    est.add_argument("--no-surrogate", action="store_true",
                     help="bayes: sample through the axisym engine itself, not its checked Chebyshev surrogate (slow)")
    est.set_defaults(func=_cmd_estimate)

    val = sub.add_parser("validate", help="check session files and report what they contain")
    val.add_argument("sessions", nargs="+")
    val.set_defaults(func=_cmd_validate)

    from .sensing import _cli as sensing_cli

    sensing_cli.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``shelljax`` console script; returns the exit code."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except ShelljaxError as err:
        print(f"shelljax: error: {err}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into e.g. `head`, which closed early
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
