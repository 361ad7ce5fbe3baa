"""The real-time runtime's named error (a child of :class:`shelljax.NoConvergenceError`)."""

from __future__ import annotations

from .._errors import NoConvergenceError


class BlowUpError(NoConvergenceError):
    """A substep produced NaN/inf, the energy grew past its bound, or a vertex tunnelled through a
    plane: the explicit stepping is unstable (Δt too large, a contact too stiff) and its state is
    no longer physical. ``reason`` is ``"not finite"``, ``"energy growth"`` or ``"tunnelled"``;
    ``time_s`` [s] the simulated time of the failing substep; ``dt_s`` [s] the substep.
    """

    def __init__(self, message: str, *, reason: str, time_s: float, dt_s: float, history=None):
        self.reason, self.time_s, self.dt_s = reason, float(time_s), float(dt_s)
        super().__init__(message, history)
