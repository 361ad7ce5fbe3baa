"""Discrete shell energy: mesh checks, analytic cases and derivatives vs central differences."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from shelljax.physics import gas_law
import shelljax.shell3d as s3
from shelljax import InvalidInputError
from shelljax.physics import ShellProperties, lame_constants_2d
from shelljax.geometry import signed_volume
from shelljax.shell3d import ContactConfig, ModelConfig, ShellModel, rigid_mode_pins

# The ground-barrier Newton test solves tests/test_shell3d_indent.py's prescribed-gas ball: on one
# xdist worker, after this file, that file finds its programs in the persistent cache.
SHARED_PROGRAMS = "shell3d_ball"

E, NU, H = 1.0e6, 0.3, 1.0e-3


def _params(**kw):
    return s3.ShellParams(young_modulus=E, poisson_ratio=NU, thickness=H, gauge_pressure=500.0).replace(**kw)


def test_shell_params_are_keyword_only_and_built_from_shell_properties():
    with pytest.raises(TypeError):
        s3.ShellParams(E, NU, H, 500.0)
    built = s3.ShellParams.of(ShellProperties(gauge_pressure=500.0, young_modulus=E, thickness=H, poisson_ratio=NU))
    assert jax.tree_util.tree_all(jax.tree_util.tree_map(np.array_equal, built, _params()))


def test_open_or_inconsistent_meshes_are_rejected_and_orientation_fixed():
    mesh = s3.ShellMesh.sphere(1.0, 200)
    with pytest.raises(InvalidInputError, match="not closed"):
        s3.ShellMesh.from_arrays(mesh.vertices, mesh.faces[1:])
    flipped = s3.ShellMesh.from_arrays(mesh.vertices, mesh.faces[:, ::-1])
    assert signed_volume(flipped.vertices, flipped.faces) > 0
    bad = mesh.faces.copy()
    bad[0] = bad[0, ::-1]
    with pytest.raises(InvalidInputError):
        s3.ShellMesh.from_arrays(mesh.vertices, bad)


def test_random_sphere_layout_is_closed_graded_and_seeded():
    radius, top, coarse = 0.13, 4e-3, 16e-3
    mesh = s3.ShellMesh.sphere(radius, layout="random", top_spacing=top, max_spacing=coarse, refined_arc=0.03)
    v, f = mesh.vertices, mesh.faces
    # closed genus-0 surface on the sphere, outward oriented, a vertex at each pole
    assert mesh.n_vertices - 3 * len(f) // 2 + len(f) == 2
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), radius, rtol=1e-12)
    assert signed_volume(v, f) > 0
    assert np.isclose(v[:, 2].max(), radius) and np.isclose(v[:, 2].min(), -radius)
    # edge lengths follow the requested spacing; single Delaunay edges of smoothed random points
    # spread widely (0.2–2 × s), so compare medians
    edges = v[f[:, [0, 1, 2]]] - v[f[:, [1, 2, 0]]]
    length = np.linalg.norm(edges, axis=-1).ravel()
    arc = radius * np.arccos(np.clip(np.repeat(v[f].mean(1)[:, 2], 3) / radius, -1, 1))
    assert np.median(length[arc < 0.02]) == pytest.approx(top, rel=0.15)
    assert np.median(length[np.abs(arc - 0.5 * np.pi * radius) < 0.02]) == pytest.approx(coarse, rel=0.15)
    # every face's flap stencil has six distinct vertices (no valence-3 vertex)
    assert all(len(set(row)) == 6 for row in mesh.stencil.tolist())
    # seeded: the same seed gives the same mesh, another seed another one
    again = s3.ShellMesh.sphere(radius, layout="random", top_spacing=top, max_spacing=coarse, refined_arc=0.03)
    other = s3.ShellMesh.sphere(radius, layout="random", top_spacing=top, max_spacing=coarse, refined_arc=0.03, seed=1)
    np.testing.assert_array_equal(again.vertices, v)
    assert not (other.vertices.shape == v.shape and np.allclose(other.vertices, v))
    with pytest.raises(InvalidInputError, match="layout='random'"):
        s3.ShellMesh.sphere(radius, layout="random", top_spacing=0.02, max_spacing=0.01)


def test_rest_curvature_of_sphere_converges_to_minus_identity_over_r():
    """ā⁻¹b̄ = −I/R on a sphere; the quadratic-patch curvature error is O(edge²)."""
    errs = []
    for n in (300, 1200):
        mesh = s3.ShellMesh.sphere(2.0, n)
        a, b, _ = s3.rest_geometry(jnp.asarray(mesh.vertices[mesh.stencil]))
        m = np.asarray(jnp.linalg.solve(a, b)) * 2.0
        errs.append(np.max(np.abs(m + np.eye(2))))
    assert errs[1] < 0.04  # measured 0.035 at 1200 faces (edge ≈ R/8)
    assert errs[1] < 0.4 * errs[0]  # 4× the faces halves the edge: O(h²) predicts 1/4


def test_second_fundamental_form_is_the_six_point_quadratic_interpolant():
    """Independent computation: fit w = c₀ + c₁s + c₂t + c₃s² + c₄st + c₅t² through all six
    stencil vertices in an orthonormal frame of the face (a 6×6 Vandermonde solve in NumPy),
    map its Hessian to the (e₁, e₂) parametrisation and compare with the barycentric-product
    solve of ``fundamental_forms`` on distorted stencils. Both are the same unique interpolant,
    so they agree to round-off (1e-9 relative allows for the conditioning of the 6×6 solve)."""
    rng = np.random.default_rng(6)
    mesh = s3.ShellMesh.sphere(1.0, 300)
    stencils = mesh.vertices[mesh.stencil[:40]] * 1.05 + 0.01 * rng.normal(size=(40, 6, 3))
    for p in stencils:
        e1, e2 = p[1] - p[0], p[2] - p[0]
        n = np.cross(e1, e2) / np.linalg.norm(np.cross(e1, e2))
        t1 = e1 / np.linalg.norm(e1)
        t2 = np.cross(n, t1)
        d = p - p[0]
        s_, t_, w_ = d @ t1, d @ t2, d @ n
        coef = np.linalg.solve(np.stack([np.ones(6), s_, t_, s_**2, s_ * t_, t_**2], axis=1), w_)
        hess_st = np.array([[2 * coef[3], coef[4]], [coef[4], 2 * coef[5]]])
        jac = np.array([[e1 @ t1, e2 @ t1], [e1 @ t2, e2 @ t2]])
        expected_b = jac.T @ hess_st @ jac
        a, b = s3.fundamental_forms(jnp.asarray(p))
        np.testing.assert_allclose(np.asarray(a), [[e1 @ e1, e1 @ e2], [e1 @ e2, e2 @ e2]], rtol=1e-12)
        np.testing.assert_allclose(np.asarray(b), expected_b, rtol=1e-9, atol=1e-9 * np.abs(expected_b).max())


def test_scaled_sphere_energies_match_analytic_values():
    """x = λX: C = λ²I exactly per face and M = (λ−1) ā⁻¹b̄ exactly, so the membrane energy is
    exact to round-off and the bending energy off only by the rest-curvature error (≤ 4 %)."""
    mesh = s3.ShellMesh.sphere(1.0, 1200)
    lam = 1.2
    model = ShellModel(mesh, mesh.vertices, ModelConfig(mesh.n_vertices), rigid_mode_pins(mesh.vertices))
    q = np.concatenate([lam * mesh.vertices.ravel(), np.zeros(3)])
    area = float(model.geometry.rest_area.sum())
    alpha, beta = lame_constants_2d(E, NU)
    w_m = H * (beta * (lam**2 - 1 - 2 * np.log(lam)) + alpha / 4 * (lam**4 - 1 - 4 * np.log(lam)))
    p0 = _params(gauge_pressure=0.0)
    x = jnp.asarray(q[:-3].reshape(-1, 3))
    from shelljax.shell3d._energy import elastic_energy

    tiny = p0.replace(thickness=1e-9)  # bending ∝ h³ vanishes; membrane ∝ h
    e_m = float(elastic_energy(x, tiny, model.geometry)) * H / 1e-9
    np.testing.assert_allclose(e_m, area * w_m, rtol=1e-9)
    e_total = float(elastic_energy(x, p0, model.geometry))
    e_b = e_total - area * w_m
    w_b = H**3 / 12 * (2 * alpha + 2 * beta) * (lam - 1) ** 2  # R = 1
    np.testing.assert_allclose(e_b, area * w_b, rtol=0.08)  # (1 ± 0.035)² curvature error


def _random_state(mesh, rng, scale=0.02):
    return mesh.vertices * 1.01 + scale * rng.normal(size=mesh.vertices.shape) * 0.1


def _contact_params(c):
    """The parameters of the tests on the 134-face sphere with indenter and ground: one pytree,
    so that one compiled energy, gradient and Hessian serves them all (the sealed gas's entries
    are unused by the prescribed gas; the weight is linear in x, it adds nothing to the Hessian)."""
    return _params(indenter_center=c, reference_volume=4.0, atmospheric_pressure=1e5, mass=0.3)


@pytest.mark.parametrize("gas", ["prescribed", "isothermal", "adiabatic"])
def test_gradient_and_sparse_hessian_match_central_differences(gas, monkeypatch):
    import shelljax.shell3d._hessian as model_module

    rng = np.random.default_rng(3)
    mesh = s3.ShellMesh.sphere(1.0, 120)
    contact = ContactConfig(
        indenter_radius=0.3, planes=(((0.0, 0.0, -1.02), (0.0, 0.0, 1.0)),), activation_distance=0.05
    )
    cfg = ModelConfig(mesh.n_vertices, gas=gas_law(gas), contact=contact)
    fixed = np.zeros(3 * mesh.n_vertices + 3, dtype=bool)
    model = ShellModel(mesh, mesh.vertices, cfg, fixed)
    x = _random_state(mesh, rng)
    top = int(np.argmax(x[:, 2]))
    c = x[top] + np.array([0.0, 0.0, 0.3 + 0.02])
    x[:, 2] = np.maximum(x[:, 2], -1.0)  # every vertex above the ground plane
    q = np.concatenate([x.ravel(), c])
    params = _contact_params(c)
    assert np.isfinite(model.host_energy(q, params))
    g = model.host_gradient(q, params)
    v = rng.normal(size=q.size) * 1e-3
    eps = 1e-4
    fd = (model.host_energy(q + eps * v, params) - model.host_energy(q - eps * v, params)) / (2 * eps)
    # Central difference: truncation O(eps² |v|³ E''') ≈ 1e-10 relative, plus round-off of the
    # energy itself, whose sealed-gas terms are each of size ~p₀V₀ = 4e5 J: ~10 ε_mach p₀V₀ / eps.
    roundoff = 10 * np.finfo(float).eps * max(abs(model.host_energy(q, params)), 1e5 * 4.0) / eps
    np.testing.assert_allclose(g @ v, fd, rtol=1e-7, atol=roundoff)
    mat, rank_one = model.host_hessian(q, params)
    hv = mat @ v
    if rank_one is not None:
        hv = hv + rank_one[0] * rank_one[1] * (rank_one[1] @ v)
    fd_h = (model.host_gradient(q + eps * v, params) - model.host_gradient(q - eps * v, params)) / (2 * eps)
    np.testing.assert_allclose(hv, fd_h, rtol=1e-6, atol=1e-6 * np.abs(fd_h).max())
    assert (rank_one is None) == (gas == "prescribed")
    # Newton's CG products, from a stored linearization (meshes up to the threshold) or by jvp
    # (above it), are the assembled Hessian's by another route: equal up to summation round-off.
    for max_faces in (mesh.n_faces, mesh.n_faces - 1):
        monkeypatch.setattr(model_module, "LINEARIZED_PRODUCT_MAX_FACES", max_faces)
        product = model.host_hessian_operator(q, params)(v)
        np.testing.assert_allclose(product, hv, rtol=0, atol=1e-9 * np.abs(hv).max())


def test_chunked_hessian_assembly_matches_dense_autodiff(monkeypatch):
    """The exact Hessian is scattered chunk by chunk (the last chunk shifted back to end at the
    last face) and the projected one streamed in chunks: both against unchunked references."""
    import shelljax.shell3d._hessian as model_module

    rng = np.random.default_rng(5)
    mesh = s3.ShellMesh.sphere(1.0, 120)  # 134 faces, the other tests' mesh: 4 chunks of 34
    n_chunks = -(-mesh.n_faces // 35)
    assert n_chunks * -(-mesh.n_faces // n_chunks) > mesh.n_faces  # the last chunk overlaps its predecessor
    contact = ContactConfig(
        indenter_radius=0.3, planes=(((0.0, 0.0, -1.02), (0.0, 0.0, 1.0)),), activation_distance=0.05
    )
    cfg = ModelConfig(mesh.n_vertices, contact=contact)
    model = ShellModel(mesh, mesh.vertices, cfg, np.zeros(3 * mesh.n_vertices + 3, dtype=bool))
    x = _random_state(mesh, rng)
    x[:, 2] = np.maximum(x[:, 2], -1.0)
    c = x[int(np.argmax(x[:, 2]))] + np.array([0.0, 0.0, 0.32])
    q = np.concatenate([x.ravel(), c])
    params = _params(indenter_center=c)
    monkeypatch.setattr(model_module, "FACE_HESSIAN_CHUNK", 35)
    monkeypatch.setattr(model_module, "PROJECTION_CHUNK", 35)
    model_module.hessian_values.clear_cache()  # the chunk size is read when tracing
    mat, _ = model.host_hessian(q, params)
    model_module.hessian_values.clear_cache()
    # Reference: every face's Hessian from one unchunked vmap, scattered at once.
    hp = model.host_params(params)
    faces = np.asarray(
        model_module.face_hessians(jnp.asarray(q), hp, model.geometry, model.jit_config, 0, mesh.n_faces)
    )
    blocks = [faces] + [
        np.asarray(b) for b in model_module.contact_hessians(jnp.asarray(q), hp, model.geometry, model.jit_config)
    ]
    exact = model.pattern.matrix(model.pattern.assemble_values([jnp.asarray(b) for b in blocks])).toarray()
    scale = np.abs(exact).max()
    # The same numbers summed in another order: equal to round-off of the largest entry. A face
    # left out or added twice would be off by a whole face stiffness (≥ 1e-3 of the largest).
    np.testing.assert_allclose(mat.toarray(), exact, rtol=0, atol=1e-12 * scale)
    projected, _ = model.host_hessian(q, params, project=True)
    reference = model.pattern.matrix(model.pattern.assemble_projected(blocks)).toarray()
    np.testing.assert_allclose(projected.toarray(), reference, rtol=0, atol=1e-12 * scale)


def test_element_energy_derivatives_match_central_differences():
    rng = np.random.default_rng(4)
    mesh = s3.ShellMesh.sphere(1.0, 200)
    rest = jnp.asarray(mesh.vertices[mesh.stencil[7]])
    a, b, area = s3.rest_geometry(rest[None])
    p = rest * 1.03 + 0.01 * rng.normal(size=rest.shape)

    def f(y):
        return s3.face_energy(y.reshape(6, 3), a[0], b[0], area[0], H, E, NU, 700.0)

    y = jnp.asarray(p.reshape(-1))
    f = jax.jit(f)
    grad_f = jax.jit(jax.grad(f))
    g = grad_f(y)
    hess = jax.hessian(f)(y)
    eps = 1e-6
    for i in range(18):
        e = jnp.zeros(18).at[i].set(eps)
        np.testing.assert_allclose(
            g[i], (f(y + e) - f(y - e)) / (2 * eps), rtol=1e-5, atol=1e-9 * float(jnp.abs(g).max())
        )
        np.testing.assert_allclose(
            hess[:, i], (grad_f(y + e) - grad_f(y - e)) / (2 * eps), rtol=1e-5, atol=1e-7 * float(jnp.abs(hess).max())
        )


def _ipc_barrier_derivatives(gap, ghat, kappa):
    """φ'(g), φ''(g) of φ = −κ (g − ĝ)² ln(g/ĝ), by hand (independent of the model's autodiff)."""
    s, log = gap - ghat, np.log(gap / ghat)
    slope = -kappa * (2 * s * log + s**2 / gap)
    curvature = -kappa * (2 * log + 4 * s / gap - s**2 / gap**2)
    return slope, curvature


def test_newton_matrix_softens_overpressed_ground_barrier_and_matches_its_product(monkeypatch):
    """Newton's matrix scales a ground barrier's φ'' by λ̂/λ_b ∈ [0.01, 1] (λ_b = −φ', λ̂ = λ_b +
    ∂E/∂z the load on the vertex); it is the Hessian at equilibrium, and CG's products agree."""
    import shelljax.shell3d._hessian as model_module
    from shelljax.shell3d._contact import contact_stiffness

    rng = np.random.default_rng(11)
    mesh = s3.ShellMesh.sphere(1.0, 120)
    ghat, ground = 0.05, -1.02
    contact = ContactConfig(
        indenter_radius=0.3, planes=(((0.0, 0.0, ground), (0.0, 0.0, 1.0)),), activation_distance=ghat
    )
    cfg = ModelConfig(mesh.n_vertices, contact=contact)
    model = ShellModel(mesh, mesh.vertices, cfg, np.zeros(3 * mesh.n_vertices + 3, dtype=bool))
    x = _random_state(mesh, rng)
    low = np.argsort(x[:, 2])[:6]
    x[low, 2] = ground + ghat * np.array([1e-7, 1e-6, 1e-5, 1e-3, 0.3, 0.9])  # barrier far over- to under-pressed
    x[:, 2] = np.maximum(x[:, 2], ground + 1e-7 * ghat)
    c = x[int(np.argmax(x[:, 2]))] + np.array([0.0, 0.0, 0.32])
    q = np.concatenate([x.ravel(), c])
    params = _contact_params(c)  # the prescribed-gas gradient test's programs
    g = model.host_gradient(q, params)
    hessian = model.host_hessian(q, params)[0].toarray()
    newton_matrix = model.host_hessian(q, params, gradient=g)[0].toarray()

    gap = x[:, 2] - ground
    kappa = np.asarray(contact_stiffness(model.geometry, contact))
    slope, curvature = _ipc_barrier_derivatives(np.minimum(gap, ghat), ghat, kappa)
    pressed = gap < ghat
    floor = model_module.BARRIER_SOFTENING_FLOOR
    factor = np.where(pressed, np.clip(1.0 + g[2:-3:3] / np.where(pressed, -slope, 1.0), floor, 1.0), 1.0)
    expected = hessian.copy()
    zdofs = 3 * np.arange(mesh.n_vertices) + 2
    expected[zdofs, zdofs] += (factor - 1.0) * np.where(pressed, curvature, 0.0)
    scale = np.abs(hessian).max()
    # Only the ground's zz entries change, by the closed-form amount; round-off of the largest entry.
    np.testing.assert_allclose(newton_matrix, expected, rtol=0, atol=1e-12 * scale)
    # softened, never stiffened: no diagonal entry grows by more than the 2 ulp by which the two
    # assemblies' rounding may differ
    softening = np.diag(newton_matrix - hessian)
    assert np.sum(factor == floor) >= 2 and np.all(softening <= 4 * np.finfo(float).eps * np.abs(np.diag(hessian)))
    # At equilibrium (zero gradient) Newton's matrix is the Hessian, to the assembly's round-off:
    # 4 ulp of each row's largest entry (two programs, each rounded as XLA fuses it).
    at_equilibrium = model.host_hessian(q, params, gradient=np.zeros_like(g))[0].toarray()
    assert np.all(
        np.abs(at_equilibrium - hessian) <= 4 * np.finfo(float).eps * np.abs(hessian).max(axis=1, keepdims=True)
    )
    # CG's products (stored linearization, and jvp above the face threshold) apply the same matrix.
    v = rng.normal(size=q.size)
    for max_faces in (mesh.n_faces, mesh.n_faces - 1):
        monkeypatch.setattr(model_module, "LINEARIZED_PRODUCT_MAX_FACES", max_faces)
        product = model.host_hessian_operator(q, params, g)(v)
        np.testing.assert_allclose(product, newton_matrix @ v, rtol=0, atol=1e-9 * np.abs(newton_matrix @ v).max())


@pytest.mark.slow  # solves the 3D shell
def test_newton_crosses_an_overpressed_ground_barrier_in_a_few_iterations():
    """A ball poked 5 mm deep, its ground-contact vertices then pushed to 1e-4 of their equilibrium
    gaps: with the true Hessian a Newton step can at most double a log barrier's gap (measured:
    17 iterations back), with Newton's softened matrix the gaps come back in a few (4)."""
    from shelljax.shell3d import EquilibriumProblem, newton

    # The ball, indenter and rest shape of tests/test_shell3d_indent.py's prescribed-gas tests
    # (500 faces, 1 cm indenter, the scan as rest shape): one set of compiled model programs
    # serves both files (SHARED_PROGRAMS).
    ball = s3.ball(radius=0.13, thickness=0.9e-3, n_triangles=500)
    sim = s3.Indentation(
        ball,
        ShellProperties(gauge_pressure=1300.0, young_modulus=2.34e6, thickness=ball.thickness, poisson_ratio=0.4),
        indenter_radius=0.01,
        rest_shape="scan",
        progress=False,
    )
    state = sim.solve(depth=0.005)
    model, params = sim.model, sim.params_at(state.q)
    x = state.vertices.copy()
    touching = x[:, 2] < sim.activation_distance
    assert touching.sum() >= 3
    x[touching, 2] *= 1e-4
    start = np.concatenate([x.ravel(), state.indenter_center])
    softened = model.equilibrium(start, params, atol=sim.atol)
    plain = newton(
        EquilibriumProblem(model, model.host_params(params), barrier_aids=False), start, atol=sim.atol, max_steps=60
    )
    # Same equilibrium: all three stop at max |force| ≤ atol ≈ 5.5e-6 N, which the softest
    # stiffness of a vertex (its membrane's, E h ≈ 2e3 N/m) turns into ≤ 3e-9 m.
    np.testing.assert_allclose(softened.value, plain.value, rtol=0, atol=1e-8)
    np.testing.assert_allclose(softened.value, state.q, rtol=0, atol=1e-8)
    print(
        f"Newton iterations from 1e-4 of the ground gaps: {plain.iterations} with the Hessian, "
        f"{softened.iterations} with the softened matrix"
    )
    assert plain.iterations >= 10, plain.iterations  # the crawl this guards against is there
    assert softened.iterations <= plain.iterations // 2, (softened.iterations, plain.iterations)
