"""What JAX traced and compiled during a stage of a run, and how long it took (``stage``: the
commands' ``--verbose`` log).

Listens to JAX's own monitoring events (``jax.monitoring``): the duration of each jaxpr trace, each
lowering to StableHLO and each XLA backend compilation, and the persistent cache's hits. A
backend compilation served from the persistent cache still reports its (short) retrieval time, so
``compiled`` counts only the cache misses.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import sys
import threading
import time
from collections.abc import Iterator

import jax

from .._placement import device_label

_TRACE = "/jax/core/compile/jaxpr_trace_duration"
_LOWER = "/jax/core/compile/jaxpr_to_mlir_module_duration"
_BACKEND = "/jax/core/compile/backend_compile_duration"
_CACHE_HIT = "/jax/compilation_cache/cache_hits"


@dataclasses.dataclass
class CompileLog:
    """Seconds [s] spent tracing, lowering and compiling, per program name, during one stage."""

    trace_seconds: float = 0.0
    lower_seconds: float = 0.0
    backend_seconds: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    backend_programs: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    cache_hits: int = 0

    @property
    def compiled(self) -> int:
        """Programs XLA compiled (persistent-cache hits excluded)."""
        return max(sum(self.backend_programs.values()) - self.cache_hits, 0)

    @property
    def total_seconds(self) -> float:
        """Trace + lowering + backend seconds [s]."""
        return self.trace_seconds + self.lower_seconds + sum(self.backend_seconds.values())

    def summary(self, top: int = 3) -> str:
        """One line: programs compiled, time by phase, the slowest programs."""
        if not self.backend_programs and self.trace_seconds < 0.05:
            return "nothing compiled"
        slowest = ", ".join(f"{name} {seconds:.1f} s" for name, seconds in self.backend_seconds.most_common(top))
        return (
            f"{self.compiled} programs compiled, {self.cache_hits} from the persistent cache; "
            f"{self.total_seconds:.1f} s (trace {self.trace_seconds:.1f} s, lower {self.lower_seconds:.1f} s, "
            f"XLA {sum(self.backend_seconds.values()):.1f} s); slowest: {slowest}"
        )

    def to_dict(self) -> dict:
        return {
            "programs_compiled": self.compiled,
            "persistent_cache_hits": self.cache_hits,
            "trace_seconds": self.trace_seconds,
            "lower_seconds": self.lower_seconds,
            "backend_seconds": sum(self.backend_seconds.values()),
            "total_seconds": self.total_seconds,
            "backend_seconds_by_program": dict(self.backend_seconds.most_common()),
        }


@contextlib.contextmanager
def compile_log() -> Iterator[CompileLog]:
    """Collect a :class:`CompileLog` of everything JAX compiles inside the ``with`` block (all threads)."""
    log = CompileLog()
    lock = threading.Lock()

    def on_duration(event: str, duration: float, **kwargs) -> None:
        with lock:
            if event == _TRACE:
                log.trace_seconds += duration
            elif event == _LOWER:
                log.lower_seconds += duration
            elif event == _BACKEND:
                name = str(kwargs.get("fun_name", "?"))
                log.backend_seconds[name] += duration
                log.backend_programs[name] += 1

    def on_event(event: str, **kwargs) -> None:
        if event == _CACHE_HIT:
            with lock:
                log.cache_hits += 1

    jax.monitoring.register_event_duration_secs_listener(on_duration)
    jax.monitoring.register_event_listener(on_event)
    try:
        yield log
    finally:
        jax.monitoring.unregister_event_duration_listener(on_duration)
        jax.monitoring.unregister_event_listener(on_event)


@contextlib.contextmanager
def stage(
    name: str, verbose: bool, stages: list[dict] | None = None, device: jax.Device | None = None
) -> Iterator[CompileLog]:
    """Time a stage of a command and what JAX compiled in it (the ``--verbose`` log of ``shelljax
    run``, ``simulate``, ``diagnose`` and ``estimate``): append its record to ``stages`` (if given)
    and, with ``verbose``, write one line to stderr (above any progress bar). ``device``: where the
    stage ran (``Placement.stage``'s device), recorded as ``"device"`` (``"cpu:0"``, ``"gpu:0"``)
    and ``"device_kind"``."""
    from tqdm.auto import tqdm

    start = time.perf_counter()
    with compile_log() as log:
        yield log
    wall = time.perf_counter() - start
    where = {} if device is None else {"device": device_label(device), "device_kind": device.device_kind}
    if stages is not None:
        stages.append({"stage": name, "wall_seconds": wall, **where, **log.to_dict()})
    if verbose:
        on = "" if device is None else f" on {where['device']}"
        tqdm.write(f"{name}: {wall:.1f} s{on}; {log.summary()}", file=sys.stderr)
