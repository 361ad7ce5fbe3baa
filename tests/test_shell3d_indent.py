"""Ball-on-ground indentation: force balance, sealed gas, force control, observables, gradients."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from shelljax.physics import IsothermalGas, PrescribedGas
import shelljax.shell3d as s3
from shelljax import InvalidInputError, NoConvergenceError
from shelljax.physics import ATMOSPHERIC_PRESSURE, ShellProperties
from shelljax.shell3d import EquilibriumProblem, SparseSolver
from shelljax.shell3d._contact import BARRIER_STEP_FRACTION, body_gaps
from shelljax.physics import STANDARD_GRAVITY as GRAVITY
from shelljax.shell3d._steps import feasible_start

from _balance import net_vertical_residual

pytestmark = pytest.mark.slow  # solves the 3D shell

# tests/test_shell3d_energy.py and tests/test_shell3d_friction.py solve this file's balls (500
# faces, 1 cm indenter, the scan as rest shape): run on one worker, the model programs they compile
# are found here in the persistent cache.
SHARED_PROGRAMS = "shell3d_ball"

R, H, E, NU, PG = 0.13, 0.9e-3, 2.34e6, 0.4, 1300.0
PEZZI = ShellProperties(gauge_pressure=PG, young_modulus=E, thickness=H, poisson_ratio=NU)
N_TRI = 500


@pytest.fixture(scope="module")
def ball():
    return s3.ball(radius=R, thickness=H, n_triangles=N_TRI)


@pytest.fixture(scope="module")
def sealed(ball):
    return s3.Indentation(ball, PEZZI, gas=IsothermalGas(), indenter_radius=0.01, rest_shape="scan", progress=False)


def test_bad_inputs_raise_clear_errors(ball):
    with pytest.raises(InvalidInputError, match="young_modulus"):
        s3.Indentation(
            ball, ShellProperties(gauge_pressure=PG, young_modulus=-1.0, thickness=ball.thickness, poisson_ratio=NU)
        )
    with pytest.raises(InvalidInputError, match="gas"):
        s3.Indentation(ball, PEZZI, gas="steam", rest_shape="scan")
    with pytest.raises(InvalidInputError, match="max_newton_iterations"):
        s3.Indentation(ball, PEZZI, max_newton_iterations=0)
    with pytest.raises(InvalidInputError, match="thickness"):  # one wall: the shell's h and the properties' agree
        s3.Indentation(ball, ShellProperties(gauge_pressure=PG, young_modulus=E, thickness=2 * H, poisson_ratio=NU))
    with pytest.raises(TypeError):  # keyword-only: no positional E, ν, P_g to swap
        s3.Indentation(ball, E, NU, PG)


def test_newton_iteration_limit_is_the_users(ball):
    # One Newton iteration cannot converge a 4 mm poke from the unloaded shell: the error must say
    # so with the limit the user set, not the default 60 (the rest state is not limited by it).
    sim = s3.Indentation(
        ball,
        PEZZI,
        gas=IsothermalGas(),
        indenter_radius=0.01,
        rest_shape="scan",
        progress=False,
        max_newton_iterations=1,
    )
    with pytest.raises(NoConvergenceError, match="after 1 iterations"):
        sim.solve(depth=0.004)


def test_sealed_gas_conserves_pv_and_forces_balance(sealed):
    states = sealed.curve([0.004, 0.008])
    p0v0 = (ATMOSPHERIC_PRESSURE + PG) * sealed.reference_volume
    prev_force = 0.0
    for st in states:
        obs = st.observables()
        # Isothermal ideal gas: (P_atm + p) V = p₀ V₀ holds exactly in the energy; the solve is
        # converged to ~1e-8 relative forces, so the product matches to ~1e-10 relative.
        np.testing.assert_allclose((ATMOSPHERIC_PRESSURE + obs["pressure"]) * obs["volume"], p0v0, rtol=1e-9)
        assert obs["pressure"] > PG  # squeezing raises the pressure
        # Independent of the gas law's bookkeeping: the sealed equilibrium must be an equilibrium
        # of the prescribed-pressure model at the gas's current pressure (same wall forces).
        prescribed = sealed.model.with_config(dataclasses.replace(sealed.model.config, gas=PrescribedGas()))
        params = sealed.params_at(st.q, gauge_pressure=obs["pressure"])
        residual = np.where(prescribed.free, prescribed.host_gradient(st.q, params), 0.0)
        assert np.max(np.abs(residual)) < 10 * sealed.atol
        # Global balance: the only vertical loads are the indenter and the ground (pins are
        # horizontal), so they cancel up to Newton's net vertical residual; round-off of sums of
        # ~500 nodal forces of ≤ 1 N is ~1e-13 N.
        unbalance = obs["ground_reaction"] - obs["force"]
        np.testing.assert_allclose(unbalance, -net_vertical_residual(sealed, st), rtol=0, atol=1e-11)
        assert abs(unbalance) < 5 * sealed.atol  # a signed sum of residuals ≤ atol each: measured ≤ 0.7 atol
        assert obs["force"] > prev_force
        prev_force = obs["force"]
        assert 0 < obs["w0"] <= st.depth + 1e-9
        assert obs["D_l"] > 0 and obs["H"] < sealed.top_height


def test_weight_adds_to_ground_reaction(ball):
    mass = 0.4
    sim = s3.Indentation(ball, PEZZI, indenter_radius=0.01, mass=mass, rest_shape="scan", progress=False)
    st = sim.solve(depth=0.004)
    obs = st.observables()
    unbalance = obs["ground_reaction"] - obs["force"] - mass * GRAVITY
    np.testing.assert_allclose(unbalance, -net_vertical_residual(sim, st), rtol=0, atol=1e-11)  # as above
    assert abs(unbalance) < 5 * sim.atol  # as above


def test_force_control_reproduces_displacement_control(ball):
    # Newton stops at max |force residual| ≤ atol, so the indenter force of a force-controlled
    # state matches the prescribed one to atol (the residual on the indenter's dof): 1e-8 N here,
    # well inside the 1e-6 relative (≈ 7e-7 N) asserted. With the default atol (5.5e-6 N) this
    # check passed or failed with the Newton path (a kept preconditioner from earlier solves).
    sim = s3.Indentation(
        ball, PEZZI, gas=IsothermalGas(), indenter_radius=0.01, rest_shape="scan", force_tolerance=1e-8, progress=False
    )
    st = sim.solve(depth=0.006)
    force = st.observables()["force"]
    st_f = sim.solve(force=force, steps=3)
    obs_f = st_f.observables()
    np.testing.assert_allclose(obs_f["force"], force, rtol=1e-6)
    # Same equilibrium (unique for this convex-in-practice load path): depth agrees to the
    # Newton tolerance divided by the stiffness, far below 1e-7 m.
    np.testing.assert_allclose(st_f.depth, 0.006, atol=1e-7)


def test_export_and_plot(sealed, tmp_path):
    st = sealed.solve(depth=0.004)
    st.export(tmp_path / "poked.obj")
    st.plot(tmp_path / "poked.png")
    text = (tmp_path / "poked.obj").read_text()
    assert text.count("\nv ") + text.startswith("v ") >= sealed.model.mesh.n_vertices - 1
    assert (tmp_path / "poked.png").stat().st_size > 10_000
    # A 4 mm poke is far before the wrinkling onset: the angular spectrum of the solved state sees
    # the axisymmetric dimple (ring means ≈ mm) and no mode above 1 % of it (mesh irregularity only).
    spectrum = st.wrinkles(max_radius=0.1, ring_width=0.01)
    assert spectrum.axisymmetric_rms > 0.2 * st.observables()["w0"]
    assert spectrum.count_amplitude < 0.01 * spectrum.axisymmetric_rms


def test_equilibrium_force_gradients_match_central_differences(ball):
    # Central differences of F need primal solves far below the default force tolerance (≈ 5e-6 N
    # here, about the F difference of a 1e-3 relative step × 2e-3): 1e-10 N.
    sim = s3.Indentation(ball, PEZZI, indenter_radius=0.01, rest_shape="scan", progress=False, force_tolerance=1e-10)
    force = sim.force_function(depth=0.005)
    theta = {"gauge_pressure": jnp.asarray(PG), "young_modulus": jnp.asarray(E), "thickness": jnp.asarray(H)}
    grad = jax.grad(force)(theta)
    for key, rel in (("gauge_pressure", 1e-3), ("young_modulus", 1e-3), ("thickness", 1e-3)):
        step = rel * float(theta[key])
        fp = float(force(dict(theta, **{key: theta[key] + step})))
        fm = float(force(dict(theta, **{key: theta[key] - step})))
        fd = (fp - fm) / (2 * step)
        # Central differences: truncation O(rel²) ≈ 1e-6 relative; solver noise atol/ΔF ≈ 4e-8.
        np.testing.assert_allclose(float(grad[key]), fd, rtol=1e-4)
        tangent = {k: jnp.asarray(float(k == key)) for k in theta}
        _, jvp = jax.jvp(force, (theta,), (tangent,))
        np.testing.assert_allclose(float(jvp), fd, rtol=1e-4)


@pytest.mark.parametrize("force_tolerance", [None, 1e-3])
def test_default_rest_shape_reproduces_the_scan_volume(ball, force_tolerance):
    """The scan is the pressurized shape: the default rest shape is the scan shrunk so that its
    pressurized equilibrium encloses the scan's volume (to 1e-6). A loose force tolerance (1e-3 N,
    ~100× the per-vertex pressure load × 1e-6) used to stall this fixed point: the forward solves
    stopped before the volume could move; the rest solve now tightens it to the volume target."""
    from shelljax.geometry import signed_volume

    sim = s3.Indentation(
        ball, PEZZI, gas=PrescribedGas(), indenter_radius=0.01, progress=False, force_tolerance=force_tolerance
    )
    scan_volume = signed_volume(ball.mesh.vertices, ball.mesh.faces)
    assert float(sim.model.volume(sim.q_reference)) == pytest.approx(scan_volume, rel=1e-6)
    # a thin sphere's small-strain rest radius R0 = R / (1 + P R (1−ν) / (2 E h)); strain ε = 0.024 here,
    # so the Neo-Hookean answer differs at O(ε²) ≈ 6e-4 (measured 2.8e-4).
    scale = (signed_volume(np.asarray(sim.rest), ball.mesh.faces) / scan_volume) ** (1 / 3)
    assert scale == pytest.approx(1 / (1 + PG * R * (1 - NU) / (2 * E * H)), rel=1e-3)
    if force_tolerance is None:
        # The reference state is one pure function, the dynamics' too: in the mesh's own frame it
        # is the simulation's, shifted by the simulation's placing of the scan on the ground.
        reference = s3.inflated_reference(ball, sim.base_params)
        shift = sim.q_reference[3 * sim.bottom : 3 * sim.bottom + 3] - ball.mesh.vertices[sim.bottom]
        np.testing.assert_allclose(reference.inflated + shift, sim.q_reference[:-3].reshape(-1, 3), rtol=0, atol=1e-12)
        np.testing.assert_allclose(reference.rest + shift, sim.rest, rtol=0, atol=1e-12)
        assert reference.reference_volume == pytest.approx(sim.reference_volume, rel=1e-12)
        assert reference.rest_mismatch == pytest.approx(sim.rest_mismatch, rel=1e-6, abs=1e-12)


def test_depth_substeps_end_exactly_on_the_requested_level():
    # Curves and checkpoints look levels up by value: the last sub-step must be the level itself,
    # not d_prev + (depth − d_prev)·n/n rounded (it is, for 0.05142 after 0.03212).
    stepper = dataclasses.make_dataclass("Stepper", ["max_step"])(max_step=0.003)
    assert 0.03212 + (0.05142 - 0.03212) * 7 / 7 != 0.05142
    for d_prev, depth in ((0.03212, 0.05142), (0.0, 0.0107), (0.1, 0.1)):
        steps = s3.Indentation._substeps(stepper, d_prev, depth)
        assert steps[-1] == depth
        assert np.all(np.diff([d_prev, *steps]) <= 0.003 + 1e-15)


def test_rim_refinement_on_ring_and_irregular_meshes():
    from shelljax.shell3d._observables import _parabola_peak

    # Ring mesh: rings of 6 vertices on z = 0.2 − (r − 0.05)²: the parabola recovers the peak
    # between the rings exactly.
    radii = np.array([0.046, 0.049, 0.053])
    r = np.repeat(radii, 6)
    z = 0.2 - (r - 0.05) ** 2
    r_all, z_all = np.concatenate([r, r]), np.concatenate([z, 1e-4 + 0 * z])  # plus a lower half
    rp, zp = _parabola_peak(r_all, z_all, 0.049)
    assert rp == pytest.approx(0.05, abs=1e-12) and zp == pytest.approx(0.2, abs=1e-12)
    # Irregular mesh (every radius distinct), a ground vertex at nearly the rim's radius: no
    # refinement, the highest vertex is the rim (it extrapolated to z = 1.67 m before).
    r_irr = np.array([0.04, 0.0497, 0.049, 0.05005, 0.06, 0.0498])
    z_irr = np.array([0.19, 0.1999, 0.2001, 7e-5, 0.18, 8e-5])
    assert _parabola_peak(r_irr, z_irr, 0.049) == (0.049, 0.2001)


def test_newton_start_keeps_the_converged_contact_gaps(sealed):
    """Vertices in the barrier's range keep their last converged gap (not ĝ/4: Newton on a log
    barrier started far above its equilibrium gap takes damped iterations, see shell3d._steps.feasible_start);
    new penetrations go to ĝ/4; every other vertex stays where the predictor put it."""
    q_prev = sealed.solve(depth=0.004).q
    ghat = sealed.activation_distance
    guess = q_prev.copy()
    guess[-1] -= 1e-3  # the indenter 1 mm deeper: its contact vertices now penetrate
    # and the nearest vertex outside its range is pushed halfway into it
    x_prev = q_prev[:-3].reshape(-1, 3)
    outside = np.linalg.norm(x_prev - q_prev[-3:], axis=1) - sealed.indenter_radius >= ghat
    k = int(np.flatnonzero(outside)[np.argmin(np.linalg.norm(x_prev[outside] - q_prev[-3:], axis=1))])
    guess[3 * k : 3 * k + 3] = guess[-3:] + 0.5 * (x_prev[k] - guess[-3:])
    start = feasible_start(guess, sealed.model.config, sealed.activation_distance, q_prev)

    def gaps(q):
        x = q[:-3].reshape(-1, 3)
        return np.linalg.norm(x - q[-3:], axis=1) - sealed.indenter_radius, x[:, 2]

    (ind_prev, ground_prev), (ind_guess, ground_guess), (ind, ground) = gaps(q_prev), gaps(guess), gaps(start)
    touching = ind_prev < ghat
    assert touching.sum() >= 1 and (ground_prev < ghat).sum() >= 3
    np.testing.assert_allclose(ind[touching], ind_prev[touching], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(ground[ground_prev < ghat], ground_prev[ground_prev < ghat], rtol=1e-9, atol=1e-15)
    fresh = ~touching & (ind_guess < 0.25 * ghat)
    assert fresh[k]
    np.testing.assert_allclose(ind[fresh], 0.25 * ghat, rtol=1e-9)
    moved = touching | fresh | (ground_prev < ghat) | (ground_guess < 0.25 * ghat)
    np.testing.assert_array_equal(start.reshape(-1)[:-3].reshape(-1, 3)[~moved], guess[:-3].reshape(-1, 3)[~moved])
    assert ind.min() > 0 and ground.min() > 0


def test_line_search_projection_stops_only_the_vertices_a_step_would_drive_into_a_body(sealed):
    """Newton's first step of a 4 mm poke from the resting ball drives a few vertices through
    the ground. The line search's projection (EquilibriumProblem.feasible_trial) stops exactly those
    short, at BARRIER_STEP_FRACTION of their gap, lets every other vertex take the whole step,
    and the projected full step is feasible and lowers the energy: it is accepted without
    halving, where the plain step is infeasible and would be halved as a whole."""
    model = sealed.model
    guess = sealed.q_reference.copy()
    guess[-3:] = sealed.touch_center - np.array([0.0, 0.0, 0.004])
    q = feasible_start(guess, model.config, sealed.activation_distance, sealed.q_reference)
    params = sealed.params_at(q)
    free = model.free
    gradient = model.host_gradient(q, params)
    g = np.where(free, gradient, 0.0)
    mat, rank_one = model.host_hessian(q, params, False, gradient)
    step = np.where(free, -SparseSolver(mat, rank_one, symmetric=True, definite=True).apply_inverse(g), 0.0)
    trial = q + step
    assert not np.isfinite(model.host_energy(trial, params))  # plain Newton would have to halve

    projected = EquilibriumProblem(model, model.host_params(params)).feasible_trial(q, trial)
    ghat = model.config.contact.activation_distance
    start, plain, after = body_gaps(q, model.config), body_gaps(trial, model.config), body_gaps(projected, model.config)
    stopped = np.zeros(model.config.n_vertices, dtype=bool)
    for g0, g1, g2 in zip(start, plain, after):
        hit = (g1 < BARRIER_STEP_FRACTION * g0) & (g1 < ghat)
        stopped |= hit
        # relative to the gap: moving a vertex along the sphere's normal repeats |x − c| − r in
        # floating point (≈ 1e-17 m against gaps ≥ 1e-6 m)
        np.testing.assert_allclose(g2[hit], BARRIER_STEP_FRACTION * g0[hit], rtol=1e-9)
        assert g2.min() > 0.0
    assert 1 <= stopped.sum() < 0.05 * stopped.size
    moved = np.repeat(stopped, 3)
    np.testing.assert_array_equal(projected[:-3][~moved], trial[:-3][~moved])
    np.testing.assert_array_equal(projected[-3:], trial[-3:])
    np.testing.assert_array_equal(projected[~free], trial[~free])

    e0, e1 = model.host_energy(q, params), model.host_energy(projected, params)
    assert e1 <= e0 + 1e-4 * min(float(g @ (projected - q)), 0.0)  # the line search's Armijo test
