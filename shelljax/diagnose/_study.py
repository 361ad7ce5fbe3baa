"""A study: the sessions of one object, their data laid out for the joint fit, and the noise model.

Noise model (estimated from the replicates, never from a model fit, so a misfit cannot hide in it):

* depth: each trial is one sweep of the force levels, so its samples share the trial's zero
  error. A two-way analysis of variance (trial × force level, per session, pooled over sessions)
  splits the scatter into a per-trial offset of standard deviation τ_t [m] and independent scatter
  σ_i [m], σ_i² = a + b·d_i² growing with the measured depth d_i (a reading error proportional to
  the depth). A trial's depths are then normal with covariance diag(σ_i²) + τ_t² 11ᵀ, and its
  residuals are whitened with the Cholesky factor of that matrix.
* wrinkle counts: the integer read is the model's continuous count plus a ±1 reading error
  (σ_n = 1, as the estimators assume).
* shape observables ([shape] table): independent normals, σ from the scatter between trials at
  one force (pooled per observable), never below ``SHAPE_RESOLUTION``.

The leave-one-out unit is a trial: its depths, its wrinkle count and its shape points.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from .._errors import InvalidInputError
from ..estimate import depth_noise_from_scatter, modulus_from_wrinkles, pressure_slope
from ..paper import PAPER_KS
from ..session import SHAPE_OBSERVABLES, Session

DEPTH_NOISE_FLOOR = 1e-5  # [m]
SHAPE_RESOLUTION = 0.5e-3  # [m] least shape noise: a ruler's millimetre, read to half
LEVEL_ROUNDING = 0.5  # [N] samples within this of each other are one force level
MIN_TRIALS = 4  # fewer leave-one-out units cannot rank candidates
MIN_DEPTHS = 10


@dataclasses.dataclass(frozen=True)
class Study:
    """The data of one study (every array SI; indices refer to ``sessions``).

    Depth samples: ``depth_session``, ``depth_unit`` (leave-one-out unit = trial), ``force`` [N],
    ``depth`` [m], ``depth_std`` [m] (marginal: scatter and trial offset), ``whitening``
    (n_depth, n_depth) [1/m], block-diagonal by trial; ``level`` [N] the force level of each
    sample. Counts: ``count_session``, ``count_unit``, ``count``. Shape points:
    ``shape_session``, ``shape_unit``, ``shape_kind`` (index into SHAPE_OBSERVABLES),
    ``shape_force`` [N], ``shape_value`` [m], ``shape_std`` [m]. Per session: ``radius`` [m],
    ``manometer`` [Pa] (NaN: none), ``start_pressure`` [Pa]. Shared: ``radius_std`` [m],
    ``thickness``/``thickness_std`` [m], ``poisson_ratio``, ``mass`` [kg] or None,
    ``gas_volume_ratio``, ``start_modulus`` [Pa], ``trial_offset_std`` τ_t [m],
    ``depth_noise`` (a [m²], b [-]). ``units``: (session, trial id) of every unit.
    """

    sessions: tuple[Session, ...]
    depth_session: np.ndarray
    depth_unit: np.ndarray
    force: np.ndarray
    depth: np.ndarray
    depth_std: np.ndarray
    whitening: np.ndarray
    level: np.ndarray
    count_session: np.ndarray
    count_unit: np.ndarray
    count: np.ndarray
    shape_session: np.ndarray
    shape_unit: np.ndarray
    shape_kind: np.ndarray
    shape_force: np.ndarray
    shape_value: np.ndarray
    shape_std: np.ndarray
    radius: np.ndarray
    manometer: np.ndarray
    start_pressure: np.ndarray
    radius_std: float
    thickness: float
    thickness_std: float
    poisson_ratio: float
    mass: float | None
    gas_volume_ratio: float
    start_modulus: float
    trial_offset_std: float
    depth_noise: tuple[float, float]
    units: tuple[tuple[int, object], ...]

    @property
    def n_sessions(self) -> int:
        return len(self.sessions)

    @property
    def n_units(self) -> int:
        return len(self.units)


def _check_one_object(sessions: Sequence[Session], command: str) -> None:
    names = {s.object_name for s in sessions}
    if len(names) > 1:
        listing = "; ".join(f"{s.source}: '{s.object_name}'" for s in sessions)
        raise InvalidInputError(
            f"the sessions are of different objects ({listing}). Fix: {command} one object at a time "
            "(the sessions given together share one E, wall and measuring chain)"
        )
    for field in ("thickness", "poisson_ratio"):
        values = [getattr(s, field) for s in sessions]
        if max(values) > min(values) * (1 + 1e-9):
            raise InvalidInputError(
                f"the sessions of '{sessions[0].object_name}' disagree on '{field}' "
                f"({', '.join(f'{s.source}: {getattr(s, field)!r}' for s in sessions)}). Fix: one object has one "
                "wall; correct the files"
            )
    for s in sessions:
        if s.wrinkle_counts is None:
            raise InvalidInputError(
                f"{s.source}: field 'wrinkles.counts': missing; the diagnosis needs the wrinkle counts to "
                "separate E from P_g. Fix: add one count per trial"
            )


def force_level_of_samples(force: np.ndarray) -> np.ndarray:
    """Force level [N] of each sample: samples within LEVEL_ROUNDING of the previous one join its level."""
    order = np.argsort(force)
    level = np.empty_like(force)
    start = 0
    for k in range(1, force.size + 1):
        if k == force.size or force[order[k]] - force[order[k - 1]] > LEVEL_ROUNDING:
            level[order[start:k]] = np.mean(force[order[start:k]])
            start = k
    return level


def trial_anova(sessions, levels):
    """(τ_t [m], a [m²], b [-]): trial offsets and scatter σ² = a + b d² from trial × level tables."""
    trial_ms, trial_dof, cells = 0.0, 0, []
    for s, lev in zip(sessions, levels):
        trials = s.trial_ids
        grid = np.unique(lev)
        table = np.full((trials.size, grid.size), np.nan)
        for i, t in enumerate(trials):
            for j, g in enumerate(grid):
                hit = (s.trial == t) & (lev == g)
                if hit.any():
                    table[i, j] = np.mean(s.depth[hit])
        full = table[:, ~np.any(np.isnan(table), axis=0)]
        if full.shape[0] < 2 or full.shape[1] < 2:
            continue
        resid = full - full.mean(axis=1, keepdims=True) - full.mean(axis=0, keepdims=True) + full.mean()
        n_t, n_l = full.shape
        scale = n_t * n_l / ((n_t - 1) * (n_l - 1))  # E[resid²] = σ² (n_t−1)(n_l−1)/(n_t n_l)
        cells += [
            (m, r * r * scale) for m, r in zip(np.broadcast_to(full.mean(axis=0), full.shape).ravel(), resid.ravel())
        ]
        trial_means = full.mean(axis=1)
        trial_ms += n_l * np.sum((trial_means - trial_means.mean()) ** 2)
        trial_dof += n_t - 1
    if not cells:
        return 0.0, None
    m2 = np.array([c[0] ** 2 for c in cells])
    v = np.array([c[1] for c in cells])
    # σ² = a + b d² by non-negative least squares on the per-cell variance estimates
    from scipy.optimize import nnls

    (a, b), _ = nnls(np.stack([np.ones_like(m2), m2], axis=1), v)
    if a + b * np.median(m2) <= 0:
        a = float(np.mean(v))
    mean_scatter = a + b * float(np.mean(m2))
    n_levels_mean = len(cells) / max(trial_dof, 1)
    tau_sq = max(trial_ms / max(trial_dof, 1) - mean_scatter, 0.0) / max(n_levels_mean, 1.0)
    return math.sqrt(tau_sq), (float(a), float(b))


def depth_whitening(depth_unit, depth_std, tau):
    """Block-diagonal W with Wᵀ W = Σ⁻¹, Σ = diag(σ²) + τ² 11ᵀ within each unit."""
    n = depth_unit.size
    w = np.zeros((n, n))
    for u in np.unique(depth_unit):
        idx = np.flatnonzero(depth_unit == u)
        cov = np.diag(depth_std[idx] ** 2) + tau**2
        w[np.ix_(idx, idx)] = np.linalg.inv(np.linalg.cholesky(cov))
    return w


def _shape_points(sessions, unit_of):
    rows = []
    for si, s in enumerate(sessions):
        shape = getattr(s, "shape", None)
        if not shape:
            continue
        for kind, name in enumerate(SHAPE_OBSERVABLES):
            values = shape.get(name)
            if values is None:
                continue
            for t, f, v in zip(s.shape_trial, s.shape_force, values):
                if np.isfinite(v):
                    rows.append((si, unit_of[(si, t)], kind, float(f), float(v)))
    if not rows:
        empty = np.zeros(0)
        return empty.astype(int), empty.astype(int), empty.astype(int), empty, empty, empty
    si, unit, kind, force, value = (np.array(c) for c in zip(*rows))
    std = np.full(value.size, SHAPE_RESOLUTION)
    for k in np.unique(kind):
        # pooled scatter between trials at one (session, force level)
        sq, dof = 0.0, 0
        for s in np.unique(si):
            sel = (kind == k) & (si == s)
            lev = force_level_of_samples(force[sel])
            for g in np.unique(lev):
                vals = value[sel][lev == g]
                if vals.size > 1:
                    sq += np.sum((vals - vals.mean()) ** 2)
                    dof += vals.size - 1
        if dof:
            std[kind == k] = max(math.sqrt(sq / dof), SHAPE_RESOLUTION)
    return si.astype(int), unit.astype(int), kind.astype(int), force, value, std


def object_unknowns(study: Study) -> tuple[str, ...]:
    """The object's own global unknowns besides P_g: E, and h and R where they carry a std."""
    return (
        ("young_modulus",)
        + (("thickness",) if study.thickness_std > 0 else ())
        + (("radius",) if study.radius_std > 0 else ())
    )


def _trial_units(
    sessions: tuple[Session, ...], min_trials: int
) -> tuple[list[tuple[int, int]], dict[tuple[int, int], int]]:
    """The leave-one-out units, (session index, trial id) each, and each one's index; refuses a study
    with fewer than ``min_trials`` trials or ``MIN_DEPTHS`` depth samples."""
    units, unit_of = [], {}
    for si, s in enumerate(sessions):
        for t in s.trial_ids:
            unit_of[(si, t)] = len(units)
            units.append((si, t))
    n_depth = sum(s.depth.size for s in sessions)
    if len(units) < min_trials or n_depth < MIN_DEPTHS:
        raise InvalidInputError(
            f"the study is too small to rank candidate effects: {len(units)} trials with {n_depth} depth samples "
            f"in {len(sessions)} session(s) (need at least {min_trials} trials and {MIN_DEPTHS} samples: "
            "leave-one-trial-out needs trials to leave out). Fix: add sessions or trials"
        )
    return units, unit_of


def _depth_noise(
    sessions: tuple[Session, ...],
    levels: list[np.ndarray],
    depth: np.ndarray,
    noise: tuple[float, tuple[float, float]] | None,
) -> tuple[float, tuple[float, float], np.ndarray]:
    """The trial offset std τ_t [m], the scatter (a [m²], b [-]) and each depth sample's marginal
    std [m]: ``noise`` where given, else estimated from the replicates."""
    tau, scatter = trial_anova(sessions, levels) if noise is None else noise
    if scatter is None:  # no replicated levels: model-free scatter about a line in force, per session
        noise = np.sqrt(np.mean([depth_noise_from_scatter(s.force, s.depth) ** 2 for s in sessions]))
        scatter = (float(noise**2), 0.0)
    depth_std = np.sqrt(np.maximum(scatter[0] + scatter[1] * depth**2, DEPTH_NOISE_FLOOR**2))
    return tau, scatter, depth_std


def _starting_values(sessions: tuple[Session, ...]) -> tuple[np.ndarray, np.ndarray, float]:
    """Per session the manometer's gauge pressure [Pa] (NaN: none) and the starting pressure [Pa];
    the shared starting Young's modulus [Pa]."""
    manometer = np.array(
        [np.nan if s.manometer_gauge_pressure is None else s.manometer_gauge_pressure for s in sessions]
    )
    # start: the manometer where there is one, else the closed form's P_g with the paper's k_s
    start_pressure = np.array(
        [m if np.isfinite(m) else pressure_slope(s)[0].value / PAPER_KS for m, s in zip(manometer, sessions)]
    )
    # E from the wrinkle law at the starting pressures (the manometer's where known, not k_s's)
    moduli = [
        modulus_from_wrinkles(p, s.radius, s.thickness, float(np.mean(s.wrinkle_counts)), s.poisson_ratio)
        for p, s in zip(start_pressure, sessions)
        if np.mean(s.wrinkle_counts) > 0
    ]
    return manometer, start_pressure, float(np.exp(np.mean(np.log(moduli)))) if moduli else 1e6


def build_study(
    sessions: Sequence[Session],
    noise: tuple[float, tuple[float, float]] | None = None,
    *,
    min_trials: int = MIN_TRIALS,
    command: str = "diagnose",
) -> Study:
    """Check that ``sessions`` are of one object and lay out their data (see :class:`Study`).

    ``noise`` = (τ_t [m], (a [m²], b [-])) fixes the depth noise model instead of estimating it
    from the replicates (e.g. a study's noise reused for a subset of its trials, or a rig's);
    ``min_trials``: fewest trials accepted (ranking needs trials to leave out; an estimate does not);
    ``command``: what the user ran, for the fix of sessions of several objects.
    """
    sessions = tuple(sessions)
    if not sessions:
        raise InvalidInputError("no sessions given. Fix: pass the session TOML files of one object")
    _check_one_object(sessions, command)
    units, unit_of = _trial_units(sessions, min_trials)
    # one protocol for the study: force levels are clustered over all sessions together
    all_levels = force_level_of_samples(np.concatenate([s.force for s in sessions]))
    levels = np.split(all_levels, np.cumsum([s.force.size for s in sessions])[:-1])
    depth = np.concatenate([s.depth for s in sessions])
    tau, scatter, depth_std = _depth_noise(sessions, levels, depth, noise)
    depth_session = np.concatenate([np.full(s.depth.size, i) for i, s in enumerate(sessions)])
    depth_unit = np.concatenate([[unit_of[(i, t)] for t in s.trial] for i, s in enumerate(sessions)]).astype(int)
    count_session = np.concatenate([np.full(s.trial_ids.size, i) for i, s in enumerate(sessions)])
    count_unit = np.array([unit_of[(i, t)] for i, s in enumerate(sessions) for t in s.trial_ids])
    shape = _shape_points(sessions, unit_of)
    radius = np.array([s.radius for s in sessions])
    manometer, start_pressure, start_modulus = _starting_values(sessions)
    masses = [s.mass for s in sessions if s.mass is not None]
    volumes = [
        s.enclosed_volume / (4.0 / 3.0 * math.pi * s.radius**3)
        for s in sessions
        if getattr(s, "enclosed_volume", None) is not None
    ]
    return Study(
        sessions=sessions,
        depth_session=depth_session,
        depth_unit=depth_unit,
        force=np.concatenate([s.force for s in sessions]),
        depth=depth,
        depth_std=depth_std,
        whitening=depth_whitening(depth_unit, depth_std, tau),
        level=np.concatenate(levels),
        count_session=count_session,
        count_unit=count_unit,
        count=np.concatenate([s.wrinkle_counts for s in sessions]).astype(float),
        shape_session=shape[0],
        shape_unit=shape[1],
        shape_kind=shape[2],
        shape_force=shape[3],
        shape_value=shape[4],
        shape_std=shape[5],
        radius=radius,
        manometer=manometer,
        start_pressure=start_pressure,
        radius_std=float(np.sqrt(np.mean([s.radius_std**2 for s in sessions]))),
        thickness=sessions[0].thickness,
        thickness_std=sessions[0].thickness_std,
        poisson_ratio=sessions[0].poisson_ratio,
        mass=float(np.mean(masses)) if masses else None,
        gas_volume_ratio=float(np.mean(volumes)) if volumes else 1.0,
        start_modulus=start_modulus,
        trial_offset_std=tau,
        depth_noise=scatter,
        units=tuple(units),
    )
