"""Bundled virtual 3D-engine curves (shelljax/data/virtual/curves.json) and session drawing.

No 3D solve: the curves were made by tools/make_virtual_sessions.py --curves; its checkpoint is
experiments/long_runs.py's.
"""

import numpy as np
import pytest
from _scripts import load_script

import shelljax.virtual as mvs
from shelljax.paper import DEFAULT_POISSON_RATIO, PAPER_FORCES

from _shells import shell

long_runs = load_script("experiments", "long_runs")


@pytest.fixture(scope="module")
def curves():
    return mvs.load_curves()


def test_curves_cover_the_protocol(curves):
    assert len(curves) >= 5
    for c in curves:
        # the paper's 5–20 N; the travel search stops within FORCE_MATCH (10× below the force noise)
        np.testing.assert_allclose(c["force"], PAPER_FORCES, rtol=0, atol=mvs.FORCE_MATCH)
        assert c["radius"] == mvs.RADIUS and c["poisson_ratio"] == DEFAULT_POISSON_RATIO
        # Mesh-converged generator: w0 moves ≤ 0.13 % from 12k to 24k faces (docs/estimators.md).
        assert c["n_faces"] > 12000


def test_curves_are_physically_sensible(curves):
    for c in curves:
        f, w, drop = (np.asarray(c[k]) for k in ("force", "w0", "top_drop"))
        assert np.all(w > 0) and np.all(np.diff(w) > 0), f"w0 not increasing with F: {w}"
        # Sinking into the ground flattening adds to the pole's drop: the local dimple is shallower.
        assert np.all(w < drop)
        # Order of magnitude: F = π k_s R P_g w0 with k_s between 0.3 and 1 (docs/axisym.md finds
        # 0.36–0.74 on the axisymmetric engine over a wide τ range).
        k = f / (np.pi * c["radius"] * c["gauge_pressure"] * w)
        assert np.all((k > 0.3) & (k < 1.0)), k
        # The depth stays below the ball's radius (no flattening through the ball).
        assert w[-1] < c["radius"]
        modes, amplitude = np.asarray(c["wrinkle_mode"]), np.asarray(c["wrinkle_amplitude"])
        assert modes.shape == amplitude.shape == f.shape and np.all(modes >= 2)
        # Non-axisymmetric displacement is a fraction of the dimple, never comparable to it.
        assert np.all((amplitude > 0) & (amplitude < 0.1 * w))


def test_only_the_ball_past_the_wrinkling_onset_wrinkles(curves):
    # Set 0 (τ = 37) goes furthest past the onset: its non-axisymmetric amplitude grows from the
    # mesh's ≈ 0.2 mm sector pattern to > 1 mm at 15 N (docs/estimators.md); sets 1 and 5, whose
    # relaxed and unrelaxed axisymmetric curves coincide to 0.01 mm (no hoop compression to
    # release), stay at the sector level.
    by_set = {c["set"]: np.asarray(c["wrinkle_amplitude"]) for c in curves}
    assert by_set[0][-1] > 4 * by_set[0][0]
    for k in (1, 5):
        assert by_set[k][-1] < 1.5 * by_set[k][0]


def test_session_drawing_is_reproducible(curves):
    a = mvs.draw_session(curves[0], 1e-3, seed=5)
    b = mvs.draw_session(curves[0], 1e-3, seed=5)
    c = mvs.draw_session(curves[0], 1e-3, seed=6)
    np.testing.assert_array_equal(a.depth, b.depth)
    np.testing.assert_array_equal(a.force, b.force)
    np.testing.assert_array_equal(a.wrinkle_counts, b.wrinkle_counts)
    assert not np.array_equal(a.depth, c.depth)
    assert a.force.size == mvs.N_TRIALS * len(PAPER_FORCES) and a.wrinkle_counts.size == mvs.N_TRIALS
    # 0.5 mm ruler: depths are multiples of the rounding step.
    np.testing.assert_allclose(a.depth / mvs.DEPTH_ROUNDING, np.round(a.depth / mvs.DEPTH_ROUNDING), atol=1e-9)


def test_noise_free_session_is_the_curve_itself(curves):
    c = curves[0]
    s = mvs.noise_free_session(c, name="exact")
    np.testing.assert_array_equal(s.force, np.tile(c["force"], mvs.N_TRIALS))
    np.testing.assert_array_equal(s.depth, np.tile(c["w0"], mvs.N_TRIALS))
    np.testing.assert_allclose(s.wrinkle_counts, 1.33 * np.sqrt(c["tau"]), rtol=1e-15)
    assert s.wrinkle_counts.size == mvs.N_TRIALS and s.manometer_gauge_pressure is None


def test_drawn_noise_matches_the_requested_level(curves):
    # Mean over many draws of the per-sample deviation from the truth: σ² + rounding²/12.
    sigma = 2e-3
    dev = []
    for seed in range(200):
        s = mvs.draw_session(curves[0], sigma, seed=seed)
        dev.append(s.depth - np.tile(curves[0]["w0"], mvs.N_TRIALS))
    dev = np.concatenate(dev)
    expected = np.sqrt(sigma**2 + mvs.DEPTH_ROUNDING**2 / 12)
    # 4200 samples: the std's relative standard error is 1/√(2·4200) ≈ 1.1 %; allow 5 %.
    assert abs(dev.std() / expected - 1) < 0.05
    assert abs(dev.mean()) < 4 * expected / np.sqrt(dev.size)


def test_test_and_calibration_sets(curves):
    sessions = mvs.draw_sessions(curves, realisations=4)  # as experiments/compare_estimators.py
    assert len(sessions) == len(curves) * len(mvs.NOISE_LEVELS) * 4 >= 50
    assert len({t["seed"] for t, _ in sessions}) == len(sessions)  # independent draws
    calib = mvs.draw_calibration_sessions(curves)
    assert all(s.manometer_gauge_pressure == c["gauge_pressure"] for s, c in zip(calib, curves))
    assert all(s.manometer_gauge_pressure is None for _, s in sessions)


def test_wrinkling_relaxation_matches_held_out_3d_curve(curves):
    from shelljax.axisym import indentation_curves

    # Set 7 (τ = 27) wrinkles the most and played no part in calibrating c_w (set 0 only).
    c = next(c for c in curves if c["set"] == 7)
    params = np.array([c["gauge_pressure"], c["young_modulus"], c["thickness"], c["poisson_ratio"]])
    w3d = np.asarray(c["w0"])

    def error(**kw):
        res = indentation_curves(
            shell(params), c["force"], radius=c["radius"], indenter_radius=c["indenter_radius"], **kw
        )
        return np.asarray(res.w0[0]) / w3d - 1.0

    # 2 %: issue 6's cross-validation target; measured ≤ 1.4 % at every level of 5–20 N (−1.4 % at
    # 20 N). The limiting models miss by +8.8 % (tension field) and −8.5 % (no relaxation) at 20 N,
    # and the previous c_w = 2.5 by −2.8 %, so the bound cannot pass by accident.
    assert np.all(np.abs(error()) < 0.02)
    assert error(hoop_capacity=0.0)[-1] > 0.04
    assert error(relax=False)[-1] < -0.04


class _FakeIndentation:
    """Stands in for shell3d.Indentation in the level search: the state is the travel itself and
    F(travel) [N] is a smooth stiffening law; Newton "fails" on steps longer than ``max_newton_step``."""

    def __init__(self, max_newton_step=np.inf):
        from shelljax.shell3d import Indentation

        self.q_reference = np.zeros(1)
        self.max_step = 5e-3
        self.max_newton_step = max_newton_step
        self._substeps = Indentation._substeps.__get__(self)
        self.solves = 0

    @staticmethod
    def force(q):
        t = float(q[0])
        return 150.0 * t + 2000.0 * t**2  # N for t in m: 5 N at ≈ 27 mm, 20 N at ≈ 68 mm

    def params_at(self, q):
        return {}

    def _depth_step(self, history, depth):
        from types import SimpleNamespace

        from shelljax import NoConvergenceError

        self.solves += 1
        if depth - history[-1][0] > self.max_newton_step:
            raise NoConvergenceError("fake: step too long", [1.0])
        return SimpleNamespace(value=np.array([depth])), {}, 0.0  # a shelljax.Solution's value


@pytest.fixture
def fake_force(monkeypatch):
    import shelljax.shell3d._search as search

    monkeypatch.setattr(search, "observables", lambda sim, q, params: {"force": _FakeIndentation.force(q)})


def test_force_levels_by_travel_hit_every_level(fake_force, tmp_path):
    sim = _FakeIndentation()
    ckpt = tmp_path / "levels.npz"
    levels = mvs.force_levels_by_travel(sim, PAPER_FORCES, long_runs.Checkpoint(ckpt))
    forces = np.array([f for f, _ in levels])
    np.testing.assert_allclose(forces, PAPER_FORCES, atol=mvs.FORCE_MATCH)
    # the state returned is the one whose force was recorded
    np.testing.assert_array_equal(forces, [_FakeIndentation.force(q) for _, q in levels])
    # 68 mm of travel in 5 mm steps is 14 solves; secant steps on a smooth F find each level in a
    # few more (a bisection to 1 mN would take ≈ 12 per level)
    assert sim.solves <= 14 + 3 * len(PAPER_FORCES)
    # a restarted run finds every level in its checkpoint without solving again
    again = _FakeIndentation()
    resumed = mvs.force_levels_by_travel(again, PAPER_FORCES, long_runs.Checkpoint(ckpt))
    assert again.solves == 0
    np.testing.assert_array_equal([f for f, _ in resumed], forces)


def test_force_levels_by_travel_halve_failed_steps(fake_force):
    sim = _FakeIndentation(max_newton_step=2e-3)  # every 5 mm step fails twice before it succeeds
    levels = mvs.force_levels_by_travel(sim, (5.0, 10.0), None)
    np.testing.assert_allclose([f for f, _ in levels], (5.0, 10.0), atol=mvs.FORCE_MATCH)
    # with no halvings left the failure surfaces instead of a state at the wrong force
    from shelljax import NoConvergenceError

    with pytest.raises(NoConvergenceError):
        mvs.force_levels_by_travel(_FakeIndentation(max_newton_step=1e-4), (5.0,), None)


def test_checkpoint_of_an_older_format_is_refused(tmp_path):
    old = tmp_path / "old.npz"
    np.savez(old, forces=[5.0], states=np.zeros((1, 3)))  # the force-controlled format: no travels
    with pytest.raises(SystemExit, match="older version"):
        long_runs.Checkpoint(old).load()
