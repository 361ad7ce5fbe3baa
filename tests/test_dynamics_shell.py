"""The 3D shell in motion: ShellDynamicSystem with SparseNewton, scenarios, the CLI and replicas.

One small stiff ball (R = 5 cm, 200 faces, P_g = 5 kPa, 0.1 kg, sealed isothermal gas) keeps
every test cheap; the expensive checks of the issue are experiments/verify_dynamics.py.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from shelljax.physics import AdiabaticGas, IsothermalGas
import shelljax.shell3d as s3
from shelljax import InvalidInputError
from shelljax import dynamics as d
from shelljax.cli import main
from shelljax.config import bundled_data_dir
from shelljax.dynamics._shell import _pattern_key
from shelljax.physics import ATMOSPHERIC_PRESSURE, ShellProperties, adiabatic_gas_energy, isothermal_gas_energy
from shelljax.replica import load_replica, replica_volume, write_replica
from shelljax.scenario import SCENARIO_CHUNK, eqx_replace_damping, load_scenario

pytestmark = pytest.mark.slow  # 3D shells in motion: every test runs the dynamics

G = 9.80665
RADIUS, THICKNESS, E, NU, P_G, MASS = 0.05, 0.5e-3, 2e6, 0.4, 5000.0, 0.1
BALL = ShellProperties(gauge_pressure=P_G, young_modulus=E, thickness=THICKNESS, poisson_ratio=NU)
GHAT = 5e-4
# One compiled chunk length for every run of the module, the scenario's own: the CLI's runs and
# the tests' backward-Euler runs on this ball (the TINY config's mesh) then share one program.
CHUNK = SCENARIO_CHUNK


@pytest.fixture(scope="module")
def shell():
    return s3.ball(RADIUS, THICKNESS, n_triangles=200)


@pytest.fixture(scope="module")
def system(shell):
    ground = d.Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], d.BarrierContact(GHAT, 1e3), name="ground")
    # The TINY config's system: its damping a float64 array as the scenario sets it (not a weakly
    # typed one), so that the CLI's runs reuse the programs these tests traced.
    return d.shell_system(shell, BALL, gas=IsothermalGas(), mass=MASS, planes=[eqx_replace_damping(ground, 0.0)])


def _impact_state(system, height):
    """Just above the ground, moving at the speed of a drop from ``height`` [m] (free flight is exact)."""
    return d.drop_state(system, system.inflated, 2 * GHAT, velocity=[0.0, 0.0, -math.sqrt(2 * G * (height - 2 * GHAT))])


def test_inflated_state_is_in_equilibrium_and_free_falls_exactly(system):
    state = d.drop_state(system, system.inflated, 0.02)
    # a₀ = M⁻¹F(x₀): the rest-shape solve leaves nodal residuals ~1e-8 E h L, i.e. ~1e-9 m/s² here.
    assert np.max(np.abs(np.asarray(state.acceleration).reshape(-1, 3) - [0.0, 0.0, -G])) < 1e-6
    assert float(system.gas_state(system.inflated)[0]) == pytest.approx(P_G, rel=1e-9)
    # 50 steps of 0.6 ms in chunks of CHUNK: the bounce's compiled program
    traj = d.simulate(system, state, 6e-4, 50 * 6e-4, minimiser=d.SparseNewton(), progress=False, chunk=CHUNK)
    t, z = traj["time_s"], traj["com_position_m"][:, 2]
    # Newmark integrates constant gravity exactly and internal forces sum to zero: only Newton's 1e-10 m tolerance remains.
    assert np.max(np.abs(z - (z[0] - 0.5 * G * t**2))) < 1e-9
    assert np.all(traj["min_gap_m"] > GHAT)


def test_bounce_conserves_energy_without_damping(system):
    height = 0.02
    # Δt must resolve the shell's membrane waves (~1 ms here): at 0.5 ms Newmark gains 50 % of m g H on the rebound.
    traj = d.simulate(
        system, _impact_state(system, height), 2.5e-4, 0.05, minimiser=d.SparseNewton(), progress=False, chunk=CHUNK
    )
    impact = d.measured_cor(traj)[0]
    e = traj["total_energy_J"]
    drift = np.max(np.abs(e - e[0])) / (MASS * G * height)
    # The criterion: ≤ 1 % of the impact energy m g H over a bounce (Newmark, no damping).
    assert drift < 0.01, drift
    assert impact.speed_out_m_per_s / impact.speed_in_m_per_s > 0.9
    # A sphere flattened by its compression δ would touch over 2√(2Rδ); the pressurized wall curves
    # away around its patch instead, so its patch is smaller, never zero on a landing.
    assert 0.0 < impact.max_contact_diameter_m < 2.0 * math.sqrt(2.0 * RADIUS * impact.max_compression_m)


def test_gradient_of_bounce_height_through_contact_onset(system):
    height, dt, steps = 0.02, 1e-3, 12  # onset at the first step; 12 ms into the contact

    @eqx.filter_jit
    def rebound(c):
        damped = system.with_planes([eqx.tree_at(lambda p: p.damping, system.planes[0], c)])
        state = d.initial_state(damped, _impact_state(system, height).position, _impact_state(system, height).velocity)
        final, _ = d.rollout(damped, state, dt, steps, minimiser=d.SparseNewton())
        com_z, com_vz = damped.centre_of_mass(final.position)[2], damped.centre_of_mass(final.velocity)[2]
        return com_z + com_vz * jnp.abs(com_vz) / (2 * G)

    value_and_grad = eqx.filter_jit(jax.value_and_grad(rebound))
    c, h = 2.0, 1e-3
    _, grad = value_and_grad(jnp.asarray(c))
    fd = (value_and_grad(jnp.asarray(c + h))[0] - value_and_grad(jnp.asarray(c - h))[0]) / (2 * h)
    # Central differences err by O(h²) ≈ 1e-6 relative here, Newton's 1e-10 m tolerance by 1e-10/h ≈ 1e-7 m per (N·s/m).
    assert float(grad) == pytest.approx(float(fd), rel=1e-4, abs=1e-6)
    # Mid-compression the dashpot slows the descent: more damping, a higher proxy apex; far from noise.
    assert float(grad) > 1e-5


@pytest.mark.parametrize("gas, exponent", [("isothermal", 1.0), ("adiabatic", 1.4)])
def test_sealed_gas_energy_is_accurate_near_its_reference_volume(gas, exponent):
    v0, u = 4.87e-4, 1e-7  # the test ball's volume [m³]; a Newton step's relative volume change
    energy = {"isothermal": isothermal_gas_energy, "adiabatic": adiabatic_gas_energy}[gas]
    value = float(energy(v0 * (1.0 + u), v0, P_G))
    p_abs = ATMOSPHERIC_PRESSURE + P_G
    series = v0 * (-P_G * u + 0.5 * exponent * p_abs * u**2 - exponent * (exponent + 1.0) * p_abs * u**3 / 6.0)
    # The energy carries its own round-off (1e-16 relative), not that of p₀V₀/(γ − 1) ≈ 130 J (1e-14 J: 1e-8 relative here).
    assert value == pytest.approx(series, rel=1e-12)


def test_adiabatic_gas_converges_through_contact_and_its_pressure_rise_is_gamma_times_the_isothermal(shell, system):
    # 12.5 ms at 0.25 ms: contact onset (step 6, where gas-energy round-off can stall Newton) and 3 mm of compression.
    adiabatic = d.shell_system(shell, BALL, gas=AdiabaticGas(), mass=MASS, planes=system.planes)
    # one mesh, one sparsity pattern: its key (a static field) lets both systems share compiled
    # steps; the key is the pattern's content, so another set of fixed dofs is another key
    assert adiabatic.sparsity.key == system.sparsity.key
    pattern = system.sparsity.pattern
    assert _pattern_key(dataclasses.replace(pattern, free=~pattern.free)) != system.sparsity.key
    newton = d.SparseNewton(reuse_matrix=False)
    traj = d.simulate(
        adiabatic, _impact_state(adiabatic, 0.02), 2.5e-4, 50 * 2.5e-4, minimiser=newton, progress=False, chunk=CHUNK
    )
    # Quadratic Newton (a fresh matrix every iteration): the stall against round-off in Φ_inc ran into max_steps = 50.
    assert np.max(traj["newton_iterations"]) <= 8
    volume, pressure = traj["gas_volume_m3"], traj["gas_pressure_Pa"]
    strain = (volume[0] - volume) / volume[0]
    assert np.max(strain) > 5e-4
    # The sealed isothermal gas's rise at the same volume change is P_abs ε / (1 − ε): the ratio by least squares.
    isothermal = (ATMOSPHERIC_PRESSURE + P_G) * strain / (1.0 - strain)
    ratio = np.sum(isothermal * (pressure - P_G)) / np.sum(isothermal**2)
    # ΔP_adiabatic / ΔP_isothermal = γ (1 + (γ − 1) ε / 2 + …): at ε < 2e-3 the second order is < 4e-4.
    assert ratio == pytest.approx(1.4, rel=1e-3), (ratio, np.max(strain))


def test_kept_newton_matrix_gives_the_same_bounce_with_fewer_factorisations(system):
    state, n_steps, tolerance = _impact_state(system, 0.02), 50, 1e-10
    runs = {
        reuse: d.simulate(
            system,
            state,
            1e-3,
            n_steps * 1e-3,
            integrator=d.BackwardEuler(),
            progress=False,
            chunk=CHUNK,
            minimiser=d.SparseNewton(step_tolerance=tolerance, reuse_matrix=reuse),
        )
        for reuse in (True, False)
    }
    kept, fresh = runs[True], runs[False]
    assert np.max(kept["min_gap_m"]) > GHAT > np.min(kept["min_gap_m"])  # the run lands and leaves
    # Each step ends within about the tolerance of its minimiser under either matrix, and backward
    # Euler does not amplify a difference: at most 2 tolerances a step accumulate.
    assert np.max(np.abs(kept["position_m"] - fresh["position_m"])) < 2 * n_steps * tolerance
    assert np.all(fresh["newton_matrices"] == fresh["newton_iterations"])
    assert np.sum(kept["newton_matrices"]) < 0.5 * np.sum(fresh["newton_matrices"])


def test_release_factorizations_frees_the_dynamics_host_caches_and_a_system_still_steps(system):
    from shelljax.shell3d import _sparse as sparse_module

    state, dt = _impact_state(system, 0.02), 6e-4

    def run():
        return d.simulate(system, state, dt, 10 * dt, minimiser=d.SparseNewton(), progress=False, chunk=CHUNK)

    before = run()
    assert sparse_module._KEPT and sparse_module._ASSEMBLIES and sparse_module._ANALYSED
    s3.release_factorizations()
    assert not sparse_module._KEPT and not sparse_module._ASSEMBLIES and not sparse_module._ANALYSED
    # the system carries its own sparsity pattern: after the release it steps, rebuilding what it needs
    after = run()
    np.testing.assert_array_equal(after["position_m"], before["position_m"])


def test_a_wild_acceleration_changes_newtons_start_not_the_step(system):
    # Backward Euler's step does not depend on aₙ; Newton's start does (x̂ + Δt²aₙ when that lowers
    # Φ_inc). An initial state far from equilibrium can carry aₙ ~ 1e5 m/s², metres at Δt = 10 ms.
    state = _impact_state(system, 0.02)
    kick = np.abs(
        np.random.default_rng(0).standard_normal(state.acceleration.shape)
    )  # every component positive: upward, off the ground
    wild = eqx.tree_at(lambda s: s.acceleration, state, jnp.asarray(1e5 * kick))
    ends = []
    # One chunk of the module's backward-Euler runs (their compiled program, not one of its own);
    # its first step is the one from each start.
    for start in (state, wild):
        traj = d.simulate(
            system,
            start,
            1e-2,
            CHUNK * 1e-2,
            integrator=d.BackwardEuler(),
            minimiser=d.SparseNewton(),
            progress=False,
            chunk=CHUNK,
        )
        assert bool(traj["converged"][1])
        ends.append(traj["position_m"][1])
    # Both end within about Newton's 1e-10 m step tolerance of the same minimiser: 2e-10 apart at most, 1e-9 with margin.
    assert np.max(np.abs(ends[0] - ends[1])) < 1e-9


def test_contact_damping_is_one_dashpot_on_the_centre_of_mass(system):
    raw = jnp.zeros(system.node_masses.shape).at[:20].set(1.0)
    # Many touching vertices: weight 1 (one dashpot c on the body, whatever the mesh); none: 0.
    assert float(system.body_damping_weights(raw)) == 1.0
    assert float(system.body_damping_weights(jnp.zeros_like(raw))) == 0.0
    assert float(jnp.max(system.damping_weights(raw))) == 0.0


def test_replica_round_trip(shell, tmp_path):
    written = write_replica(
        tmp_path,
        shell,
        {
            "gauge_pressure_Pa": (P_G, 150.0),
            "youngs_modulus_Pa": (E, 1e5),
            "poisson_ratio": NU,
            "thickness_m": (THICKNESS, 2e-5),
            "mass_kg": MASS,
            "cor": 0.75,
        },
        gas="adiabatic",
    )
    assert [p.name for p in written] == ["replica.glb", "replica.json"]
    system, replica = load_replica(tmp_path)
    assert replica["gauge_pressure_Pa"] == {"value": P_G, "std": 150.0}
    assert replica["cor"]["value"] == 0.75
    assert float(system.params.young_modulus) == E and float(system.params.thickness) == THICKNESS
    assert float(jnp.sum(system.node_masses)) == pytest.approx(MASS, rel=1e-12)
    assert system.config.gas == AdiabaticGas()
    # glTF stores float32 positions (7 digits); the inflated state reproduces the mesh's volume to the rest solve's 1e-6.
    assert float(system.volume(system.inflated)) == pytest.approx(replica_volume(tmp_path), rel=1e-5)
    assert float(system.gas_state(system.inflated)[0]) == pytest.approx(P_G, rel=1e-9)


TINY = """
name = "tiny"
[object]
gauge_pressure_Pa = 5000.0
youngs_modulus_Pa = 2e6
radius_m = 0.05
thickness_m = 5e-4
poisson_ratio = 0.4
mass_kg = 0.1
gas = "isothermal"
mesh_faces = 200
[integrator]
scheme = "backward-euler"
dt_s = 2e-3
duration_s = 0.08
[dissipation]
contact_damping_N_s_per_m = 1.0
[[planes]]
name = "ground"
point_m = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
activation_distance_m = 5e-4
barrier_stiffness_J_per_m2 = 1e3
[initial]
drop_heights_m = [0.002]
[outputs]
figures = true
max_frames = 3
preview_gif = true
"""


def test_cli_simulate_tiny_config(tmp_path, capsys):
    config = tmp_path / "tiny.toml"
    config.write_text(TINY)
    assert main(["simulate", str(config), "--out", str(tmp_path / "out"), "--quiet", "--device", "cpu"]) == 0
    run = tmp_path / "out" / "h0.00m"
    results = json.loads((run / "results.json").read_text())
    # Backward Euler at 2 ms damps a 2 mm drop to rest: the check is that it lands and everything is written.
    assert max(step[0][2] for step in results["steps"]["contact_force_N"]) > 0.5 * MASS * G
    for name in (
        "figures/trajectory.png",
        "figures/energies.png",
        "figures/contact_force.png",
        "figures/max_deformation.png",
        "frames/frame_0000.ply",
        "preview.gif",
    ):
        assert (run / name).is_file() and (run / name).stat().st_size > 1_000, name  # written and holding data
    summary = json.loads((tmp_path / "out" / "scenario.json").read_text())
    assert summary["parameters"]["mesh_faces"] == 210  # the remesher's nearest to 200
    assert "results:" in capsys.readouterr().out
    # where it ran: the request, and each stage's device (the drop: a sparse stage, on the CPU here)
    assert summary["placement"]["request"] == "cpu"
    assert [(s["stage"], s["device"]) for s in summary["compilation"]["stages"] if "device" in s] == [
        ("drop 0.00 m", "cpu:0")
    ]


def test_scenario_calibrates_the_cor_even_past_critical_damping(tmp_path):
    # The bracket's top, 60 N·s/m, is past critical damping 2√(2πR P_g m) = 25 N·s/m: the ball
    # may not leave the ground there, which must read as COR ≈ 0, not fail the calibration.
    config = tmp_path / "calibrated.toml"
    config.write_text(
        TINY.replace(
            "contact_damping_N_s_per_m = 1.0\n",
            "cor = 0.6\ncalibration_bracket_N_s_per_m = [0.0, 60.0]\ncalibration_height_m = 0.02\n",
        )
    )
    assert main(["simulate", str(config), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    calibration = json.loads((tmp_path / "out" / "scenario.json").read_text())["calibration"]
    # The criterion: the calibrated drop's √(h/H) within 2 % of the target.
    assert calibration["cor"] == pytest.approx(0.6, rel=0.02)
    by_damping = dict(calibration["evaluations"])
    assert by_damping[60.0] < 0.1 < 0.6 < by_damping[0.0]


@pytest.mark.parametrize(
    "change, field",
    [
        (("mass_kg = 0.1\n", ""), "mass"),
        (("drop_heights_m = [0.002]", "drop_heights_m = [-0.5]"), "initial.drop_heights_m"),
        (("dt_s = 2e-3", "dt_s = 0.01"), "integrator.dt_s"),
        (("youngs_modulus_Pa = 2e6\n", ""), "object.gauge_pressure_Pa"),
        (('scheme = "backward-euler"', 'scheme = "leapfrog"'), "integrator.scheme"),
        (("[dissipation]\n", "[dissipation]\ncor = 1.5\n"), "dissipation.cor"),
        (("[integrator]\n", '[estimators]\nwrinkle_law = "guess"\n[integrator]\n'), "estimators.wrinkle_law"),
        (("[integrator]\n", '[estimators]\nmethods = ["fit"]\n[integrator]\n'), "estimators.methods"),
    ],
)
def test_bad_configs_name_file_field_and_fix(tmp_path, change, field):
    config = tmp_path / "bad.toml"
    config.write_text(
        TINY.replace(*change).replace(
            "contact_damping_N_s_per_m = 1.0\n", "" if "cor" in change[1] else "contact_damping_N_s_per_m = 1.0\n"
        )
    )
    with pytest.raises(InvalidInputError) as err:
        from shelljax.scenario import resolve_object, run_scenario

        scenario = load_scenario(config)
        if field in ("mass",):
            resolve_object(scenario)
        run_scenario(scenario, tmp_path / "out", progress=False)
    message = str(err.value)
    assert str(config) in message and field in message and "Fix" in message
    assert not (tmp_path / "out").exists()  # a refused config leaves no output directory behind


def test_scenario_estimates_the_object_with_its_estimators_table(tmp_path):
    from shelljax.estimate import EstimatorOptions, run_estimator
    from shelljax.scenario import resolve_object
    from shelljax.session import load_session

    session_path = bundled_data_dir() / "sessions" / "pezzi.toml"
    config = tmp_path / "estimated.toml"
    given = "gauge_pressure_Pa = 5000.0\nyoungs_modulus_Pa = 2e6\nradius_m = 0.05\n"
    config.write_text(
        TINY.replace(given, f'session = "{session_path}"\nestimate = "fit"\n').replace(
            "[integrator]\n", '[estimators]\nforward_model = "scaling"\n[integrator]\n'
        )
    )
    scenario = load_scenario(config)
    # A sealed object is estimated with a sealed (isothermal) gas unless [estimators] says otherwise.
    assert scenario.estimator_options["gas"] == "isothermal"
    obj = resolve_object(scenario)
    expected = run_estimator(
        "fit", load_session(session_path), EstimatorOptions(forward_model="scaling", gas="isothermal")
    )
    assert obj.properties.gauge_pressure == expected.estimates["gauge_pressure"].value
    assert obj.properties.young_modulus == expected.estimates["young_modulus"].value
    assert obj.source["estimator_options"]["forward_model"] == "scaling"


def test_contact_damping_calibrates_to_0_75_and_rejects_a_cor_above_the_numerics_alone(system):
    # The configs' scheme and step: backward Euler at 1 ms, whose own COR(c = 0) is ≈ 0.80 on this ball.
    height, dt = 0.02, 1e-3

    @functools.cache  # the 0.9 check reuses the bracket's runs
    def cor(c):
        damped = system.with_planes([eqx_replace_damping(system.planes[0], c)])
        # 50 steps hold the 42 ms contact and its release; the apex is extrapolated ballistically.
        traj = d.simulate(
            damped,
            _impact_state(damped, height),
            dt,
            0.05,
            integrator=d.BackwardEuler(),
            minimiser=d.SparseNewton(),
            progress=False,
            chunk=CHUNK,
        )
        first = d.measured_cor(traj)[0]
        return math.sqrt(first.bounce_height_m / (first.speed_in_m_per_s**2 / (2 * G)))

    cal = d.calibrate_contact_damping(cor, 0.75, (0.0, 2.0), rtol=1e-2)
    # The criterion: within 2 % of the target COR (Brent's c tolerance 0.02 N·s/m moves the COR by ~1e-3).
    assert abs(cal.cor - 0.75) < 0.02 * 0.75
    assert 0.0 < cal.damping < 2.0
    # Numerical dissipation must not pass for physical damping: a target above COR(c = 0) is refused, naming the range.
    assert 0.75 < cor(0.0) < 0.9
    with pytest.raises(InvalidInputError, match="outside the reachable range"):
        d.calibrate_contact_damping(cor, 0.9, (0.0, 2.0))
