"""Displacement-controlled states at prescribed indenter travels or forces, resumable.

Force control can lose the indenter at high forces (its Newton stalls with residual = F), while
the force F(travel) of displacement control increases smoothly: a force level is found by secant
steps on the travel, then regula falsi inside the bracket. Every solved state is kept as a
(travel [m], force [N], q) triple in a list ``solved`` that the caller may pass in (states of an
earlier, interrupted run) and persist after each solve (``on_solve(solved)``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .._errors import NoConvergenceError
from ._observables import observables


def solve_travel(sim, solved: list, travel: float, halvings: int = 3) -> None:
    """Add the equilibrium at indenter ``travel`` [m] of ``sim`` (an :class:`Indentation`) to
    ``solved`` (kept sorted by travel), started from the solved states just below it with the
    secant predictor and sub-steps of :meth:`Indentation.curve`. A sub-step whose Newton fails is
    retried as two half steps, up to ``halvings`` times."""
    below = [s for s in solved if s[0] < travel]
    history = [(0.0, sim.q_reference)] + [(t, q) for t, _, q in below]
    for d in sim._substeps(history[-1][0], travel):
        try:
            res, _, _ = sim._depth_step(history[-2:], d)
        except NoConvergenceError:
            if halvings == 0:
                raise
            solve_travel(sim, solved, 0.5 * (history[-1][0] + d), halvings - 1)
            solve_travel(sim, solved, d, halvings - 1)
            history = [(0.0, sim.q_reference)] + [(t, q) for t, _, q in solved if t <= d]
            continue
        history.append((d, np.asarray(res.value)))
        force = float(observables(sim, res.value, sim.params_at(res.value))["force"])
        solved.append((d, force, history[-1][1]))
        solved.sort(key=lambda s: s[0])


def solve_travels(
    sim, travels, *, solved: list | None = None, on_solve: Callable | None = None
) -> list[tuple[float, np.ndarray]]:
    """[(travel [m], state q)] at each of ``travels`` [m] (increasing); travels already in
    ``solved`` are not solved again, and ``on_solve(solved)`` runs after each new one."""
    solved = [] if solved is None else solved
    for travel in travels:
        if not any(s[0] == travel for s in solved):
            solve_travel(sim, solved, travel)
            if on_solve is not None:
                on_solve(solved)
    return [(t, q) for t, _, q in solved if t in travels]


def _next_travel(solved: list, target: float, max_step: float) -> float:
    """Travel [m] to try for force ``target`` [N]: regula falsi between the nearest solved states
    on either side, or else a secant step from the last two (at most ``max_step``)."""
    lower = [s for s in solved if s[1] < target]
    upper = [s for s in solved if s[1] > target]
    if upper:
        (ta, fa, _), (tb, fb, _) = (lower[-1] if lower else (0.0, 0.0, None)), upper[0]
        return ta + (target - fa) * (tb - ta) / (fb - fa)
    # first touch: F = 0 at travel 0
    (ta, fa), (tb, fb) = ([(0.0, 0.0), (0.0, 0.0)] + [s[:2] for s in lower])[-2:]
    slope = (fb - fa) / (tb - ta) if tb > ta and fb > fa else 0.0
    return tb + min((target - fb) / slope if slope > 0 else np.inf, max_step)


def match_forces(
    sim, forces, *, tolerance: float, solved: list | None = None, on_solve: Callable | None = None, max_solves: int = 40
) -> list[tuple[float, np.ndarray]]:
    """[(force [N], state q)] at each of ``forces`` [N] (increasing), each within ``tolerance``
    [N], solved under displacement control (module docstring). Raises RuntimeError when a level
    takes more than ``max_solves`` solves."""
    solved = [] if solved is None else solved
    out = []
    for target in forces:
        for _ in range(max_solves):
            hit = [s for s in solved if abs(s[1] - target) <= tolerance]
            if hit:
                out.append((hit[0][1], hit[0][2]))
                break
            solve_travel(sim, solved, _next_travel(solved, target, sim.max_step))
            if on_solve is not None:
                on_solve(solved)
        else:
            raise RuntimeError(f"force level {target} N: no state within {tolerance} N after {max_solves} solves")
    return out
