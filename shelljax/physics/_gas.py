"""Gas loading as potential energies of the enclosed volume V [m³].

An equilibrium minimises elastic energy + gas energy; the gas energy's derivative −dΠ/dV is the
gauge pressure acting on the wall. All pressures in Pa, volumes in m³, energies in J.

* prescribed: constant gauge pressure P_g (the paper's model), Π = −P_g V.
* sealed isothermal: a fixed amount of ideal gas at constant temperature, atmosphere outside.
  Absolute pressure p = p₀ V₀ / V, so Π = −p₀ V₀ ln(V / V₀) + P_atm (V − V₀).
* sealed adiabatic: p V^γ constant, Π = p₀ V₀ / (γ − 1) [(V₀ / V)^(γ−1) − 1] + P_atm (V − V₀).
* sealed polytropic: p V^κ constant with the exponent κ a (traceable) value, so one compiled
  program spans the three laws above: κ = 0 is the prescribed gauge pressure (Π = −P_g0 (V − V₀)),
  κ = 1 the isothermal and κ = γ the adiabatic gas.
  Π = −p₀ V₀ ∫₁^{V/V₀} u^(−κ) du + P_atm (V − V₀) = −p₀ V₀ L φ((1 − κ) L) + P_atm (V − V₀),
  L = ln(V / V₀), φ(x) = (eˣ − 1)/x, which is analytic through κ = 1 (x = 0).

Here p₀ = P_atm + P_g0 is the absolute pressure at the reference volume V₀.

The laws are objects, :class:`AbstractGasLaw`'s final subclasses :class:`PrescribedGas` (κ = 0),
:class:`IsothermalGas` (κ = 1), :class:`AdiabaticGas` (κ = γ, air's by default) and
:class:`PolytropicGas` (any κ, which may be traced: the axisymmetric engine's one compiled program
for every sealed law, ``axisym.CurvePhysics.gas_exponent``); each gives its energy and gauge
pressure as functions of V, and the engines and the dynamics take them. Names exist only at the
edge (TOML, session files, CLI options): :func:`gas_law` maps one of :data:`GAS_LAWS` to its law.

The sealed gases' energies vanish at V₀ and are evaluated from the volume change u = (V − V₀)/V₀
as ln(V / V₀) = log1p(u) and (V₀ / V)^(γ−1) − 1 = expm1(−(γ − 1) log1p(u)), so they carry the
round-off of their own (small) value, not of the terms p₀V₀ ≈ 50 J (isothermal) or
p₀V₀/(γ − 1) ≈ 130 J (adiabatic, a 5 cm ball) whose difference they are: that round-off
(≈ 1e-14 J) exceeds the decrease of a converging Newton step of a dynamic step's incremental
potential, and its line search then stalls.
"""

from __future__ import annotations

import abc
import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._errors import InvalidInputError

ATMOSPHERIC_PRESSURE = 101_325.0  # [Pa], standard atmosphere
AIR_HEAT_CAPACITY_RATIO = 1.4  # [-], diatomic ideal gas

# φ(x) = (eˣ − 1)/x = Σ xⁿ/(n + 1)! is evaluated by its Taylor series for |x| < 0.1, where the
# closed form's derivatives lose digits (d²/dx² of expm1(x)/x cancels to ≈ eps/x² relative): the
# 13 terms leave a remainder below 1e-19 in φ, φ' and φ'' there, and beyond 0.1 the closed form's
# second derivative is good to ≈ 2e-14.
_EXPREL_SERIES_LIMIT = 0.1
_EXPREL_COEFFICIENTS = tuple(1.0 / math.factorial(n + 1) for n in range(13))


def prescribed_pressure_energy(volume, gauge_pressure):
    """Π = −P_g V [J] for a constant gauge pressure P_g [Pa] and enclosed volume V [m³]."""
    return -gauge_pressure * volume


def isothermal_gas_energy(
    volume, reference_volume, reference_gauge_pressure, atmospheric_pressure=ATMOSPHERIC_PRESSURE
):
    """Energy [J] of a sealed isothermal ideal gas at V [m³]; at V₀ [m³] its gauge pressure is P_g0 [Pa]."""
    p0 = atmospheric_pressure + reference_gauge_pressure
    change = volume - reference_volume
    return -p0 * reference_volume * jnp.log1p(change / reference_volume) + atmospheric_pressure * change


def adiabatic_gas_energy(
    volume,
    reference_volume,
    reference_gauge_pressure,
    heat_capacity_ratio=AIR_HEAT_CAPACITY_RATIO,
    atmospheric_pressure=ATMOSPHERIC_PRESSURE,
):
    """Energy [J] of a sealed adiabatic ideal gas (ratio γ [-]) at V [m³], gauge P_g0 [Pa] at V₀ [m³]."""
    p0 = atmospheric_pressure + reference_gauge_pressure
    gm1 = heat_capacity_ratio - 1.0
    change = volume - reference_volume
    return (
        p0 * reference_volume / gm1 * jnp.expm1(-gm1 * jnp.log1p(change / reference_volume))
        + atmospheric_pressure * change
    )


def isothermal_gauge_pressure(
    volume, reference_volume, reference_gauge_pressure, atmospheric_pressure=ATMOSPHERIC_PRESSURE
):
    """Gauge pressure [Pa] of a sealed isothermal gas at V [m³]: p₀V₀/V − P_atm."""
    return (atmospheric_pressure + reference_gauge_pressure) * reference_volume / volume - (atmospheric_pressure)


def adiabatic_gauge_pressure(
    volume,
    reference_volume,
    reference_gauge_pressure,
    heat_capacity_ratio=AIR_HEAT_CAPACITY_RATIO,
    atmospheric_pressure=ATMOSPHERIC_PRESSURE,
):
    """Gauge pressure [Pa] of a sealed adiabatic gas at V [m³]: p₀(V₀/V)^γ − P_atm."""
    return (atmospheric_pressure + reference_gauge_pressure) * (
        reference_volume / volume
    ) ** heat_capacity_ratio - atmospheric_pressure


def _exprel(x):
    """φ(x) = (eˣ − 1)/x [-] (1 at x = 0), with exact derivatives of every order through x = 0.

    Both branches are evaluated on safe arguments (the series at 0, the closed form at 1), so the
    branch ``jnp.where`` does not select is finite with finite derivatives: no NaN gradients.
    """
    x = jnp.asarray(x)
    small = jnp.abs(x) < _EXPREL_SERIES_LIMIT
    x_series = jnp.where(small, x, 0.0)
    series = jnp.zeros_like(x_series)
    for c in reversed(_EXPREL_COEFFICIENTS):
        series = series * x_series + c
    x_closed = jnp.where(small, 1.0, x)
    return jnp.where(small, series, jnp.expm1(x_closed) / x_closed)


def polytropic_gas_energy(
    volume, reference_volume, reference_gauge_pressure, exponent, atmospheric_pressure=ATMOSPHERIC_PRESSURE
):
    """Energy [J] of a sealed polytropic gas (p V^κ constant) at V [m³], gauge P_g0 [Pa] at V₀ [m³].

    ``exponent`` κ [-] may be traced: 0 gives the prescribed gauge pressure (Π = −P_g0 (V − V₀)),
    1 the isothermal law, 1.4 the adiabatic one of air. Smooth in V and κ, through κ = 1 included.
    """
    p0 = atmospheric_pressure + reference_gauge_pressure
    log_ratio = jnp.log1p((volume - reference_volume) / reference_volume)
    return -p0 * reference_volume * log_ratio * _exprel((1.0 - exponent) * log_ratio) + atmospheric_pressure * (
        volume - reference_volume
    )


def polytropic_gauge_pressure(
    volume, reference_volume, reference_gauge_pressure, exponent, atmospheric_pressure=ATMOSPHERIC_PRESSURE
):
    """Gauge pressure [Pa] of a sealed polytropic gas (exponent κ [-]) at V [m³]: p₀(V₀/V)^κ − P_atm."""
    return (atmospheric_pressure + reference_gauge_pressure) * jnp.exp(
        -exponent * jnp.log(volume / reference_volume)
    ) - atmospheric_pressure


class AbstractGasLaw(eqx.Module):
    """The gas inside a shell: its potential energy Π(V) [J] and gauge pressure −dΠ/dV [Pa] as
    functions of the enclosed volume V [m³].

    Every law takes the same arguments: V [m³], the reference volume V₀ [m³] and the gauge pressure
    P_g0 [Pa] there (the prescribed law's constant P_g; it reads no V₀), and the outside
    (atmospheric) pressure P_atm [Pa]. ``exponent`` is κ [-] of p V^κ constant; ``sealed`` says
    whether the gas is a fixed amount (its pressure follows V) or held at P_g.
    """

    sealed: ClassVar[bool]

    @property
    @abc.abstractmethod
    def exponent(self) -> float | Float[Array, ""]:
        """κ [-] of p V^κ constant (0: a prescribed gauge pressure)."""

    @abc.abstractmethod
    def energy(
        self,
        volume: Float[ArrayLike, "*shape"],
        reference_volume: Float[ArrayLike, ""] | None,
        reference_gauge_pressure: Float[ArrayLike, ""],
        atmospheric_pressure: Float[ArrayLike, ""] = ATMOSPHERIC_PRESSURE,
    ) -> Float[Array, "*shape"]:
        """Π(V) [J]."""

    @abc.abstractmethod
    def gauge_pressure(
        self,
        volume: Float[ArrayLike, "*shape"],
        reference_volume: Float[ArrayLike, ""] | None,
        reference_gauge_pressure: Float[ArrayLike, ""],
        atmospheric_pressure: Float[ArrayLike, ""] = ATMOSPHERIC_PRESSURE,
    ) -> Float[Array, "*shape"]:
        """P_g(V) = −dΠ/dV [Pa]."""


class PrescribedGas(AbstractGasLaw):
    """A constant gauge pressure P_g [Pa] (the paper's model): Π = −P_g V; V₀ and P_atm are not read."""

    sealed: ClassVar[bool] = False

    @property
    def exponent(self) -> float:
        return 0.0

    def energy(self, volume, reference_volume, reference_gauge_pressure, atmospheric_pressure=ATMOSPHERIC_PRESSURE):
        return prescribed_pressure_energy(volume, reference_gauge_pressure)

    def gauge_pressure(
        self, volume, reference_volume, reference_gauge_pressure, atmospheric_pressure=ATMOSPHERIC_PRESSURE
    ):
        return jnp.broadcast_to(jnp.asarray(reference_gauge_pressure, float), jnp.shape(volume))


class IsothermalGas(AbstractGasLaw):
    """A sealed ideal gas at constant temperature: p V constant (κ = 1)."""

    sealed: ClassVar[bool] = True

    @property
    def exponent(self) -> float:
        return 1.0

    def energy(self, volume, reference_volume, reference_gauge_pressure, atmospheric_pressure=ATMOSPHERIC_PRESSURE):
        return isothermal_gas_energy(volume, reference_volume, reference_gauge_pressure, atmospheric_pressure)

    def gauge_pressure(
        self, volume, reference_volume, reference_gauge_pressure, atmospheric_pressure=ATMOSPHERIC_PRESSURE
    ):
        return isothermal_gauge_pressure(volume, reference_volume, reference_gauge_pressure, atmospheric_pressure)


class AdiabaticGas(AbstractGasLaw):
    """A sealed ideal gas compressed without heat exchange: p V^γ constant, ``heat_capacity_ratio``
    γ [-] > 1 (air's by default), a compile-time constant."""

    sealed: ClassVar[bool] = True
    heat_capacity_ratio: float = eqx.field(static=True, default=AIR_HEAT_CAPACITY_RATIO)

    def __check_init__(self):
        if not (math.isfinite(self.heat_capacity_ratio) and self.heat_capacity_ratio > 1.0):
            raise InvalidInputError(
                f"AdiabaticGas: heat_capacity_ratio = {self.heat_capacity_ratio!r} must be > 1. "
                f"Fix: air's is {AIR_HEAT_CAPACITY_RATIO}"
            )

    @property
    def exponent(self) -> float:
        return self.heat_capacity_ratio

    def energy(self, volume, reference_volume, reference_gauge_pressure, atmospheric_pressure=ATMOSPHERIC_PRESSURE):
        return adiabatic_gas_energy(
            volume, reference_volume, reference_gauge_pressure, self.heat_capacity_ratio, atmospheric_pressure
        )

    def gauge_pressure(
        self, volume, reference_volume, reference_gauge_pressure, atmospheric_pressure=ATMOSPHERIC_PRESSURE
    ):
        return adiabatic_gauge_pressure(
            volume, reference_volume, reference_gauge_pressure, self.heat_capacity_ratio, atmospheric_pressure
        )


class PolytropicGas(AbstractGasLaw):
    """A sealed gas with p V^κ constant, κ = ``exponent`` [-] ≥ 0 a value that may be traced, so
    one compiled program spans every law (0: the gauge pressure P_g0 held, Π = −P_g0 (V − V₀);
    1: isothermal; γ: adiabatic). Smooth in V and κ, through κ = 1 included."""

    sealed: ClassVar[bool] = True
    exponent: float | Float[Array, "*batch"] = 1.0

    def energy(self, volume, reference_volume, reference_gauge_pressure, atmospheric_pressure=ATMOSPHERIC_PRESSURE):
        return polytropic_gas_energy(
            volume, reference_volume, reference_gauge_pressure, self.exponent, atmospheric_pressure
        )

    def gauge_pressure(
        self, volume, reference_volume, reference_gauge_pressure, atmospheric_pressure=ATMOSPHERIC_PRESSURE
    ):
        return polytropic_gauge_pressure(
            volume, reference_volume, reference_gauge_pressure, self.exponent, atmospheric_pressure
        )


_NAMED_LAWS = {"prescribed": PrescribedGas, "isothermal": IsothermalGas, "adiabatic": AdiabaticGas}
#: The gas laws' names at the edge (TOML, session files, CLI options), each :func:`gas_law`'s.
GAS_LAWS = tuple(_NAMED_LAWS)


def gas_law(name: str) -> AbstractGasLaw:
    """The gas law of ``name``, one of :data:`GAS_LAWS` (the adiabatic one with air's γ)."""
    if name not in _NAMED_LAWS:
        raise InvalidInputError(f"gas: unknown law {name!r}. Fix: use one of {', '.join(GAS_LAWS)}")
    return _NAMED_LAWS[name]()
