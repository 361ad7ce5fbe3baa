"""The real-time runtime (shelljax.realtime): compiled kernels against shell3d's JAX energies, the
gas, conservation in free flight, a static ball on the ground, the stable Δt and the blow-up
guard, and input errors. Meshes are small (≤ 500 faces) and built without the JAX rest-shape
solve (``rest_shape="small-strain"``), so the module runs in well under a minute once Numba's
cache holds the kernels (the first run compiles them: ≈ 30 s)."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from shelljax.physics import AdiabaticGas, IsothermalGas
from shelljax import realtime as rt
from shelljax._errors import InvalidInputError, NoConvergenceError, ShelljaxError
from shelljax.dynamics import BarrierContact
from shelljax.physics import Plane, ShellProperties, barrier_energy, isothermal_gauge_pressure
from shelljax.realtime import _contact as rt_contact
from shelljax.realtime import _elastic as elastic
from shelljax.shell3d import Shell, ShellMesh
from shelljax.shell3d._energy import bending_energy, make_geometry, membrane_energy

# One xdist worker for the files that step the real-time runtime (conftest.py): its Numba kernels
# (≈ 30 s to compile) are then compiled once, by the first file, and loaded from Numba's cache by the other.
SHARED_PROGRAMS = "realtime kernels"

E, NU, H, P_G, R, MASS = 2.34e6, 0.4, 0.9e-3, 1300.0, 0.13, 0.8
PROPS = ShellProperties(gauge_pressure=P_G, young_modulus=E, thickness=H, poisson_ratio=NU, radius=R)


def _ball(n_faces=300, **options):
    shell = Shell(mesh=ShellMesh.sphere(R, n_faces, pole_refinement=1.0), thickness=H)
    options.setdefault("mass", MASS)
    return rt.RealtimeShell.from_shell(shell, PROPS, rest_shape="small-strain", **options)


def _kernel_gradient(x, mesh, geo, bending):
    inv = np.linalg.inv(np.asarray(geo.rest_metric))
    rb = np.asarray(geo.rest_curvature)
    alpha, beta = E * NU / (1 - NU**2), E / (2 * (1 + NU))
    force = np.zeros_like(x)
    none = np.zeros(0, dtype=np.int64)  # the threaded kernel's incidence, unused here
    geometry = rt.Geometry(
        np.asarray(mesh.stencil, dtype=np.int64),
        np.ascontiguousarray(np.asarray(mesh.stencil, dtype=np.int64)[:, :3]),
        np.ascontiguousarray(np.stack([inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]], 1)),
        np.ascontiguousarray(np.stack([rb[:, 0, 0], rb[:, 0, 1], rb[:, 1, 1]], 1)),
        np.asarray(geo.rest_area),
        np.asarray(geo.vertex_area),
        float(np.mean(geo.vertex_area)),
        none,
        none,
    )
    material = rt.Material(H, alpha, beta, bending, 0, 0.0, 1.0, 1.0, 1.4)
    e = elastic.elastic_forces_serial(np.ascontiguousarray(x), geometry, material, force)
    return e, -force


@pytest.fixture(scope="module")
def deformed():
    """A 300-face sphere mesh, a randomly perturbed rest shape and a random deformed state [m]."""
    mesh = ShellMesh.sphere(R, 300, pole_refinement=1.0)
    rng = np.random.default_rng(0)
    rest = mesh.vertices * 0.97 + 1e-3 * rng.standard_normal(mesh.vertices.shape)
    x = mesh.vertices * 1.02 + 4e-3 * rng.standard_normal(mesh.vertices.shape)
    return mesh, make_geometry(mesh, rest), x


def test_membrane_gradient_matches_jax_grad_of_shell3d(deformed):
    mesh, geo, x = deformed

    def energy(y):
        per_face = jax.vmap(membrane_energy, in_axes=(0, 0, 0, None, None, None))(
            y[geo.stencil], geo.rest_metric, geo.rest_area, H, E, NU
        )
        return jnp.sum(per_face)

    e_ref = float(energy(jnp.asarray(x)))
    g_ref = np.asarray(jax.grad(energy)(jnp.asarray(x)))
    e, g = _kernel_gradient(x, mesh, geo, False)
    assert abs(e - e_ref) <= 1e-12 * abs(e_ref)
    assert np.abs(g - g_ref).max() <= 1e-10 * np.abs(g_ref).max()  # measured 6e-16


def test_bending_gradient_matches_jax_grad_of_shell3d(deformed):
    """The kernel's bending is shell3d's own stencil energy (not a hinge substitute): the same
    value and gradient on a random deformation."""
    mesh, geo, x = deformed

    def energy(y):
        per_face = jax.vmap(bending_energy, in_axes=(0, 0, 0, 0, None, None, None))(
            y[geo.stencil], geo.rest_metric, geo.rest_curvature, geo.rest_area, H, E, NU
        )
        return jnp.sum(per_face)

    e_ref = float(energy(jnp.asarray(x)))
    g_ref = np.asarray(jax.grad(energy)(jnp.asarray(x)))
    e_all, g_all = _kernel_gradient(x, mesh, geo, True)
    e_mem, g_mem = _kernel_gradient(x, mesh, geo, False)
    assert abs((e_all - e_mem) - e_ref) <= 1e-9 * abs(e_ref)
    # The bending gradient is the difference of two kernels' results ~1e3 times larger: round-off 1e-13.
    assert np.abs((g_all - g_mem) - g_ref).max() <= 1e-8 * np.abs(g_ref).max()


def test_gas_volume_and_pressure_force_on_a_sphere():
    ball = _ball(2000, gas=IsothermalGas())
    pressure, volume, force = ball.gas_state()
    # The polyhedron's own volume exactly; the inscribed polyhedron is below 4/3 π R³ by
    # O(edge²/R²) (measured 0.58 % at 1962 faces, edge/R = 0.12).
    import trimesh

    polyhedron = trimesh.Trimesh(ball.x, ball.geometry.faces, process=False)
    assert volume == pytest.approx(float(polyhedron.volume), rel=1e-12)
    assert volume == pytest.approx(4.0 / 3.0 * math.pi * R**3, rel=1e-2)
    assert pressure == pytest.approx(P_G, rel=1e-12)  # at its reference volume
    # Closed surface: the pressure forces sum to zero; each is radial, of size P × its area share.
    assert np.abs(force.sum(axis=0)).max() <= 1e-12 * np.abs(force).sum()
    radial = ball.x / np.linalg.norm(ball.x, axis=1)[:, None]
    cos = np.sum(force * radial, axis=1) / np.linalg.norm(force, axis=1)
    assert cos.min() > 0.999
    # P ∂V/∂xᵢ = P Σ_{f ∋ i} A_f n_f / 3: a third of the vector area of the faces around vertex i.
    area_vectors = 0.5 * np.cross(
        ball.x[ball.geometry.faces[:, 1]] - ball.x[ball.geometry.faces[:, 0]],
        ball.x[ball.geometry.faces[:, 2]] - ball.x[ball.geometry.faces[:, 0]],
    )
    share = np.zeros_like(ball.x)
    np.add.at(share, ball.geometry.faces, area_vectors[:, None, :] / 3.0)
    np.testing.assert_allclose(force, P_G * share, atol=1e-12 * np.abs(force).max())
    assert np.linalg.norm(force, axis=1).sum() == pytest.approx(P_G * 4 * math.pi * R**2, rel=1e-2)
    # The sealed law away from V₀: Boyle's law.
    x = ball.x * 0.99
    p_iso, v_iso, _ = ball.gas_state(x)
    assert p_iso == pytest.approx(
        float(isothermal_gauge_pressure(v_iso, ball.material.reference_volume, P_G)), rel=1e-12
    )


def test_free_flight_conserves_momentum_and_energy():
    """No gravity, no planes; the shell starts off-equilibrium (the scan, not its inflated state),
    spinning and translating. Internal forces sum to zero and carry no torque, so velocity Verlet
    (kicks and drifts, each of which keeps L = Σ x × m v: a drift adds Σ Δt v × m v = 0, a kick
    Δt/2 Σ x × F = 0) keeps the linear and angular momenta to round-off. Its energy is not
    conserved step by step but stays within O(Δt²) of a modified energy that it does conserve:
    |H − H₀| is checked below Δt max|Σ v·F|, the size of one substep's work (measured ≈ 0.1 of it),
    and windowed means 1 s apart agree to 1e-3 of the energy (the issue's criterion: 0.5 %/s)."""
    ball = _ball(300, gravity=0.0)
    spin = np.cross([0.0, 0.0, 3.0], ball.x - ball.x.mean(0))
    ball.set_state(ball.x, spin + np.array([0.5, 0.0, 0.2]))
    m = ball.body.masses[:, None]
    p0, l0 = (m * ball.v).sum(0), np.cross(ball.x, m * ball.v).sum(0)
    total, power = [], []
    for _ in range(60):
        frame = ball.frame()
        total.append(frame.energies_J["total"])
        power.append(abs(float(np.sum(ball.v * ball.internal_forces(ball.x)))))
    p1, l1 = (m * ball.v).sum(0), np.cross(ball.x, m * ball.v).sum(0)
    assert np.abs(p1 - p0).max() <= 1e-12 * np.abs(p0).max()
    assert np.abs(l1 - l0).max() <= 1e-10 * np.abs(l0).max()
    total = np.array(total)
    assert np.abs(total - total[0]).max() <= frame.dt_s * max(power)
    assert abs(total[-10:].mean() - total[:10].mean()) < 1e-3 * abs(total[0])


@pytest.mark.parametrize("law", [None, BarrierContact(1e-3, 1e3)], ids=["spring", "barrier"])
def test_ball_resting_on_the_ground_carries_its_weight(law):
    """Relaxed onto the ground, the ball's contact force, averaged over a frame, equals its weight
    up to the momentum change M Δv_com / T of that window (momentum balance); the ball is static
    when that remainder is below 0.5 % of the weight. On the reference's barrier it rests off the
    plane, within the barrier's reach ĝ, as the reference's does; on the spring, in the plane."""
    ground = Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], law, name="ground")
    ball = _ball(300, planes=[ground])
    ball.drop(0.0)
    ball.relax(0.6)
    ball.relax(0.3)
    weight = ball.total_mass * 9.80665
    _, v0 = ball.com()
    frames = [ball.frame() for _ in range(12)]
    _, v1 = ball.com()
    force = np.mean([f.plane_forces_N[0] for f in frames], axis=0)
    duration = frames[-1].time_s
    balance = ball.total_mass * (v1 - v0) / duration
    np.testing.assert_allclose(force[2] - weight, balance[2], atol=1e-9 * weight)
    assert abs(force[2] - weight) < 5e-3 * weight
    assert abs(force[0]) + abs(force[1]) < 1e-6 * weight
    lowest = float(ball.x[:, 2].min())
    assert (0.0 < lowest < 1e-3) if law is not None else (-1e-3 < lowest < 0.0)


def test_stable_dt_bounded_at_it_and_blows_up_at_one_and_a_half():
    """At the estimated Δt a 0.2 m drop with its impact stays bounded (energy within 1 % of the
    start: velocity Verlet's O(Δt²) error; measured ≤ 0.4 %); at 1.5× Δt (1.35× the critical step
    2/ω_max) the stiffest mode grows by |λ| ≈ 5 per substep and the guard raises BlowUpError when
    frames may not be redone; when they may (the default), each frame that trips the guard is
    redone from its start at half the substep (0.68× the critical step), and the drop stays bounded."""
    ground = Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], name="ground")
    ball = _ball(300, planes=[ground])
    stable = ball.stable
    assert stable.element_s <= stable.spectral_s  # the element bound is the safe one (measured 0.69 of it)
    assert stable.dt_s == pytest.approx(stable.safety * stable.spectral_s)
    start = ball.x.copy()
    ball.drop(0.2)
    frame_dt = 1.0 / 60.0
    n = ball.substeps_for(frame_dt)
    frames = [ball.frame(frame_dt) for _ in range(30)]  # falls 0.2 m, hits the ground, rebounds
    assert max(np.abs(f.plane_forces_N[0, 2]) for f in frames) > ball.total_mass * 9.8
    total = [f.energies_J["total"] for f in frames]
    assert max(total) - total[0] < 1e-2 * abs(total[0])
    assert all(f.refinements == 0 for f in frames)
    coarse = max(1, math.floor(n / 1.5))
    ball.set_state(start)
    ball.drop(0.2)
    frames = [ball.frame(frame_dt, substeps=coarse) for _ in range(30)]
    assert max(f.refinements for f in frames) >= 1
    assert all(f.substeps == coarse * 2**f.refinements for f in frames)
    total = [f.energies_J["total"] for f in frames]
    assert max(total) - total[0] < 1e-2 * abs(total[0])
    ball.set_state(start)
    ball.drop(0.2)
    ball.options = dataclasses.replace(ball.options, max_refinements=0)
    with pytest.raises(rt.BlowUpError) as err:
        for _ in range(30):
            ball.frame(frame_dt, substeps=coarse)
    assert isinstance(err.value, NoConvergenceError) and isinstance(err.value, ShelljaxError)
    assert err.value.reason in ("not finite", "energy growth", "tunnelled")
    assert "Fix" in str(err.value)


def test_tunnelling_is_caught():
    ground = Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], name="ground")
    ball = _ball(300, planes=[ground], contact_stiffness=1.0)  # a contact spring far too soft
    ball.drop(0.01, velocity=(0.0, 0.0, -5.0))
    with pytest.raises(rt.BlowUpError, match="tunnelled") as err:
        for _ in range(30):
            ball.frame()
    assert err.value.reason == "tunnelled"


def test_collider_pushes_the_shell_and_feels_the_reaction():
    ball = _ball(300, gravity=0.0)
    top = ball.x[:, 2].max()
    ball.set_collider(rt.Collider.sphere((0.0, 0.0, top + 0.01 - 0.005), 0.01, velocity=(0.0, 0.0, -0.1)))
    _, v0 = ball.com()
    frame = ball.frame()
    assert frame.collider_force_N[2] < 0.0  # the force on the shell: pushed down (the hand feels −F)
    _, v1 = ball.com()
    # No gravity, no planes: the collider's impulse is the shell's whole momentum change.
    np.testing.assert_allclose(
        ball.total_mass * (v1 - v0), frame.collider_force_N * frame.time_s, rtol=1e-9, atol=1e-15
    )


@pytest.mark.parametrize(
    "options, field",
    [
        ({"young_modulus": -1.0}, "young_modulus"),
        ({"poisson_ratio": 0.7}, "poisson_ratio"),
        ({"thickness": float("nan")}, "thickness"),
        ({"gas": "polytropic"}, "gas"),
        ({"mass": -0.1}, "mass"),
        ({"safety": 0.0}, "safety"),
        ({"contact_stiffness": -5.0}, "contact_stiffness"),
        ({"max_refinements": -1}, "max_refinements"),
        ({"max_refinements": 1.5}, "max_refinements"),
        ({"no_such_option": 1.0}, "no_such_option"),  # not a RealtimeOptions field
        ({"planes": [type("P", (), {"point": [0, 0], "normal": [0, 0, 1]})()]}, "planes[0]"),
    ],
)
def test_bad_inputs_name_the_field(options, field):
    shell = Shell(mesh=ShellMesh.sphere(R, 200, pole_refinement=1.0), thickness=H)
    props = {"gauge_pressure": P_G, "young_modulus": E, "thickness": H, "poisson_ratio": NU}
    for key in ("young_modulus", "poisson_ratio", "thickness"):
        if key in options:
            props[key] = options.pop(key)
    kwargs = {"mass": MASS, **options}
    with pytest.raises(InvalidInputError) as err:
        rt.RealtimeShell.from_shell(shell, ShellProperties(**props), rest_shape="small-strain", **kwargs)
    message = str(err.value)
    assert field in message and "\n" not in message


def test_bad_frame_and_collider_inputs():
    ball = _ball(200)
    with pytest.raises(InvalidInputError, match="frame_dt"):
        ball.frame(-1.0)
    with pytest.raises(InvalidInputError, match="Collider.radius"):
        ball.set_collider(rt.Collider.sphere((0, 0, 0), -0.01))
    with pytest.raises(InvalidInputError, match="rest_shape"):
        rt.RealtimeShell.from_shell(Shell(mesh=ShellMesh.sphere(R, 200), thickness=H), PROPS, mass=MASS, rest_shape="x")
    with pytest.raises(InvalidInputError, match="replica.json"):
        rt.RealtimeShell.from_replica("/nonexistent-replica-dir")


def test_replica_round_trip(tmp_path):
    from shelljax.replica import write_replica

    shell = Shell(mesh=ShellMesh.sphere(R, 200, pole_refinement=1.0), thickness=H)
    quantities = {
        "gauge_pressure_Pa": P_G,
        "youngs_modulus_Pa": E,
        "poisson_ratio": NU,
        "thickness_m": H,
        "mass_kg": MASS,
        "cor": None,
    }
    write_replica(tmp_path, shell, quantities, gas="adiabatic")
    ball = rt.RealtimeShell.from_replica(tmp_path, rest_shape="small-strain")
    assert ball.total_mass == pytest.approx(MASS)
    assert ball.gas == AdiabaticGas() and ball.properties.young_modulus == E and ball.properties.thickness == H


def test_from_session_takes_the_sessions_mass_thickness_and_radius():
    from pathlib import Path

    import shelljax

    session = Path(shelljax.__file__).parent / "data" / "sessions" / "pezzi.toml"
    estimates = ShellProperties(gauge_pressure=P_G, young_modulus=E, thickness=None, poisson_ratio=None)
    ball = rt.RealtimeShell.from_session(session, estimates, n_faces=200, rest_shape="small-strain")
    assert (
        ball.total_mass == pytest.approx(0.8)
        and ball.properties.thickness == pytest.approx(0.9e-3)
        and ball.properties.poisson_ratio == pytest.approx(0.4)
    )
    assert np.ptp(ball.x[:, 2]) == pytest.approx(2 * 0.13, rel=1e-6)


def test_parallel_kernel_equals_the_serial_one():
    ball = _ball(300)
    x = ball.x + 1e-3 * np.random.default_rng(1).standard_normal(ball.x.shape)
    args = (ball.geometry, ball.material._replace(bending=True))
    serial, parallel = np.zeros_like(x), np.zeros_like(x)
    e_s = elastic.elastic_forces_serial(x, *args, serial, True)
    e_p = elastic.elastic_forces_parallel(
        x, *args, parallel, np.zeros((len(ball.geometry.faces), 6, 3)), np.zeros(len(ball.geometry.faces)), True
    )
    assert e_p == pytest.approx(e_s, rel=1e-12)
    np.testing.assert_allclose(parallel, serial, rtol=0, atol=1e-12 * np.abs(serial).max())


def test_scenario_planes_are_accepted():
    """The scenario's [[planes]] (configs/bounce.toml: the ground and the wall) as realtime planes."""
    from pathlib import Path

    from shelljax.scenario import load_scenario

    scenario = load_scenario(Path(__file__).resolve().parents[1] / "configs" / "bounce.toml")
    ball = _ball(200, planes=scenario.planes)
    assert ball.plane_names == ("ground", "wall")
    planes = ball.contact.planes
    np.testing.assert_allclose(np.concatenate([planes.point[1], planes.normal[1]]), [0.53, 0, 0, -1, 0, 0])
    assert planes.friction[0] == 0.5  # μ


def test_a_hand_pressing_for_many_frames_is_not_a_blow_up():
    """The collider's work on the shell is subtracted from the energy the guard watches."""
    ground = Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], friction=0.5, name="ground")
    ball = _ball(300, planes=[ground], energy_growth=0.05)
    ball.drop(0.0)
    ball.relax(0.3)
    top = ball.x[:, 2].max()
    centre = np.array([0.0, 0.0, top + 0.04])
    speed = 0.6  # m/s down, 12 frames: 0.12 m of travel, 0.08 m into the ball
    # (a fist; tests/test_realtime_hand.py presses a 2 cm finger)
    ball.set_collider(
        rt.Collider(a=tuple(centre), b=tuple(centre + [0.0, 0.0, 0.05]), radius=0.04, velocity=(0.0, 0.0, -speed))
    )
    for _ in range(12):
        frame = ball.frame()
    np.testing.assert_allclose(ball.contact.collider[2], centre[2] - speed * frame.time_s, atol=1e-12)  # it moved
    assert ball.collider_work > 0.0
    assert frame.collider_force_N[2] < -1.0


def _rotation(seed):
    """A random proper rotation (3, 3) [-] (QR of a Gaussian matrix, sign-fixed)."""
    q, r = np.linalg.qr(np.random.default_rng(seed).standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def test_display_embedding_follows_rigid_motion_and_inflation():
    """A 3000-face display sphere on a 300-face simulation sphere: reproduced at the state it was
    built on; a rigid motion of the simulation mesh moves it rigidly, a uniform scaling about any
    point scales it (both exact in exact arithmetic: the offsets live in each face's own frame
    and are measured in its length √A; 1e-12 m is round-off on 0.1 m coordinates)."""
    from shelljax.geometry import sphere_mesh

    coarse, coarse_faces = sphere_mesh(R, 300)
    fine, fine_faces = sphere_mesh(R, 3000)
    fine = fine @ _rotation(3).T  # not aligned with the coarse rings
    display = rt.DisplayEmbedding(coarse, coarse_faces, fine, fine_faces)
    assert np.abs(display.positions(coarse) - fine).max() <= 1e-15
    # Each display vertex's closest point is no farther than the nearest simulation vertex, and the
    # inscribed polyhedron lies within the sagitta edge²/(8R) (+ slack for the longest edges) of the sphere.
    nearest_vertex = np.min(np.linalg.norm(fine[:, None, :] - coarse[None, :, :], axis=2), axis=1)
    assert np.all(display.offset_m <= nearest_vertex + 1e-15)
    edge = np.linalg.norm(coarse[coarse_faces[:, 0]] - coarse[coarse_faces[:, 1]], axis=1).max()
    assert display.offset_m.max() <= 2.0 * edge**2 / (8.0 * R)
    assert np.all(display.bary >= -1e-12) and np.allclose(display.bary.sum(axis=1), 1.0, atol=1e-12)
    rot, shift = _rotation(4), np.array([0.3, -1.2, 0.7])
    np.testing.assert_allclose(display.positions(coarse @ rot.T + shift), fine @ rot.T + shift, rtol=0, atol=1e-12)
    centre, scale = np.array([0.05, 0.02, -0.4]), 1.37
    np.testing.assert_allclose(
        display.positions(centre + scale * (coarse - centre)), centre + scale * (fine - centre), rtol=0, atol=1e-12
    )


def test_display_embedding_rides_on_a_bouncing_ball():
    """The display mesh of a dropped 300-face ball stays on it through the impact: its centroid
    tracks the simulated centre of mass (within 2 mm, a sixth of the coarse edge), and it reaches
    no lower than the simulated surface less the build-time offsets."""
    from shelljax.geometry import sphere_mesh

    ball = _ball(300, planes=[Plane([0, 0, 0], [0, 0, 1], friction=0.5, name="ground")])
    ball.drop(0.05)
    fine, _ = sphere_mesh(R, 3000)
    fine = fine + (ball.com()[0] - fine.mean(axis=0))
    display = ball.embed(fine)
    for _ in range(10):
        ball.frame(1 / 60)
    shown = display.positions(ball.x)
    assert np.linalg.norm(shown.mean(axis=0) - ball.com()[0]) < 2e-3
    # No lower than the simulated surface, less the offsets (outward: the fine sphere is outside the
    # inscribed coarse one) stretched by at most 2× in the impact.
    assert shown[:, 2].min() >= ball.x[:, 2].min() - 2.0 * display.offset_m.max()
    with pytest.raises(InvalidInputError, match="simulation_faces"):
        rt.DisplayEmbedding(ball.x, ball.geometry.faces + ball.x.shape[0], fine)


def test_impact_is_measured_below_the_vertex_chatter():
    """experiments/verify_realtime.py's impact analysis on a synthetic record. The COM arrives at
    2 m/s, is stopped over T₁ by a quarter sine and sent back over T₂ = 1.25 T₁ by another, leaving
    at 1.6 m/s (COR 0.8, contact time T = T₁ + T₂, compression 4T₁/π m: the closed forms); the
    contact force F₀ sin(πt/T) carries a 375 Hz chatter of ±80 % (the vertices' bounces) and the
    pressure a 150 Hz breathing of ±25 % of the pulse. Low-passed at 60 Hz (4 poles, both ways:
    an attenuation of (375/60)⁸ and (150/60)⁸), their peaks are the clean pulse's own low-passed
    peak, and that is F₀ within 0.2 % (the 60 ms pulse lies below 60 Hz)."""
    from _scripts import load_script

    verify = load_script("experiments", "verify_realtime")
    dt, t1, f0, rest, t0 = 1e-5, 0.06 / 2.25, 150.0, 0.1, 0.05
    t2, depth = 1.25 * t1, 4 * t1 / np.pi
    t = np.arange(0.0, 0.2, dt)
    s1, s2 = (t - t0) / t1, (t - t0 - t1) / t2
    height = np.select(
        [t < t0, t < t0 + t1, t < t0 + t1 + t2],
        [rest + 2.0 * (t0 - t), rest - depth * np.sin(np.pi * s1 / 2), rest - depth * np.cos(np.pi * s2 / 2)],
        rest + 1.6 * (t - t0 - t1 - t2),
    )
    speed = np.gradient(height, dt)
    on = (t >= t0) & (t <= t0 + t1 + t2)
    pulse = np.where(on, f0 * np.sin(np.pi * (t - t0) / (t1 + t2)), 0.0)
    force = pulse * (1.0 + 0.8 * np.sin(2 * np.pi * 375.0 * (t - t0)))
    pressure = 1000.0 + pulse * (1.0 + 0.25 * np.sin(2 * np.pi * 150.0 * (t - t0)))
    m = verify.impact(t, height, speed, force, pressure, rest_height=rest)
    clean = float(verify.low_pass(t, pulse, 60.0).max())
    assert clean == pytest.approx(f0, rel=2e-3)
    assert m["peak_force_N"] == pytest.approx(clean, rel=1e-4)  # the chatter: 8e-7 of it left
    assert m["peak_gauge_pressure_Pa"] == pytest.approx(1000.0 + clean, rel=1e-4)
    assert m["peak_force_raw_N"] > 1.5 * f0 and m["peak_gauge_pressure_raw_Pa"] > 1000.0 + 1.2 * f0
    assert m["contact_time_s"] == pytest.approx(t1 + t2, abs=2 * dt)  # linear interpolation of sampled crossings
    assert m["cor"] == pytest.approx(0.8, abs=1e-3)  # np.gradient's one-sample rounding at the kinks
    assert m["max_compression_m"] == pytest.approx(depth, rel=1e-6)


def test_barrier_plane_is_the_references_law_continued_by_the_spring():
    """A plane with the reference's barrier (ĝ = 1 mm, κ = 1e3 J/m²): each vertex at gap g feels
    −d/dg of ``physics.barrier_energy`` (by jax.grad, the reference's own function) above its clamp
    gap g_c, where the barrier's stiffness (jax's second derivative) equals its spring k_i, and
    f(g_c) + k_i (g_c − g) below it; the plane's energy is the barrier's above g_c and its C¹
    quadratic continuation below; vertices beyond ĝ feel nothing."""
    reach, kappa = 1e-3, 1e3
    ball = _ball(300, planes=[Plane([0, 0, 0], [0, 0, 1], BarrierContact(reach, kappa), name="ground")])
    ball.drop(0.05)
    # twelve vertices placed at gaps from 1.5 mm (beyond ĝ) through the clamp to 0.4 mm behind the plane
    lowest = np.argsort(ball.x[:, 2])[:12]
    ball.x[lowest, 2] = np.concatenate(
        [np.linspace(-0.4e-3, 0.5e-3, 6), np.linspace(0.75e-3, 0.98e-3, 4), [1.2e-3, 1.5e-3]]
    )
    gap = ball.x[:, 2].copy()
    k, clamp = ball.contact.stiffness, ball.contact.clamps[0, :, 0]
    energy = jax.vmap(lambda g: barrier_energy(g, reach, kappa))
    force = jax.vmap(jax.grad(lambda g: -barrier_energy(g, reach, kappa)))
    stiffness = jax.vmap(jax.grad(jax.grad(lambda g: barrier_energy(g, reach, kappa))))
    np.testing.assert_allclose(
        stiffness(jnp.asarray(clamp)), rt_contact.BARRIER_CLAMP_FRACTION * k, rtol=1e-9
    )  # bisection to 2⁻⁸⁰ of ĝ
    f_clamp, e_clamp = np.asarray(force(jnp.asarray(clamp))), np.asarray(energy(jnp.asarray(clamp)))
    safe = np.clip(gap, 1e-9, None)
    expected_f = np.where(
        gap >= reach, 0.0, np.where(gap >= clamp, np.asarray(force(jnp.asarray(safe))), f_clamp + k * (clamp - gap))
    )
    expected_e = np.where(
        gap >= reach,
        0.0,
        np.where(
            gap >= clamp,
            np.asarray(energy(jnp.asarray(safe))),
            e_clamp + f_clamp * (clamp - gap) + 0.5 * k * (clamp - gap) ** 2,
        ),
    )
    assert np.sum(gap < clamp) >= 3 and np.sum((gap >= clamp) & (gap < reach)) >= 3 and np.sum(gap < 0) >= 1
    planes, _ = ball.contact_forces()
    assert planes[0, 2] == pytest.approx(float(expected_f.sum()), rel=1e-10)
    assert ball.energies()["contact"] == pytest.approx(float(expected_e.sum()), rel=1e-10)


@pytest.mark.slow
def test_static_poke_matches_the_quasi_static_engine():
    """An 8 mm sphere 20 mm into the 478-face ball on the ground (no gravity, isothermal gas):
    the realtime ball relaxed under the collider at the engine's solved indenter height carries
    the force of shell3d.Indentation's quasi-static solve within the issue's 2 % (the same mesh,
    rest shape and gas; what differs is the contact law: penalty against the engine's barrier,
    both at the vertices)."""
    from _scripts import load_script

    verify = load_script("experiments", "verify_realtime")
    p = verify.poke(500)
    assert p["realtime_force_N"] == pytest.approx(p["reference_force_N"], rel=0.02)


def test_contact_forces_at_rest_equal_the_springs():
    """``contact_forces()`` reads the forces without stepping: the state is unchanged, and the
    ground's push is Σ k_i δ_i over the vertices behind it (the penalty law, by hand)."""
    ball = _ball(300, planes=[Plane([0, 0, 0], [0, 0, 1], name="ground")])
    ball.drop(0.0)
    ball.x[:, 2] -= 1e-3  # 1 mm into the ground
    x, v, t = ball.x.copy(), ball.v.copy(), ball.time
    planes, collider = ball.contact_forces()
    depth = np.maximum(-ball.x[:, 2], 0.0)
    assert planes[0, 2] == pytest.approx(float(np.sum(ball.contact.stiffness * depth)), rel=1e-12)
    assert np.all(collider == 0.0)
    assert np.array_equal(ball.x, x) and np.array_equal(ball.v, v) and ball.time == t


def test_sliding_contact_feels_the_regularised_coulomb_law():
    """A ball pressed 1 mm into a μ = 0.5 ground and sliding at 0.3 m/s: the ground's tangential
    force is −Σ min(μ k_i δ_i v/√(v² + v_ε²), m_i v/Δt) over the touching vertices (by hand), and
    pushes against the slip; the normal push is unchanged by it."""
    ball = _ball(300, planes=[Plane([0, 0, 0], [0, 0, 1], friction=0.5, name="ground")])
    ball.drop(0.0)
    ball.x[:, 2] -= 1e-3
    ball.v[:] = (0.3, 0.0, 0.0)
    planes, _ = ball.contact_forces()
    depth = np.maximum(-ball.x[:, 2], 0.0)
    slip = 0.3
    coulomb = 0.5 * ball.contact.stiffness * depth * slip / np.hypot(slip, ball.options.slip_velocity)
    expected = -np.sum(np.where(depth > 0.0, np.minimum(coulomb, ball.body.masses * slip / ball.stable.dt_s), 0.0))
    assert expected < 0.0
    assert planes[0, 0] == pytest.approx(expected, rel=1e-12)  # the same sums in another order
    assert planes[0, 1] == pytest.approx(0.0, abs=1e-12)
    assert planes[0, 2] == pytest.approx(float(np.sum(ball.contact.stiffness * depth)), rel=1e-12)
