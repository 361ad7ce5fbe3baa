"""``shelljax diagnose``: the sim-to-real gap of one object's sessions, or of many studies as work items."""

from __future__ import annotations

import json
import sys

from .._errors import ShelljaxError
from .._files import check_output_dir
from .._options import DEFAULT_OPTIONS, WRINKLE_LAWS
from ..physics import GAS_LAWS
from ..report import summary_text
from ._common import add_device_argument, resumed_out


def _cmd_diagnose(args) -> int:
    from ..diagnose import diagnose
    from ..report import jsonable, write_diagnosis
    from ..runner import diagnosis_baseline

    if args.study:
        return _diagnose_studies(args)
    if not args.sessions:
        raise ShelljaxError(
            "no sessions given. Fix: shelljax diagnose S1.toml S2.toml ... (one object), or --study DIR "
            "--study DIR ... --out DIR (many studies)"
        )
    if args.workers is not None or args.cluster is not None or args.resume is not None:
        raise ShelljaxError(
            "--workers/--cluster/--resume run many studies (--study), and one study is one piece of work. "
            "Fix: give each study as --study DIR_OR_PATTERN, or leave them out"
        )
    if args.out is not None:
        check_output_dir(args.out, "--out")
    measurement, gas, wrinkle_law = diagnosis_baseline(args.rig, args.gas, args.wrinkle_law)
    from ..runner import stage

    with stage("diagnose", args.verbose):
        result = diagnose(
            args.sessions,
            effects=args.effects,
            baseline=args.baseline,
            gas=gas,
            wrinkle_law=wrinkle_law or DEFAULT_OPTIONS.wrinkle_law,
            progress=not args.quiet and not args.json,
            measurement=measurement,
        )
    if args.out is not None:
        written = write_diagnosis(result, args.out)
        if not args.json:
            print(f"written: {', '.join(str(p) for p in written)}")
    if args.json:
        json.dump(jsonable(result.report), sys.stdout, indent=2)
        print()
    else:
        print(summary_text(result.report))
    return 0


def _diagnose_studies(args) -> int:
    """``shelljax diagnose --study A --study B ... --out DIR``: one work item per study."""
    from ..executor import executor_options
    from ..runner import diagnose_studies, diagnoses_table, study_groups

    if args.sessions:
        raise ShelljaxError(
            f"session files ({args.sessions[0]} ...) and --study both given. Fix: give one study as "
            "session files, or every study as --study"
        )
    out = resumed_out(args)
    if out is None:
        raise ShelljaxError(
            "--study needs --out DIR: each study's diagnosis is written to DIR/<study>/. Fix: add --out DIR"
        )
    try:
        summary = diagnose_studies(
            study_groups(args.study),
            out,
            effects=args.effects,
            baseline=args.baseline,
            gas=args.gas,
            wrinkle_law=args.wrinkle_law,
            rig=args.rig,
            executor=executor_options(args),
            progress=None if not args.quiet else False,
            resume=args.resume is not None,
        )
    except KeyboardInterrupt:
        return 130  # the finished studies' diagnoses and records stay in --out
    if args.json:
        json.dump(summary, sys.stdout, indent=2)
        print()
    else:
        print(diagnoses_table(summary))
        print(f"results: {out}/diagnoses.json")
    return 0


def register(sub) -> None:
    """``shelljax diagnose``."""
    diag = sub.add_parser(
        "diagnose",
        help="sim-to-real gap: where the shell model misfits sessions of one object, "
        "which candidate effect explains it, how far the gap shrinks",
    )
    diag.add_argument("sessions", nargs="*", help="session TOML files of one object (e.g. at several pressures)")
    diag.add_argument(
        "--study",
        action="append",
        default=None,
        metavar="DIR_OR_PATTERN",
        help="many studies instead (repeat it): a directory of one object's session files, or a pattern "
        "such as 'dir/ball_*.toml' ('bundled:' for the package's); one work item per study, written to "
        "--out/<study>/ and summed up in --out/diagnoses.json (docs/cluster.md)",
    )
    diag.add_argument("--out", default=None, help="directory for diagnosis.json, diagnosis.png and report.md (created)")
    diag.add_argument("--json", action="store_true", help="print the diagnosis JSON on stdout")
    diag.add_argument(
        "--baseline",
        choices=["estimator", "paper"],
        default="estimator",
        help="baseline model: the fitted estimator's (sealed isothermal gas) or the paper's (prescribed pressure)",
    )
    diag.add_argument(
        "--gas",
        choices=GAS_LAWS,
        default=None,
        help="gas law of the baseline (default: the baseline's; with --rig, the rig's)",
    )
    diag.add_argument(
        "--wrinkle-law",
        choices=WRINKLE_LAWS,
        default=None,
        help=f"wrinkle count: n = 1.33 tau^1/2 (scaling) or the engine's (mechanics) (default: "
        f"{DEFAULT_OPTIONS.wrinkle_law}; with --rig, the rig's)",
    )
    diag.add_argument(
        "--rig",
        default=None,
        help="rig file from `shelljax rig calibrate`: its measuring chain is the "
        "baseline, and its gas and wrinkle law the model's",
    )
    diag.add_argument(
        "--effects",
        nargs="+",
        default=None,
        metavar="EFFECT",
        help="candidate effects to try (default: all of shelljax.diagnose.EFFECTS)",
    )
    diag.add_argument("--quiet", action="store_true", help="no progress bar")
    diag.add_argument(
        "--verbose", action="store_true", help="print each stage's wall time and what JAX compiled in it (on stderr)"
    )
    from ..executor import add_executor_arguments

    add_executor_arguments(diag)  # the studies of --study (docs/cluster.md); --resume: the --out of an interrupted one
    add_device_argument(diag)
    diag.set_defaults(func=_cmd_diagnose)
