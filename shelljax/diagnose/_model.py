"""The joint forward model of a study: every session through the axisymmetric engine at once.

E, h, R and the effect parameters are shared by the sessions; each has its own gauge pressure.
Every candidate effect is a traced value of this one model (see ``_effects``), so one compiled
program serves the baseline, every candidate and every object:

* the engine runs at a fixed reference radius R_REF and reaches a session's radius R by
  similarity (lengths × s = R/R_REF, forces × s², pressures unchanged; ``estimate._forward``),
  the finger's radius included; only the contact penalty is not rescaled (its penetration,
  contact pressure / 1e11 N/m³ ≈ 10 nm, is far below any measured length);
* each session's curve is solved on one fixed grid of forces (reference frame) and interpolated
  at the true forces of its samples (the F–w(0) curve is smooth: the interpolation error is far
  below the depth noise).

Measurement model of a depth sample recorded at force F [N]: the true force is
F_t = g F_ref (F / F_ref)^p (``force_sensor_gain`` g, ``force_sensor_nonlinearity`` p; F_ref the
study's mid force), and the depth read is w0(F_t) + δ + c F_ref (F_t / F_ref)^q (``depth_offset``
δ, ``finger_compliance`` c, a pad compressing c F_t when linear, q = 1, the default; a rig model
(``shelljax.rig``) may free q). A rig's calibrated parameters enter as a correlated normal prior:
``rig_whitening`` L and ``rig_mean`` μ add the residuals L (u − μ). Wrinkle counts are the paper's n = 1.33 τ^½ ("scaling") or the
engine's count at the top force ("mechanics"); shape observables come from the engine's state.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..axisym import CurvePhysics, Setup, indentation_curves_raw, inflation_stretch
from ..physics import (
    STANDARD_GRAVITY,
    AbstractGasLaw,
    IsothermalGas,
    PolytropicGas,
    ShellProperties,
    Similarity,
    scaling_wrinkle_count,
)
from ..estimate import FAILED_RESIDUAL, count_log_likelihood
from ..paper import PAPER_INDENTER_RADIUS
from ._effects import (
    FREE_THICKNESS_STD,
    FRICTION_REFERENCE,
    GLOBAL_PARAMETERS,
    LINEAR_SCALE,
    LOG_PARAMETERS,
    MANOMETER_STD,
    MIN_INDENTER_FRACTION,
    PRIOR_STD,
    UNWEIGHED_MASS,
    UNWEIGHED_MASS_STD,
    WEIGHED_MASS_STD,
)
from ._study import Study

R_REF = 0.2  # [m] the engine's radius; every object is reached by similarity
N_GRID = 12  # forces per curve
# the grid covers [0.5 F_min, 1.7 F_max], as the rig's calibration: a sensor reading 1.5x low at the
# top force (gain and exponent together) lies inside it; beyond the grid a curve is clamped at its end
GRID_SPAN = (0.5, 1.7)
N_ELEMENTS = 101  # meridian elements, as the fitted estimator's forward model
_INDEX = {name: i for i, name in enumerate(GLOBAL_PARAMETERS)}


class StudyArrays(eqx.Module):
    """A study's data and priors as arrays (see ``_study.Study``; every value SI).

    ``prior_mean``/``prior_std`` of u (std = inf: flat), ``free`` mask, ``u_base`` (the value of
    every fixed entry), references for u = 0: ``start_pressure`` [Pa], ``start_modulus`` [Pa],
    ``thickness`` [m], ``radius`` [m] per session, ``mass_ref`` [kg], ``indenter_radius`` [m],
    ``gas_exponent`` κ₀ [-]; ``force_ref`` [N]; ``grid`` [N] in the reference frame;
    ``rig_whitening`` (u, u) and ``rig_mean`` (u,): a correlated prior L (u − μ) on the entries of a
    calibrated rig (zeros: none).
    """

    depth_session: Int[Array, " n"]
    depth_unit: Int[Array, " n"]
    force: Float[Array, " n"]
    depth: Float[Array, " n"]
    whitening: Float[Array, "n n"]
    count_session: Int[Array, " c"]
    count_unit: Int[Array, " c"]
    count: Float[Array, " c"]
    shape_session: Int[Array, " k"]
    shape_unit: Int[Array, " k"]
    shape_kind: Int[Array, " k"]
    shape_force: Float[Array, " k"]
    shape_value: Float[Array, " k"]
    shape_std: Float[Array, " k"]
    depth_unit_constant: Float[Array, " units"]
    radius: Float[Array, " s"]
    start_pressure: Float[Array, " s"]
    start_modulus: Float[Array, ""]
    thickness: Float[Array, ""]
    poisson_ratio: Float[Array, ""]
    mass_ref: Float[Array, ""]
    indenter_radius: Float[Array, ""]
    gas_exponent: Float[Array, ""]
    gas_volume_ratio: Float[Array, ""]
    force_ref: Float[Array, ""]
    grid: Float[Array, " g"]
    prior_mean: Float[Array, " u"]
    prior_std: Float[Array, " u"]
    free: Bool[Array, " u"]
    u_base: Float[Array, " u"]
    rig_whitening: Float[Array, "u u"]
    rig_mean: Float[Array, " u"]
    n_units: int = eqx.field(static=True)


def study_arrays(
    study: Study,
    *,
    gas: AbstractGasLaw = IsothermalGas(),
    indenter_radius: float = PAPER_INDENTER_RADIUS,
    force_ref: float | None = None,
    manometer_std: float = MANOMETER_STD,
) -> StudyArrays:
    """The arrays of ``study`` with the baseline's priors (free mask: gauge pressures only).

    ``gas``: the baseline's gas law (a ``physics.AbstractGasLaw``: its κ [-] is the engine's);
    ``force_ref`` [N]: the force about which the sensor's and the pad's power laws are written
    (None: the study's mid force; a rig carries its own to every later study); ``manometer_std``
    [-]: the manometer readings' relative standard deviation.
    """
    s = study.n_sessions
    n_u = s + len(GLOBAL_PARAMETERS)
    mean, std = np.zeros(n_u), np.full(n_u, np.inf)
    manometer = np.isfinite(study.manometer)
    std[:s] = np.where(manometer, manometer_std, np.inf)
    g = {name: s + i for i, name in enumerate(GLOBAL_PARAMETERS)}
    std[g["thickness"]] = study.thickness_std / study.thickness if study.thickness_std > 0 else FREE_THICKNESS_STD
    std[g["radius"]] = study.radius_std / float(np.mean(study.radius)) if study.radius_std > 0 else np.inf
    for name, value in PRIOR_STD.items():
        std[g[name]] = value
    std[g["body_mass"]] = WEIGHED_MASS_STD if study.mass is not None else UNWEIGHED_MASS_STD
    # the whitened depth block of a unit has log-density −½‖W r‖² + log|det W| − n/2 log 2π
    constant = np.zeros(study.n_units)
    for u in range(study.n_units):
        idx = np.flatnonzero(study.depth_unit == u)
        if idx.size:
            block = study.whitening[np.ix_(idx, idx)]
            constant[u] = np.sum(np.log(np.abs(np.diag(block)))) - 0.5 * idx.size * math.log(2 * math.pi)
    levels = np.unique(study.level)
    force_ref = math.sqrt(levels[0] * levels[-1]) if force_ref is None else float(force_ref)
    f = lambda v: jnp.asarray(v, jnp.float64)  # noqa: E731
    i = lambda v: jnp.asarray(v, jnp.int32)  # noqa: E731
    return StudyArrays(
        depth_session=i(study.depth_session),
        depth_unit=i(study.depth_unit),
        force=f(study.force),
        depth=f(study.depth),
        whitening=f(study.whitening),
        count_session=i(study.count_session),
        count_unit=i(study.count_unit),
        count=f(study.count),
        shape_session=i(study.shape_session),
        shape_unit=i(study.shape_unit),
        shape_kind=i(study.shape_kind),
        shape_force=f(study.shape_force),
        shape_value=f(study.shape_value),
        shape_std=f(study.shape_std),
        depth_unit_constant=f(constant),
        radius=f(study.radius),
        start_pressure=f(study.start_pressure),
        start_modulus=f(study.start_modulus),
        thickness=f(study.thickness),
        poisson_ratio=f(study.poisson_ratio),
        mass_ref=f(study.mass if study.mass is not None else UNWEIGHED_MASS),
        indenter_radius=f(indenter_radius),
        gas_exponent=f(gas.exponent),
        gas_volume_ratio=f(study.gas_volume_ratio),
        force_ref=f(force_ref),
        grid=f(np.linspace(*engine_force_bounds(study.radius, study.force, GRID_SPAN), N_GRID)),
        prior_mean=f(mean),
        prior_std=f(std),
        free=jnp.asarray(np.arange(n_u) < s),
        u_base=f(np.zeros(n_u)),
        rig_whitening=f(np.zeros((n_u, n_u))),
        rig_mean=f(np.zeros(n_u)),
        n_units=study.n_units,
    )


def physical(u: Float[Array, " u"], data: StudyArrays) -> dict[str, Float[Array, "..."]]:
    """Physical values (SI) of every unknown at u (fixed entries at their baseline value)."""
    u = jnp.where(data.free, u, data.u_base)
    s = data.start_pressure.shape[0]
    get = {name: u[s + i] for i, name in enumerate(GLOBAL_PARAMETERS)}
    out = {"gauge_pressure": data.start_pressure * jnp.exp(u[:s])}
    refs = {
        "young_modulus": data.start_modulus,
        "thickness": data.thickness,
        "radius": 1.0,
        "force_gain": 1.0,
        "indenter_radius": data.indenter_radius,
        "body_mass": data.mass_ref,
        "friction_coefficient": FRICTION_REFERENCE,
    }
    for name in GLOBAL_PARAMETERS:
        if name in LOG_PARAMETERS:
            out[name] = refs[name] * jnp.exp(get[name])
        else:
            out[name] = LINEAR_SCALE[name] * get[name]
    out["radius"] = data.radius * out["radius"]  # per session
    out["indenter_radius"] = data.indenter_radius * (
        MIN_INDENTER_FRACTION + (1 - MIN_INDENTER_FRACTION) * jnp.exp(get["indenter_radius"])
    )
    out["force_exponent"] = 1.0 + out["force_exponent"]
    out["pad_exponent"] = 1.0 + out["pad_exponent"]
    out["gas_exponent"] = data.gas_exponent + out["gas_exponent"]
    # self-weight and ground friction are on only when their parameter is free
    for name in ("body_mass", "friction_coefficient"):
        out[name] = jnp.where(data.free[s + _INDEX[name]], out[name], 0.0)
    return out


def true_force(recorded, phys, data: StudyArrays):
    """F_t [N] from a recorded force [N]: gain and power-law response about F_ref."""
    return phys["force_gain"] * data.force_ref * (recorded / data.force_ref) ** phys["force_exponent"]


def pad_compression(force, phys, data: StudyArrays):
    """The finger pad's compression [m] under the true force [N]: c F_ref (F / F_ref)^q."""
    return phys["finger_compliance"] * data.force_ref * (force / data.force_ref) ** phys["pad_exponent"]


def engine_force_bounds(radius, forces, span: tuple[float, float]) -> tuple[float, float]:
    """The ends [N] of the engine's force grid (its frame) covering, by ``span``, the true
    ``forces`` [N] on balls of every session's ``radius`` [m]: the smallest force on the largest
    ball to the largest on the smallest."""
    scale = Similarity.between(np.asarray(radius), R_REF).scale
    lo = span[0] * float(np.min(forces)) / float(np.max(scale)) ** 2
    hi = span[1] * float(np.max(forces)) / float(np.min(scale)) ** 2
    return lo, hi


def engine_inputs(phys, data: StudyArrays):
    """The engine's ShellProperties (fields (s,): P_g, E, h/scale, ν) and the CurvePhysics of every session."""
    similarity = Similarity.between(phys["radius"], R_REF)
    pressure, young, thick, nu = phys["gauge_pressure"], phys["young_modulus"], phys["thickness"], data.poisson_ratio
    shell = ShellProperties(
        gauge_pressure=pressure,
        young_modulus=jnp.broadcast_to(young, pressure.shape),
        thickness=similarity.length_to_engine(thick),
        poisson_ratio=jnp.broadcast_to(nu, pressure.shape),
    )
    stretch = jax.vmap(lambda p, r: inflation_stretch(p, r, young, thick, nu))(pressure, phys["radius"])
    rest_area = 4.0 * jnp.pi * (phys["radius"] / stretch) ** 2
    ones = jnp.ones_like(pressure)
    physics = CurvePhysics(
        indenter_radius=similarity.length_to_engine(phys["indenter_radius"]),
        gas_volume_ratio=data.gas_volume_ratio * ones,
        gas_exponent=phys["gas_exponent"] * ones,
        stiffening=phys["stiffening"] * ones,
        areal_weight=phys["body_mass"] * STANDARD_GRAVITY / rest_area,
        friction_coefficient=phys["friction_coefficient"] * ones,
    )
    return shell, physics


def engine_setup() -> Setup:
    """The engine's static setup: reference radius, sealed polytropic gas, relaxed wrinkling."""
    return Setup(radius=R_REF, n_elements=N_ELEMENTS, gas=PolytropicGas(), indenter_radius=PAPER_INDENTER_RADIUS)


def solve_curves(shell: ShellProperties, physics, data: StudyArrays, chunk: int = 0):
    """The engine's curves on the study's grid (reference frame), one per session (or draw)."""
    return indentation_curves_raw(shell, data.grid, engine_setup(), chunk, physics=physics)


def _at(curves_field, session, force_ref, grid):
    """A curve field interpolated at reference-frame forces of samples of the given sessions."""
    return jax.vmap(lambda s, f: jnp.interp(f, grid, curves_field[s]))(session, force_ref)


def predict(u, data: StudyArrays, curves, wrinkle_law: str):
    """Predictions at u from the sessions' curves: depth [m], count [-], shape [m], the
    sample's wrinkled regime (bool) and whether every needed force level converged."""
    phys = physical(u, data)
    similarity = Similarity.between(phys["radius"], R_REF)
    at_depth, at_shape = similarity.at(data.depth_session), similarity.at(data.shape_session)
    f_true = true_force(data.force, phys, data)
    f_ref = at_depth.force_to_engine(f_true)
    w0 = at_depth.length_from_engine(_at(curves.w0, data.depth_session, f_ref, data.grid))
    depth = w0 + phys["depth_offset"] + pad_compression(f_true, phys, data)
    wrinkled = _at(curves.min_hoop_tension, data.depth_session, f_ref, data.grid) < 0.0
    n_sessions = phys["radius"].shape[0]
    top = jax.ops.segment_max(f_ref, data.depth_session, num_segments=n_sessions)
    if wrinkle_law == "scaling":
        per_session = scaling_wrinkle_count(
            phys["gauge_pressure"], phys["radius"], phys["young_modulus"], phys["thickness"], data.poisson_ratio
        )
    else:
        per_session = jax.vmap(lambda n, f: jnp.interp(f, data.grid, n))(curves.wrinkle_count, top)
    count = per_session[data.count_session]
    shape_fields = jnp.stack([curves.height, curves.upper_diameter, curves.contact_diameter, curves.sunken_depth])
    shape_ref = at_shape.force_to_engine(true_force(data.shape_force, phys, data))
    shape = at_shape.length_from_engine(
        jax.vmap(lambda k, s, f: jnp.interp(f, data.grid, shape_fields[k, s]))(
            data.shape_kind, data.shape_session, shape_ref
        )
    )
    # every grid level up to one above the largest force a session needs must have converged
    needed = jnp.maximum(top, jax.ops.segment_max(shape_ref, data.shape_session, num_segments=n_sessions))
    step = data.grid[1] - data.grid[0]
    ok = jnp.all(curves.converged | (data.grid[None, :] > needed[:, None] + step))
    ok = ok & jnp.all(jnp.isfinite(depth)) & jnp.all(jnp.isfinite(count)) & jnp.all(jnp.isfinite(shape))
    return dict(depth=depth, count=count, shape=shape, wrinkled=wrinkled), ok


def prior_residuals(u, data: StudyArrays):
    """(u − μ)/σ of every free entry with a proper prior, 0 elsewhere; then the rig's L (u − μ_rig)."""
    finite = jnp.isfinite(data.prior_std) & data.free
    independent = jnp.where(finite, (u - data.prior_mean) / jnp.where(finite, data.prior_std, 1.0), 0.0)
    rig = data.rig_whitening @ (jnp.where(data.free, u, data.u_base) - data.rig_mean)
    return jnp.concatenate([independent, rig])


def data_residuals(pred, data: StudyArrays):
    """Whitened residuals: depth (W r, by trial), counts (σ_n = 1), shape (r / σ)."""
    return (
        data.whitening @ (pred["depth"] - data.depth),
        pred["count"] - data.count,
        (pred["shape"] - data.shape_value) / data.shape_std,
    )


def unit_log_likelihood(pred, data: StudyArrays):
    """Log-likelihood [-] of each leave-one-out unit (trial): its depths, count and shape points."""
    depth_white, _, shape_white = data_residuals(pred, data)
    ll = jax.ops.segment_sum(-0.5 * depth_white**2, data.depth_unit, num_segments=data.n_units)
    ll = ll + data.depth_unit_constant
    ll = ll + jax.ops.segment_sum(
        count_log_likelihood(data.count, pred["count"]), data.count_unit, num_segments=data.n_units
    )
    shape_ll = -0.5 * shape_white**2 - jnp.log(data.shape_std) - 0.5 * math.log(2 * math.pi)
    return ll + jax.ops.segment_sum(shape_ll, data.shape_unit, num_segments=data.n_units)


class JointProblem(eqx.Module):
    """Least-squares form of a study for ``estimate.solve_least_squares``: whitened data and
    prior residuals at u, with (predictions, forward model finite) as aux."""

    data: StudyArrays
    wrinkle_law: str = eqx.field(static=True)

    def residuals_and_prediction(self, u, args=None):
        shell, physics = engine_inputs(physical(u, self.data), self.data)
        pred, ok = predict(u, self.data, solve_curves(shell, physics, self.data), self.wrinkle_law)
        r = jnp.concatenate([*data_residuals(pred, self.data), prior_residuals(u, self.data)])
        ok = ok & jnp.all(jnp.isfinite(r))
        return jnp.where(ok, r, FAILED_RESIDUAL), (pred, ok)


def log_prior(u, data: StudyArrays):
    """Log prior density [-] of u up to a constant (flat where the prior std is infinite)."""
    return -0.5 * jnp.sum(prior_residuals(u, data) ** 2)
