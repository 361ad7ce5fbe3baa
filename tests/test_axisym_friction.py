"""Ground friction of the axisymmetric engine (``CurvePhysics.friction_coefficient``).

Smoothed, lagged Coulomb friction (IPC, ``physics.friction_energy``) on the radial slip of the
ground-contact nodes, lagged per load step. One compiled program (a jvp of the curves of several
μ, vmapped) serves every curve test; the frictionless default curve is a second one.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from shelljax.physics import IsothermalGas
from shelljax.axisym import Config, CurvePhysics, Setup, curve_single
from shelljax.axisym._energy import ground_friction_energy, rest_nodes
from shelljax.axisym._hessian import hessian_at
from shelljax.axisym._model import _params

from _shells import shell

SETUP = Setup(radius=0.13, n_elements=41, gas=IsothermalGas())
THETA = (1300.0, 2.34e6, 0.9e-3, 0.4)  # P_g [Pa], E [Pa], h [m], ν [-]: the Pezzi-like ball
FORCES = jnp.array([5.0, 10.0, 15.0])  # [N]
MU0, DMU = 0.5, 1e-2  # FD point and half step of dw0/dμ
MUS = jnp.array([0.0, 0.5, 3.0, MU0 - DMU, MU0 + DMU])  # curve lanes; lane 1 is μ0


def _physics(mu):
    return eqx.tree_at(lambda c: c.friction_coefficient, CurvePhysics.defaults(SETUP), mu)


def _curve(mu):
    return curve_single(SETUP, shell(THETA), FORCES, return_states=True, physics=_physics(mu))


@jax.jit
def _lanes_and_slopes(mus):
    # each lane depends on its own μ only, so a unit tangent gives every lane's d/dμ
    return jax.jvp(jax.vmap(_curve), (mus,), (jnp.ones_like(mus),))


@pytest.fixture(scope="module")
def lanes():
    out, slopes = _lanes_and_slopes(MUS)
    out = jax.tree_util.tree_map(np.asarray, out)
    assert np.all(out["residual"] <= SETUP.atol)
    return out, jax.tree_util.tree_map(np.asarray, slopes)


def _radii(out, lane):
    n = len(SETUP.theta())
    return out["state"][lane, 1:, : 2 * n].reshape(len(FORCES), n, 2)[..., 0]


def test_zero_friction_is_the_frictionless_curve_exactly(lanes):
    out, _ = lanes
    # The default physics (μ = 0 constant) against a traced μ = 0 lane, vmapped beside lanes with
    # friction and with nonzero lagged anchors and normal forces: μ λ̂ f₀ adds an exact 0.0 to the
    # energy, gradient and Hessian. Unbatched, the two agree bit for bit; the vmapped program sums
    # in another order (measured 8e-16 relative in w0), hence 1e-13, with identical iterations.
    plain = jax.tree_util.tree_map(
        np.asarray, jax.jit(lambda: curve_single(SETUP, shell(THETA), FORCES, return_states=True))()
    )
    assert np.any(out["friction_normal_force"][0] > 0)
    for key in ("w0", "contact_diameter", "contact_diameter_mesh", "volume"):
        np.testing.assert_allclose(out[key][0], plain[key], rtol=1e-13, err_msg=key)
    np.testing.assert_allclose(out["state"][0], plain["state"], rtol=0, atol=1e-13 * SETUP.radius)
    np.testing.assert_array_equal(out["iterations"][0], plain["iterations"])


@jax.jit
@jax.vmap
def _friction_forces(x, anchor, normal, mu):
    """−∂D/∂x [N] (n, 2) of the ground friction at node coordinates x (n, 2) with the given lag."""
    p = eqx.tree_at(
        lambda q: (q.friction_coefficient, q.friction_anchor, q.friction_normal_force),
        _params(*THETA[1:3], THETA[3], SETUP.radius, THETA[0], SETUP),
        (mu, anchor, normal),
    )
    return -jax.grad(lambda xx: ground_friction_energy(xx, p))(x)


def test_friction_force_stays_in_the_coulomb_cone(lanes):
    out, _ = lanes
    n, k = len(SETUP.theta()), len(FORCES)
    x = out["state"][:, 1:, : 2 * n].reshape(-1, n, 2)
    normal = out["friction_normal_force"].reshape(-1, n)
    mu = np.repeat(np.asarray(MUS), k)
    force = np.asarray(
        _friction_forces(
            jnp.asarray(x), jnp.asarray(out["friction_anchor"].reshape(-1, n)), jnp.asarray(normal), jnp.asarray(mu)
        )
    )
    bound = mu[:, None] * normal
    assert np.all(force[..., 1] == 0.0)  # friction is tangential (radial) only
    # |force| = μ λ̂ f₁ with f₁ ∈ [0, 1]: the cone holds to round-off (1e-12 relative)
    assert np.all(np.abs(force[..., 0]) <= bound * (1 + 1e-12))
    # and is reached by sliding nodes (slip ≫ ε) of the μ = 0.5 curve
    ratio = np.abs(force[k : 2 * k, :, 0]) / np.where(bound[k : 2 * k] > 0, bound[k : 2 * k], np.inf)
    assert np.max(ratio) > 1 - 1e-12


def test_friction_restrains_the_contact_disc_and_barely_moves_its_diameter(lanes):
    out, _ = lanes
    # slip of each contact node over each level (its radius minus its lagged anchor), summed
    slips = []
    for lane in (0, 1, 2):
        contact = out["friction_normal_force"][lane] > 0
        slips.append(np.sum(np.abs(_radii(out, lane) - out["friction_anchor"][lane])[contact]))
    # Frictionless, the disc slides inward as it grows (≈ 0.1 mm per level at its rim); friction
    # holds it back, the more the larger μ, and μ = 3 nearly sticks it.
    assert slips[0] > slips[1] > slips[2]
    assert slips[2] < 0.1 * slips[0]
    # Held back from its inward slide, the disc comes out slightly LARGER with friction, not
    # smaller as the paper expected (it blamed friction for its 10.1 % D_l error): by well under
    # 1 % here, as in the 3D engine (docs/axisym.md, *Ground friction*).
    for key in ("contact_diameter", "contact_diameter_mesh"):
        change = out[key][1:3] / out[key][0] - 1.0
        assert np.all(change >= 0.0) and np.all(change < 1e-2), (key, change)


def test_w0_derivative_in_mu_matches_central_differences(lanes):
    out, slopes = lanes
    fd = (out["w0"][4] - out["w0"][3]) / (2 * DMU)
    # Newton's atol 1e-7 N leaves ≈ 1e-10 m in w0, ≈ 1e-4 of the ≈ 2e-6 m difference; the O(δ²)
    # truncation is smaller still; 2e-3 leaves room for a contact node changing state in [μ ± δ].
    np.testing.assert_allclose(slopes["w0"][1], fd, rtol=2e-3)
    assert np.all(np.abs(fd) > 0)


def test_hessian_friction_entries_match_central_differences(lanes):
    out, _ = lanes
    cfg = Config(
        theta=SETUP.theta(),
        gas=SETUP.gas,
        loading="sphere",
        ground=True,
        pin_bottom=False,
        relax=SETUP.relax,
        hoop_capacity=SETUP.hoop_capacity,
    )
    n = len(SETUP.theta())
    lane, k = 1, 1
    y = jnp.asarray(out["state"][lane, 1 + k])
    eps = SETUP.slip_tolerance()
    # anchors moved so that the contact nodes alternate sticking (|u| < ε) and sliding (|u| > ε)
    offsets = np.where(np.arange(n) % 2 == 0, 0.3 * eps, 3.0 * eps)
    base = eqx.tree_at(
        lambda q: q.friction_anchor,
        _params(
            *THETA[1:3],
            THETA[3],
            out["rest_radius"][lane],
            THETA[0],
            SETUP,
            force=FORCES[k],
            physics=_physics(MUS[lane]),
        ),
        jnp.asarray(out["state"][lane, 1 + k, 0 : 2 * n : 2] - offsets),
    )
    p = eqx.tree_at(lambda q: q.friction_normal_force, base, jnp.asarray(out["friction_normal_force"][lane, k]))
    p0 = eqx.tree_at(lambda q: q.friction_coefficient, p, jnp.asarray(0.0))

    @jax.jit
    def entries(y):
        # one trace of the Hessian for μ and 0: their difference is friction's share
        both = jax.vmap(lambda q: hessian_at(y, cfg, q))(jax.tree_util.tree_map(lambda a, b: jnp.stack([a, b]), p, p0))
        h_mu, h_0 = (jax.tree_util.tree_map(lambda a, i=i: a[i], both) for i in range(2))
        diag = lambda h: jnp.stack([h.diag[i][i] for i in range(4)], -1).ravel()[0 : 2 * n : 2]  # noqa: E731
        step = 1e-3 * eps  # ≪ ε: inside the cubic of f₀ for the sticking nodes
        radial = jnp.zeros((n, 2 * n + 1)).at[jnp.arange(n), 2 * jnp.arange(n)].set(step)

        def friction_grad(yy):
            # the friction term's share of the energy gradient (the energy is the frictionless one
            # plus ground_friction_energy, exactly)
            return jax.grad(lambda v: ground_friction_energy(v[: 2 * n].reshape(n, 2), p))(yy)

        fd = jax.vmap(lambda e: (friction_grad(y + e) - friction_grad(y - e)) / (2 * step))(radial)
        return diag(h_mu) - diag(h_0), fd

    assembled, fd = (np.asarray(a) for a in entries(y))
    contact = out["friction_normal_force"][lane, k] > 0
    contact[0] = False  # the bottom pole's radius is a fixed dof (identity row)
    sticking = contact & (offsets < eps)
    assert np.any(sticking) and np.any(contact & ~sticking)
    # friction's Hessian is diagonal in the radii: FD columns have nothing off the diagonal
    off = fd.copy()
    off[np.arange(n), 2 * np.arange(n)] = 0.0
    scale = np.max(np.abs(assembled))
    assert scale > 0 and np.max(np.abs(off)) < 1e-6 * scale
    # The FD's truncation is O(step²/ε²) = 1e-6 relative; round-off of gradients of ≈ 1 N over a
    # step of 4e-9 m is ≈ 1e-7 N/m, far below the sticking stiffness 2 μ λ̂/ε ≈ 1e2–1e3 N/m.
    np.testing.assert_allclose(np.diag(fd[:, 0 : 2 * n : 2])[contact], assembled[contact], rtol=1e-5, atol=1e-6 * scale)
    np.testing.assert_allclose(
        assembled[sticking],
        (2 * float(MUS[lane]) / eps) * out["friction_normal_force"][lane, k][sticking] * (1 - 0.3),
        rtol=1e-10,
    )
