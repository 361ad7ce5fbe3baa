"""Command line: shelljax run, estimate, diagnose, simulate, replica, play, rig, validate, and the sensor commands acquire,
sensor-calibrate, sensor-emulator (docs/sensing.md); the same text is the --help description."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import sys
from pathlib import Path

from .._arguments import OneLineParser, real, whole
from .._errors import InvalidInputError, ShelljaxError
from .._files import check_output_file
from .._options import DEFAULT_OPTIONS, ESTIMATOR_GASES, METHODS, MIN_MAX_STEPS, MIN_WALKERS, WRINKLE_LAWS
from ..physics import GAS_LAWS, gas_law
from ..replica import MESH_FACES
from ..report import summary_text
from . import _diagnose, _rig
from ._common import add_device_argument, command_placement, resumed_out

__all__ = ["build_parser", "main", "summary_text"]  # summary_text: the diagnosis's summary, for notebooks


def _cmd_run(args) -> int:
    from ..executor import executor_options
    from ..runner import run_experiment, summary_table

    given = args.workers is not None or args.cluster is not None or args.cache_dir is not None
    try:
        run_dir = run_experiment(
            args.config,
            output_dir=args.out,
            progress=None if not args.quiet else False,
            verbose=args.verbose,
            executor=executor_options(args) if given else None,
            resume=args.resume,
            device=args.device,
        )
    except KeyboardInterrupt:
        return 130  # the runner said how to resume
    print(summary_table(json.loads((run_dir / "results.json").read_text())))
    print(f"results: {run_dir / 'results.json'}")
    return 0


def _cmd_estimate(args) -> int:
    from ..estimate import Estimate, EstimatorOptions, run_estimator
    from ..session import load_session

    if args.rig is not None:
        return _estimate_with_rig(args)
    if len(args.session) > 1:
        raise ShelljaxError(
            f"{len(args.session)} sessions given: without --rig, estimate one session at a time. Fix: "
            "pass one session, or several sessions of one object with --rig rig.toml"
        )
    if args.chain is not None:
        check_output_file(args.chain, "--chain", example="chain.h5")
    session = load_session(args.session[0])
    k_s = None
    if args.method == "closed-form" and args.k_s is not None:
        k_s = Estimate.lognormal(args.k_s, args.k_s_std / args.k_s, "1", "given on the command line")
    options = EstimatorOptions(
        k_s=k_s,
        bootstrap_samples=args.bootstrap,
        seed=args.seed,
        forward_model=args.model,
        gas=args.gas or DEFAULT_OPTIONS.gas,
        wrinkle_law=args.wrinkle_law or DEFAULT_OPTIONS.wrinkle_law,
        nuisance=tuple(args.nuisance or ()),
        walkers=args.walkers,
        max_steps=args.max_steps,
        surrogate=not args.no_surrogate,
    )
    with _stage_bar(f"estimate: {args.method} on {session.source.name}", args):
        result = run_estimator(
            args.method, session, options, backend_path=args.chain, progress=None if not args.quiet else False
        )
    out = {"session": str(session.source), "object": session.object_name, "method": args.method, **result.to_dict()}
    if args.method != "closed-form":
        out["forward_model"] = args.model
    _print_estimates(out, result.estimates, args.json)
    return 0


@contextlib.contextmanager
def _stage_bar(name: str, args):
    """One command stage: a progress bar on stderr (unless ``--quiet``) that says what runs and
    for how long, and with ``--verbose`` the stage's wall time and what JAX compiled in it."""
    from tqdm.auto import tqdm

    from ..runner import stage

    # shown after a second: an input refused at once leaves its one-line error alone on stderr
    with tqdm(total=1, desc=name, unit="stage", disable=args.quiet, delay=1.0) as bar, stage(name, args.verbose):
        yield
        bar.update(1)


def _print_estimates(out: dict, estimates: dict, as_json: bool, sources: tuple[str, ...] = ()) -> None:
    """The estimates as JSON, or one line each; with several ``sources``, a per-session quantity
    (``gauge_pressure[i]``) is named by its session file's stem."""
    import re

    if as_json:
        json.dump(out, sys.stdout, indent=2)
        print()
        return
    for name, est in estimates.items():
        unit = "" if est.unit == "1" else f" {est.unit}"
        if len(sources) > 1:
            name = re.sub(r"\[(\d+)\]", lambda m: f"[{Path(sources[int(m.group(1))]).stem}]", name)
        print(
            f"{name:>24s} = {est.value:.5g} ± {est.std:.2g}{unit}  "
            f"(95 %: {est.ci95[0]:.5g} … {est.ci95[1]:.5g}){'  [' + est.note.split(':')[0] + ']' if est.note else ''}"
        )


def _estimate_with_rig(args) -> int:
    from ..rig import estimate_with_rig, load_rig

    if args.method == "closed-form" or args.model != "axisym" or args.nuisance:
        raise ShelljaxError(
            "--rig works with --method fit or bayes through the axisym model, without --nuisance "
            "(the rig holds the measuring chain). Fix: add --method fit"
        )
    rig = load_rig(args.rig)
    with _stage_bar(f"estimate: {args.method} through the rig", args):
        result = estimate_with_rig(
            args.session, rig, method=args.method, gas=args.gas, wrinkle_law=args.wrinkle_law, seed=args.seed
        )
    out = {
        "session": result.sources[0] if len(result.sources) == 1 else list(result.sources),
        "method": args.method,
        "rig": str(args.rig),
        **result.to_dict(),
    }
    _print_estimates(out, result.estimates, args.json, tuple(result.sources))
    if not args.json:
        for m in result.models:
            share = f"{100 * m['weight']:.0f} %"
            print(f"    rig model {'+'.join(m['terms']) or 'ideal':<40s} weight {share:>5s}  {m['status']}")
        if result.not_identified:
            print(
                f"    not identified by the calibration: {', '.join(result.not_identified)} "
                "(the intervals include their spread)"
            )
            for s in result.separating():
                print(f"      {s['term']}: {s['measurement']}")
            shrink = result.separating()[0]["young_modulus_interval_shrink"]
            if shrink:
                print(f"    with them settled, E's 95 % interval would be {shrink:.1f}x narrower")
    return 0


def _cmd_simulate(args) -> int:
    from ..executor import executor_options
    from ..scenario import load_scenario, run_scenario

    scenario = load_scenario(args.config)
    if args.device is not None:
        scenario = dataclasses.replace(scenario, device=args.device)
    if scenario.sweep is not None:
        return _simulate_sweep(scenario, args, executor_options(args))
    if args.workers is not None or args.cluster is not None or args.resume is not None:
        raise ShelljaxError(
            f"--workers/--cluster/--resume run the values of a [sweep] table, and {args.config} has none. "
            'Fix: add [sweep] parameter = "..." and values = [...] (docs/cluster.md), or leave them out'
        )
    summary = run_scenario(scenario, args.out, session=args.session, progress=not args.quiet, verbose=args.verbose)
    p = summary["parameters"]
    print(
        f"{summary['name']}: P_g = {p['gauge_pressure_Pa']:.5g} Pa, E = {p['youngs_modulus_Pa']:.5g} Pa, m = {p['mass_kg']:.4g} kg, "
        f"{p['gas']} gas, {p['mesh_faces']} faces, contact damping c = {summary['contact_damping_N_s_per_m']:.4g} N·s/m"
    )
    for run in summary["runs"]:
        label = f"drop {run['drop_height_m']:.3g} m" if "drop_height_m" in run else "swing"
        if "max_deviation_from_rigid_m" in run:
            print(
                f"  swing: held vertices on the schedule to {run['held_error_m']:.2g} m, largest departure from the rigid "
                f"swing {1e3 * run['max_deviation_from_rigid_m']:.1f} mm, peak gauge pressure {run['peak_gas_pressure_Pa']:.5g} Pa"
            )
        for m in run["impacts"]:
            print(
                f"  {label}: {m['plane']} impact at {m['onset_s']:.4f} s, COR {m['cor']:.4f}, "
                f"contact {1e3 * m['contact_time_s']:.2f} ms, peak {m['peak_force_N']:.4g} N, compression {1e3 * m['max_compression_m']:.2f} mm, "
                f"contact diameter {1e3 * m['max_contact_diameter_m']:.1f} mm"
            )
        print(f"  results: {run['directory']}/results.json")
    return 0


def _simulate_sweep(scenario, args, executor) -> int:
    from pathlib import Path

    from ..scenario import run_sweep, sweep_table

    out = resumed_out(args)
    try:
        summary = run_sweep(
            scenario,
            out,
            session=args.session,
            executor=executor,
            progress=not args.quiet,
            resume=args.resume is not None,
        )
    except KeyboardInterrupt:
        return 130  # the finished values' records stay in the output directory: --resume DIR runs the rest
    print(sweep_table(summary))
    print(f"results: {Path(out) if out else scenario.output_dir / scenario.name}/sweep.json")
    return 0


def _cmd_replica(args) -> int:
    from ..replica import export_replica

    written = export_replica(
        args.session,
        args.out,
        method=args.method,
        gas=args.gas,
        cor=args.cor,
        mesh_faces=args.mesh_faces,
        wrinkle_law=args.wrinkle_law,
        rig=args.rig,
    )
    print(f"written: {', '.join(str(p) for p in written)}")
    return 0


def _cmd_validate(args) -> int:
    from ..session import load_rigid_press, load_session, session_kind

    for path in args.sessions:
        if session_kind(path) == "rigid_press":
            p = load_rigid_press(path)
            print(
                f"ok: {path}: rigid-surface press on {p.object_name}, {p.force.size} samples in {p.trial_ids.size} trials"
            )
            continue
        s = load_session(path)
        print(f"ok: {path}: {s.object_name}, {s.force.size} samples in {s.trial_ids.size} trials, R = {s.radius:.4g} m")
    return 0


def _cmd_play(args) -> int:
    from ..viewer import check_replay_outputs, play_headless, play_live, play_scene, require_viser

    if args.headless and args.script is None:
        raise ShelljaxError("--headless replays a script. Fix: add --script configs/interaction.toml")
    if (args.record or args.records) and not args.headless:
        raise ShelljaxError("--record and --records write a headless replay. Fix: add --headless (and --script)")
    if not args.headless:
        require_viser()  # before the object loads: say at once what is missing
    check_replay_outputs(args.record, args.records)
    scene = play_scene(args.source, args.script, mesh_faces=args.mesh_faces, gas=gas_law(args.gas))
    if not args.headless:
        return play_live(scene, host=args.host, port=args.port)
    result = play_headless(scene, record=args.record, records_json=args.records)
    s = result.summary()
    print(
        f"{scene.label}\n  {s['frames']} frames, {s['simulated_s']:.2f} s: peak gauge pressure {s['peak_gauge_pressure_Pa']:.0f} Pa, "
        f"peak hand force {s['peak_collider_force_N']:.2f} N, "
        + ", ".join(f"peak {n} force {f:.1f} N" for n, f in s["peak_plane_force_N"].items())
        + f"; real-time factor {s['real_time_factor_median']:.1f} (median), {s['real_time_factor_p01']:.1f} (1st percentile)"
    )
    for path in (args.record, args.records):
        if path is not None:
            print(f"written: {path}")
    return 0


def _register_play(sub) -> None:
    """``shelljax play``."""
    play = sub.add_parser(
        "play",
        help="move a replica or session in real time: live 3D view in the browser (viser), "
        "or --headless replay of an interaction script into a GIF (docs/realtime.md#viewer)",
    )
    play.add_argument(
        "source",
        help="a `shelljax replica` directory (its P_g, E, mesh) or a session TOML (P_g and E by "
        "the closed form, seconds; e.g. bundled:sessions/pezzi.toml); the rest shape is the small-strain shrink "
        "of the mesh, relaxed on the ground (no 30 s JAX rest-shape solve): it starts in seconds",
    )
    play.add_argument(
        "--script",
        default=None,
        help="interaction script TOML (planes, hand, timed drop/poke/throw/wait "
        "actions), e.g. configs/interaction.toml",
    )
    play.add_argument("--headless", action="store_true", help="no browser: replay --script and print its peaks")
    play.add_argument(
        "--record",
        default=None,
        help="with --headless: write the replay as a GIF here (a .gif file; missing folders are created)",
    )
    play.add_argument("--records", default=None, help="with --headless: write the per-frame records as JSON here")
    play.add_argument(
        "--mesh-faces",
        type=whole(*MESH_FACES),
        default=None,
        help="triangles of a session's sphere [count] (default: the script's, 500)",
    )
    play.add_argument(
        "--gas", choices=GAS_LAWS, default="adiabatic", help="gas law of a session's shell (a replica keeps its own)"
    )
    play.add_argument("--host", default="127.0.0.1", help="address the live viewer listens on")
    play.add_argument("--port", type=whole(1, 65535), default=8080, help="TCP port of the live viewer")
    add_device_argument(play)
    play.set_defaults(func=_cmd_play)


def _register_run(sub) -> None:
    """``shelljax run``."""
    from ..executor import add_executor_arguments

    run = sub.add_parser("run", help="run an experiment config into a fresh run directory")
    run.add_argument(
        "config",
        nargs="?",
        default=None,
        help="experiment config TOML, e.g. configs/paper.toml (not needed with --resume)",
    )
    run.add_argument(
        "--out", default=None, help="parent directory of the run directory (default: the config's output_dir)"
    )
    run.add_argument("--quiet", action="store_true", help="no progress bars")
    run.add_argument("--verbose", action="store_true", help="print each stage's wall time and what JAX compiled in it")
    add_executor_arguments(run)
    add_device_argument(run, whole=None)
    run.set_defaults(func=_cmd_run)


def _register_estimate(sub) -> None:
    """``shelljax estimate``: its defaults are ``shelljax.estimate.DEFAULT_OPTIONS``."""
    d = DEFAULT_OPTIONS
    est = sub.add_parser("estimate", help="estimate P_g and E of one session")
    est.add_argument(
        "session",
        nargs="+",
        help="session TOML file (with --rig: the sessions of one object, estimated at "
        "once with a shared E and measuring chain)",
    )
    est.add_argument(
        "--method",
        choices=METHODS,
        default="closed-form",
        help="closed-form: the paper's Procedures 2-3; fit: least squares through a shell model; "
        "bayes: MCMC posterior through a shell model",
    )
    est.add_argument("--json", action="store_true", help="print JSON on stdout")
    est.add_argument(
        "--k-s",
        type=real(0.0, 10.0, low_open=True),
        default=None,
        help="closed form: k_s [-] (default: the paper's 0.64)",
    )
    est.add_argument("--k-s-std", type=real(0.0), default=0.0, help="closed form: standard deviation of --k-s [-]")
    est.add_argument(
        "--bootstrap",
        type=whole(0, hint=" (0 disables)"),
        default=d.bootstrap_samples,
        help="closed form: bootstrap resamples [count] (0 disables)",
    )
    est.add_argument("--seed", type=whole(0), default=d.seed, help="random seed of the bootstrap and the MCMC")
    est.add_argument(
        "--model",
        choices=["axisym", "scaling"],
        default=d.forward_model,
        help="forward model of fit/bayes: the axisymmetric shell engine, or the scaling law",
    )
    est.add_argument(
        "--gas",
        choices=ESTIMATOR_GASES,
        default=None,
        help=f"gas model of the axisym engine (default: {d.gas}, a sealed ball poked slowly; with --rig, the rig's)",
    )
    est.add_argument(
        "--wrinkle-law",
        choices=WRINKLE_LAWS,
        default=None,
        help=f"wrinkle count of the axisym model: n = 1.33 tau^1/2 (scaling) or the engine's (mechanics) "
        f"(default: {d.wrinkle_law}; with --rig, the rig's)",
    )
    est.add_argument(
        "--rig",
        default=None,
        help="rig file from `shelljax rig calibrate`: estimate through the calibrated measuring chain (fit or bayes)",
    )
    est.add_argument("--nuisance", nargs="*", choices=["depth_offset", "force_gain"], help="extra fitted parameters")
    est.add_argument("--walkers", type=whole(MIN_WALKERS), default=d.walkers, help="bayes: emcee walkers [count]")
    est.add_argument(
        "--max-steps", type=whole(MIN_MAX_STEPS), default=d.max_steps, help="bayes: most MCMC steps [count]"
    )
    est.add_argument("--chain", default=None, help="bayes: HDF5 file for the chain (resumed if it exists)")
    est.add_argument(
        "--no-surrogate",
        action="store_true",
        help="bayes: sample through the axisym engine itself, not its checked Chebyshev surrogate (slow)",
    )
    est.add_argument("--quiet", action="store_true", help="no progress bar")
    est.add_argument(
        "--verbose", action="store_true", help="print each stage's wall time and what JAX compiled in it (on stderr)"
    )
    add_device_argument(est)
    est.set_defaults(func=_cmd_estimate)


def _register_simulate(sub) -> None:
    """``shelljax simulate``."""
    from ..executor import add_executor_arguments

    sim = sub.add_parser("simulate", help="run a dynamic scenario config (drop, bounce) into --out")
    sim.add_argument("config", help="scenario config TOML, e.g. configs/drop.toml")
    sim.add_argument("--out", default=None, help="output directory (default: the config's output_dir/name)")
    sim.add_argument(
        "--session", default=None, help="take P_g and E from this session's estimate (overrides the config)"
    )
    sim.add_argument("--quiet", action="store_true", help="no progress bars")
    sim.add_argument(
        "--verbose", action="store_true", help="print each stage's wall time and what JAX compiled in it (on stderr)"
    )
    add_executor_arguments(
        sim
    )  # the values of a [sweep] table (docs/cluster.md); --resume: the --out of an interrupted one
    add_device_argument(sim, whole=None)
    sim.set_defaults(func=_cmd_simulate)


def _register_replica(sub) -> None:
    """``shelljax replica``."""
    rep = sub.add_parser("replica", help="export a session's digital replica: mesh (glTF) + replica.json")
    rep.add_argument("session", help="session TOML file")
    rep.add_argument("--out", required=True, help="output directory (created; checked before the estimate)")
    rep.add_argument("--method", choices=METHODS, default="fit", help="estimator of P_g and E")
    rep.add_argument(
        "--gas",
        choices=GAS_LAWS,
        default="adiabatic",
        help="gas law of the replica's dynamics (its impacts are fast); the estimate's is "
        f"{DEFAULT_OPTIONS.gas} unless prescribed",
    )
    rep.add_argument(
        "--cor",
        type=real(0.0, 1.0, low_open=True),
        default=None,
        help="measured coefficient of restitution [-], if known",
    )
    rep.add_argument(
        "--mesh-faces",
        type=whole(*MESH_FACES),
        default=2000,
        help="triangles of a sphere replica [count] (sessions without a mesh)",
    )
    rep.add_argument(
        "--wrinkle-law",
        choices=WRINKLE_LAWS,
        default=None,
        help="wrinkle count of the fit: n = 1.33 tau^1/2 (scaling) or the engine's (mechanics) (default: "
        f"{DEFAULT_OPTIONS.wrinkle_law}; with --rig, the rig's)",
    )
    rep.add_argument(
        "--rig", default=None, help="rig file from `shelljax rig calibrate`: estimate through it (fit, bayes)"
    )
    add_device_argument(rep)
    rep.set_defaults(func=_cmd_replica)


def build_parser() -> argparse.ArgumentParser:
    """The argparse parser of the ``shelljax`` command: every subcommand's --help shows its
    defaults and units, and every usage error is one line (``shelljax._arguments``)."""
    from .. import __version__

    parser = OneLineParser(prog="shelljax", description=__doc__.partition(";")[0] + ".")
    parser.add_argument("--version", action="version", version=f"shelljax {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for register in (
        _register_run,
        _register_estimate,
        _diagnose.register,
        _register_simulate,
        _register_replica,
        _rig.register,
        _register_play,
    ):
        register(sub)
    val = sub.add_parser("validate", help="check session files and report what they contain")
    val.add_argument("sessions", nargs="+", help="session TOML files (indentation sessions or rigid-surface presses)")
    val.set_defaults(func=_cmd_validate)

    from ..sensing.internal import register as register_sensing

    register_sensing(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``shelljax`` console script; returns the exit code: 2, with one line on
    stderr naming the option or field and a fix, for every input it refuses."""
    try:
        args = build_parser().parse_args(argv)
        with command_placement(args):
            return args.func(args)
    except ShelljaxError as err:
        print(f"shelljax: error: {_one_line(err)}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into e.g. `head`, which closed early
        sys.stderr.close()
        return 0


def _one_line(err: ShelljaxError) -> str:
    """An input error on one line (a solver's error keeps its residual history on the lines after it)."""
    return " ".join(str(err).split()) if isinstance(err, InvalidInputError) else str(err)
