"""Run independent work items in-process or on Dask workers, with the same results either way.

A :class:`WorkItem` is a module-level function with its arguments and its own seed; it returns a
JSON-ready value. :func:`run_items` runs a list of them:

* in-process, one after the other (the default);
* on a ``dask.distributed.LocalCluster`` of ``workers`` processes (one thread each: XLA already
  uses the cores a process is given, and one program per process keeps runs reproducible);
* on an existing Dask scheduler (``cluster = "tcp://HOST:PORT"``), so that SLURM, PBS or Kubernetes
  workers started by dask-jobqueue or dask-kubernetes serve shelljax without new services.

Each finished item is written atomically to ``<run_dir>/items/`` by the caller's process (the
only writer), so a killed worker, a killed run or Ctrl-C loses at most the items in flight, and
``resume=True`` skips the finished ones. Dask reruns the item of a worker that died on another
worker; an item whose function raises is recorded as failed with its error, never dropped.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import socket
import sys
import time
import urllib.parse
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from .._errors import InvalidInputError
from ._store import ItemResult, read_item, write_item

CONNECT_TIMEOUT_S = 10.0


@dataclasses.dataclass(frozen=True)
class WorkItem:
    """One independent piece of work: ``function(*args, **kwargs, seed=seed)`` (``seed`` passed
    only when not None). ``function`` must be importable on a worker (a module-level function of
    an installed package) and return a JSON-ready value; ``key`` names the item in the run directory."""

    key: str
    function: Callable[..., object]
    args: tuple = ()
    kwargs: Mapping = dataclasses.field(default_factory=dict)
    seed: int | None = None


@dataclasses.dataclass(frozen=True)
class ExecutorOptions:
    """Where work items run: ``workers`` (None: in-process; N: a local Dask cluster of N
    processes), or ``cluster`` (the address of a running Dask scheduler, "tcp://HOST:PORT");
    ``cache_dir``: the JAX compilation cache the workers share (None: each worker's default,
    ``$SHELLJAX_CACHE_DIR`` or ``~/.cache/shelljax/jax``); ``connect_timeout_s`` [s]."""

    workers: int | None = None
    cluster: str | None = None
    cache_dir: str | Path | None = None
    connect_timeout_s: float = CONNECT_TIMEOUT_S

    def __post_init__(self):
        if self.workers is not None and (
            isinstance(self.workers, bool) or not isinstance(self.workers, int) or self.workers < 1
        ):
            raise InvalidInputError(
                f"--workers = {self.workers!r}: must be a whole number ≥ 1. Fix: e.g. --workers 2, "
                "or leave it out to run in-process"
            )
        if self.workers is not None and self.cluster is not None:
            raise InvalidInputError(
                f"--workers {self.workers} and --cluster {self.cluster} both given: the cluster's "
                "workers are its own. Fix: give one of them"
            )
        if self.cluster is not None and "://" not in str(self.cluster):
            raise InvalidInputError(
                f"--cluster = {self.cluster!r}: not a scheduler address. Fix: give it as "
                "tcp://HOST:PORT (what `dask scheduler` prints)"
            )

    @property
    def distributed(self) -> bool:
        """Whether the items go to Dask workers."""
        return self.workers is not None or self.cluster is not None

    def describe(self) -> dict:
        """JSON-ready: where the items ran."""
        if self.cluster is not None:
            return {"backend": "dask", "cluster": self.cluster}
        if self.workers is not None:
            return {"backend": "dask", "local_cluster_workers": self.workers}
        return {"backend": "in-process"}


def call_item(item: WorkItem) -> ItemResult:
    """Run one item where this is called; an exception becomes a failed result, never a loss."""
    worker = "local"
    with contextlib.suppress(ImportError, ValueError):
        from distributed import get_worker

        worker = get_worker().address
    start = time.perf_counter()
    try:
        value = item.function(*item.args, **item.kwargs, **({} if item.seed is None else {"seed": item.seed}))
    except Exception as err:  # noqa: BLE001 - recorded in the item's result, with its type
        return ItemResult(
            item.key,
            "failed",
            error=f"{type(err).__name__}: {err}",
            seconds=time.perf_counter() - start,
            worker=worker,
            seed=item.seed,
        )
    return ItemResult(item.key, "done", value=value, seconds=time.perf_counter() - start, worker=worker, seed=item.seed)


def _check_keys(items: Sequence[WorkItem]) -> None:
    seen = set()
    for item in items:
        if item.key in seen:
            raise InvalidInputError(
                f"two work items share the key {item.key!r}; each item's record needs its own. "
                "Fix: give every item a distinct key"
            )
        seen.add(item.key)


def _no_dask() -> InvalidInputError:
    return InvalidInputError(
        "--workers and --cluster run on Dask, which is not installed. Fix: "
        "python3 -m pip install 'shelljax[cluster]' (or dask[distributed])"
    )


def _no_scheduler(options: ExecutorOptions, err: BaseException) -> InvalidInputError:
    return InvalidInputError(
        f"--cluster {options.cluster}: no Dask scheduler answered within {options.connect_timeout_s:g} s "
        f"({type(err).__name__}). Fix: start one (`dask scheduler`, then `dask worker {options.cluster}` on "
        "each machine), check the address, or leave --cluster out to run locally"
    )


def check_executor(options: ExecutorOptions) -> None:
    """Refuse, before a caller lays out a run directory, options that cannot run: Dask not
    installed, or nothing listening at a ``tcp://`` or ``tls://`` scheduler address (the port is
    tried; other protocols are left to Dask).

    Raises:
        InvalidInputError: naming the option and a fix.
    """
    if not options.distributed:
        return
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise _no_dask() from None
    if options.cluster is None:
        return
    address = urllib.parse.urlsplit(str(options.cluster))
    try:
        port = address.port
    except ValueError:
        port = None
    if address.scheme not in ("tcp", "tls"):
        return
    if not address.hostname or port is None:
        raise InvalidInputError(
            f"--cluster = {options.cluster!r}: no host and port in the address. Fix: give it as "
            "tcp://HOST:PORT (what `dask scheduler` prints)"
        )
    try:
        socket.create_connection((address.hostname, port), timeout=options.connect_timeout_s).close()
    except OSError as err:
        raise _no_scheduler(options, err) from None


@contextlib.contextmanager
def dask_client(options: ExecutorOptions):
    """A ``distributed.Client`` for ``options`` (a new LocalCluster, or the given scheduler),
    closed on exit; the workers keep every program they compile in their persistent cache
    (``options.cache_dir`` when given, shared by them)."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise _no_dask() from None

    from ._plugin import CompilationCache

    cluster = None
    if options.cluster is not None:
        try:
            client = Client(options.cluster, timeout=f"{options.connect_timeout_s}s")
        except (OSError, TimeoutError) as err:
            raise _no_scheduler(options, err) from None
    else:
        cluster = LocalCluster(
            n_workers=options.workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.CRITICAL,
        )
        client = Client(cluster)
    try:
        client.register_plugin(
            CompilationCache(None if options.cache_dir is None else str(Path(options.cache_dir).resolve()))
        )
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _bar(total: int, initial: int, desc: str, progress: bool | None):
    from tqdm.auto import tqdm

    disable = (not sys.stderr.isatty()) if progress is None else not progress
    return tqdm(total=total, initial=initial, desc=desc, unit="item", disable=disable, file=sys.stderr)


def run_items(
    items: Sequence[WorkItem],
    *,
    run_dir: str | Path | None = None,
    options: ExecutorOptions | None = None,
    resume: bool = False,
    progress: bool | None = None,
    desc: str = "items",
) -> list[ItemResult]:
    """Run ``items`` (module docstring); return their results in the items' order.

    ``run_dir``: where each finished item's record is written (None: nowhere); ``resume``: skip
    the items whose records say "done" (failed ones run again); ``progress``: a bar on stderr
    (None: on a terminal only) with items done, failed, rate and ETA.

    Raises:
        InvalidInputError: duplicate keys, bad options, an unreachable scheduler, resume without a run_dir.
        KeyboardInterrupt: after cancelling the items in flight; the finished ones stay on disk.
    """
    options = options or ExecutorOptions()
    _check_keys(items)
    if resume and run_dir is None:
        raise InvalidInputError("resume needs the run directory to read finished items from. Fix: pass run_dir")
    results: dict[str, ItemResult] = {}
    if resume:
        for item in items:
            previous = read_item(Path(run_dir), item.key)
            if previous is not None:
                results[item.key] = previous
    pending = [item for item in items if item.key not in results]
    bar = _bar(len(items), len(results), desc, progress)
    failed = 0

    def finish(result: ItemResult):
        nonlocal failed
        if run_dir is not None:
            write_item(Path(run_dir), result)
        results[result.key] = result
        failed += result.status == "failed"
        bar.update(1)
        if failed:
            bar.set_postfix(failed=failed)

    try:
        if pending and options.distributed:
            _run_on_dask(pending, options, finish)
        else:
            for item in pending:
                finish(call_item(item))
    finally:
        bar.close()
    return [results[item.key] for item in items]


def _run_on_dask(pending: Sequence[WorkItem], options: ExecutorOptions, finish) -> None:
    from distributed import as_completed

    with dask_client(options) as client:
        futures = {client.submit(call_item, item, pure=False): item for item in pending}
        try:
            for future in as_completed(futures):
                item = futures[future]
                try:
                    result = future.result()
                except Exception as err:  # noqa: BLE001 - e.g. KilledWorker after Dask's retries
                    result = ItemResult(
                        item.key, "failed", error=f"{type(err).__name__}: {err}", seed=item.seed, worker="dask"
                    )
                finish(result)
        except KeyboardInterrupt:
            client.cancel(list(futures))
            raise
