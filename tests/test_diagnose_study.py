"""The diagnosis's data layer: one object per study, the noise model from replicates, clear errors."""

from __future__ import annotations

import numpy as np
import pytest

from shelljax import InvalidInputError
from shelljax.diagnose import EFFECTS, build_study
from shelljax.diagnose._effects import check_effect_names
from shelljax.session import write_session

LEVELS = np.arange(5.0, 20.0 + 1e-9, 2.5)


def _session(
    path,
    rng,
    *,
    trials=3,
    offset_std=0.0,
    scatter=0.3e-3,
    name="ball",
    thickness=0.9e-3,
    slope=2e-3,
    counts=True,
    manometer=1000.0,
):
    trial, force, depth = [], [], []
    for t in range(1, trials + 1):
        offset = rng.normal(0.0, offset_std)
        f = LEVELS + rng.normal(0.0, 0.05, LEVELS.size)
        trial += [t] * f.size
        force += f.tolist()
        depth += (slope * f + offset + rng.normal(0.0, scatter, f.size)).tolist()
    return write_session(
        path,
        object_name=name,
        radius=0.13,
        radius_std=0.002,
        thickness=thickness,
        thickness_std=0.05e-3,
        trial=trial,
        force=force,
        depth=depth,
        wrinkle_counts=[7] * trials if counts else None,
        manometer_gauge_pressure=manometer,
    )


def test_noise_model_separates_trial_offsets_from_scatter(tmp_path):
    # 4 sessions × 12 trials × 7 levels: the two-way ANOVA's variance estimates have ≈ 250 (scatter)
    # and 44 (offset) degrees of freedom, so ±25 % on σ and ±35 % on τ are > 3 standard errors.
    rng = np.random.default_rng(1)
    sessions = [
        _session(tmp_path / f"s{i}.toml", rng, trials=12, offset_std=0.8e-3, scatter=0.3e-3, slope=(2 + i) * 1e-3)
        for i in range(4)
    ]
    study = build_study(sessions)
    scatter = np.sqrt(study.depth_noise[0] + study.depth_noise[1] * np.mean(study.depth**2))
    assert scatter == pytest.approx(0.3e-3, rel=0.25)
    assert study.trial_offset_std == pytest.approx(0.8e-3, rel=0.35)
    # the whitening matrix inverts the trial-block covariance diag(σ²) + τ² 11ᵀ
    idx = np.flatnonzero(study.depth_unit == 0)
    cov = np.diag(study.depth_std[idx] ** 2) + study.trial_offset_std**2
    block = study.whitening[np.ix_(idx, idx)]
    assert np.allclose(block @ cov @ block.T, np.eye(idx.size), atol=1e-9)
    assert study.n_units == 48 and study.start_pressure.tolist() == [1000.0] * 4


def test_levels_group_samples_of_one_force_step(tmp_path):
    study = build_study(
        [
            _session(tmp_path / "a.toml", np.random.default_rng(0)),
            _session(tmp_path / "b.toml", np.random.default_rng(1)),
        ]
    )
    for s in range(2):
        levels = study.level[study.depth_session == s]
        assert np.unique(levels).size == LEVELS.size  # 3 trials' forces (±0.05 N) at each of 7 steps
        assert np.all(np.abs(study.force[study.depth_session == s] - levels) < 0.2)


def test_sessions_of_different_objects_are_refused(tmp_path):
    rng = np.random.default_rng(0)
    a = _session(tmp_path / "a.toml", rng, name="pezzi-ball")
    b = _session(tmp_path / "b.toml", rng, name="yoga-ball")
    with pytest.raises(InvalidInputError, match=r"different objects.*a\.toml.*'pezzi-ball'.*b\.toml.*'yoga-ball'"):
        build_study([a, b])


def test_sessions_disagreeing_on_the_wall_are_refused(tmp_path):
    rng = np.random.default_rng(0)
    a = _session(tmp_path / "a.toml", rng)
    b = _session(tmp_path / "b.toml", rng, thickness=1.2e-3)
    with pytest.raises(InvalidInputError, match="disagree on 'thickness'"):
        build_study([a, b])


def test_a_study_too_small_to_rank_is_refused(tmp_path):
    one = _session(tmp_path / "a.toml", np.random.default_rng(0), trials=3)
    with pytest.raises(InvalidInputError, match=r"too small to rank.*3 trials.*need at least 4"):
        build_study([one])


def test_sessions_without_wrinkle_counts_are_refused(tmp_path):
    rng = np.random.default_rng(0)
    a = _session(tmp_path / "a.toml", rng)
    b = _session(tmp_path / "b.toml", rng, counts=False)
    with pytest.raises(InvalidInputError, match=r"b\.toml: field 'wrinkles.counts': missing"):
        build_study([a, b])


def test_unknown_effect_names_list_the_valid_ones():
    with pytest.raises(InvalidInputError, match="unknown effect.*'finger_size'.*finger_compliance.*self_weight"):
        check_effect_names(["gas", "finger_size"])
    assert check_effect_names(["gas"]) == ("gas",)
    required = {
        "finger_compliance",
        "depth_offset",
        "force_sensor_gain",
        "force_sensor_nonlinearity",
        "indenter_size",
        "gas",
        "material_stiffening",
        "wall_thickness",
        "self_weight",
        "ground_friction",
    }
    assert required <= set(EFFECTS)
    assert all(
        1 <= len(e.parameters) <= 2 and e.layer in ("measurement", "contact", "physics") for e in EFFECTS.values()
    )


def test_leave_one_trial_out_score_equals_refits_of_a_linear_model():
    """On a linear model the linearised score is exact: compare with explicit refits without each trial."""
    from types import SimpleNamespace

    from shelljax.diagnose._loo import CandidateFit, loo_score

    rng = np.random.default_rng(5)
    n_units, per_unit, n_params, n_prior = 5, 4, 3, 3
    depth_unit = np.repeat(np.arange(n_units), per_unit)
    # whitening of correlated trial blocks, as the study builds it
    blocks = [np.linalg.inv(np.linalg.cholesky(np.eye(per_unit) * 0.3**2 + 0.2**2)) for _ in range(n_units)]
    whitening = np.zeros((depth_unit.size, depth_unit.size))
    for u, b in enumerate(blocks):
        whitening[np.ix_(depth_unit == u, depth_unit == u)] = b
    constant = np.array([np.sum(np.log(np.diag(b))) - 0.5 * per_unit * np.log(2 * np.pi) for b in blocks])
    data = SimpleNamespace(
        depth=np.zeros(depth_unit.size),
        depth_unit=depth_unit,
        count_unit=np.arange(n_units),
        shape_unit=np.zeros(0, int),
        whitening=whitening,
        count=np.zeros(n_units),
        shape_std=np.zeros(0),
        depth_unit_constant=constant,
        n_units=n_units,
    )
    n_rows = depth_unit.size + n_units + n_prior
    jac = rng.normal(size=(n_rows, n_params))
    y = rng.normal(size=n_rows)
    u_hat = np.linalg.lstsq(jac, y, rcond=None)[0]
    resid = jac @ u_hat - y  # r(u) = J u − y, optimum of ½‖r‖²
    fit = CandidateFit(
        data=data,
        u=u_hat,
        jacobian=jac,
        residual=resid,
        covariance=np.linalg.inv(jac.T @ jac),
        chi2=float(resid @ resid),
        steps=0,
        converged=True,
        message="",
        prediction={},
    )
    score = loo_score(fit)
    units = np.concatenate([depth_unit, np.arange(n_units), np.full(n_prior, -1)])
    for i in range(n_units):
        keep, out = units != i, units == i
        u_minus = np.linalg.lstsq(jac[keep], y[keep], rcond=None)[0]
        cov = np.eye(out.sum()) + jac[out] @ np.linalg.inv(jac[keep].T @ jac[keep]) @ jac[out].T
        e = jac[out] @ u_minus - y[out]
        log_density = -0.5 * e @ np.linalg.solve(cov, e) - 0.5 * np.linalg.slogdet(cov)[1] - 0.5 * np.log(2 * np.pi)
        # (the unit's count row is a unit-variance normal: its 2π term; the depth block's is in `constant`)
        assert score.elpd[i] == pytest.approx(log_density + constant[i], abs=1e-9)
