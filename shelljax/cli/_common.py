"""What several commands share: the output directory of many studies or a sweep, and ``--device``."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from .._errors import ShelljaxError
from .._placement import DEVICE_REQUESTS, StageKind, requested_placement, use_cpu_only


def resumed_out(args):
    """The output directory of many studies or a sweep: --out, or the --resume directory it continues."""
    from pathlib import Path

    if args.resume is not None and args.out is not None and Path(args.resume).resolve() != Path(args.out).resolve():
        raise ShelljaxError(
            f"--resume {args.resume} and --out {args.out} name two directories. Fix: give --resume alone "
            "(it continues in that directory)"
        )
    return args.resume if args.resume is not None else args.out


def add_device_argument(parser, *, whole: StageKind | None = StageKind.LATENCY) -> None:
    """``--device {auto,cpu,gpu}`` (docs/gpu.md); ``whole``: the stage kind the command runs as one
    stage (None: the command places its own stages, from ``args.device`` or its config's)."""
    parser.add_argument(
        "--device",
        choices=DEVICE_REQUESTS,
        default=None,
        help="where its stages run: auto (latency-bound work on the CPU, batches and large sparse problems "
        "on a GPU when JAX sees one), cpu (all, without starting CUDA), gpu (all it can; refused without one); "
        "default: the config's [compute] device, else auto (docs/gpu.md)",
    )
    parser.set_defaults(placed_whole=whole)


@contextlib.contextmanager
def command_placement(args) -> Iterator[None]:
    """Run a command under its ``--device``: ``cpu`` keeps JAX from starting CUDA (this runs before
    any computation), ``gpu`` without one is refused, and a command placed whole runs under its
    stage kind's device (``shelljax.Placement``)."""
    if not hasattr(args, "device"):
        yield
        return
    if args.device == "cpu":
        use_cpu_only()
    kind = getattr(args, "placed_whole", None)
    if kind is None:
        if args.device is not None:
            requested_placement(args.device)  # 'gpu' without one: refused before the command starts
        yield
        return
    with requested_placement(args.device or "auto").stage(kind):
        yield
