"""A calibrated measuring chain as a study's baseline (``shelljax.rig`` makes one from a rig file).

The chain's parameters are free in the baseline and in every candidate, under the calibration's
correlated normal posterior as their prior (``StudyArrays.rig_whitening``); the values a chain fixes
(a Hertzian pad's exponent) and its reference force hold too, and its depth-noise model replaces
the study's own.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._effects import GLOBAL_PARAMETERS
from ._model import N_GRID, StudyArrays, engine_force_bounds


@dataclasses.dataclass(frozen=True)
class MeasurementPrior:
    """A measuring chain known from a calibration: ``name``; the diagnosis ``parameters`` it frees
    with their ``mean`` and ``covariance`` in the scaled coordinates (``_effects``); the scaled
    values it ``fixes``; ``force_ref`` [N] of its power laws; ``noise`` (τ_t [m], (a [m²], b [-]))."""

    name: str
    parameters: tuple[str, ...]
    mean: np.ndarray
    covariance: np.ndarray
    fixes: dict
    force_ref: float
    noise: tuple[float, tuple[float, float]]


def widened_grid(data: StudyArrays, forces_true, span: tuple[float, float]) -> StudyArrays:
    """``data`` with its engine force grid [N] (reference frame) covering ``forces_true`` [N] by ``span``."""
    return eqx.tree_at(
        lambda d: d.grid, data, jnp.linspace(*engine_force_bounds(data.radius, forces_true, span), N_GRID)
    )


def with_measurement(
    data: StudyArrays, *, free: tuple[str, ...] = (), fixes: dict | None = None, prior: tuple | None = None
) -> StudyArrays:
    """``data`` with the global parameters ``free`` freed (the gauge pressures stay free), the scaled
    values ``fixes`` (name → u) set, and ``prior`` = (parameters, mean u, covariance) as a correlated
    normal prior replacing the weak one of those parameters (which are freed too)."""
    n_s = int(data.radius.shape[0])
    mask, u_base = np.asarray(data.free).copy(), np.asarray(data.u_base).copy()
    names, mean_u, cov = prior if prior is not None else ((), np.zeros(0), np.zeros((0, 0)))
    for name in tuple(free) + tuple(names):
        mask[n_s + GLOBAL_PARAMETERS.index(name)] = True
    for name, value in (fixes or {}).items():
        u_base[n_s + GLOBAL_PARAMETERS.index(name)] = value
    n_u = u_base.size
    index = [n_s + GLOBAL_PARAMETERS.index(p) for p in names]
    whitening, mean, std = np.zeros((n_u, n_u)), np.zeros(n_u), np.asarray(data.prior_std).copy()
    if index:
        # L with Lᵀ L = Σ⁻¹, so that L (u − μ) are the whitened prior residuals
        whitening[np.ix_(index, index)] = np.linalg.cholesky(np.linalg.inv(cov)).T
        mean[index] = mean_u
        std[index] = np.inf  # the chain's prior replaces the diagnosis's weak one
    return eqx.tree_at(
        lambda d: (d.free, d.u_base, d.rig_whitening, d.rig_mean, d.prior_std),
        data,
        tuple(jnp.asarray(v) for v in (mask, u_base, whitening, mean, std)),
    )


def measured_baseline(data: StudyArrays, measurement: MeasurementPrior | None) -> StudyArrays:
    """``data`` with ``measurement``'s chain as its baseline (unchanged when None)."""
    if measurement is None:
        return data
    return with_measurement(
        data, fixes=measurement.fixes, prior=(measurement.parameters, measurement.mean, measurement.covariance)
    )
