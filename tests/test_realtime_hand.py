"""The real-time runtime's hand (shelljax.realtime's collider): closest-point contact between the
moving capsule and the shell's triangles. A 2 cm capsule pressed at 1 m/s into a 300-face ball
never gets inside it, and the segment–triangle closest points match a dense sampling."""

from __future__ import annotations

import numpy as np
import pytest

from shelljax import realtime as rt
from shelljax.physics import Plane, ShellProperties
from shelljax.realtime import _hand

# One xdist worker for the files that step the real-time runtime (conftest.py).
SHARED_PROGRAMS = "realtime kernels"

PROPS = ShellProperties(gauge_pressure=1300.0, young_modulus=2.34e6, thickness=0.9e-3, poisson_ratio=0.4, radius=0.13)


def _winding_number(x, faces, p):
    """The generalized winding number [-] of the closed mesh (x (V, 3) [m], faces (F, 3)) at p (3,)
    [m]: Σ of the faces' solid angles / 4π (Van Oosterom–Strackee), 1 inside, 0 outside."""
    a, b, c = (x[faces[:, k]] - p for k in range(3))
    la, lb, lc = (np.linalg.norm(r, axis=1) for r in (a, b, c))
    numerator = np.einsum("ij,ij->i", a, np.cross(b, c))
    denominator = (
        la * lb * lc
        + np.einsum("ij,ij->i", a, b) * lc
        + np.einsum("ij,ij->i", b, c) * la
        + np.einsum("ij,ij->i", c, a) * lb
    )
    return abs(2.0 * np.arctan2(numerator, denominator).sum() / (4.0 * np.pi))


def _resting_ball():
    """The 300-face ball relaxed on the ground [m]."""
    ground = Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], friction=0.5, name="ground")
    ball = rt.RealtimeShell.ball(PROPS, mass=0.8, n_faces=300, rest_shape="small-strain", planes=[ground])
    ball.drop(0.0)
    ball.relax(0.3)
    return ball


def _deepest_axis_winding(ball):
    """The largest winding number [-] of the mesh at 11 points along the collider's axis."""
    end_a, end_b = ball.contact.collider[:3], ball.contact.collider[3:6]
    axis = end_a + np.linspace(0.0, 1.0, 11)[:, None] * (end_b - end_a)
    return max(_winding_number(ball.x, ball.geometry.faces, p) for p in axis)


def _press_finger(ball, speed, travel, n_frames):
    """A 2 cm-radius, 20 cm capsule coming down at ``speed`` [m/s] through the top of the ball, off
    the pole vertex (between vertices), for ``travel`` [m] in ``n_frames`` frames; asserts at every
    frame that its axis is outside the shell; returns the push [N] along its motion per frame."""
    radius = 0.02
    a = np.array([0.003, 0.002, ball.x[:, 2].max() + radius + 0.002])
    ball.set_collider(rt.Collider(a=tuple(a), b=tuple(a + [0.0, 0.0, 0.2]), radius=radius, velocity=(0, 0, -speed)))
    pushing = []
    for _ in range(n_frames):
        frame = ball.frame(travel / speed / n_frames)
        assert _deepest_axis_winding(ball) < 0.5, f"the capsule's axis is inside the shell at t = {ball.time:.3f} s"
        pushing.append(-frame.collider_force_N[2])  # along the capsule's motion, into the shell
    return pushing


def test_a_thin_capsule_pressed_into_a_coarse_ball_never_gets_inside():
    """Issue 61: a 2 cm capsule at 1 m/s down through the top of a 300-face ball on the ground, 10
    cm (the sample-point contact let it in after 5.5 cm); it pushes, harder as it goes."""
    pushing = _press_finger(_resting_ball(), 1.0, 0.10, 6)
    assert min(pushing[2:]) > 1.0 and pushing[-1] > pushing[2]  # touching from the 2nd frame on, pushing harder


@pytest.mark.parametrize("speed", [1.0, 3.0])
def test_a_deep_push_at_the_viewers_speeds_never_gets_inside(speed):
    """The same finger 12.5 cm in (the tip 10 cm below the ball's first top, the ball squashed to
    its middle against the ground), at 1 m/s and at the viewer's top speed, 3 m/s: the vertex under
    the tip is pushed into the shell along its normal however deep it is (``exit_distance``), so
    it does not slip round the tip (along the gap from the axis it did, at 12 cm)."""
    pushing = _press_finger(_resting_ball(), speed, 0.125, 5)
    assert pushing[-1] > 20.0  # the shell resists: ≈ 45 N at the end


def test_a_hand_behind_the_surface_is_expelled_and_the_shell_gets_its_impulse():
    """A 2 cm capsule lying 5 mm under the top of the ball (its axis inside the shell), at rest, no
    gravity nor ground: the faces and vertices around it push the shell past it along their inward
    normals, so its axis ends outside; the shell's momentum change is the collider's impulse (the
    frames' averaged forces × their durations, to round-off)."""
    # placed there, the hand's springs hold ≈ 1 J a vertex (k_j δ²/2, δ ≈ 2.5 cm), which the energy
    # guard (it counts the planes' springs, not the collider's) would read as growth
    ball = rt.RealtimeShell.ball(
        PROPS, mass=0.8, n_faces=300, rest_shape="small-strain", gravity=0.0, energy_growth=1e3
    )
    ball.relax(0.2)
    top = ball.x[:, 2].max()
    ball.set_collider(rt.Collider(a=(-0.03, 0.0, top - 0.005), b=(0.03, 0.0, top - 0.005), radius=0.02))
    assert _deepest_axis_winding(ball) > 0.5  # inside at the start
    _, v0 = ball.com()
    impulse = np.zeros(3)
    for _ in range(20):
        frame = ball.frame()
        impulse += frame.collider_force_N * frame.dt_s * frame.substeps
    _, v1 = ball.com()
    assert _deepest_axis_winding(ball) < 0.5
    assert impulse[2] < 0.0  # the shell pushed down, away from the hand above its new top
    np.testing.assert_allclose(ball.total_mass * (v1 - v0), impulse, rtol=1e-9, atol=1e-12)


def _gap_to_capsule(q, a, b, radius):
    """Distance [m] from q to the capsule a–b of ``radius`` (negative inside)."""
    d = b - a
    w = np.clip((q - a) @ d / (d @ d), 0.0, 1.0) if d @ d > 0.0 else 0.0
    return np.linalg.norm(q - a - w * d) - radius


def test_the_exit_distance_matches_a_bisection():
    """``exit_distance`` (closed form: the far crossings of the end spheres and the cylinder) against
    a bisection on the distance to the capsule along the ray (convex in t, so it crosses 0 once),
    to 1e-12 m."""
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(200):
        a, b = rng.standard_normal(3), rng.standard_normal(3)
        if rng.random() < 0.2:
            b = a  # a sphere
        radius = 0.5 + rng.random()
        p = a + rng.random() * (b - a) + 0.5 * radius * rng.standard_normal(3) / np.sqrt(3.0)
        u = rng.standard_normal(3)
        u /= np.linalg.norm(u)
        if _gap_to_capsule(p, a, b, radius) >= 0.0:
            continue  # outside: not a contact
        t = _hand.exit_distance(tuple(p), tuple(u), np.concatenate([a, b, [radius], np.zeros(4)]))
        lo, hi = 0.0, 10.0  # 10 m along the ray is outside these unit-size capsules
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if _gap_to_capsule(p + mid * u, a, b, radius) < 0.0 else (lo, mid)
        assert abs(t - lo) < 1e-12, (t, lo)
        checked += 1
    assert checked > 100  # most random points fall inside


def _dense_least_distance(a, b, tri, n_segment=400, n_triangle=60):
    """(least distance [m] between samples of the segment a–b and of the triangle tri (3, 3), the
    samples' covering bound [m]): ``n_segment`` + 1 points along the segment, the barycentric grid
    of step 1/``n_triangle`` on the triangle. Every point of the segment is within |b − a|/(2
    n_segment) of a sample and every point of the triangle within its longest edge / n_triangle
    of one (the grid's sub-triangles), so the true least distance lies within the bound below."""
    s = np.linspace(0.0, 1.0, n_segment + 1)
    on_segment = a + s[:, None] * (b - a)
    i, j = np.meshgrid(np.arange(n_triangle + 1), np.arange(n_triangle + 1), indexing="ij")
    keep = i + j <= n_triangle
    u, v = i[keep] / n_triangle, j[keep] / n_triangle
    on_triangle = (1.0 - u - v)[:, None] * tri[0] + u[:, None] * tri[1] + v[:, None] * tri[2]
    gaps = np.linalg.norm(on_segment[:, None, :] - on_triangle[None, :, :], axis=2)
    edges = np.linalg.norm(tri - np.roll(tri, 1, axis=0), axis=1)
    return gaps.min(), np.linalg.norm(b - a) / (2 * n_segment) + edges.max() / n_triangle


def test_segment_triangle_closest_points_match_a_dense_sampling():
    """Random segments and triangles (unit size, with segments through the triangle and parallel
    to it): the kernel's closest points are points of the segment and the triangle, no farther apart
    than any pair of samples (to round-off, 1e-12 m) and no nearer than the samples' least distance
    less their covering bound (``_dense_least_distance``: ≈ 0.05 m here): a true least distance."""
    rng = np.random.default_rng(61)
    for case in range(100):
        tri = rng.standard_normal((3, 3))
        a, b = rng.standard_normal(3), rng.standard_normal(3)
        if case % 10 == 0:  # a segment through the triangle: distance 0
            inside = tri.T @ rng.dirichlet(np.ones(3))
            a, b = inside - 0.5 * (b - a), inside + 0.5 * (b - a)
        if case % 10 == 1:  # a segment parallel to the triangle's plane
            n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
            b = b - (b - a) @ n / (n @ n) * n
        s, w0, w1, w2 = _hand.segment_triangle_closest(tuple(a), tuple(b), tuple(tri[0]), tuple(tri[1]), tuple(tri[2]))
        assert 0.0 <= s <= 1.0 and min(w0, w1, w2) >= 0.0 and abs(w0 + w1 + w2 - 1.0) < 1e-12
        kernel = float(np.linalg.norm(a + s * (b - a) - (w0 * tri[0] + w1 * tri[1] + w2 * tri[2])))
        sampled, bound = _dense_least_distance(a, b, tri)
        assert kernel <= sampled + 1e-12, (case, kernel, sampled)
        assert kernel >= sampled - bound, (case, kernel, sampled, bound)
