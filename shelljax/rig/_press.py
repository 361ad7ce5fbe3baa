"""Rigid-surface presses: the finger pressed on a table measures the pad and the sensor alone.

No object and no engine: a sample recorded at force F [N] reads depth = δ + c F_ref (F_t/F_ref)^q
with F_t = g F_ref (F/F_ref)^p (the rig's terms, ``_terms``). The depth noise is the diagnosis's
model of replicates (per-trial offsets and scatter, whitened trial by trial); the fit is scipy's
least squares in the diagnosis's scaled coordinates with the same weak priors, and its score the
same leave-one-trial-out density, exact for the model linearised at the optimum, one unit a trial.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
from scipy import optimize

from .._errors import InvalidInputError
from ..diagnose.internal import (
    DEPTH_NOISE_FLOOR,
    LINEAR_SCALE,
    PRIOR_STD,
    depth_whitening,
    force_level_of_samples,
    held_out_units,
    trial_anova,
)
from ..estimate import depth_noise_from_scatter
from ._terms import fixed_values, freed_parameters

PRESS_PARAMETERS = ("finger_compliance", "pad_exponent", "depth_offset", "force_gain", "force_exponent")


@dataclasses.dataclass(frozen=True)
class PressData:
    """Every press sample: ``force`` [N], ``depth`` [m], its trial ``unit``, the whitening [1/m] and
    each unit's log-Jacobian [-]; ``sources`` of the press sessions."""

    force: np.ndarray
    depth: np.ndarray
    unit: np.ndarray
    whitening: np.ndarray
    log_jacobian: np.ndarray
    sources: tuple[str, ...]

    @property
    def n_units(self) -> int:
        return int(self.log_jacobian.size)


@dataclasses.dataclass(frozen=True)
class PressFit:
    """A press fit under a rig model: the press ``parameters`` it fits (scaled u) with ``mean`` and
    ``covariance``, and each trial's leave-one-out ``elpd`` [nats]."""

    parameters: tuple[str, ...]
    mean: np.ndarray
    covariance: np.ndarray
    elpd: np.ndarray


def press_data(presses: Sequence) -> PressData:
    """Lay out rigid presses (``shelljax.session.RigidPress``) with the noise model of their replicates."""
    presses = tuple(presses)
    levels = np.split(
        force_level_of_samples(np.concatenate([p.force for p in presses])),
        np.cumsum([p.force.size for p in presses])[:-1],
    )
    tau, scatter = trial_anova(presses, levels)
    depth = np.concatenate([p.depth for p in presses])
    if scatter is None:
        scatter = (float(np.mean([depth_noise_from_scatter(p.force, p.depth) ** 2 for p in presses])), 0.0)
    std = np.sqrt(np.maximum(scatter[0] + scatter[1] * depth**2, DEPTH_NOISE_FLOOR**2))
    unit_of = {}
    for k, p in enumerate(presses):
        for t in p.trial_ids:
            unit_of[(k, t)] = len(unit_of)
    unit = np.array([unit_of[(k, t)] for k, p in enumerate(presses) for t in p.trial])
    whitening = depth_whitening(unit, std, tau)
    log_jac = np.array(
        [
            np.sum(np.log(np.abs(np.diag(whitening)[unit == u]))) - 0.5 * np.sum(unit == u) * math.log(2 * math.pi)
            for u in range(len(unit_of))
        ]
    )
    return PressData(
        force=np.concatenate([p.force for p in presses]),
        depth=depth,
        unit=unit,
        whitening=whitening,
        log_jacobian=log_jac,
        sources=tuple(str(p.source) for p in presses),
    )


def _physical(u: dict) -> dict:
    return {
        "c": LINEAR_SCALE["finger_compliance"] * u["finger_compliance"],
        "q": 1.0 + LINEAR_SCALE["pad_exponent"] * u["pad_exponent"],
        "delta": LINEAR_SCALE["depth_offset"] * u["depth_offset"],
        "g": math.exp(u["force_gain"]),
        "p": 1.0 + LINEAR_SCALE["force_exponent"] * u["force_exponent"],
    }


def press_depth(u: dict, force: np.ndarray, force_ref: float) -> np.ndarray:
    """Depth [m] a press reads at recorded forces [N] under the rig's scaled parameters ``u``."""
    v = _physical(u)
    true = v["g"] * force_ref * (force / force_ref) ** v["p"]
    return v["delta"] + v["c"] * force_ref * (true / force_ref) ** v["q"]


def fit_press(data: PressData, terms, force_ref: float) -> PressFit:
    """The press fit and score under the rig model with ``terms`` (see the module docstring)."""
    names = tuple(p for p in freed_parameters(terms) if p in PRESS_PARAMETERS)
    base = {p: 0.0 for p in PRESS_PARAMETERS} | fixed_values(terms)
    prior = np.array([PRIOR_STD[p] for p in names])

    def residuals(x):
        u = base | dict(zip(names, x))
        return np.concatenate([data.whitening @ (press_depth(u, data.force, force_ref) - data.depth), x / prior])

    if names:
        # a pad of zero compliance has no exponent to fit: start with a millimetre at F_ref
        start = np.array(
            [1e-3 / force_ref / LINEAR_SCALE["finger_compliance"] if p == "finger_compliance" else 0.0 for p in names]
        )
        out = optimize.least_squares(residuals, start, jac="3-point", x_scale="jac", xtol=1e-12, ftol=1e-12)
        if not out.success:
            raise InvalidInputError(
                f"the rigid-surface press ({', '.join(data.sources)}) could not be fitted under rig model "
                f"{'+'.join(terms)}: {out.message}. Fix: check the press session for outliers"
            )
        x, jac = out.x, out.jac
        covariance = np.linalg.inv(jac.T @ jac)
    else:
        x, jac, covariance = np.zeros(0), np.zeros((data.depth.size, 0)), np.zeros((0, 0))
    resid = residuals(x)
    elpd = np.zeros(data.n_units)
    for i, _, _, _, _, log_density in held_out_units(jac, resid, data.unit, data.n_units):
        elpd[i] = log_density + data.log_jacobian[i]
    return PressFit(parameters=names, mean=x, covariance=covariance, elpd=elpd)
