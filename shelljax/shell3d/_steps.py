"""Host-side helpers of the continuation's load steps: warm starts and ground slip (SI units)."""

from __future__ import annotations

import numpy as np

from ._config import ModelConfig
from ._contact import body_gaps, place_at_gaps


def feasible_start(q, config: ModelConfig, activation_distance: float, q_prev=None) -> np.ndarray:
    """Newton's start from the guess ``q`` [m]: the barrier energy finite and near equilibrium.

    A vertex that was within the barrier's range ĝ (``activation_distance`` [m]) of a body in the
    converged state ``q_prev`` gets back the gap it had there; any other vertex closer than ĝ/4 to
    a body (or inside it) is put at ĝ/4. Why not ĝ/4 for all: vertices pressed by the indenter sit
    at gaps far below ĝ, and Newton on a log barrier started far above its equilibrium gap g* can
    only take steps of length ≈ g*/g (longer ones cross the body). A vertex's contact force
    changes little from one load step to the next, and so does its gap.
    """
    if config.contact.kind != "barrier":
        return q
    ghat = activation_distance
    floor = 0.25 * ghat
    gaps_prev = None if q_prev is None else body_gaps(q_prev, config)

    def target(body, gap):
        goal = np.where(gap < floor, floor, np.nan)
        if gaps_prev is not None:
            goal = np.where(gaps_prev[body] < ghat, np.maximum(gaps_prev[body], 1e-6 * ghat), goal)
        return goal

    return place_at_gaps(q, config, target)


def initial_slip(config: ModelConfig) -> np.ndarray | None:
    """Zero ground slip (V, 3) [m], or None without a ground plane."""
    return np.zeros((config.n_vertices, 3)) if config.contact.planes else None


def accumulate_slip(slip, config: ModelConfig, activation_distance: float, q_start, q_end):
    """``slip`` (V, 3) [m] plus the tangential motion from ``q_start`` to ``q_end`` of the vertices
    within ``activation_distance`` [m] of the ground (the first plane) at ``q_end``."""
    if slip is None:
        return None
    point, normal = (
        np.asarray(v, dtype=np.float64) for v in (config.contact.planes[0].point, config.contact.planes[0].normal)
    )
    x0, x1 = q_start[:-3].reshape(-1, 3), q_end[:-3].reshape(-1, 3)
    touching = (x1 - point) @ normal < activation_distance
    d = x1 - x0
    d = d - (d @ normal)[:, None] * normal
    return slip + np.where(touching[:, None], d, 0.0)


def secant_predict(history, value) -> np.ndarray:
    """Warm start at load ``value`` by linear extrapolation of the last two (load, q) of
    ``history`` (a copy of the last state if there is only one or they share a load)."""
    if len(history) < 2:
        return history[-1][1].copy()
    (a, qa), (b, qb) = history[-2], history[-1]
    if b == a:
        return qb.copy()
    return qb + (qb - qa) * (value - b) / (b - a)
