"""Impacts of a trajectory: coefficient of restitution, contact time, peak force, compression;
and the 1-D solve that calibrates the contact damping to a measured COR.

An impact on a plane is an interval where its closest contact point is nearer than the law's
contact distance [m]; its start and end times are interpolated linearly between steps. On a plane
that gravity presses against, contacts separated by a flight in which the centre of mass stays
below its height at the first one's onset are one impact (chatter: the shell's lowest vertices
bouncing off the plane while the body is still coming down, as under TR-BDF2 at the first
milliseconds of a drop). Heights are
the centre of mass's [m] along the plane normal, measured from where it was at contact onset.
A body with a mesh also reports its largest contact-patch diameter [m] (``contact_diameter``).
For planes that gravity presses against, COR = √(bounce apex height / drop height); otherwise
(walls, no gravity) COR is the ratio of normal speeds out/in of the centre of mass.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import scipy.optimize

from .._errors import InvalidInputError
from ._run import Trajectory


@dataclasses.dataclass(frozen=True)
class Impact:
    """One impact on plane ``plane``: times [s], speeds [m/s], heights [m], force [N], compression [m]."""

    plane: str
    onset_s: float
    end_s: float
    contact_time_s: float
    speed_in_m_per_s: float
    speed_out_m_per_s: float
    drop_height_m: float
    bounce_height_m: float
    cor: float
    cor_from_speeds: float
    peak_force_N: float
    max_compression_m: float
    max_contact_diameter_m: float = float("nan")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def _crossing(values, level, k):
    """Fraction s ∈ [0, 1] where values[k−1] + s (values[k] − values[k−1]) = level."""
    a, b = values[k - 1], values[k]
    return float(np.clip((a - level) / (a - b), 0.0, 1.0)) if a != b else 0.0


def mesh_edges(faces: np.ndarray) -> np.ndarray:
    """The unique edges (E, 2) of triangles ``faces`` (F, 3)."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    return np.unique(edges, axis=0)


def contact_diameter(nodes: np.ndarray, edges: np.ndarray, gaps: np.ndarray, normal: np.ndarray, level: float) -> float:
    """Diameter [m] of a contact patch on a plane: 2 × the mean distance, from their centroid, of the
    points where the mesh's edges cross the gap ``level`` [m] (the law's contact distance).

    ``nodes`` (V, 3) [m], ``edges`` (E, 2), ``gaps`` (V,) [m] to the plane of unit ``normal``. The
    faces are flat, so a crossing interpolated along an edge lies on the surface, and the measure
    grows continuously with the patch instead of by a vertex spacing; 0 with fewer than 3 crossings.
    """
    a, b = edges[:, 0], edges[:, 1]
    cross = (gaps[a] < level) != (gaps[b] < level)
    if np.count_nonzero(cross) < 3:
        return 0.0
    a, b = a[cross], b[cross]
    s = (level - gaps[a]) / (gaps[b] - gaps[a])
    points = nodes[a] + s[:, None] * (nodes[b] - nodes[a])
    points = points - np.outer(points @ normal, normal)
    return 2.0 * float(np.mean(np.linalg.norm(points - points.mean(axis=0), axis=1)))


def _max_contact_diameter(trajectory: Trajectory, edges, p: int, steps: range) -> float:
    """Largest contact diameter [m] on plane ``p`` over ``steps``; NaN without a mesh."""
    if edges is None:
        return float("nan")
    n, level = trajectory.plane_normals[p], trajectory.contact_distances_m[p]
    diameters = []
    for k in steps:
        nodes = trajectory["position_m"][k].reshape(-1, 3)
        heights = nodes @ n
        # The record keeps the smallest gap, so the plane's offset along n is min(x·n) − min gap.
        gaps = heights - (heights.min() - trajectory["min_gap_m"][k, p])
        diameters.append(contact_diameter(nodes, edges, gaps, n, level))
    return max(diameters, default=0.0)


def _merge_chatter(starts: list[int], ends: list[int], height: np.ndarray) -> tuple[list[int], list[int]]:
    """Contact intervals (start and end steps) with chatter merged: a separation after which the
    centre of mass's height [m] along the normal stays below its height just before the interval's
    onset (the body was still coming down: its lowest points bounced off the plane, it did not)
    joins the interval to the next one."""
    merged = []
    for k0 in starts:
        later = [k for k in ends if k > k0]
        k1 = later[0] if later else None
        if merged and merged[-1][1] is not None and np.max(height[merged[-1][1] : k0 + 1]) < height[merged[-1][0] - 1]:
            merged[-1][1] = k1
        else:
            merged.append([k0, k1])
    return [k0 for k0, _ in merged], [k1 for _, k1 in merged if k1 is not None]


def measured_cor(trajectory: Trajectory) -> tuple[Impact, ...]:
    """Every completed impact of ``trajectory`` on every plane, in time order (see module doc)."""
    t = trajectory["time_s"]
    com = trajectory["com_position_m"]
    vel = trajectory["com_velocity_m_per_s"]
    impacts = []
    edges = None if trajectory.faces is None else mesh_edges(np.asarray(trajectory.faces))
    for p, name in enumerate(trajectory.plane_names):
        n = trajectory.plane_normals[p]
        gap = trajectory["min_gap_m"][:, p]
        level = trajectory.contact_distances_m[p]
        touching = gap < level
        height, speed = com @ n, vel @ n
        g_n = float(-(trajectory.gravity_m_per_s2 @ n))
        starts = [k for k in range(1, len(t)) if touching[k] and not touching[k - 1]]
        ends = [k for k in range(1, len(t)) if touching[k - 1] and not touching[k]]
        if g_n > 0.0:
            starts, ends = _merge_chatter(starts, ends, height)
        for i, k0 in enumerate(starts):
            later = [k for k in ends if k > k0]
            if not later:
                continue
            k1 = later[0]
            s0, s1 = _crossing(gap, level, k0), _crossing(gap, level, k1)
            lerp = lambda a, k, s: a[k - 1] + s * (a[k] - a[k - 1])  # noqa: E731
            t0, t1 = lerp(t, k0, s0), lerp(t, k1, s1)
            v_in, v_out = -lerp(speed, k0, s0), lerp(speed, k1, s1)
            z0 = lerp(height, k0, s0)
            previous_end = max([k for k in ends if k <= k0], default=0)
            next_start = starts[i + 1] if i + 1 < len(starts) else len(t)
            drop = float(np.max(height[previous_end:k0]) - z0)
            rebound = height[k1:next_start]
            bounce = float(np.max(rebound) - z0)
            if next_start == len(t) and g_n > 0.0 and speed[-1] > 0.0:
                # The record ends on the way up: the ballistic apex of its last state.
                bounce = float(height[-1] + speed[-1] ** 2 / (2.0 * g_n) - z0)
            by_speed = v_out / v_in if v_in > 0.0 else float("nan")
            by_height = np.sqrt(max(bounce, 0.0) / drop) if g_n > 0.0 and drop > 0.0 else by_speed
            force = trajectory["contact_force_N"][k0 : k1 + 1, p] @ n
            impacts.append(
                Impact(
                    plane=name,
                    onset_s=float(t0),
                    end_s=float(t1),
                    contact_time_s=float(t1 - t0),
                    speed_in_m_per_s=float(v_in),
                    speed_out_m_per_s=float(v_out),
                    drop_height_m=drop,
                    bounce_height_m=bounce,
                    cor=float(by_height),
                    cor_from_speeds=float(by_speed),
                    peak_force_N=float(np.max(force)),
                    max_compression_m=float(z0 - np.min(height[k0 : k1 + 1])),
                    max_contact_diameter_m=_max_contact_diameter(trajectory, edges, p, range(k0, k1 + 1)),
                )
            )
    return tuple(sorted(impacts, key=lambda m: m.onset_s))


@dataclasses.dataclass(frozen=True)
class DampingCalibration:
    """The calibrated damping c [N·s/m], its simulated COR [-], and every (c, COR) evaluated."""

    damping: float
    cor: float
    evaluations: tuple[tuple[float, float], ...]


def calibrate_contact_damping(
    simulate: Callable[[float], float | Trajectory],
    target_cor: float,
    bracket: tuple[float, float],
    *,
    rtol: float = 1e-4,
) -> DampingCalibration:
    """The contact damping c [N·s/m] in ``bracket`` whose simulated COR equals ``target_cor``.

    ``simulate(c)`` returns the COR [-] of a run with damping c, or its ``Trajectory`` (its first
    impact's COR is used). COR falls as c grows; a target outside [COR(c_hi), COR(c_lo)] raises
    ``InvalidInputError`` with the reachable range. Brent's method stops at a relative c
    tolerance ``rtol``.
    """
    lo, hi = (float(b) for b in bracket)
    if not 0.0 < target_cor <= 1.0:
        raise InvalidInputError(
            f"target COR must be in (0, 1]; got {target_cor}. Measure it as √(bounce height / drop height)."
        )
    if not 0.0 <= lo < hi:
        raise InvalidInputError(f"bracket must be 0 ≤ c_lo < c_hi [N·s/m]; got {bracket}.")
    evaluations = []

    def cor(c):
        # brentq evaluates the bracket's ends again: reuse those runs.
        known = [value for damping, value in evaluations if damping == float(c)]
        if known:
            return known[0]
        out = simulate(c)
        if isinstance(out, Trajectory):
            impacts = measured_cor(out)
            if not impacts:
                raise InvalidInputError(
                    "the simulated run has no completed impact; run it longer so the body leaves the plane again."
                )
            out = impacts[0].cor
        evaluations.append((float(c), float(out)))
        return float(out)

    cor_lo, cor_hi = cor(lo), cor(hi)
    if not min(cor_lo, cor_hi) <= target_cor <= max(cor_lo, cor_hi):
        raise InvalidInputError(
            f"target COR {target_cor} is outside the reachable range [{min(cor_lo, cor_hi):.4f}, {max(cor_lo, cor_hi):.4f}] "
            f"of damping c in [{lo}, {hi}] N·s/m. Widen the bracket; a target above COR(c_lo) may need a smaller dt "
            "(the integrator's own dissipation) or a COR measurement check."
        )
    c = scipy.optimize.brentq(lambda c: cor(c) - target_cor, lo, hi, xtol=rtol * hi, rtol=rtol)
    return DampingCalibration(float(c), cor(c), tuple(evaluations))
