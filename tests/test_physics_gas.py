"""The gas laws as objects (physics.AbstractGasLaw): energy, gauge pressure and the name at the edge."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from shelljax import InvalidInputError
from shelljax.physics import (
    AIR_HEAT_CAPACITY_RATIO,
    ATMOSPHERIC_PRESSURE,
    GAS_LAWS,
    AbstractGasLaw,
    AdiabaticGas,
    IsothermalGas,
    PolytropicGas,
    PrescribedGas,
    gas_law,
)

V0 = 4.0 / 3.0 * np.pi * 0.13**3  # [m³] the paper's ball
P_G0 = 1300.0  # [Pa]
LAWS = [PrescribedGas(), IsothermalGas(), AdiabaticGas(), AdiabaticGas(1.3), PolytropicGas(0.7), PolytropicGas(1.0)]
VOLUMES = V0 * np.array([0.8, 0.97, 1.0, 1.05])


@pytest.mark.parametrize("law", LAWS, ids=repr)
def test_the_gauge_pressure_is_minus_the_energys_derivative(law):
    dv = 1e-6 * V0
    for v in VOLUMES:
        derivative = -jax.grad(law.energy)(v, V0, P_G0)
        central = -(law.energy(v + dv, V0, P_G0) - law.energy(v - dv, V0, P_G0)) / (2 * dv)
        pressure = law.gauge_pressure(v, V0, P_G0)
        np.testing.assert_allclose(derivative, pressure, rtol=1e-12, atol=1e-9)
        # the energies are O(p₀V₀) ≈ 1e3 J: central differences keep ≈ 1e-16 · 1e3 / 1e-8 relative
        np.testing.assert_allclose(central, pressure, rtol=1e-6, atol=1e-3)
    # at the reference volume every law holds its gauge pressure
    np.testing.assert_allclose(law.gauge_pressure(V0, V0, P_G0), P_G0, rtol=1e-14)


@pytest.mark.parametrize("law", LAWS, ids=repr)
def test_the_pressure_follows_the_closed_form_of_p_v_to_the_kappa(law):
    p0 = ATMOSPHERIC_PRESSURE + P_G0
    kappa = law.exponent
    for v in VOLUMES:
        closed = P_G0 if not law.sealed else p0 * (V0 / v) ** kappa - ATMOSPHERIC_PRESSURE
        np.testing.assert_allclose(law.gauge_pressure(v, V0, P_G0), closed, rtol=1e-13)


def test_the_energies_are_the_closed_forms():
    p0 = ATMOSPHERIC_PRESSURE + P_G0
    v = 0.9 * V0
    np.testing.assert_allclose(PrescribedGas().energy(v, None, P_G0), -P_G0 * v, rtol=1e-15)
    isothermal = -p0 * V0 * np.log(v / V0) + ATMOSPHERIC_PRESSURE * (v - V0)
    np.testing.assert_allclose(IsothermalGas().energy(v, V0, P_G0), isothermal, rtol=1e-12)
    g = AIR_HEAT_CAPACITY_RATIO
    adiabatic = p0 * V0 / (g - 1) * ((V0 / v) ** (g - 1) - 1) + ATMOSPHERIC_PRESSURE * (v - V0)
    np.testing.assert_allclose(AdiabaticGas().energy(v, V0, P_G0), adiabatic, rtol=1e-12)
    # the polytropic law is the isothermal one at κ = 1 and the adiabatic one at κ = γ (its own
    # series through κ = 1, so equal to round-off, not bit for bit)
    np.testing.assert_allclose(PolytropicGas(1.0).energy(v, V0, P_G0), isothermal, rtol=1e-12)
    np.testing.assert_allclose(PolytropicGas(g).energy(v, V0, P_G0), adiabatic, rtol=1e-12)
    # and at κ = 0 the prescribed gauge pressure, up to the constant P_g0 V₀
    np.testing.assert_allclose(PolytropicGas(0.0).energy(v, V0, P_G0), -P_G0 * (v - V0), rtol=1e-12)


def test_the_polytropic_exponent_can_be_traced():
    def pressure(kappa):
        return PolytropicGas(kappa).gauge_pressure(0.9 * V0, V0, P_G0)

    p0 = ATMOSPHERIC_PRESSURE + P_G0
    np.testing.assert_allclose(jax.jit(pressure)(1.2), p0 * (1 / 0.9) ** 1.2 - ATMOSPHERIC_PRESSURE, rtol=1e-13)
    np.testing.assert_allclose(jax.grad(pressure)(1.2), p0 * (1 / 0.9) ** 1.2 * np.log(1 / 0.9), rtol=1e-12)
    batch = jax.vmap(pressure)(jnp.array([0.0, 1.0, AIR_HEAT_CAPACITY_RATIO]))
    assert batch.shape == (3,) and float(batch[0]) == pytest.approx(P_G0, rel=1e-14)


def test_each_law_says_its_exponent_and_whether_it_is_sealed():
    assert [law.exponent for law in (PrescribedGas(), IsothermalGas(), AdiabaticGas())] == [
        0.0,
        1.0,
        AIR_HEAT_CAPACITY_RATIO,
    ]
    assert not PrescribedGas().sealed and IsothermalGas().sealed and AdiabaticGas().sealed and PolytropicGas().sealed
    # laws are values: equal laws compare and hash equal (static fields of a compiled program)
    assert AdiabaticGas() == AdiabaticGas(AIR_HEAT_CAPACITY_RATIO) and AdiabaticGas() != AdiabaticGas(1.3)
    assert hash(IsothermalGas()) == hash(IsothermalGas())
    with pytest.raises(TypeError):
        AbstractGasLaw()
    with pytest.raises(InvalidInputError, match="heat_capacity_ratio"):
        AdiabaticGas(1.0)


def test_a_name_maps_to_its_law_and_an_unknown_name_lists_the_valid_ones():
    assert GAS_LAWS == ("prescribed", "isothermal", "adiabatic")
    assert [gas_law(name) for name in GAS_LAWS] == [PrescribedGas(), IsothermalGas(), AdiabaticGas()]
    with pytest.raises(InvalidInputError, match="'steam'.*prescribed, isothermal, adiabatic"):
        gas_law("steam")
