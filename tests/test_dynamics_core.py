"""shelljax.dynamics against analytic solutions: impacts of a point mass on contact springs.

Each run is ≤ 10⁴ steps of a 3-DOF system; the numbers quoted in the
comments are the measured ones that docs/dynamics.md reports.
"""

from __future__ import annotations

import json
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import shelljax
from shelljax import InvalidInputError, NoConvergenceError
from shelljax import dynamics as d
from shelljax.geometry import sphere_mesh
from shelljax.physics import STANDARD_GRAVITY

MASS, K_LINEAR = 0.1, 1e4  # [kg], [N/m]: contact time π√(m/k) = 9.93 ms
K_HERTZ = 1e6  # [N/m^1.5]: F = K δ^1.5, a 10 cm drop of 0.1 kg peaks at 109 N over 4.8 ms
LINEAR = d.CompressionCurve(lambda x: K_LINEAR * x, energy_curve=lambda x: 0.5 * K_LINEAR * x**2)
HERTZ = d.CompressionCurve(lambda x: K_HERTZ * x**1.5, energy_curve=lambda x: 0.4 * K_HERTZ * x**2.5)


def spring_impact(damping=0.0, integrator=d.Newmark(), dt=2e-5, law=LINEAR, duration=0.0125):
    """A 0.1 kg mass at 1 m/s onto a linear spring, no gravity: one half-sine impact (then it flies off for good)."""
    system = d.PointMassOnGround(MASS, [d.ground(law, damping=damping)], gravity=0.0)
    state = d.initial_state(system, [0.0, 0.0, 1e-3], [0.0, 0.0, -1.0])
    return d.simulate(system, state, dt, duration, integrator=integrator, progress=False)


def hertz_drop(damping=0.0, duration=0.16, dt=1e-4, height=0.1):
    """A 0.1 kg ball dropped from ``height`` [m] onto a Hertzian ground, with gravity."""
    system = d.PointMassOnGround(MASS, [d.ground(HERTZ, damping=damping)])
    return d.simulate(system, d.drop_state(system, [0.0, 0.0, 0.0], height), dt, duration, progress=False)


def test_newmark_half_sine_impact_is_exact_to_its_period_error():
    (impact,) = d.measured_cor(spring_impact())
    period = math.pi * math.sqrt(MASS / K_LINEAR)
    # Trapezoidal-rule period error (ωΔt)²/12 = 3.3e-6 at ωΔt = 6.3e-3, plus O(Δt²) from the
    # interpolated onset and end times; measured 3.3e-6.
    assert impact.contact_time_s == pytest.approx(period, rel=2e-5)
    # Average acceleration conserves a linear system's energy up to the Newton tolerance (1e-11 m):
    # measured |COR − 1| = 2e-11.
    assert impact.cor == pytest.approx(1.0, abs=1e-8)
    # Peak force v √(k m) = 31.62 N; sampled at steps, so the apex can be missed by O((ωΔt)²).
    assert impact.peak_force_N == pytest.approx(1.0 * math.sqrt(K_LINEAR * MASS), rel=1e-4)


def test_newmark_energy_drift_over_three_bounces_is_below_one_percent():
    trajectory = hertz_drop(duration=0.95)
    impacts = d.measured_cor(trajectory)
    assert len(impacts) >= 3
    energy = trajectory["total_energy_J"]
    drift = np.max(np.abs(energy - energy[0])) / energy[0]
    # The criterion; measured 0.106 % (the nonlinear contact's trapezoidal error, at Δt = 0.1 ms).
    assert drift <= 0.01
    assert all(impact.cor == pytest.approx(1.0, abs=2e-3) for impact in impacts)


def test_backward_euler_cor_below_one_and_converging_to_one_as_dt_falls():
    omega = math.sqrt(K_LINEAR / MASS)
    cors = []
    for dt in (2e-4, 1e-4, 5e-5):
        # At least one whole chunk of simulate's 250 steps at each Δt (0.05 s: 250 steps at the
        # largest): a run shorter than a chunk compiles a chunk of its own length, one per Δt.
        (impact,) = d.measured_cor(spring_impact(integrator=d.BackwardEuler(), dt=dt, duration=0.05))
        cors.append(impact.cor)
        # Each step scales the amplitude by (1 + ω²Δt²)^(−½); over π/(ωΔt) steps that is
        # exp(−πωΔt/2) to first order in ωΔt (measured 0.9058 vs 0.9054 at Δt = 0.2 ms).
        assert impact.cor == pytest.approx(math.exp(-math.pi * omega * dt / 2), abs=1e-3)
    assert cors[0] < cors[1] < cors[2] < 1.0
    # First order: halving Δt halves 1 − COR (measured ratios 1.95 and 1.97).
    for coarse, fine in zip(cors, cors[1:]):
        assert (1 - coarse) / (1 - fine) == pytest.approx(2.0, rel=0.1)


def test_kelvin_voigt_contact_matches_the_analytic_cor():
    zeta = 0.1
    damping = zeta * 2.0 * math.sqrt(K_LINEAR * MASS)  # [N·s/m]
    analytic = math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2))  # 0.72925
    errors = []
    for dt in (2e-5, 1e-5):
        (impact,) = d.measured_cor(spring_impact(damping=damping, dt=dt))
        errors.append(impact.cor / analytic - 1)
    # The dashpot c (x − xₙ)/Δt with weights lagged at xₙ is first order in Δt: measured relative
    # errors 5.4e-4 and 2.7e-4, halving with Δt, so the simulated COR converges to the analytic one.
    assert abs(errors[1]) < 5e-4
    assert errors[0] / errors[1] == pytest.approx(2.0, rel=0.15)


def test_tabulated_curve_reproduces_the_callable_spring():
    table = d.TabulatedCompressionCurve([0.002, 0.004, 0.01], [20.0, 40.0, 100.0])
    gaps = jnp.array([1e-3, 0.0, -1e-3, -3e-3, -0.02])
    np.testing.assert_allclose(table.energy(gaps), LINEAR.energy(gaps), rtol=1e-13, atol=1e-18)
    np.testing.assert_allclose(table.force(gaps), K_LINEAR * np.maximum(-np.asarray(gaps), 0.0), rtol=1e-13, atol=1e-12)
    (impact,) = d.measured_cor(spring_impact(law=table))
    assert impact.contact_time_s == pytest.approx(math.pi * math.sqrt(MASS / K_LINEAR), rel=2e-5)


@pytest.mark.parametrize("target", [0.6, 0.75, 0.9])
def test_calibrate_contact_damping_hits_the_target_cor(target):
    def cor(c):
        return d.measured_cor(hertz_drop(damping=c))[0].cor

    result = d.calibrate_contact_damping(cor, target, (0.0, 50.0))
    # Brent's root on c to 1e-4 relative leaves the COR far inside the 2 %; re-simulating the
    # calibrated c confirms it (measured c = 18.14, 10.46, 3.94 N·s/m; COR off by ≤ 1e-5).
    assert result.cor == pytest.approx(target, rel=0.02)
    assert cor(result.damping) == pytest.approx(target, rel=0.02)


def test_calibration_rejects_an_unreachable_target():
    with pytest.raises(InvalidInputError, match="reachable range"):
        d.calibrate_contact_damping(lambda c: d.measured_cor(hertz_drop(damping=c))[0].cor, 0.3, (0.0, 5.0))


def test_bounce_apex_gradient_in_damping_and_stiffness_matches_finite_differences():
    dt, g = 1e-4, STANDARD_GRAVITY

    def apex(c, stiffness):
        system = d.PointMassOnGround(MASS, [d.ground(d.PowerLawContact(stiffness, 1.5), damping=c)])
        state = d.initial_state(system, jnp.array([0.0, 0.0, 2e-3]), jnp.array([0.0, 0.0, -1.0]))
        end, record = d.rollout(system, state, dt, 90)
        # Ballistic apex of the final state (Newmark integrates constant gravity exactly).
        return end.position[2] + end.velocity[2] ** 2 / (2 * g), record

    c0, k0 = 10.0, K_HERTZ
    run = jax.jit(apex)  # one compiled roll-out for the run and the finite differences
    value, record = run(c0, k0)
    touching = np.flatnonzero(np.asarray(record.min_gap_m[:, 0]) < 0.0)
    assert bool(record.converged.all()) and touching[0] > 0 and touching[-1] < 89  # onset and release inside the run
    grad_c, grad_k = jax.jit(jax.grad(lambda c, k: apex(c, k)[0], argnums=(0, 1)))(c0, k0)

    def f(c, k):
        return run(c, k)[0]

    fd_c = (f(c0 + 1e-3, k0) - f(c0 - 1e-3, k0)) / 2e-3
    fd_k = (f(c0, k0 * (1 + 1e-5)) - f(c0, k0 * (1 - 1e-5))) / (2e-5 * k0)
    # Central differences converge as O(h²) to the implicit gradient (for K: 3e-3, 3e-5, 3e-7 at
    # relative steps 1e-2, 1e-3, 1e-4); at the steps used, measured 7e-10 (c) and 6e-9 (K).
    assert float(grad_c) == pytest.approx(float(fd_c), rel=1e-6)
    assert float(grad_k) == pytest.approx(float(fd_k), rel=1e-6)
    assert float(grad_c) < 0.0  # more damping, lower bounce


def test_write_results_json_and_figures(tmp_path):
    trajectory = spring_impact()
    written = d.write_results(trajectory, tmp_path)
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["summary"]["impacts"][0]["contact_time_s"] == pytest.approx(
        math.pi * math.sqrt(MASS / K_LINEAR), rel=2e-5
    )
    assert {
        "time_s",
        "com_position_m",
        "com_velocity_m_per_s",
        "contact_force_N",
        "kinetic_energy_J",
        "gas_pressure_Pa",
    } <= set(results["steps"])
    assert all(p.exists() for p in written) and (tmp_path / "figures" / "energies.png").exists()


def test_bad_inputs_name_the_fix():
    with pytest.raises(InvalidInputError, match="mass"):
        d.PointMassOnGround(None, [d.ground(LINEAR)])
    with pytest.raises(InvalidInputError, match="mass"):
        d.PointMassOnGround(-1.0, [d.ground(LINEAR)])
    system = d.PointMassOnGround(MASS, [d.ground(LINEAR)])
    with pytest.raises(InvalidInputError, match="drop height"):
        d.drop_state(system, [0.0, 0.0, 0.0], -0.5)
    state = d.drop_state(system, [0.0, 0.0, 0.0], 0.1)
    with pytest.raises(InvalidInputError, match="dt"):
        d.simulate(system, state, -1e-4, 0.1, progress=False)
    with pytest.raises(InvalidInputError, match="dt"):
        d.simulate(system, state, 1.0, 0.1, progress=False)
    with pytest.raises(InvalidInputError, match="degrees of freedom"):
        d.initial_state(system, [0.0, 0.0])
    with pytest.raises(InvalidInputError, match="damping"):
        d.ground(LINEAR, damping=-1.0)
    with pytest.raises(InvalidInputError, match="increase strictly"):
        d.TabulatedCompressionCurve([0.002, 0.001], [1.0, 2.0])
    with pytest.raises(InvalidInputError, match="target COR"):
        d.calibrate_contact_damping(lambda c: 0.5, 1.5, (0.0, 1.0))


def test_a_step_that_does_not_converge_raises_with_its_history():
    # One Newton iteration cannot settle a Hertzian contact step: the run must stop, not skip it.
    with pytest.raises(NoConvergenceError, match="Reduce dt") as info:
        system = d.PointMassOnGround(MASS, [d.ground(HERTZ)])
        state = d.initial_state(system, [0.0, 0.0, 1e-4], [0.0, 0.0, -1.0])
        d.simulate(system, state, 1e-3, 0.01, minimiser=d.DenseNewton(max_steps=1), progress=False)
    assert len(info.value.history) == 1 and info.value.history[0] > 0.0


def test_a_step_minimiser_returns_the_shared_solution():
    # The dynamics' minimisers return the package's one Solution, with the result code the engines use.
    system = d.PointMassOnGround(MASS, [d.ground(HERTZ)])
    state = d.initial_state(system, [0.0, 0.0, 1e-4], [0.0, 0.0, -1.0])
    potential = d.incremental_potential(system, d.Newmark(), state, jnp.asarray(1e-3))
    y0 = potential.free(state.position)
    # compiled: op by op the Newton loop's operations are each compiled on their own (~150 of them)
    minimise = eqx.filter_jit(lambda minimiser, potential, y: minimiser.minimise(potential, y))
    solved = minimise(d.DenseNewton(), potential, y0)
    assert isinstance(solved, shelljax.Solution) and bool(solved.converged)
    assert solved.result == shelljax.RESULTS.successful and int(solved.stats["assemblies"]) == int(solved.iterations)
    cut = minimise(d.DenseNewton(max_steps=1), potential, y0)
    assert cut.result == shelljax.RESULTS.max_steps_reached and not bool(cut.converged)


def test_one_plane_class_serves_the_dynamics_and_the_3d_engine():
    from shelljax.shell3d import ContactConfig

    assert d.Plane is shelljax.physics.Plane
    ground = d.Plane([0.0, 0.0, 0.0], [0.0, 0.0, 2.0], name="ground")
    # A static setup's planes hash and compare by their numbers (they key compiled programs) ...
    assert ground == d.Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], name="ground") and ground != d.Plane(
        [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], name="ground"
    )
    config = ContactConfig(planes=(((0.0, 0.0, 0.0), (0.0, 0.0, 1.0)),))
    assert config.planes == (ground,) and hash(config) == hash(ContactConfig(planes=(ground,)))
    np.testing.assert_array_equal(np.asarray(ground.gap(jnp.array([[1.0, 2.0, 0.5]]))), [0.5])
    # ... and carry no law of their own there: the setup's kind and friction apply to all of them.
    with pytest.raises(InvalidInputError, match="ContactConfig"):
        ContactConfig(planes=(d.ground(HERTZ),))


def test_mass_proportional_rayleigh_damping_decays_velocity_exponentially():
    alpha = 10.0  # [1/s]
    system = d.PointMassOnGround(MASS, [d.ground(LINEAR)], gravity=0.0)
    state = d.initial_state(system, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    trajectory = d.simulate(system, state, 1e-4, 0.1, rayleigh=d.Rayleigh(mass_coefficient=alpha), progress=False)
    speed = trajectory["com_velocity_m_per_s"][-1, 0]
    # With Newmark, (x − xₙ)/Δt is the mean of the step's end velocities, so each step scales v by
    # (1 − αΔt/2)/(1 + αΔt/2) = exp(−αΔt) + O((αΔt)³): ~1e-7 over 1000 steps (measured 4e-8).
    assert speed == pytest.approx(math.exp(-alpha * 0.1), rel=1e-6)


def test_hertz_impact_matches_its_closed_form():
    (impact,) = d.measured_cor(spring_impact(law=HERTZ, dt=1e-5))
    expected = d.hertz_impact(MASS, 1.0, K_HERTZ)
    # Newmark's O((ωΔt)²) error at ~470 steps per contact, plus O(Δt²) in the interpolated onset
    # and end: measured relative errors below 1e-5.
    assert impact.contact_time_s == pytest.approx(expected["contact_time_s"], rel=1e-4)
    assert impact.peak_force_N == pytest.approx(expected["peak_force_N"], rel=1e-4)
    assert impact.max_compression_m == pytest.approx(expected["max_compression_m"], rel=1e-4)
    assert impact.cor == pytest.approx(1.0, abs=1e-6)


def test_coulomb_friction_decelerates_a_sliding_mass_at_mu_g():
    mu, g = 0.5, STANDARD_GRAVITY
    system = d.PointMassOnGround(MASS, [d.ground(LINEAR, friction=mu, slip_tolerance=1e-6)])
    resting = -MASS * g / K_LINEAR  # [m]: the spring carries the weight, so the lagged λ = m g
    state = d.initial_state(system, [0.0, 0.0, resting], [1.0, 0.0, 0.0])
    trajectory = d.simulate(system, state, 1e-4, 0.1, progress=False)
    # Sliding at ‖slip‖ ≫ ε the friction force is exactly μ λ, so v = v₀ − μ g t, less half a step:
    # Newmark's a₀ holds the conservative forces only (friction needs a lagged previous state).
    assert trajectory["com_velocity_m_per_s"][-1, 0] == pytest.approx(1.0 - mu * g * (0.1 - 0.5e-4), rel=1e-9)
    np.testing.assert_allclose(trajectory["contact_force_N"][:, 0, 0][1:], -mu * MASS * g, rtol=1e-6)


@pytest.mark.parametrize("depth", [0.005, 0.01, 0.02])
def test_contact_diameter_of_a_sphere_cut_by_a_plane(depth):
    # A sphere of radius R cut at height h above its bottom meets the plane in a circle of radius
    # r = √(2Rh − h²). The icosphere's flat faces sit inside the sphere by at most the sag ℓ²/8R of
    # its longest edge ℓ, and a surface moved in by s moves the cut circle by s R / r: the bound.
    radius = 0.05
    nodes, faces = sphere_mesh(radius, layout="icosphere", subdivisions=4)
    edges = d.mesh_edges(faces)
    normal = np.array([0.0, 0.0, 1.0])
    gaps = nodes[:, 2] + radius
    diameter = d.contact_diameter(nodes, edges, gaps, normal, depth)
    circle = math.sqrt(2.0 * radius * depth - depth**2)
    sag = np.max(np.linalg.norm(nodes[edges[:, 0]] - nodes[edges[:, 1]], axis=1)) ** 2 / (8.0 * radius)
    assert 0.0 < 2.0 * circle - diameter <= 2.0 * sag * radius / circle
    # Tilted plane: the same patch seen along another normal.
    rotation = np.linalg.qr(np.array([[1.0, 0.3, 0.2], [0.1, 1.0, 0.4], [0.3, 0.2, 1.0]]))[0]
    tilted = d.contact_diameter(nodes @ rotation.T, edges, gaps, rotation @ normal, depth)
    assert tilted == pytest.approx(diameter, rel=1e-12)
    assert d.contact_diameter(nodes, edges, gaps + 1.0, normal, depth) == 0.0


def test_the_most_deformed_step_is_the_flattest_while_touching():
    from shelljax.dynamics._output import most_deformed_step

    # a tetrahedron "ball" 0.1 m tall: flattest (0.05 m) in the air at step 0, which must not count;
    # touching the ground (gap 0 ≤ contact distance) at steps 1 and 2, flatter at step 1
    def ball(height, lift):
        return np.array([[0.0, 0.0, lift], [0.05, 0.0, lift], [0.0, 0.05, lift], [0.0, 0.0, lift + height]]).ravel()

    positions = np.stack([ball(0.05, 0.2), ball(0.08, 0.0), ball(0.09, 0.0)])
    trajectory = d.Trajectory(
        records={"position_m": positions, "time_s": np.arange(3) * 1e-3, "min_gap_m": np.array([[0.2], [0.0], [0.0]])},
        plane_names=("ground",),
        plane_normals=np.array([[0.0, 0.0, 1.0]]),
        contact_distances_m=np.array([1e-3]),
        gravity_m_per_s2=np.array([0.0, 0.0, -9.81]),
        dt_s=1e-3,
        faces=np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]),
    )
    assert most_deformed_step(trajectory) == (1, 0)
