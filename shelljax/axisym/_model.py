"""Force-controlled indentation of an inflated ball resting on the ground: set-up and curves.

Set-up (the paper's finger poke and its Fig. "elasticity" (b) vertical indentation): a closed
Neo-Hookean sphere of inflated radius R [m] at gauge pressure P_g [Pa] rests on a rigid ground
plane (bottom pole) and a rigid spherical indenter of radius a [m] pushes the top pole down with
force F [N] (force control: the indenter height is an unknown loaded by F). Contact is an
area-weighted penalty: contact pressure = k_c × penetration, so the penetration bound is
(contact pressure) / k_c [m]. The observables of each level are defined in :mod:`._observables`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxtyping import Array, Float

from .._errors import InvalidInputError
from ..paper import PAPER_INDENTER_RADIUS
from ..physics import AbstractGasLaw, AdiabaticGas, PolytropicGas, PrescribedGas, ShellProperties
from ._energy import (
    WRINKLED_HOOP_CAPACITY,
    Config,
    Params,
    enclosed_volume,
    ground_normal_forces,
    rest_nodes,
    rest_zone_areas,
    split,
)
from ._geometry import unit_polar_angles
from ._inflation import inflation_stretch
from ._linalg import structured_solve
from ._newton import SolverOptions, equilibrium, hessian_at
from ._observables import observables
from ._tracing import tied_to


# ε / R [-]: the 3D engine's default slip tolerance (4 µm on the 0.13 m ball, docs/shell3d.md) in
# units of the radius, so similar balls stay similar.
FRICTION_SLIP_TOLERANCE = 4e-6 / 0.13


class Setup(eqx.Module):
    """Static description of an indentation experiment on a ball (all lengths in m).

    ``radius`` R: inflated radius; ``n_elements``: meridian elements pole to pole (made odd);
    ``grading`` ∈ [0, 1): refinement towards the poles; ``gas``: a ``physics.AbstractGasLaw``,
    ``PrescribedGas()`` (constant P_g, the paper's model), ``IsothermalGas()`` or ``AdiabaticGas()``
    (sealed ideal gas, P_g is the gauge pressure before indentation), or ``PolytropicGas(κ)``
    (sealed gas with p V^κ constant, κ the traced ``CurvePhysics.gas_exponent``, by default the
    law's own, so that one program serves every law; the adiabatic gas is this program with
    κ = γ unless ``CurvePhysics.gas_exponent`` says otherwise); ``relax``:
    relaxation of compressive hoop stress (wrinkled shell), which saturates at ``hoop_capacity``
    [-] classical buckling resultants E h²/(R0 √(3(1−ν²))) (default calibrated on a 3D curve,
    see ``_energy.WRINKLED_HOOP_CAPACITY``; 0: tension field);
    ``indenter_radius`` a (the default of the traced ``CurvePhysics.indenter_radius``, and the
    Newton step cap); ``contact_stiffness`` k_c [N/m³]; ``ramp``: fractions of the first
    force solved first (load stepping; none by default: the flattened start converges without);
    ``atol`` [N]: Newton tolerance on the out-of-balance force; ``max_steps``: Newton iterations
    per load step; ``predictor``: "none" (start from the last converged state: the most robust),
    "secant" (extrapolate the last two states) or "tangent" (Euler step);
    ``substeps``: equal load steps per interval between requested forces (raise it when the
    requested forces are far apart; the paper's 2.5 N steps need 1); ``friction_slip_tolerance`` ε
    [m]: slip below which a node sticks to the ground under friction (``CurvePhysics.
    friction_coefficient``; None: ``FRICTION_SLIP_TOLERANCE`` × R, the 3D engine's default scaled).
    """

    radius: float = eqx.field(static=True, default=0.13)
    n_elements: int = eqx.field(static=True, default=101)
    grading: float = eqx.field(static=True, default=0.85)
    gas: AbstractGasLaw = eqx.field(static=True, default=PrescribedGas())
    relax: bool = eqx.field(static=True, default=True)
    indenter_radius: float = eqx.field(static=True, default=PAPER_INDENTER_RADIUS)
    contact_stiffness: float = eqx.field(static=True, default=1e11)
    ramp: tuple = eqx.field(static=True, default=())
    atol: float = eqx.field(static=True, default=1e-7)
    max_steps: int = eqx.field(static=True, default=100)
    predictor: str = eqx.field(static=True, default="none")
    substeps: int = eqx.field(static=True, default=1)
    hoop_capacity: float = eqx.field(static=True, default=WRINKLED_HOOP_CAPACITY)
    friction_slip_tolerance: float | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        if not isinstance(self.gas, AbstractGasLaw):
            raise InvalidInputError(
                f"Setup: gas = {self.gas!r} is no gas law. Fix: pass a physics.AbstractGasLaw, e.g. "
                "physics.IsothermalGas(), or physics.gas_law(name) for a name"
            )
        if not (math.isfinite(self.indenter_radius) and self.indenter_radius > 0):
            raise InvalidInputError(
                f"Setup: indenter_radius = {self.indenter_radius!r} must be a positive length [m]. "
                f"Fix: pass the finger's radius, e.g. {PAPER_INDENTER_RADIUS}"
            )
        if not (math.isfinite(self.hoop_capacity) and self.hoop_capacity >= 0):
            raise InvalidInputError(
                f"Setup: hoop_capacity = {self.hoop_capacity!r} must be a number >= 0 (hoop compression "
                "of the wrinkled wall in classical buckling resultants). Fix: 0 for a tension field, "
                f"or the calibrated default {WRINKLED_HOOP_CAPACITY}"
            )
        eps = self.friction_slip_tolerance
        if eps is not None and not (math.isfinite(eps) and eps > 0):
            raise InvalidInputError(
                f"Setup: friction_slip_tolerance = {eps!r} must be a positive length [m]. "
                f"Fix: None for the default {FRICTION_SLIP_TOLERANCE:.3g} × radius"
            )

    def slip_tolerance(self) -> float:
        """Ground friction slip tolerance ε [m]."""
        eps = self.friction_slip_tolerance
        return FRICTION_SLIP_TOLERANCE * self.radius if eps is None else float(eps)

    def theta(self) -> tuple:
        n_el = self.n_elements + (1 - self.n_elements % 2)
        return tuple(float(t) for t in unit_polar_angles(n_el, self.grading))

    def options(self) -> SolverOptions:
        # Newton steps capped at one indenter radius of motion relative to the indenter
        # (_newton._step_cap), between tunnelling and slow steps (docs/axisym.md, *Solver*)
        return SolverOptions(self.atol, self.max_steps, 30, self.indenter_radius)


class CurvePhysics(eqx.Module):
    """Per-curve physical effects, traced: one compiled program serves every value.

    Each field is a scalar for :func:`curve_single` and has shape (batch,) for
    :func:`~shelljax.axisym.indentation_curves_raw`. ``indenter_radius`` a [m] (the finger);
    ``gas_volume_ratio`` [-] (sealed gas volume over 4/3 π R³, the sealed gases: 1 for a ball, an
    object's enclosed volume over 4/3 π R³ when only its poke region is a sphere); ``gas_exponent``
    κ [-] (the polytropic and adiabatic gases: p V^κ constant; 0 is the prescribed gauge pressure,
    1 isothermal, 1.4 adiabatic, ``physics.AbstractGasLaw.exponent``); ``stiffening`` s = 1/J_m
    [-] (Gent stiffening of the membrane, ``physics.gent_membrane_invariants``; 0: Neo-Hookean);
    ``areal_weight`` q = ρ h g [Pa] (self-weight per unit rest area along −z, acting while the
    ball rests on the ground; 0: no gravity); ``friction_coefficient`` μ [-] (Coulomb friction of
    the ground, smoothed and lagged per load step, ``_energy.ground_friction_energy``; 0, the
    default: frictionless); ``contact_stiffness`` k_c [N/m³] (None: the Setup's, a compile-time
    constant). Every field has a default: ``indenter_radius`` None is the Setup's finger and
    ``gas_exponent`` None the κ of the Setup's gas (if it compiles to the polytropic program);
    :meth:`resolved` fills them in, :meth:`defaults` is the default physics.

    Similarity (``estimate._forward``): a ball ``scale`` times larger in every length, at the same
    pressures and moduli, has a ``scale`` times larger finger and the same κ, s, q and volume
    ratio and μ, and a contact stiffness k_c [N/m³] ÷ scale (:meth:`similar`); its forces are
    scale² and its depths scale times as large.
    """

    indenter_radius: Float[Array, "*batch"] | None = None
    gas_volume_ratio: Float[Array, "*batch"] = 1.0
    gas_exponent: Float[Array, "*batch"] | None = None
    stiffening: Float[Array, "*batch"] = 0.0
    areal_weight: Float[Array, "*batch"] = 0.0
    friction_coefficient: Float[Array, "*batch"] = 0.0
    contact_stiffness: Float[Array, "*batch"] | None = None

    def resolved(self, setup: Setup, batch: int | None = None) -> "CurvePhysics":
        """Every field a float64 array, of shape (batch,) when ``batch`` is given: the finger and κ
        left None are ``setup``'s (its finger, its gas's κ); ``contact_stiffness`` may stay None."""
        # the prescribed and isothermal programs never read κ: they keep the polytropic default, 1
        kappa = setup.gas.exponent if isinstance(_compiled_gas(setup.gas), PolytropicGas) else PolytropicGas().exponent
        filled = dataclasses.replace(
            self,
            indenter_radius=setup.indenter_radius if self.indenter_radius is None else self.indenter_radius,
            gas_exponent=kappa if self.gas_exponent is None else self.gas_exponent,
        )

        def array(v):
            v = jnp.asarray(v, jnp.float64)
            return v if batch is None else jnp.broadcast_to(v, (int(batch),))

        return jax.tree_util.tree_map(array, filled)

    @classmethod
    def defaults(cls, setup: Setup, batch: int | None = None) -> "CurvePhysics":
        """``setup``'s finger and gas κ, volume ratio 1, s = 0, q = 0, μ = 0: scalars, or (batch,);
        the contact stiffness None (the Setup's, a compile-time constant)."""
        return cls().resolved(setup, batch)

    def similar(self, scale) -> "CurvePhysics":
        """The physics of the similar ball with every length times ``scale`` [-]: a × scale, and
        k_c ÷ scale where it is set."""
        out = eqx.tree_at(lambda c: c.indenter_radius, self, self.indenter_radius * scale)
        if self.contact_stiffness is None:
            return out
        return eqx.tree_at(lambda c: c.contact_stiffness, out, self.contact_stiffness / scale)


def _params(
    young,
    thick,
    nu,
    rest_radius,
    pressure,
    setup,
    *,
    force=0.0,
    ref_volume=1.0,
    ground_z=0.0,
    bending_scale=1.0,
    physics: CurvePhysics | None = None,
):
    f = lambda v: jnp.asarray(v, dtype=jnp.float64)  # noqa: E731
    physics = CurvePhysics.defaults(setup) if physics is None else physics.resolved(setup)
    stiffness = setup.contact_stiffness if physics.contact_stiffness is None else physics.contact_stiffness
    return Params(
        f(young),
        f(thick),
        f(nu),
        f(rest_radius),
        f(pressure),
        f(ref_volume),
        f(force),
        f(physics.indenter_radius),
        f(ground_z),
        f(stiffness),
        f(bending_scale),
        f(physics.gas_volume_ratio),
        f(physics.gas_exponent),
        f(physics.stiffening),
        f(physics.areal_weight),
        f(physics.friction_coefficient),
        friction_slip_tolerance=f(setup.slip_tolerance()),
    )


def _shell(properties: ShellProperties, setup: Setup, caller: str):
    """(P_g [Pa], E [Pa], h [m], ν [-]) of ``properties``, whose radius, if it has one, must be
    the Setup's: the engine's radius is static (the mesh), the properties' traced."""
    if not isinstance(properties, ShellProperties):
        raise InvalidInputError(
            f"{caller}: expected a physics.ShellProperties, got {type(properties).__name__}. "
            "Fix: ShellProperties(gauge_pressure=…, young_modulus=…, thickness=…, poisson_ratio=…)"
        )
    if properties.radius is not None and not isinstance(properties.radius, jax.Array):
        if np.any(np.asarray(properties.radius, dtype=float) != float(setup.radius)):
            raise InvalidInputError(
                f"{caller}: properties.radius = {properties.radius!r} m is not the Setup's radius "
                f"{setup.radius!r} m. Fix: leave it None or pass Setup(radius=…) the same value"
            )
    return properties.gauge_pressure, properties.young_modulus, properties.thickness, properties.poisson_ratio


def inflate(setup: Setup, properties: ShellProperties, bending_scale=1.0, guesses=None, stiffening=0.0):
    """Inflated (pre-indentation) state of the discrete sphere of ``properties`` (scalar fields;
    the radius is ``setup.radius``).

    Returns (rest radius R0 [m], inflated unknowns y [m], residual [N], iterations). The bottom
    pole height is pinned at −R (rigid mode); nothing touches the ball (the indenter's z_c is
    parked 10 R above it). Solved by the indentation's Newton (``Params.inflating``), from the
    lowest-energy of the continuous sphere's stretch and ``guesses`` (c, n_y) [m] (NaN: none).
    ``stiffening`` s [-]: Gent stiffening of the membrane (0: Neo-Hookean); the rest radius
    R0 = R/λ comes from the same law.
    """
    pressure, young, thick, nu = _shell(properties, setup, "inflate")
    physics = eqx.tree_at(lambda c: c.stiffening, CurvePhysics.defaults(setup), jnp.asarray(stiffening, jnp.float64))
    r0, y0, p = _inflation(setup, pressure, young, thick, nu, bending_scale, physics)
    if guesses is not None:
        y0 = jnp.concatenate([y0[None], jax.lax.stop_gradient(guesses)])
    sol = equilibrium(_indentation_config(setup), setup.options(), p, y0)
    return r0, sol.value, sol.stats["residual"], sol.iterations


def _inflation(setup: Setup, pressure, young, thick, nu, bending_scale, physics: CurvePhysics):
    """(rest radius R0 [m], Newton's start [m], Params) of the inflation, solved in the
    indentation's configuration (``Params.inflating``): the continuous sphere's stretch, the gas at
    its gauge pressure, no contact stiffness, load, weight or friction, and the ground and the
    indenter parked 10 R away."""
    lam = inflation_stretch(pressure, setup.radius, young, thick, nu, bending_scale, stiffening=physics.stiffening)
    r0 = setup.radius / lam
    far = 10.0 * setup.radius
    # (the sealed gas's reference volume is not used while inflating; the ball's keeps it finite)
    p = _params(
        young,
        thick,
        nu,
        r0,
        pressure,
        setup,
        ground_z=-far,
        bending_scale=bending_scale,
        physics=physics,
        ref_volume=4.0 / 3.0 * jnp.pi * setup.radius**3,
    )
    p = eqx.tree_at(
        lambda c: (c.contact_stiffness, c.areal_weight, c.friction_coefficient, c.inflating),
        p,
        (jnp.zeros(()), jnp.zeros(()), jnp.zeros(()), jnp.asarray(True)),
    )
    y0 = jnp.concatenate([lam * rest_nodes(_indentation_config(setup), r0).ravel(), jnp.full(1, far)])
    return r0, y0, p


def _compiled_gas(law: AbstractGasLaw) -> AbstractGasLaw:
    """The compiled program's gas law of a Setup's ``law``: the adiabatic and every polytropic gas
    are the one polytropic program, its κ traced (``CurvePhysics.resolved``)."""
    return PolytropicGas() if isinstance(law, (AdiabaticGas, PolytropicGas)) else law


def _indentation_config(setup: Setup) -> Config:
    return Config(
        theta=setup.theta(),
        gas=_compiled_gas(setup.gas),
        loading="sphere",
        ground=True,
        pin_bottom=False,
        relax=setup.relax,
        hoop_capacity=setup.hoop_capacity,
    )


def _load_schedule(setup: Setup, forces: Float[Array, " k"]) -> tuple[Float[Array, " s"], Float[Array, ""]]:
    """(every load step's force (n_ramp + k · substeps,) [N], the first step's force [N]).

    The ramp's fractions of the first force come first; then ``substeps`` equal steps per
    interval between requested forces, of which only the last is reported.
    """
    ramp = jnp.asarray(setup.ramp, dtype=jnp.float64) * forces[0]
    m = setup.substeps
    start = ramp[-1:] if len(setup.ramp) else jnp.zeros(1)
    anchors = jnp.concatenate([start, forces[:-1]])
    frac = jnp.arange(1, m + 1, dtype=jnp.float64) / m
    sub = anchors[:, None] + (forces - anchors)[:, None] * frac[None, :]
    first_load = ramp[0] if len(setup.ramp) else forces[0]
    return jnp.concatenate([ramp, sub.ravel()]), first_load


def _start_state(setup: Setup, x_inf: Float[Array, "n 2"], zc_contact, pressure, load) -> Float[Array, " ny"]:
    """Unknowns [m] of the first load step's start: the inflated ball with both contacts slightly
    engaged (a non-singular first Hessian) and sunk by the membrane estimate δ = load / (2π R P_g)
    into the ground, flattened there (a contact disc of area load / P_g) for ``load`` [N] (the
    first force plus the wall's weight)."""
    nudge = 1e-4 * setup.radius
    ground_z = x_inf[0, 1]
    sink = load / (2.0 * jnp.pi * setup.radius * jnp.abs(pressure))
    x_start = x_inf - jnp.array([0.0, nudge]) - jnp.array([0.0, 1.0]) * sink
    x_start = x_start.at[:, 1].max(ground_z - nudge)
    return jnp.concatenate([x_start.ravel(), (zc_contact - sink - 2.0 * nudge)[None]])


def _with_load(p: Params, force, lag) -> Params:
    """``p`` at one load step: its force [N] and its ground-friction lag (anchor radii [m],
    normal forces [N])."""
    return eqx.tree_at(lambda c: (c.force, c.friction_anchor, c.friction_normal_force), p, (force, *lag))


def _friction_lag(y, cfg: Config, p: Params):
    """Ground-friction lag of a converged state: (node radii (n,) [m], ground forces (n,) [N])."""
    x, _ = split(y, cfg.n_nodes)
    return x[:, 0], ground_normal_forces(x, cfg, p)


def _predicted_start(setup: Setup, cfg: Config, base: Params, carry, force) -> Float[Array, " ny"]:
    """Newton's start [m] for the load step at ``force`` [N] from the previous steps (``predictor``)."""
    y_prev, y_prev2, f_prev, f_prev2, lag = carry
    if setup.predictor == "tangent":
        # Euler predictor along the equilibrium path: dy/dF = −H⁻¹ ∂g/∂F = −H⁻¹ e_zc.
        p_prev = _with_load(base, f_prev, lag)
        e_zc = jnp.zeros_like(y_prev).at[-1].set(1.0)
        dy_df = -structured_solve(hessian_at(y_prev, cfg, p_prev), e_zc)
        return y_prev + (force - f_prev) * dy_df
    if setup.predictor == "none":
        return y_prev
    # Secant predictor, never extrapolating further than the last increment (a long
    # extrapolation can land on a folded state).
    w = jnp.where(f_prev - f_prev2 > 0, (force - f_prev) / (f_prev - f_prev2), 0.0)
    w = jnp.clip(w, 0.0, 1.0)
    return y_prev + w * (y_prev - y_prev2)


def _initial_carry(y_start, cfg: Config, base: Params, load):
    """The load-step scan's first carry: (state, previous state, force, previous force, lag).

    The first step's lag takes the start state's radii and its contact forces scaled to the
    step's ground reaction ``load`` [N]: the start's nudge penetration carries penalty forces
    (≈ 1e3 × P_g per area) that are no physical load, but its disc spread evenly is the membrane's.
    """
    anchor0, normal0 = _friction_lag(y_start, cfg, base)
    normal0 = normal0 * load / jnp.maximum(jnp.sum(normal0), 1e-300)
    return (y_start, y_start, *tied_to(y_start, jnp.asarray(0.0), jnp.asarray(0.0)), (anchor0, normal0))


def _nearby_per_step(nearby_guesses, n_steps: int, n_ramp: int, m: int):
    """The guesses at the requested forces spread over the load steps: only the last sub-step of
    each level gets them; the others get NaN guesses, which are never chosen."""
    if nearby_guesses is None:
        return None
    nearby = jnp.full((n_steps,) + nearby_guesses.shape[1:], jnp.nan)
    return nearby.at[n_ramp + m - 1 :: m].set(nearby_guesses[1:])


def _levels(obs, n_ramp: int, m: int):
    """The requested levels' rows of the per-load-step outputs."""
    out = {key: val[n_ramp + m - 1 :: m] for key, val in obs.items()}
    # a level counts as converged only if every load step before it converged
    out["residual"] = jax.lax.cummax(obs["residual"])[n_ramp + m - 1 :: m]
    # Newton iterations of each level's load steps (the ramp's go to the first level)
    done = jnp.cumsum(obs["iterations"])[n_ramp + m - 1 :: m]
    out["iterations"] = jnp.diff(done, prepend=0).astype(jnp.int32)
    return out


def curve_single(
    setup: Setup,
    properties: ShellProperties,
    forces,
    bending_scale=1.0,
    return_states: bool = False,
    nearby_guesses=None,
    physics: CurvePhysics | None = None,
):
    """One force-controlled curve (unbatched, traceable) of ``properties`` (scalar P_g, E, h, ν;
    the radius is ``setup.radius``). ``forces`` (k,) [N], increasing.

    ``physics``: the curve's traced effects (:class:`CurvePhysics` of scalars; None: the default
    physics; None fields are the Setup's). Curves are differentiable in them too.

    Returns a dict of (k,) arrays: the observables, ``residual`` [N], ``iterations`` (Newton
    iterations of the level's load steps) and ``rest_radius`` [m] (scalar); with
    ``return_states`` also ``state`` (1 + k, n_y) [m], the equilibrium unknowns of the inflated
    ball and of each level, and the ground-friction lag each level was solved with:
    ``friction_anchor`` (k, n) [m] (node radii r̂) and ``friction_normal_force`` (k, n) [N] (λ̂).

    Ground friction (``physics.friction_coefficient`` μ > 0) is lagged per load step (ramp,
    sub-steps and levels alike): each step takes the anchors r̂ and normal forces λ̂ from the
    previous converged step, the first from the start state. The curve is then path dependent
    (on the load steps), as a real poke is, and differentiable through the lag.

    ``nearby_guesses`` (1 + k, c, n_y) [m]: for the inflation and each level, c guesses of the
    state taken from curves with nearby parameters at the same forces (their states, or states
    extrapolated from them; NaN: none). Each Newton solve starts from the guess of lowest
    energy, the usual start (the previous level's state) included. The result does not depend on
    the guesses beyond the tolerance ``atol``, and no derivative flows through them.
    """
    forces = jnp.asarray(forces, dtype=jnp.float64)
    pressure, young, thick, nu = _shell(properties, setup, "curve_single")
    physics = (CurvePhysics() if physics is None else physics).resolved(setup)
    cfg = _indentation_config(setup)
    r0, y_inflation, p_inflation = _inflation(setup, pressure, young, thick, nu, bending_scale, physics)
    schedule, first_load = _load_schedule(setup, forces)
    # the ground first carries the first force and the wall's weight
    load = first_load + physics.areal_weight * jnp.sum(rest_zone_areas(cfg, r0))
    curve = _Curve(
        setup, cfg, setup.options(), physics, (young, thick, nu, pressure), r0, bending_scale, load, p_inflation
    )
    return _scan_levels(curve, y_inflation, schedule, nearby_guesses, return_states)


class _Curve(NamedTuple):
    """What every step of one curve shares: the Setup, its Config and SolverOptions, the resolved
    CurvePhysics, the shell (E [Pa], h [m], ν [-], P_g [Pa]), the rest radius R0 [m], the bending
    scale [-], the first step's ground load [N] and the inflation's Params."""

    setup: Setup
    cfg: Config
    opts: SolverOptions
    physics: CurvePhysics
    shell: tuple
    r0: Float[Array, ""]
    bending_scale: Float[Array, ""]
    load: Float[Array, ""]
    p_inflation: Params


def _indentation(curve: _Curve, y_inf):
    """(z_c at first contact [m], the indentation's Params, the first load step's carry) of the
    inflated state y_inf [m]."""
    young, thick, nu, pressure = curve.shell
    x_inf, _ = split(y_inf, curve.cfg.n_nodes)
    zc_contact = x_inf[-1, 1] + curve.physics.indenter_radius
    base = _params(
        young,
        thick,
        nu,
        curve.r0,
        pressure,
        curve.setup,
        ref_volume=enclosed_volume(x_inf),
        ground_z=x_inf[0, 1],
        bending_scale=curve.bending_scale,
        physics=curve.physics,
    )
    y_start = _start_state(curve.setup, x_inf, zc_contact, pressure, curve.load)
    return zc_contact, base, _initial_carry(y_start, curve.cfg, base, curve.load)


def _curve_step(curve: _Curve, y_inflation, with_nearby: bool, return_states: bool, carry, level):
    """One step of the curve's scan: the inflation (the first) or one load step, its observables."""
    setup, cfg = curve.setup, curve.cfg
    y_inf, zc_contact, base, loading = carry
    force, nearby, inflating = level
    p = _where(inflating, curve.p_inflation, _with_load(base, force, loading[-1]))
    guess = jnp.where(inflating, y_inflation, _predicted_start(setup, cfg, base, loading, force))
    if with_nearby:
        guess = jnp.concatenate([guess[None], jax.lax.stop_gradient(nearby)])
    sol = equilibrium(cfg, curve.opts, p, guess)
    y, res, it = sol.value, sol.stats["residual"], sol.iterations
    y_inf = jnp.where(inflating, y, y_inf)
    inflated_zc, inflated_base, first = _indentation(curve, y_inf)
    zc_contact, base = _where(inflating, (inflated_zc, inflated_base), (zc_contact, base))
    # (the inflation's row is dropped; observed with the indentation's parameters it stays finite)
    obs = observables(cfg, _where(inflating, _with_load(base, force, first[-1]), p), y, y_inf, zc_contact)
    obs.update(residual=res, iterations=it)
    if return_states:
        obs.update(state=y, friction_anchor=loading[-1][0], friction_normal_force=loading[-1][1])
    loading = _where(inflating, first, (y, loading[0], force, loading[2], _friction_lag(y, cfg, base)))
    return (y_inf, zc_contact, base, loading), obs


def _scan_levels(curve: _Curve, y_inflation, schedule, nearby_guesses, return_states: bool) -> dict:
    """The curve's outputs at the requested levels (:func:`curve_single`).

    The inflation is the scan's first step, so that one Newton solve (one copy of the engine in
    the compiled program, and in its derivatives) serves it and every load step."""
    setup = curve.setup
    n_ramp, m = len(setup.ramp), setup.substeps
    nearby = _nearby_per_step(nearby_guesses, schedule.shape[0], n_ramp, m)
    if nearby is not None:
        nearby = jnp.concatenate([nearby_guesses[:1], nearby])
    levels = (jnp.concatenate([jnp.zeros(1), schedule]), nearby, jnp.arange(1 + schedule.shape[0]) == 0)
    step = functools.partial(_curve_step, curve, y_inflation, nearby_guesses is not None, return_states)
    _, obs = jax.lax.scan(step, (y_inflation, *_indentation(curve, y_inflation)), levels)
    out = _levels(jax.tree_util.tree_map(lambda v: v[1:], obs), n_ramp, m)
    out["rest_radius"] = curve.r0
    out["inflation_residual"] = obs["residual"][0]
    if return_states:
        out["state"] = jnp.concatenate([obs["state"][:1], out["state"]])
    return out


def _where(condition, on_true, on_false):
    """``on_true`` where the traced bool ``condition`` holds, else ``on_false``, leaf by leaf."""
    return jax.tree_util.tree_map(lambda a, b: jnp.where(condition, a, b), on_true, on_false)


__all__ = ["CurvePhysics", "Setup", "curve_single", "inflate"]
