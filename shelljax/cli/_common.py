"""What several commands share: the output directory of many studies or a sweep."""

from __future__ import annotations

from .._errors import ShelljaxError


def resumed_out(args):
    """The output directory of many studies or a sweep: --out, or the --resume directory it continues."""
    from pathlib import Path

    if args.resume is not None and args.out is not None and Path(args.resume).resolve() != Path(args.out).resolve():
        raise ShelljaxError(
            f"--resume {args.resume} and --out {args.out} name two directories. Fix: give --resume alone "
            "(it continues in that directory)"
        )
    return args.resume if args.resume is not None else args.out
