"""The executor's command-line options, one definition for the CLI and the experiment scripts."""

from __future__ import annotations

import argparse

from .._arguments import whole
from ._execute import ExecutorOptions


def add_executor_arguments(parser: argparse.ArgumentParser, *, resume: bool = True) -> None:
    """Add ``--workers``, ``--cluster``, ``--cache-dir`` (and ``--resume RUN_DIR``) to ``parser``."""
    group = parser.add_argument_group("where the work runs (docs/cluster.md)")
    group.add_argument(
        "--workers",
        type=whole(1),
        default=None,
        metavar="N",
        help="run the items on a local Dask cluster of N processes (default: in this process)",
    )
    group.add_argument(
        "--cluster",
        default=None,
        metavar="tcp://HOST:PORT",
        help="run the items on a running Dask scheduler (SLURM, PBS, Kubernetes: docs/cluster.md)",
    )
    group.add_argument(
        "--cache-dir",
        default=None,
        metavar="DIR",
        help="JAX compilation cache shared by the workers (a directory every worker can reach)",
    )
    if resume:
        group.add_argument(
            "--resume",
            default=None,
            metavar="RUN_DIR",
            help="finish an interrupted run in RUN_DIR, skipping the items it finished",
        )


def executor_options(args: argparse.Namespace) -> ExecutorOptions:
    """The :class:`ExecutorOptions` of parsed arguments (raises InvalidInputError on bad ones)."""
    return ExecutorOptions(workers=args.workers, cluster=args.cluster, cache_dir=args.cache_dir)
