"""Traced per-curve effects: polytropic gas, Gent stiffening, self-weight, finger and gas volume.

The physics laws are checked against the existing laws, closed forms and finite differences; the
engine's curves against the static modes they generalise, global balance, similarity and implicit
derivatives. Every engine check shares a few compiled programs (41 elements, two forces): one
walked batch holds every case's row, so the compilation the suite pays for stays small.
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from shelljax.physics import AdiabaticGas, IsothermalGas, PolytropicGas, PrescribedGas, gas_law
import shelljax
from shelljax.axisym import (
    CurvePhysics,
    Setup,
    gent_sphere_pressure,
    indentation_curves,
    indentation_curves_raw,
    inflate,
)
from shelljax.axisym._energy import split
from shelljax.physics import (
    ATMOSPHERIC_PRESSURE,
    GAS_LAWS,
    ShellProperties,
    adiabatic_gas_energy,
    adiabatic_gauge_pressure,
    gent_membrane_invariants,
    gent_shear_energy,
    isothermal_gas_energy,
    isothermal_gauge_pressure,
    lame_constants_2d,
    neo_hookean_membrane_invariants,
    polytropic_gas_energy,
    polytropic_gauge_pressure,
)

from _shells import shell

# --- polytropic gas ------------------------------------------------------------------------------

V0, PG0 = 9.2e-3, 1300.0  # [m³], [Pa]
P0 = ATMOSPHERIC_PRESSURE + PG0
# Energies carry the round-off of p₀V₀ ≈ 1e3 J (the absolute pressure times the volume).
ENERGY_ATOL = 1e-12 * P0 * V0


@pytest.mark.parametrize("ratio", [0.9, 0.99, 1.0, 1.03])
def test_polytropic_gas_spans_the_three_laws(ratio):
    v = ratio * V0
    poly = lambda kappa: float(polytropic_gas_energy(v, V0, PG0, kappa))  # noqa: E731
    np.testing.assert_allclose(poly(0.0), -PG0 * (v - V0), rtol=0, atol=ENERGY_ATOL)
    np.testing.assert_allclose(poly(1.0), float(isothermal_gas_energy(v, V0, PG0)), rtol=0, atol=ENERGY_ATOL)
    np.testing.assert_allclose(poly(1.4), float(adiabatic_gas_energy(v, V0, PG0)), rtol=0, atol=ENERGY_ATOL)
    pressure = lambda kappa: float(polytropic_gauge_pressure(v, V0, PG0, kappa))  # noqa: E731
    # gauge pressures: round-off of the 1e5 Pa absolute pressure
    np.testing.assert_allclose(pressure(0.0), PG0, rtol=0, atol=1e-10)
    np.testing.assert_allclose(pressure(1.0), float(isothermal_gauge_pressure(v, V0, PG0)), rtol=0, atol=1e-10)
    np.testing.assert_allclose(pressure(1.4), float(adiabatic_gauge_pressure(v, V0, PG0)), rtol=0, atol=1e-10)


@pytest.mark.parametrize("kappa", [0.0, 0.7, 1.0 - 1e-7, 1.0, 1.0 + 1e-7, 1.4])
@pytest.mark.parametrize("ratio", [0.97, 1.0, 1.2])
def test_polytropic_gas_derivatives_through_the_isothermal_exponent(kappa, ratio):
    v, k = jnp.asarray(ratio * V0), jnp.asarray(kappa)
    energy = lambda vv, kk: polytropic_gas_energy(vv, V0, PG0, kk)  # noqa: E731
    p_abs = P0 * ratio**-kappa
    # −dΠ/dV is the gauge pressure and d²Π/dV² = κ p_abs / V (the gas's bulk stiffness)
    np.testing.assert_allclose(
        -float(jax.grad(energy)(v, k)), float(polytropic_gauge_pressure(v, V0, PG0, k)), rtol=1e-13, atol=1e-10
    )
    np.testing.assert_allclose(
        float(jax.grad(jax.grad(energy))(v, k)), kappa * p_abs / float(v), rtol=1e-12, atol=1e-12 * P0 / V0
    )
    # in κ: ∂²Π/∂V∂κ = −∂P/∂κ = p_abs ln(V/V₀), and ∂Π/∂κ against central differences (step
    # 1e-4: truncation ≈ 1e-8 ∂³Π/∂κ³ ≪ the 1e-6 relative tolerance, round-off ≈ 1e-16·p₀V₀/1e-4)
    np.testing.assert_allclose(
        float(jax.grad(jax.grad(energy), argnums=1)(v, k)), p_abs * np.log(ratio), rtol=1e-12, atol=1e-9
    )
    step = 1e-4
    fd = (float(energy(v, k + step)) - float(energy(v, k - step))) / (2 * step)
    dk = float(jax.grad(energy, argnums=1)(v, k))
    assert np.isfinite(dk)
    np.testing.assert_allclose(dk, fd, rtol=1e-6, atol=1e-9 * P0 * V0)
    # and ∂²Π/∂κ² exists (finite) at the series/closed-form seam
    assert np.isfinite(float(jax.grad(jax.grad(energy, argnums=1), argnums=1)(v, k)))


# --- Gent membrane -------------------------------------------------------------------------------

E, NU, H = 2.34e6, 0.4, 9e-4


def _equibiaxial(stretch, stiffening):
    return gent_membrane_invariants(2.0 * stretch**2, stretch**4, H, E, NU, stiffening)


def test_gent_membrane_is_neo_hookean_at_zero_stiffening():
    rng = np.random.default_rng(0)
    lam = rng.uniform(0.8, 1.3, size=(2, 50))
    trace_c, det_c = jnp.asarray(lam[0] ** 2 + lam[1] ** 2), jnp.asarray((lam[0] * lam[1]) ** 2)

    @jax.jit
    def derivatives(t, d):
        # values, gradients and (diagonal) second derivatives in tr C and det C of both laws
        out = []
        for law in (
            lambda tt, dd: gent_membrane_invariants(tt, dd, H, E, NU, 0.0),
            lambda tt, dd: neo_hookean_membrane_invariants(tt, dd, H, E, NU),
        ):
            total = lambda tt, dd: jnp.sum(law(tt, dd))  # noqa: E731
            out.append(
                [law(t, d)]
                + [jax.grad(total, k)(t, d) for k in (0, 1)]
                + [jax.grad(lambda tt, dd: jnp.sum(jax.grad(total, k)(tt, dd)), k)(t, d) for k in (0, 1)]
            )
        return out

    gent, neo = derivatives(trace_c, det_c)
    for a, b in zip(gent, neo):
        # the same arithmetic, to the last bit or two: how XLA fuses each expression decides the
        # rounding of the last operation (2 ulp = 4.4e-16 relative)
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=4.5e-16, atol=0.0)


@pytest.mark.parametrize("stiffening", [-0.2, 0.0, 1e-6, 0.05, 0.8])
def test_gent_derivatives_in_the_stiffening_match_central_differences(stiffening):
    s = jnp.asarray(stiffening)
    invariant = jnp.asarray([0.0, 1e-4, 0.02, 0.4])
    shear = lambda ss: gent_shear_energy(invariant, ss)  # noqa: E731
    slope = np.asarray(jax.jacfwd(shear)(s))
    # step 1e-3: truncation ≈ 1e-6 ∂³/∂s³ ~ 1e-6 I⁴ ≪ the tolerance; round-off ≈ 1e-16/1e-3
    step = 1e-3
    fd = (np.asarray(shear(s + step)) - np.asarray(shear(s - step))) / (2 * step)
    np.testing.assert_allclose(slope, fd, rtol=1e-6, atol=1e-12)
    if stiffening == 0.0:  # ∂/∂s [−ln(1 − sI)/s] = I²/2 at s = 0
        np.testing.assert_allclose(slope, np.asarray(invariant) ** 2 / 2, rtol=1e-15)
    # the mixed derivative the implicit differentiation of the engine uses: ∂²/∂I∂s = I/(1 − sI)²
    mixed = jax.vmap(jax.grad(jax.grad(gent_shear_energy, 0), 1), (0, None))(invariant, s)
    np.testing.assert_allclose(
        np.asarray(mixed),
        np.asarray(invariant) / (1 - stiffening * np.asarray(invariant)) ** 2,
        rtol=1e-14,
        atol=1e-300,
    )


def test_gent_locks_with_infinite_energy_and_finite_gradients():
    invariant = jnp.asarray([0.1, 0.5, 1.0, 2.0])
    energy = gent_shear_energy(invariant, 1.0)  # s I ≥ 1 from the third on
    assert np.all(np.isfinite(np.asarray(energy[:2]))) and np.all(np.isinf(np.asarray(energy[2:])))
    # a batch mixing locked and free points: the free points' gradients are exact, none is NaN
    grads = jax.grad(lambda i, s: jnp.sum(jnp.where(i < 1.0, gent_shear_energy(i, s), 0.0)), (0, 1))(invariant, 1.0)
    assert all(np.all(np.isfinite(np.asarray(g))) for g in grads)
    np.testing.assert_allclose(np.asarray(grads[0][:2]), 1 / (1 - np.asarray(invariant[:2])), rtol=1e-14)


@pytest.mark.parametrize("stiffening", [0.0, 0.5, -0.2])
def test_gent_equibiaxial_stress_is_the_energy_slope(stiffening):
    alpha, beta = lame_constants_2d(E, NU)
    for stretch in (1.01, 1.2, 1.5):
        invariant = 2 * stretch**2 - 2 - 4 * np.log(stretch)
        # nominal stress resultant per direction [N/m] of the hand-derived law ...
        stress = H * (
            beta * (stretch - 1 / stretch) / (1 - stiffening * invariant) + 0.5 * alpha * (stretch**3 - 1 / stretch)
        )
        # ... is half the slope dW/dλ of the energy (two directions); central differences of
        # step 1e-6 are good to ≈ 1e-10 relative (truncation 1e-12 W''', round-off 1e-16 W/1e-6)
        step = 1e-6
        up, down = float(_equibiaxial(stretch + step, stiffening)), float(_equibiaxial(stretch - step, stiffening))
        fd = (up - down) / (4 * step)
        np.testing.assert_allclose(fd, stress, rtol=1e-7)
        np.testing.assert_allclose(
            0.5 * float(jax.grad(_equibiaxial)(jnp.asarray(stretch), stiffening)), stress, rtol=1e-13
        )


def test_inflated_gent_sphere_follows_the_closed_form():
    # The engine's inflation (discrete meridian, bending) against the membrane law of the Gent
    # sphere, at a pressure that stretches the wall by ≈ 50 % (I ≈ 0.85: s = 0.5 stiffens the
    # shear part by 1/(1 − s I) ≈ 1.7).
    pressure, radius = 2.0e4, 0.13
    setup = Setup(radius=radius, n_elements=101)
    properties = ShellProperties(gauge_pressure=pressure, young_modulus=E, thickness=H, poisson_ratio=NU)
    inflated = jax.jit(lambda s: inflate(setup, properties, stiffening=s))  # one compilation
    found = {}
    for stiffening in (0.0, 0.5):
        r0, y, res, _ = inflated(stiffening)
        x, _ = split(y, len(setup.theta()))
        centre = 0.5 * (x[0, 1] + x[-1, 1])
        radii = np.hypot(np.asarray(x[:, 0]), np.asarray(x[:, 1] - centre))
        lam = radii.mean() / float(r0)
        exact = float(gent_sphere_pressure(lam, r0, E, H, NU, stiffening))
        # as the Neo-Hookean check (test_axisym_physics.py): bending O(h²/R²) ≈ 5e-5, the polygon
        # O(Δθ²) ≈ 1e-4 (measured 1.9e-4 and 0.9e-4 for s = 0 and 0.5), so 1e-3
        assert abs(exact / pressure - 1.0) < 1e-3, (stiffening, exact)
        assert abs(radii.mean() / radius - 1.0) < 1e-3  # the rest radius comes from the Gent law too
        assert float(res) < 1e-6
        found[stiffening] = float(r0)
    # not vacuous: the stiffer wall needs a larger rest sphere to reach R (measured 5.2 % larger)
    assert found[0.5] > 1.03 * found[0.0]


# --- the engine's energy: gradient and assembled Hessian with every effect on ------------------


def test_assembled_hessian_and_gradient_include_every_effect():
    from shelljax.axisym._energy import (
        Config,
        constrained_mask,
        enclosed_volume,
        local_energy,
        rest_nodes,
        total_energy,
    )
    from shelljax.axisym._hessian import hessian_at
    from shelljax.axisym._model import _params
    from test_axisym_solver import _dense

    setup = Setup(radius=0.13, n_elements=21)
    cfg = Config(
        theta=setup.theta(),
        gas=PolytropicGas(),
        loading="sphere",
        ground=True,
        pin_bottom=False,
        relax=True,
        hoop_capacity=setup.hoop_capacity,
    )
    # The rest sphere stretched by 2 %, both contacts engaged by 0.1 mm and every node moved by
    # ~0.1 mm: gas, contact, membrane and bending all have non-zero gradients and curvatures.
    r0 = 0.13 / 1.02
    x = 1.02 * rest_nodes(cfg, r0)
    effects = CurvePhysics(
        indenter_radius=6e-3, gas_volume_ratio=1.7, gas_exponent=1.4, stiffening=0.5, areal_weight=20.0
    )
    p = _params(
        E, H, NU, r0, 1300.0, setup, force=5.0, ref_volume=enclosed_volume(x), ground_z=x[0, 1] + 1e-4, physics=effects
    )
    y = jnp.concatenate([x.ravel(), (x[-1, 1] + 6e-3 - 1e-4)[None]])
    y = y + 1e-4 * jnp.asarray(np.random.default_rng(1).normal(size=y.shape))
    mask = constrained_mask(cfg)
    reference = np.array(jax.jit(jax.hessian(total_energy), static_argnums=1)(y, cfg, p))
    reference[mask, :] = 0.0
    reference[:, mask] = 0.0
    reference[mask, mask] = 1.0
    assembled = _dense(jax.tree_util.tree_map(np.asarray, jax.jit(hessian_at, static_argnums=1)(y, cfg, p)), mask)
    # as test_axisym_solver.py: two exact second derivatives in float64, entries 1e-3 … 1e9 N/m
    np.testing.assert_allclose(assembled, reference, rtol=0, atol=1e-12 * np.max(np.abs(reference)))
    # The self-weight is linear in the heights: nothing in the Hessian, and in the gradient the
    # load q on each node's share of the rest sphere, 4π R0² q in all (round-off of 1e-15)
    weightless = eqx.tree_at(lambda q: q.areal_weight, p, jnp.asarray(0.0))
    gradient = jax.jit(jax.grad(local_energy), static_argnums=1)
    load = gradient(y, cfg, p) - gradient(y, cfg, weightless)
    np.testing.assert_allclose(float(jnp.sum(load[1:-1:2])), 20.0 * 4 * np.pi * r0**2, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(load[0:-1:2]), 0.0, atol=1e-15)


# --- the engine ----------------------------------------------------------------------------------

RADIUS = 0.13
PEZZI = np.array([1300.0, 2.34e6, 9e-4, 0.4])  # P_g [Pa], E [Pa], h [m], ν
FORCES = np.array([5.0, 10.0])
N_ELEMENTS = 41
SETUP = Setup(radius=RADIUS, n_elements=N_ELEMENTS, gas=PolytropicGas())
FIELDS = ("indenter_radius", "gas_volume_ratio", "gas_exponent", "stiffening", "areal_weight")
DEFAULT = dict(indenter_radius=8e-3, gas_volume_ratio=1.0, gas_exponent=1.0, stiffening=0.0, areal_weight=0.0)
# Named rows of the walked batch, followed by ten rows of central differences around FD_BASE.
CASES = {
    "isothermal_override": dict(gas_exponent=1.0, gas_volume_ratio=2.5, indenter_radius=6e-3),
    "prescribed": dict(gas_exponent=0.0),
    "isothermal": dict(gas_exponent=1.0),
    "adiabatic": dict(gas_exponent=1.4),
    "gravity": dict(areal_weight=20.0),
    "stiffened": dict(stiffening=0.3),
    "softened": dict(stiffening=-0.3),
}
# every effect away from its default, κ = 1 and s = 0 included (the series branches of both laws)
FD_BASE = dict(indenter_radius=8e-3, gas_volume_ratio=1.3, gas_exponent=1.0, stiffening=0.0, areal_weight=5.0)
CASES["fd_base"] = FD_BASE
# Steps: large enough that the Newton tolerance (w0 within ≈ 6e-10 m of the equilibrium) stays
# below 1e-4 of each difference, small enough that the O(step²) truncation does too (measured
# ≤ 7e-5 relative to the implicit derivative, walked; the self-weight's 5 N entry aside, below).
FD_STEPS = dict(indenter_radius=2e-5, gas_volume_ratio=0.02, gas_exponent=0.01, stiffening=0.05, areal_weight=0.5)
WALK_LANES = 4
# Walked and cold solves, or solves of two equivalent programs, stop at different points within
# the Newton tolerance: max|∂E/∂y| ≤ 1e-7 N against a dimple stiffness ≳ 170 N/m leaves
# ≲ 6e-10 m on depths ≥ 10 mm, 6e-8 relative (test_axisym_curves.py measured ≤ 3e-8).
NEWTON_RTOL = 1e-7


def _physics(rows):
    return CurvePhysics(**{name: jnp.asarray([row[name] for row in rows]) for name in FIELDS})


def _rows():
    rows = [DEFAULT | case for case in CASES.values()]
    for name in FIELDS:
        for sign in (1.0, -1.0):
            rows.append(FD_BASE | {name: FD_BASE[name] + sign * FD_STEPS[name]})
    return rows


@functools.partial(jax.jit, static_argnums=(0, 1))
def _curves(setup, chunk, params, forces, physics):
    return indentation_curves_raw(shell(params), forces, setup, chunk, physics)


@pytest.fixture(scope="module")
def walked():
    rows = _rows()
    res = _curves(SETUP, WALK_LANES, np.tile(PEZZI, (len(rows), 1)), FORCES, _physics(rows))
    assert bool(np.all(res.converged))
    return {name: jax.tree_util.tree_map(lambda v: np.asarray(v)[i], res) for i, name in enumerate(CASES)}, res


def _cold(setup, physics=None):
    res = _curves(setup, 0, PEZZI[None], FORCES, physics)
    assert bool(np.all(res.converged))
    return jax.tree_util.tree_map(lambda v: np.asarray(v)[0], res)


def _assert_same_curve(a, b, rtol=NEWTON_RTOL):
    for key in ("w0", "height", "travel", "volume"):
        np.testing.assert_allclose(getattr(a, key), getattr(b, key), rtol=rtol, err_msg=key)
    # gauge pressures: rtol of their ≈ 1 kPa rise (1 % of the absolute pressure), 1e-4 Pa
    np.testing.assert_allclose(a.pressure, b.pressure, rtol=0, atol=rtol * 1e-2 * (ATMOSPHERIC_PRESSURE + PEZZI[0]))


def test_polytropic_exponents_one_and_zero_are_the_isothermal_and_prescribed_gases(walked):
    cases, _ = walked
    # κ = 1 with a traced finger and gas volume: the isothermal law's own program, its finger the
    # Setup's and its gas volume traced
    isothermal = _cold(
        Setup(radius=RADIUS, n_elements=N_ELEMENTS, gas=IsothermalGas(), indenter_radius=6e-3),
        CurvePhysics(gas_volume_ratio=np.full(1, 2.5)),
    )
    _assert_same_curve(cases["isothermal_override"], isothermal)
    # the named adiabatic gas is the polytropic program at κ = γ, by default
    adiabatic = _cold(Setup(radius=RADIUS, n_elements=N_ELEMENTS, gas=AdiabaticGas()))
    _assert_same_curve(cases["adiabatic"], adiabatic)
    prescribed = _cold(Setup(radius=RADIUS, n_elements=N_ELEMENTS, gas=PrescribedGas()))
    _assert_same_curve(cases["prescribed"], prescribed)
    np.testing.assert_allclose(cases["prescribed"].pressure, PEZZI[0], rtol=1e-9)
    # not vacuous: the sealed gas stiffens the ball by far more than the tolerance
    assert np.all(cases["isothermal"].w0 < 0.97 * prescribed.w0)


def test_adiabatic_gas_raises_the_pressure_1_4_times_as_much(walked):
    cases, _ = walked
    iso, adi = cases["isothermal"], cases["adiabatic"]
    # Same inflation, so the same reference volume: Boyle's law of the isothermal row gives it.
    p_abs = lambda c: c.pressure + ATMOSPHERIC_PRESSURE  # noqa: E731
    volume_ref = float(p_abs(iso)[0] * iso.volume[0] / (ATMOSPHERIC_PRESSURE + PEZZI[0]))
    for case, kappa in ((iso, 1.0), (adi, 1.4)):
        # p V^κ is conserved (to round-off of the 1e5 Pa absolute pressure) ...
        np.testing.assert_allclose(
            p_abs(case) * case.volume**kappa, (ATMOSPHERIC_PRESSURE + PEZZI[0]) * volume_ref**kappa, rtol=1e-9
        )
        # ... so ΔP = κ p_abs (−ΔV/V) up to the relative correction (κ + 1)/2 · |ΔV/V|
        shrink = 1.0 - case.volume / volume_ref
        rise = case.pressure - PEZZI[0]
        linear = kappa * (ATMOSPHERIC_PRESSURE + PEZZI[0]) * shrink
        assert np.all(np.abs(rise / linear - 1.0) < (kappa + 1.0) * shrink), (rise, linear)
    # At equal volume change the adiabatic rise is 1.4 × the isothermal one (within the same
    # O(|ΔV/V|) ≈ 1 % corrections). At equal force it is not: the force sets the pressure rise
    # (measured 1.04 ×), and the stiffer gas gives way by less volume (measured 26 % less).
    stiffness = lambda c: (c.pressure - PEZZI[0]) / (1.0 - c.volume / volume_ref)  # noqa: E731
    np.testing.assert_allclose(stiffness(adi) / stiffness(iso), 1.4, rtol=0.03)
    assert np.all(adi.w0 < iso.w0)


def test_self_weight_is_carried_by_the_ground(walked):
    cases, _ = walked
    heavy, light = cases["gravity"], cases["isothermal"]
    weight = 20.0 * 4.0 * np.pi * float(heavy.rest_radius) ** 2  # q × rest area [N]
    # Global balance: the ground carries the finger's force and the wall's weight. The Newton
    # residual leaves ≤ 1e-7 N per unknown (≈ 80 vertical ones): 1e-6 relative of ≥ 5 N is ample.
    np.testing.assert_allclose(heavy.ground_reaction, FORCES + weight, rtol=1e-6)
    np.testing.assert_allclose(light.ground_reaction, FORCES, rtol=1e-6)
    assert weight > 3.0  # not vacuous: comparable to the 5 N force
    # the heavier wall flattens more onto the ground: a larger contact disc, a lower ball
    assert np.all(heavy.contact_diameter > light.contact_diameter)
    assert np.all(heavy.height < light.height)


def test_gent_stiffening_stiffens_and_softening_softens(walked):
    cases, _ = walked
    assert np.all(cases["stiffened"].w0 < cases["isothermal"].w0)
    assert np.all(cases["softened"].w0 > cases["isothermal"].w0)


@pytest.mark.slow  # central differences in every effect
def test_implicit_gradients_in_every_effect_match_central_differences(walked):
    cases, res = walked

    def depths(values):
        physics = CurvePhysics(**{name: values[j][None] for j, name in enumerate(FIELDS)})
        curve = indentation_curves_raw(shell(PEZZI[None]), FORCES, SETUP, 0, physics)
        return curve.w0[0], curve

    base = jnp.asarray([FD_BASE[name] for name in FIELDS])
    jac, cold = jax.jit(jax.jacfwd(depths, has_aux=True))(base)  # (levels, effects), the cold curve
    jac = np.asarray(jac)
    # The walk (chunk > 0) carries each physics row with its parameter row: every row here has the
    # same (P_g, E, h, ν), so only the tie-break orders them, and each must keep its own physics.
    assert bool(np.all(cold.converged))
    _assert_same_curve(cases["fd_base"], jax.tree_util.tree_map(lambda v: np.asarray(v)[0], cold))
    w0 = np.asarray(res.w0)[len(CASES) :]
    for j, name in enumerate(FIELDS):
        fd = (w0[2 * j] - w0[2 * j + 1]) / (2 * FD_STEPS[name])
        # 1e-3 of the column's largest entry, as for P_g, E, h (test_axisym_curves.py: nodes
        # switching contact, the penalty is C¹). Relative to the column, not entry by entry: the
        # self-weight barely moves the 5 N depth (3.8e-7 m/Pa against 1.3e-5 at 10 N) and w0(q)
        # bends there as ground nodes enter contact (measured 8e-3 of that entry, 2e-4 of the column).
        np.testing.assert_allclose(jac[:, j], fd, rtol=0, atol=1e-3 * np.max(np.abs(fd)), err_msg=name)


def test_similar_balls_give_similar_curves(walked):
    # A ball `scale` times larger in every length at the same pressures and moduli: forces scale by
    # scale², depths by scale; the finger is a length, the self-weight q a pressure, κ, s and the
    # volume ratio are numbers, and the contact stiffness [N/m³] (pressure per length) ÷ scale.
    radius = 0.15
    scale = radius / RADIUS
    physics = dict(indenter_radius=9e-3, gas_volume_ratio=1.3, gas_exponent=1.4, stiffening=0.2, areal_weight=10.0)
    big = Setup(
        radius=radius, n_elements=N_ELEMENTS, gas=PolytropicGas(), contact_stiffness=SETUP.contact_stiffness / scale
    )
    at_radius = _cold(big, _physics([physics]))
    reference = _physics([physics]).similar(1.0 / scale)
    rows = _rows()
    params = np.tile(PEZZI / np.array([1.0, 1.0, scale, 1.0]), (len(rows), 1))
    # the (1,) rows broadcast, the scalar default μ kept: the walked fixture's compiled program
    padded = jax.tree_util.tree_map(lambda v: jnp.broadcast_to(v, (len(rows),)) if np.ndim(v) else v, reference)
    small = _curves(SETUP, WALK_LANES, params, FORCES / scale**2, padded)
    assert bool(np.all(small.converged))
    np.testing.assert_allclose(at_radius.w0, scale * np.asarray(small.w0[0]), rtol=NEWTON_RTOL)
    np.testing.assert_allclose(at_radius.height, scale * np.asarray(small.height[0]), rtol=NEWTON_RTOL)
    np.testing.assert_allclose(
        at_radius.ground_reaction, scale**2 * np.asarray(small.ground_reaction[0]), rtol=NEWTON_RTOL
    )
    np.testing.assert_allclose(at_radius.pressure, np.asarray(small.pressure[0]), rtol=1e-9)


def test_checked_api_validates_the_physics():
    physics = CurvePhysics.defaults(Setup(radius=RADIUS), 1)
    bad = CurvePhysics(**{**{n: getattr(physics, n) for n in FIELDS}, "indenter_radius": jnp.asarray([-1e-3])})
    with pytest.raises(shelljax.InvalidInputError, match="indenter_radius"):
        indentation_curves(shell(PEZZI), FORCES, radius=RADIUS, physics=bad)
    wrong_shape = CurvePhysics(**{**{n: getattr(physics, n) for n in FIELDS}, "areal_weight": jnp.zeros(3)})
    with pytest.raises(shelljax.InvalidInputError, match="areal_weight"):
        indentation_curves(shell(PEZZI), FORCES, radius=RADIUS, physics=wrong_shape)
    with pytest.raises(shelljax.InvalidInputError, match="gas"):
        Setup(gas="steam")
    # the named laws are the 3D engine's and the dynamics' (physics.GAS_LAWS)
    assert all(Setup(gas=gas_law(name)).gas == gas_law(name) for name in GAS_LAWS)
