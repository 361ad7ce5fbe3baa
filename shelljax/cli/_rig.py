"""``shelljax rig calibrate``: the measuring chain, fitted on sessions with manometer readings."""

from __future__ import annotations

from .._arguments import real
from .._files import check_output_file
from .._options import DEFAULT_OPTIONS, ESTIMATOR_GASES, WRINKLE_LAWS
from ._common import add_device_argument


def _cmd_rig_calibrate(args) -> int:
    from ..rig import calibrate_rig, physical_parameter, write_rig
    from ..session import session_kind

    check_output_file(args.out, "--out", example="rig.toml")  # before the fit: a refused path costs nothing
    kinds = [session_kind(path) for path in args.sessions]
    presses = [p for p, kind in zip(args.sessions, kinds) if kind == "rigid_press"]
    sessions = [p for p, kind in zip(args.sessions, kinds) if kind != "rigid_press"]
    rig = calibrate_rig(
        sessions,
        gas=args.gas,
        wrinkle_law=args.wrinkle_law,
        terms=args.terms,
        presses=presses,
        manometer_std=args.manometer_std,
        progress=not args.quiet,
    )
    write_rig(rig, args.out)
    print(f"rig: {len(rig.models)} model(s) the calibration cannot exclude (weights: pseudo-BMA+)")
    for m in rig.models:
        stds = [float(v) for v in (m.covariance.diagonal() ** 0.5)]
        values = ", ".join(
            f"{n} = {v:.4g} ± {e:.2g}"
            for n, (v, e) in (
                (n, physical_parameter(n, float(u), s, rig.indenter_radius))
                for n, u, s in zip(m.parameters, m.mean, stds)
            )
        )
        print(
            f"  {'+'.join(m.terms) or 'ideal':<40s} weight {m.weight:5.2f}  Δelpd {m.delta:6.2f} ± {m.delta_se:4.2f}  {values}"
        )
    if rig.not_identified:
        print(f"not identified: {', '.join(rig.not_identified)}")
    for f in rig.failed:
        print(f"  {'+'.join(f['terms'])}: FAILED, left out ({f['message']})")
    print(f"written: {args.out}")
    return 0


def register(sub) -> None:
    """``shelljax rig calibrate``."""
    rig = sub.add_parser("rig", help="the measuring chain: calibrate it once where the pressure is known (docs/rig.md)")
    rig_sub = rig.add_subparsers(dest="rig_command", required=True)
    cal = rig_sub.add_parser("calibrate", help="fit and select the rig's terms on sessions with manometer readings")
    cal.add_argument(
        "sessions",
        nargs="+",
        help="session TOML files with manometer readings, of one or more objects, "
        'and optionally rigid-surface press sessions (kind = "rigid_press", docs/session-format.md)',
    )
    cal.add_argument("--out", required=True, help="rig TOML file to write (checked before the fit; folders created)")
    cal.add_argument(
        "--gas",
        choices=ESTIMATOR_GASES,
        default=DEFAULT_OPTIONS.gas,
        help="gas law of the forward model (every estimate through the rig uses it; a poke is slow, so a "
        "sealed object's gas is isothermal)",
    )
    cal.add_argument(
        "--wrinkle-law",
        choices=WRINKLE_LAWS,
        default=DEFAULT_OPTIONS.wrinkle_law,
        help="wrinkle count of the forward model: n = 1.33 tau^1/2 (scaling) or the engine's (mechanics)",
    )
    cal.add_argument(
        "--terms",
        nargs="+",
        default=None,
        metavar="TERM",
        help="candidate terms (default: all of shelljax.rig.RIG_TERMS)",
    )
    cal.add_argument(
        "--manometer-std",
        type=real(0.0, 1.0, low_open=True),
        default=0.02,
        help="the manometer readings' relative standard deviation [-] (0.02: 2 %%)",
    )
    cal.add_argument("--quiet", action="store_true", help="no progress bar")
    add_device_argument(cal)
    cal.set_defaults(func=_cmd_rig_calibrate)
