"""Smoothed lagged Coulomb friction on the ground: potential, Hessian, cone, stick/slip, balance."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from shelljax.physics import IsothermalGas
import shelljax.shell3d as s3
from shelljax import InvalidInputError
from shelljax.physics import ShellProperties, friction_energy, friction_force, friction_mollifier
from shelljax.shell3d import ContactConfig

from _balance import net_vertical_residual

pytestmark = pytest.mark.slow  # solves the 3D shell

R, H, E, NU, PG = 0.13, 0.9e-3, 2.34e6, 0.4, 1300.0
PEZZI = ShellProperties(gauge_pressure=PG, young_modulus=E, thickness=H, poisson_ratio=NU)
N_TRI = 500  # 258 vertices, 15 in ground contact at 2 cm: enough for stick/slip statistics
DEPTH = 0.02
MUS = (0.0, 0.05, 0.5, 2.0)

# The frictionless ball is tests/test_shell3d_indent.py's sealed one (500 faces, 1 cm indenter,
# the scan as rest shape): run on one worker, that file finds its model programs in the
# persistent cache.
SHARED_PROGRAMS = "shell3d_ball"


@pytest.fixture(scope="module")
def frictionless():
    ball = s3.ball(R, H, N_TRI)
    return s3.Indentation(ball, PEZZI, gas=IsothermalGas(), indenter_radius=0.01, rest_shape="scan", progress=False)


@pytest.fixture(scope="module")
def poked(frictionless):
    """μ ↦ (simulation, state at DEPTH); one rest shape shared by all μ."""
    out = {}
    for mu in MUS:
        sim = frictionless if mu == 0 else frictionless.with_friction(mu)
        out[mu] = (sim, sim.solve(depth=DEPTH))
    return out


def _touching(sim, state):
    return state.vertices[:, 2] < sim.activation_distance


# --- the friction potential --------------------------------------------------------------------
MU, LAM, EPS = 0.3, 2.0, 1e-3  # [-], [N], [m]


def _d(u):
    return friction_energy(u, LAM, MU, EPS)


@pytest.mark.parametrize("dim", [2, 3])
def test_friction_potential_derivatives_match_central_differences(dim):
    rng = np.random.default_rng(11)
    grad = jax.jit(jax.grad(_d))
    hess = jax.jit(jax.hessian(_d))
    directions = rng.normal(size=(3, dim))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    # u = 0, inside the sticking zone, just below/above the switch y = ε and sliding.
    radii = (0.0, 1e-3 * EPS, 0.3 * EPS, (1 - 1e-7) * EPS, (1 + 1e-7) * EPS, 3.0 * EPS)
    h = 1e-6 * EPS  # FD step [m]
    for rad in radii:
        for d in directions:
            u = jnp.asarray(rad * d)
            g, hm = np.asarray(grad(u)), np.asarray(hess(u))
            assert np.all(np.isfinite(g)) and np.all(np.isfinite(hm))
            for i in range(dim):
                e = jnp.zeros(dim).at[i].set(h)
                fd_g = (float(_d(u + e)) - float(_d(u - e))) / (2 * h)
                # Round-off of D (~μλε = 6e-4 J) over 2h: 1e-16·6e-4/2e-9 ≈ 3e-11 N; truncation
                # h²·μλ/ε² ≈ 6e-13 N: 1e-8 μλ (6e-9 N) bounds both with margin.
                np.testing.assert_allclose(g[i], fd_g, rtol=1e-6, atol=1e-8 * MU * LAM)
                fd_h = (np.asarray(grad(u + e)) - np.asarray(grad(u - e))) / (2 * h)
                # f₀ is C² (f₀'' → 0 from both sides of ε) and f₀''' = −2/ε² is bounded, so the
                # central difference is off by ≲ h·μλ·2/ε² = 2e-6 μλ/ε, also across y = ε.
                np.testing.assert_allclose(hm[:, i], fd_h, rtol=1e-5, atol=1e-5 * MU * LAM / EPS)
    # Exact values at u = 0: no force, isotropic stick stiffness 2μλ/ε.
    np.testing.assert_array_equal(np.asarray(grad(jnp.zeros(dim))), 0.0)
    np.testing.assert_allclose(np.asarray(hess(jnp.zeros(dim))), 2 * MU * LAM / EPS * np.eye(dim), rtol=1e-14)


def test_friction_force_is_mu_lambda_when_sliding_and_never_more():
    rng = np.random.default_rng(12)
    directions = rng.normal(size=(400, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    radii = EPS * 10 ** rng.uniform(-4, 2, size=400)
    u = jnp.asarray(directions * radii[:, None])
    f = np.asarray(friction_force(u, LAM, MU, EPS))
    np.testing.assert_allclose(f, -np.asarray(jax.vmap(jax.grad(_d))(u)), rtol=1e-12, atol=1e-15)
    mag = np.linalg.norm(f, axis=1)
    # Sliding: exactly the Coulomb force (up to round-off of the unit direction).
    np.testing.assert_allclose(mag[radii >= EPS], MU * LAM, rtol=1e-12)
    # Sticking: strictly inside the cone, f₁(y) = 2y/ε − y²/ε² < 1, and opposing the slip.
    assert np.all(mag[radii < EPS] < MU * LAM)
    np.testing.assert_allclose(mag[radii < EPS], MU * LAM * (2 * radii - radii**2 / EPS)[radii < EPS] / EPS, rtol=1e-10)
    assert np.all(np.sum(f * np.asarray(u), axis=1) <= 0)
    # The mollifier is C¹ at ε: value and slope match the sliding branch f₀(y) = y.
    np.testing.assert_allclose(float(friction_mollifier(EPS * (1 - 1e-12), EPS)), EPS, rtol=1e-10)
    np.testing.assert_allclose(float(jax.grad(friction_mollifier)(EPS * (1 - 1e-9), EPS)), 1.0, atol=1e-8)


def test_invalid_friction_inputs_raise_clear_errors():
    ball = s3.ball(R, H, 200)
    with pytest.raises(InvalidInputError, match="friction.*-0.2"):
        s3.Indentation(ball, PEZZI, friction=-0.2, rest_shape="scan")
    with pytest.raises(InvalidInputError, match="slip_tolerance.*0.0"):
        s3.Indentation(ball, PEZZI, friction=0.3, slip_tolerance=0.0, rest_shape="scan")
    with pytest.raises(InvalidInputError, match="friction"):
        ContactConfig(friction=float("nan"))
    with pytest.raises(InvalidInputError, match="friction_iterations"):
        s3.Indentation(ball, PEZZI, friction=0.3, friction_iterations=-1, rest_shape="scan")


# --- the model's sparse Hessian with friction -----------------------------------------------------
def test_sparse_hessian_with_friction_matches_central_differences(poked):
    """On the solved μ = 0.5 ball (its compiled model), at the equilibrium with its lagged data
    and with random anchors (slips 1e-3 ε … 10 ε) and normal forces on every vertex, so that every
    per-vertex friction block and both branches of f₀ are exercised. (Exactly at u = 0, f₀(‖u‖)
    is C² but not C³: a central difference of step δ is off by δ/(2ε) there, so the exact value
    (2/ε) μλ I is checked in the potential's own test instead.)"""
    rng = np.random.default_rng(13)
    sim, st = poked[0.5]
    eps = sim.model.config.contact.friction_slip_tolerance
    n = len(st.vertices)
    slip = rng.normal(size=(n, 3)) * eps * 10 ** rng.uniform(-3, 1, size=(n, 1))
    random_lag = {"friction_anchor": st.vertices - slip, "friction_normal_force": rng.uniform(0.05, 0.3, size=(1, n))}
    # Smallest contact gap (ground or indenter) [m]: the barrier's derivatives vary on this scale.
    indenter_gap = np.linalg.norm(st.vertices - st.indenter_center, axis=1) - sim.indenter_radius
    gap = min(st.vertices[:, 2].min(), indenter_gap.min())
    for lagged in (st.friction, random_lag):
        params = sim.params_at(st.q, **lagged)
        # Trial displacements h·v ≲ 4e-10 m: far below the smallest gap (~2e-6 m under the
        # indenter; the barrier's third derivative adds ~(δ/gap)² ≈ 4e-8 relative error) and
        # below ε (2e-6 m).
        # Only free dofs move: the pinned ones (and the prescribed indenter) are folded out of
        # the matrix as unit diagonal entries.
        v = np.where(sim.model.free, rng.normal(size=st.q.size) * 1e-6, 0.0)
        h = 1e-4
        assert h * np.abs(v).max() < 0.001 * min(gap, eps)
        mat, (c2, u) = sim.model.host_hessian(st.q, params)
        hv = mat @ v + c2 * u * (u @ v)
        g = lambda q: np.where(sim.model.free, sim.model.host_gradient(q, params), 0.0)  # noqa: E731
        fd = (g(st.q + h * v) - g(st.q - h * v)) / (2 * h)
        hv = np.where(sim.model.free, hv, 0.0)
        # As in tests/test_shell3d_energy.py: f₀ is C², so the central difference is O(δ²) even
        # across ‖u‖ = ε; round-off of the ≲ 3 N nodal forces over 2h is ~1e-10 of |Hv|.
        np.testing.assert_allclose(hv, fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())
    # The friction blocks are really there: with random anchors the Hessian differs from the
    # frictionless one by about the stick stiffness 2μλ/ε on the contact vertices.
    diff = sim.model.host_hessian(st.q, params)[0] - poked[0.0][0].model.host_hessian(st.q, params)[0]
    assert np.abs(diff).max() > 0.1 * 2 * 0.5 * 0.05 / eps


# --- the solved ball ----------------------------------------------------------------------------
def test_zero_friction_reproduces_the_frictionless_solution(frictionless, poked):
    # μ = 0 is the frictionless model itself: equal config, i.e. the same jit key and solution.
    assert frictionless.with_friction(0.0).model.config == frictionless.model.config
    _, state0 = poked[0.0]
    obs = state0.observables()
    assert obs["friction_force"] == 0.0 and obs["friction_inward"] == 0.0 and state0.friction == {}
    # The friction code path with no normal force (λ ≡ 0) adds nothing: at the frictionless
    # equilibrium the μ > 0 model's gradient and Hessian are the frictionless ones, so its Newton
    # solve stops at once, within the solver tolerance of the frictionless solution.
    sim = poked[0.5][0]
    q = state0.q
    lagged = {"friction_anchor": state0.vertices + 1e-3, "friction_normal_force": np.zeros((1, len(state0.vertices)))}
    params = sim.params_at(q, **lagged)
    np.testing.assert_array_equal(sim.model.host_gradient(q, params), frictionless.model.host_gradient(q, params))
    # the Hessians to the assembly's round-off, 4 ulp of each row's largest entry: how XLA fuses the
    # two programs' sums decides their last bits
    frictionless_hessian = frictionless.model.host_hessian(q, params)[0].toarray()
    round_off = 4 * np.finfo(float).eps * np.abs(frictionless_hessian).max(axis=1, keepdims=True)
    assert np.all(np.abs(sim.model.host_hessian(q, params)[0].toarray() - frictionless_hessian) <= round_off)
    res = sim.model.equilibrium(q, params, atol=sim.atol)
    assert res.iterations == 0
    np.testing.assert_array_equal(res.value, q)


def test_coulomb_cone_holds_small_mu_slides_large_mu_sticks(poked):
    for mu in (0.05, 2.0):
        sim, st = poked[mu]
        touching = _touching(sim, st)
        lam_lagged = st.friction["friction_normal_force"][0]
        lam_now = sim.model.plane_normal_forces(st.q)[0]
        f = sim.model.friction_forces(st.q, sim.params_at(st.q, **st.friction))[0]
        mag = np.linalg.norm(f, axis=1)
        assert np.all(np.abs(f[:, 2]) <= 1e-12 * mag.max())  # friction is tangential to the ground
        # Cone on the lagged normal force: f₁ ≤ 1 exactly, so only round-off (1e-12) is allowed.
        assert np.all(mag <= mu * lam_lagged * (1 + 1e-12))
        # Cone on the converged normal force: the lagging stopped once λ moved by < 1 % of its
        # largest value, so the excess can be at most μ × that change.
        assert st.friction_lag_change < 0.01
        assert np.all(mag[touching] <= mu * (lam_now[touching] + st.friction_lag_change * lam_now.max()) * (1 + 1e-12))
        anchor = st.friction["friction_anchor"]
        step_slip = np.linalg.norm((st.vertices - anchor)[:, :2], axis=1)
        loaded = touching & (lam_lagged > 0)
        eps = sim.model.config.contact.friction_slip_tolerance
        if mu == 0.05:
            # Sliding: several contact vertices sit on the cone (‖u‖ ≥ ε ⇔ f₁ = 1), i.e. the
            # Coulomb limit is actually reached, not just respected.
            on_cone = loaded & (mag >= mu * lam_lagged * (1 - 1e-9))
            assert on_cone.sum() >= 5
            assert step_slip[loaded].max() > 3 * eps
        else:
            # Sticking: every vertex that was already on the ground at the start of the last
            # load step stays inside the cone, i.e. slips less than ε (measured ≤ 0.49 ε). Vertices
            # that touched down during the step slid while they approached and are excluded.
            held = loaded & (anchor[:, 2] < sim.activation_distance)
            assert held.sum() >= 10
            assert step_slip[held].max() < eps
            assert np.all(mag[held] < mu * lam_lagged[held])


def test_friction_reduces_ground_slip_monotonically_and_keeps_vertical_balance(poked):
    slips, forces = [], []
    for mu in MUS:
        sim, st = poked[mu]
        obs = st.observables()
        touching = _touching(sim, st)
        x = st.vertices
        r = np.hypot(x[:, 0], x[:, 1])
        radial = np.stack([x[:, 0], x[:, 1]], axis=1) / np.maximum(r, 1e-300)[:, None]
        radial_slip = np.sum(st.ground_slip[:, :2] * radial, axis=1)[touching]
        slips.append(np.mean(np.abs(radial_slip)))
        if mu == 0:
            frictionless_slip = np.mean(radial_slip)
        forces.append(obs["force"])
        # Global vertical balance: friction is horizontal and the pins only hold x/y, so the
        # indenter force equals the ground's normal reaction up to Newton's net vertical residual
        # (round-off ~1e-13 N, as in tests/test_shell3d_indent.py).
        unbalance = obs["ground_reaction"] - obs["force"]
        np.testing.assert_allclose(unbalance, -net_vertical_residual(sim, st), rtol=0, atol=1e-11)
        assert abs(unbalance) < 5 * sim.atol  # a signed sum of residuals ≤ atol each: measured ≤ 0.7 atol
        if mu > 0:
            f = sim.model.friction_forces(st.q, sim.params_at(st.q, **st.friction))[0]
            total = np.abs(f).sum()
            # Centred poke: the friction forces cancel by symmetry up to the mesh's asymmetry
            # (the pinned vertices carry the rest); measured < 0.7 % of Σ|f_v|.
            assert obs["friction_force"] < 0.02 * total
            # Friction resists the way the frictionless patch slides (inward on this ball, see
            # docs/shell3d.md): friction_inward has the sign of the frictionless mean radial slip.
            # (Not of this μ's own accumulated slip: a sticking patch creeps by ~ε either way.)
            assert obs["friction_inward"] * frictionless_slip > 0
    slips, forces = np.array(slips), np.array(forces)
    # The slip decreases strictly with μ; μ = 2 sticks (≥ 10× less slip than frictionless).
    assert np.all(np.diff(slips) < 0), slips
    assert slips[-1] < 0.1 * slips[0]
    # Friction only restrains the contact patch: it stiffens the ball (F non-decreasing in μ, by
    # more than the solver tolerance atol/F ~ 1e-8 relative) without changing F by more than a few %.
    assert np.all(np.diff(forces) > 0), forces
    assert forces[-1] < 1.05 * forces[0]


def test_force_control_with_friction_matches_displacement_control(poked):
    sim, st = poked[0.5]
    force = st.observables()["force"]
    st_f = sim.solve(force=force, steps=4)
    obs = st_f.observables()
    assert st_f.friction and st_f.friction_lag_change < 0.01  # lagged in force control too
    # The indenter's height is an unknown: its force residual is within Newton's tolerance.
    assert abs(obs["force"] - force) <= sim.atol
    unbalance = obs["ground_reaction"] - obs["force"]
    np.testing.assert_allclose(unbalance, -net_vertical_residual(sim, st_f, sim.force_model), rtol=0, atol=1e-11)
    # Friction makes the equilibrium path dependent (4 force steps vs 8 depth sub-steps give other
    # anchors), but the path can only move the depth by a fraction of friction's whole effect,
    # ΔF/k with ΔF = F(μ=0.5) − F(0) and the secant stiffness k = F/DEPTH (6e-5 m; measured: 8e-8 m).
    effect = (force - poked[0.0][1].observables()["force"]) / (force / DEPTH)
    assert effect > 0
    assert abs(st_f.depth - DEPTH) < 0.1 * effect
