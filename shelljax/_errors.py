"""The one exception hierarchy of shelljax.

Every error a user can trigger is a :class:`ShelljaxError`; its message names the file, the field,
the offending value and what to do about it.
"""

from __future__ import annotations


class ShelljaxError(Exception):
    """Base class of every error shelljax raises on purpose."""


class InvalidInputError(ShelljaxError, ValueError):
    """A session, config, mesh or argument is malformed or physically implausible."""


class NoConvergenceError(ShelljaxError, RuntimeError):
    """An iterative solver stopped without meeting its tolerance.

    ``history`` holds the residual norms per iteration (in the solver's stated units) so the user
    can see whether it stalled, diverged or just needed more iterations.
    """

    def __init__(self, message: str, history: list[float] | None = None):
        self.history = list(history or [])
        if self.history:
            tail = ", ".join(f"{r:.3e}" for r in self.history[-8:])
            message = f"{message}\n  residual history (last {min(8, len(self.history))}): {tail}"
        super().__init__(message)


class DeviceError(ShelljaxError, OSError):
    """The force-sensor hardware (serial port) could not be opened or stopped answering."""
