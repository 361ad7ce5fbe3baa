"""Process tools for the long 3D runs of these scripts and of tools/make_virtual_sessions.py.

XLA's CPU runtime wedged in runs of an hour or more (docs/shell3d.md, *XLA:CPU hangs*), so such a
run solves each curve in a child process under a :class:`Watchdog`, saves every solved state to a
:class:`Checkpoint`, and :func:`run_with_restarts` starts the child again from it. A script imports
this module as a sibling (``python experiments/x.py`` puts this folder first on the module path);
a tool or a test loads it from its file.
"""

from __future__ import annotations

import os
import subprocess
import threading
import time
from pathlib import Path

import numpy as np


class Watchdog:
    """Exits the process (status 3) when :meth:`beat` was not called for ``limit`` s (a wedged XLA
    run); :func:`run_with_restarts` then restarts it from its checkpoint."""

    def __init__(self, limit: float):
        self.limit = float(limit)
        self.last = time.monotonic()

    def beat(self) -> None:
        """Record progress."""
        self.last = time.monotonic()

    def start(self) -> "Watchdog":
        """Start watching in a daemon thread."""

        def watch():
            while True:
                time.sleep(5)
                if time.monotonic() - self.last > self.limit:
                    print(f"watchdog: no progress for {self.limit:.0f} s, exiting for a restart", flush=True)
                    os._exit(3)

        threading.Thread(target=watch, daemon=True).start()
        return self


class Checkpoint:
    """Solved (travel [m], force [N], state) triples of one curve in an npz file (None: no file),
    saved after every solve so that a restarted run resumes there; a save also beats the
    ``watchdog``. ``shelljax.virtual.solve_curve`` takes it as its ``checkpoint``."""

    def __init__(self, path: Path | None, watchdog: Watchdog | None = None):
        self.path = None if path is None else Path(path)
        self.watchdog = watchdog

    def load(self) -> list[tuple[float, float, np.ndarray]]:
        """The saved triples, by travel (empty without a file)."""
        if self.path is None or not self.path.exists():
            return []
        saved = np.load(self.path)
        if "travels" not in saved:
            raise SystemExit(f"{self.path}: a checkpoint of an older version of this script (no travels); delete it")
        return [(float(t), float(f), q) for t, f, q in zip(saved["travels"], saved["forces"], saved["states"])]

    def save(self, solved) -> None:
        """Write ``solved`` (the triples) and beat the watchdog."""
        if self.watchdog is not None:
            self.watchdog.beat()
        if self.path is not None:
            np.savez(
                self.path,
                travels=[s[0] for s in solved],
                forces=[s[1] for s in solved],
                states=np.stack([s[2] for s in solved]),
            )


def run_with_restarts(cmd: list[str], restarts: int, label: str) -> bool:
    """Run a child process that checkpoints per level; restart it (up to ``restarts`` times) when
    it exits abnormally (the watchdog's exit after a wedged XLA run). True when it succeeded."""
    for attempt in range(restarts + 1):
        if subprocess.run(cmd).returncode == 0:
            return True
        print(f"{label}: child exited abnormally (attempt {attempt + 1}), restarting from its checkpoint", flush=True)
    return False
