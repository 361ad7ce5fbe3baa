"""One session's inverse problem: unknowns, data, noise model and priors, shared by fit and bayes.

Unknowns live in a well-scaled vector ``u`` (all O(1) near the start):

| name | u | physical | prior |
|---|---|---|---|
| gauge_pressure | log(P_g / P_ref) | P_g [Pa] | log-uniform on [10 Pa, 100 kPa] |
| young_modulus | log(E / E_ref) | E [Pa] | log-uniform on [10 kPa, 10 GPa] |
| thickness | log(h / h_meas) | h [m] | normal(h_meas, σ_h), when σ_h > 0 |
| radius | log(R / R_meas) | R [m] | normal(R_meas, σ_R), when σ_R > 0 |
| depth_offset | δ / 1 mm | δ [m] added to every predicted depth | uniform on ±10 mm (optional) |
| force_gain | log g | g [-] multiplies recorded forces | normal(1, 5 %) (optional) |

P_ref and E_ref are the starting values (the closed-form estimate), so u = 0 at the start.

Noise model: depths are independent normals with standard deviation σ_w [m] — from the sensor
calibration when known, otherwise estimated from the scatter of depth about a straight line in
force (model-free) and, in ``bayes``, sampled with a log-uniform prior on [10 µm, 10 mm].
Wrinkle counts are integers: each is the model's continuous n plus a ±1 reading error, with
likelihood P(k) = Φ((k + ½ − n)/σ_n) − Φ((k − ½ − n)/σ_n), σ_n = 1 (the fit uses the Gaussian
residual (k − n)/σ_n).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import log_ndtr
from jaxtyping import Array, Bool, Float

from .._errors import InvalidInputError
from ..session import Session
from ._forward import AbstractForwardModel

PRESSURE_BOUNDS = (10.0, 1e5)  # [Pa]
MODULUS_BOUNDS = (1e4, 1e10)  # [Pa]
DEPTH_NOISE_BOUNDS = (1e-5, 1e-2)  # [m]
OFFSET_BOUND = 10e-3  # [m]
GAIN_STD = 0.05  # [-]
COUNT_NOISE = 1.0  # [wrinkles]
OFFSET_SCALE = 1e-3  # [m] per unit of u
FAILED_RESIDUAL = 1e4  # [-] whitened residual of a failed forward solve (cost 5e7 per entry)
OPTIONAL_PARAMETERS = ("depth_offset", "force_gain")


def depth_noise_from_scatter(force: np.ndarray, depth: np.ndarray) -> float:
    """σ_w [m]: residual standard deviation of depth regressed linearly on force (model-free)."""
    design = np.stack([force, np.ones_like(force)], axis=1)
    coef, *_ = np.linalg.lstsq(design, depth, rcond=None)
    residual = depth - design @ coef
    return float(max(np.sqrt(residual @ residual / max(depth.size - 2, 1)), DEPTH_NOISE_BOUNDS[0]))


def count_log_likelihood(counts, predicted, noise=COUNT_NOISE):
    """log P(k) [-] of each integer count k read off a continuous model count n [-]:
    P(k) = Φ((k + ½ − n)/σ_n) − Φ((k − ½ − n)/σ_n), σ_n = ``noise`` [wrinkles]."""
    upper = (counts + 0.5 - predicted) / noise
    lower = (counts - 0.5 - predicted) / noise
    # log(Φ(a) − Φ(b)) = log Φ(a) + log(1 − exp(log Φ(b) − log Φ(a))); mirrored (Φ(−b) − Φ(−a))
    # when both bounds are positive, so the subtraction never happens near Φ = 1
    flip = lower > 0
    log_a = log_ndtr(jnp.where(flip, -lower, upper))
    log_b = log_ndtr(jnp.where(flip, -upper, lower))
    return log_a + jnp.log1p(-jnp.exp(jnp.minimum(log_b - log_a, -1e-300)))


class InverseProblem(eqx.Module):
    """Data, forward model and priors of one session (see the module docstring for the layout).

    ``force`` [N], ``depth`` [m], ``counts`` [-] (may be empty), ``depth_noise`` σ_w [m],
    ``thickness``/``thickness_std`` [m], ``radius``/``radius_std`` [m], ``reference_pressure`` [Pa],
    ``reference_modulus`` [Pa]; ``names``: the free unknowns, in order.
    """

    model: AbstractForwardModel
    force: Float[Array, " m"]
    depth: Float[Array, " m"]
    counts: Float[Array, " k"]
    depth_noise: float
    thickness: float
    thickness_std: float
    radius: float
    radius_std: float
    reference_pressure: float
    reference_modulus: float
    names: tuple[str, ...] = eqx.field(static=True)

    @property
    def ndim(self) -> int:
        return len(self.names)

    def physical(self, u: Float[Array, " d"]) -> dict[str, Float[Array, ""]]:
        """Physical values (SI) of every parameter, fixed ones included, for unknowns ``u``."""
        get = {n: u[i] for i, n in enumerate(self.names)}
        zero = jnp.zeros((), u.dtype)
        return {
            "gauge_pressure": self.reference_pressure * jnp.exp(get["gauge_pressure"]),
            "young_modulus": self.reference_modulus * jnp.exp(get["young_modulus"]),
            "thickness": self.thickness * jnp.exp(get.get("thickness", zero)),
            "radius": self.radius * jnp.exp(get.get("radius", zero)),
            "depth_offset": OFFSET_SCALE * get.get("depth_offset", zero),
            "force_gain": jnp.exp(get.get("force_gain", zero)),
        }

    def predict(self, u):
        """Predicted depths [m] at the recorded forces, wrinkle count [-], converged flag."""
        p = self.physical(u)
        pred = self.model(
            p["gauge_pressure"], p["young_modulus"], p["thickness"], p["radius"], self.force * p["force_gain"]
        )
        return pred.depth + p["depth_offset"], pred.wrinkle_count, pred.converged

    def _prior_residuals(self, u) -> list:
        p = self.physical(u)
        out = []
        if "thickness" in self.names:
            out.append((p["thickness"] - self.thickness) / self.thickness_std)
        if "radius" in self.names:
            out.append((p["radius"] - self.radius) / self.radius_std)
        if "force_gain" in self.names:
            out.append((p["force_gain"] - 1.0) / GAIN_STD)
        return out

    def residuals(self, u, args=None) -> Float[Array, " r"]:
        """Whitened residuals (data and Gaussian priors) for least squares.

        Where the forward model fails every residual is ``FAILED_RESIDUAL``: a finite cost far
        above any fit's, so Levenberg–Marquardt rejects the trial step and shrinks its trust
        region (a NaN would stop it); :meth:`forward_ok` tells a real optimum from such a point.
        """
        return self.residuals_and_prediction(u)[0]

    def residuals_and_prediction(self, u, args=None):
        """(:meth:`residuals`, (predicted depths [m], wrinkle count [-], :meth:`forward_ok`))
        from one evaluation of the forward model."""
        depth, count, converged = self.predict(u)
        parts = [(depth - self.depth) / self.depth_noise, (count - self.counts) / COUNT_NOISE]
        parts += [jnp.atleast_1d(r) for r in self._prior_residuals(u)]
        r = jnp.concatenate(parts)
        r = jnp.where(converged & jnp.all(jnp.isfinite(r)), r, FAILED_RESIDUAL)
        return r, (depth, count, converged & jnp.all(jnp.isfinite(depth)) & jnp.isfinite(count))

    def forward_ok(self, u) -> Bool[Array, ""]:
        """Whether the forward model converged at ``u`` with finite predictions."""
        return self.residuals_and_prediction(u)[1][2]


def build_problem(
    session: Session,
    model: AbstractForwardModel,
    *,
    start_pressure: float,
    start_modulus: float,
    depth_noise: float | None = None,
    nuisance: tuple[str, ...] = (),
) -> InverseProblem:
    """The inverse problem of ``session`` under ``model``, started at P_g [Pa], E [Pa].

    ``depth_noise`` σ_w [m] (None: from the data's scatter); ``nuisance``: any of
    "depth_offset", "force_gain". Thickness and radius are free with normal priors when the
    session gives them a standard deviation.
    """
    unknown = sorted(set(nuisance) - set(OPTIONAL_PARAMETERS))
    if unknown:
        raise InvalidInputError(
            f"unknown nuisance parameter(s) {unknown}. Fix: choose from {list(OPTIONAL_PARAMETERS)}"
        )
    if session.wrinkle_counts is None:
        raise InvalidInputError(
            f"{session.source}: no [wrinkles] counts: the fit needs them to separate E from P_g. "
            "Fix: add one wrinkle count per trial"
        )
    names = ["gauge_pressure", "young_modulus"]
    if session.thickness_std > 0:
        names.append("thickness")
    if session.radius_std > 0:
        names.append("radius")
    names += [n for n in OPTIONAL_PARAMETERS if n in nuisance]
    noise = depth_noise if depth_noise is not None else depth_noise_from_scatter(session.force, session.depth)
    return InverseProblem(
        model=model,
        force=jnp.asarray(session.force),
        depth=jnp.asarray(session.depth),
        counts=jnp.asarray(session.wrinkle_counts, dtype=jnp.float64),
        depth_noise=float(noise),
        thickness=session.thickness,
        thickness_std=session.thickness_std,
        radius=session.radius,
        radius_std=session.radius_std,
        reference_pressure=float(start_pressure),
        reference_modulus=float(start_modulus),
        names=tuple(names),
    )


def jacobian(problem: InverseProblem, u) -> Float[Array, "r d"]:
    """Jacobian of the whitened residuals with respect to u (forward mode)."""
    return jax.jacfwd(problem.residuals)(u)


SAMPLE_QUANTUM = 32  # depth samples are padded to a multiple of this
COUNT_QUANTUM = 8  # wrinkle counts are padded to a multiple of this
ALL_NAMES = ("gauge_pressure", "young_modulus", "thickness", "radius", *OPTIONAL_PARAMETERS)
_PRIORS = ("thickness", "radius", "force_gain")  # the Gaussian prior residuals, in InverseProblem's order


class PaddedProblem(eqx.Module):
    """:class:`InverseProblem` with every per-session size and switch traced, for the fit.

    Every unknown of ``ALL_NAMES`` is present, ``free`` says which are fitted (a fixed one has a
    residual of its own, u, and stays at 0); samples and counts are padded to a multiple of
    ``SAMPLE_QUANTUM`` and ``COUNT_QUANTUM`` with masks (a padded residual is 0). So one compiled
    fit serves every session of a forward model's structure.
    """

    model: AbstractForwardModel
    force: Float[Array, " mp"]
    depth: Float[Array, " mp"]
    sample_mask: Bool[Array, " mp"]
    counts: Float[Array, " kp"]
    count_mask: Bool[Array, " kp"]
    free: Bool[Array, " 6"]
    depth_noise: Float[Array, ""]
    thickness: Float[Array, ""]
    thickness_std: Float[Array, ""]
    radius: Float[Array, ""]
    radius_std: Float[Array, ""]
    reference_pressure: Float[Array, ""]
    reference_modulus: Float[Array, ""]

    def physical(self, u):
        get = dict(zip(ALL_NAMES, jnp.where(self.free, u, 0.0)))
        return {
            "gauge_pressure": self.reference_pressure * jnp.exp(get["gauge_pressure"]),
            "young_modulus": self.reference_modulus * jnp.exp(get["young_modulus"]),
            "thickness": self.thickness * jnp.exp(get["thickness"]),
            "radius": self.radius * jnp.exp(get["radius"]),
            "depth_offset": OFFSET_SCALE * get["depth_offset"],
            "force_gain": jnp.exp(get["force_gain"]),
        }

    def residuals_and_prediction(self, u, args=None):
        """As :meth:`InverseProblem.residuals_and_prediction`, padded: depth rows, count rows,
        then the thickness, radius and gain priors (each 0 where it is not fitted), then u of
        every fixed unknown."""
        p = self.physical(u)
        pred = self.model(
            p["gauge_pressure"], p["young_modulus"], p["thickness"], p["radius"], self.force * p["force_gain"]
        )
        depth = pred.depth + p["depth_offset"]
        on = dict(zip(ALL_NAMES, self.free))
        # a fixed unknown's σ may be 0: its prior row divides by 1 instead
        std = {"thickness": self.thickness_std, "radius": self.radius_std, "force_gain": GAIN_STD}
        mean = {"thickness": self.thickness, "radius": self.radius, "force_gain": 1.0}
        priors = jnp.stack([(p[n] - mean[n]) / jnp.where(on[n], std[n], 1.0) for n in _PRIORS])
        mask = jnp.concatenate([self.sample_mask, self.count_mask, jnp.stack([on[n] for n in _PRIORS])])
        r = jnp.concatenate([(depth - self.depth) / self.depth_noise, pred.wrinkle_count - self.counts, priors])
        r = jnp.where(mask, r, 0.0)
        converged = pred.converged
        ok = converged & jnp.all(jnp.isfinite(r))
        r = jnp.where(mask, jnp.where(ok, r, FAILED_RESIDUAL), 0.0)
        # a fixed unknown is pinned at 0 by a residual of its own: a zero Jacobian column would
        # leave Levenberg–Marquardt's damped system singular as its damping vanishes
        r = jnp.concatenate([r, jnp.where(self.free, 0.0, u)])
        finite = jnp.all(jnp.isfinite(jnp.where(self.sample_mask, depth, 0.0))) & jnp.isfinite(pred.wrinkle_count)
        return r, (depth, pred.wrinkle_count, converged & finite)

    def forward_ok(self, u) -> Bool[Array, ""]:
        return self.residuals_and_prediction(u)[1][2]

    def log_posterior(self, u_and_noise: Float[Array, " 7"]) -> tuple[Float[Array, ""], Bool[Array, ""]]:
        """Log posterior [-] (up to a constant) of (u, log σ_w) and whether the forward model
        converged: Gaussian depths of standard deviation σ_w [m], the integer counts'
        :func:`count_log_likelihood`, the normal priors of the fitted thickness, radius and gain,
        log-uniform P_g, E and σ_w within their bounds (−∞ outside them or where the forward
        model failed). Padded samples and counts and fixed unknowns contribute nothing."""
        u, log_noise = u_and_noise[:-1], u_and_noise[-1]
        p = self.physical(u)
        in_bounds = (
            (p["gauge_pressure"] > PRESSURE_BOUNDS[0])
            & (p["gauge_pressure"] < PRESSURE_BOUNDS[1])
            & (p["young_modulus"] > MODULUS_BOUNDS[0])
            & (p["young_modulus"] < MODULUS_BOUNDS[1])
            & (log_noise > math.log(DEPTH_NOISE_BOUNDS[0]))
            & (log_noise < math.log(DEPTH_NOISE_BOUNDS[1]))
            & (jnp.abs(p["depth_offset"]) < OFFSET_BOUND)
        )
        pred = self.model(
            p["gauge_pressure"], p["young_modulus"], p["thickness"], p["radius"], self.force * p["force_gain"]
        )
        depth_misfit = jnp.where(
            self.sample_mask, (pred.depth + p["depth_offset"] - self.depth) * jnp.exp(-log_noise), 0.0
        )
        log_like = -0.5 * jnp.sum(depth_misfit**2) - jnp.sum(self.sample_mask, dtype=log_noise.dtype) * log_noise
        log_like += jnp.sum(jnp.where(self.count_mask, count_log_likelihood(self.counts, pred.wrinkle_count), 0.0))
        on = dict(zip(ALL_NAMES, self.free))
        std = {"thickness": self.thickness_std, "radius": self.radius_std, "force_gain": GAIN_STD}
        mean = {"thickness": self.thickness, "radius": self.radius, "force_gain": 1.0}
        # uniform priors in log P, log E, log σ_w are log-uniform in the physical values
        log_prior = sum(
            jnp.where(on[n], -0.5 * ((p[n] - mean[n]) / jnp.where(on[n], std[n], 1.0)) ** 2, 0.0) for n in _PRIORS
        )
        log_p = log_like + log_prior
        ok = in_bounds & pred.converged & jnp.isfinite(log_p)
        return jnp.where(ok, log_p, -jnp.inf), pred.converged


def _pad(values, quantum: int, fill: float):
    n = values.shape[0]
    size = max(-(-n // quantum), 1) * quantum
    return jnp.concatenate([jnp.asarray(values, jnp.float64), jnp.full(size - n, fill)]), jnp.arange(size) < n


def padded_problem(problem: InverseProblem) -> tuple[PaddedProblem, np.ndarray, np.ndarray]:
    """(the padded problem, the indices of ``problem``'s unknowns in its u, the indices of
    ``problem``'s residuals in its residual vector)."""
    force, sample_mask = _pad(problem.force, SAMPLE_QUANTUM, float(problem.force[0]))
    depth, _ = _pad(problem.depth, SAMPLE_QUANTUM, 0.0)
    counts, count_mask = _pad(problem.counts, COUNT_QUANTUM, 0.0)
    f = lambda v: jnp.asarray(v, jnp.float64)  # noqa: E731
    padded = PaddedProblem(
        model=problem.model,
        force=force,
        depth=depth,
        sample_mask=sample_mask,
        counts=counts,
        count_mask=count_mask,
        free=jnp.asarray([n in problem.names for n in ALL_NAMES]),
        depth_noise=f(problem.depth_noise),
        thickness=f(problem.thickness),
        thickness_std=f(problem.thickness_std),
        radius=f(problem.radius),
        radius_std=f(problem.radius_std),
        reference_pressure=f(problem.reference_pressure),
        reference_modulus=f(problem.reference_modulus),
    )
    columns = np.asarray([ALL_NAMES.index(n) for n in problem.names])
    m, k, mp, kp = problem.force.shape[0], problem.counts.shape[0], force.shape[0], counts.shape[0]
    priors = [mp + kp + j for j, n in enumerate(_PRIORS) if n in problem.names]
    rows = np.concatenate([np.arange(m), mp + np.arange(k), np.asarray(priors, int)])
    return padded, columns, rows
