"""Gas loading as potential energies of the enclosed volume V [m³].

An equilibrium minimises elastic energy + gas energy; the gas energy's derivative −dΠ/dV is the
gauge pressure acting on the wall. All pressures in Pa, volumes in m³, energies in J.

* prescribed: constant gauge pressure P_g (the paper's model), Π = −P_g V.
* sealed isothermal: a fixed amount of ideal gas at constant temperature, atmosphere outside.
  Absolute pressure p = p₀ V₀ / V, so Π = −p₀ V₀ ln(V / V₀) + P_atm (V − V₀).
* sealed adiabatic: p V^γ constant, Π = p₀ V₀ / (γ − 1) [(V₀ / V)^(γ−1) − 1] + P_atm (V − V₀).

Here p₀ = P_atm + P_g0 is the absolute pressure at the reference volume V₀.
"""

from __future__ import annotations

import jax.numpy as jnp

ATMOSPHERIC_PRESSURE = 101_325.0  # [Pa], standard atmosphere
AIR_HEAT_CAPACITY_RATIO = 1.4  # [-], diatomic ideal gas


def prescribed_pressure_energy(volume, gauge_pressure):
    """Π = −P_g V [J] for a constant gauge pressure P_g [Pa] and enclosed volume V [m³]."""
    return -gauge_pressure * volume


def isothermal_gas_energy(
    volume, reference_volume, reference_gauge_pressure, atmospheric_pressure=ATMOSPHERIC_PRESSURE
):
    """Energy [J] of a sealed isothermal ideal gas at V [m³]; at V₀ [m³] its gauge pressure is P_g0 [Pa]."""
    p0 = atmospheric_pressure + reference_gauge_pressure
    return -p0 * reference_volume * jnp.log(volume / reference_volume) + atmospheric_pressure * (
        volume - reference_volume
    )


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
    return p0 * reference_volume / gm1 * (
        (reference_volume / volume) ** gm1 - 1.0
    ) + atmospheric_pressure * (volume - reference_volume)


def isothermal_gauge_pressure(
    volume, reference_volume, reference_gauge_pressure, atmospheric_pressure=ATMOSPHERIC_PRESSURE
):
    """Gauge pressure [Pa] of a sealed isothermal gas at V [m³]: p₀V₀/V − P_atm."""
    return (atmospheric_pressure + reference_gauge_pressure) * reference_volume / volume - (
        atmospheric_pressure
    )


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
