"""Traced programs kept across processes (shelljax/_programs.py) and the shipped fit program."""

import warnings
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from shelljax import _programs
from shelljax.config import load_config
from shelljax.estimate import options_forward_model
from shelljax.estimate._fit import _solve
from shelljax.estimate._problem import ALL_NAMES, build_problem, padded_problem
from shelljax.session import load_session

ROOT = Path(__file__).resolve().parents[1]


class _Spring(eqx.Module):
    stiffness: jax.Array
    mode: str = eqx.field(static=True)


def _energy(spring: _Spring, x, *, power: int):
    _energy.traces += 1  # counts traces: a program read from disk runs without one
    scale = 2.0 if spring.mode == "double" else 1.0
    return scale * jnp.sum(spring.stiffness * x**power), jnp.linalg.qr(jnp.outer(x, x) + jnp.eye(x.size))[1]


@pytest.fixture
def kept(tmp_path, monkeypatch):
    """``persistent_jit(_energy)`` storing in ``tmp_path``, with nothing loaded in memory."""
    monkeypatch.setattr(_programs, "user_program_dir", lambda: tmp_path)
    monkeypatch.setattr(_programs, "_LOADED", {})
    _energy.traces = 0
    return _programs.persistent_jit(_energy)


def test_a_program_read_back_runs_without_tracing_and_gives_the_same_result(kept, tmp_path, monkeypatch):
    spring, x = _Spring(jnp.asarray([1.0, 2.0, 3.0]), "single"), jnp.asarray([0.5, -1.0, 2.0])
    first = kept(spring, x, power=2)
    assert _energy.traces == 1 and len(list(tmp_path.glob("*.jaxexport"))) == 1
    monkeypatch.setattr(_programs, "_LOADED", {})  # a new process: only the file is left
    again = kept(spring, x, power=2)
    assert _energy.traces == 1
    # the same compiled arithmetic on both sides: equal to the last bit
    np.testing.assert_array_equal(np.asarray(first[0]), np.asarray(again[0]))
    np.testing.assert_array_equal(np.asarray(first[1]), np.asarray(again[1]))
    assert float(again[0]) == pytest.approx(0.25 + 2.0 + 12.0, rel=1e-15)  # Σ k x²
    # new values of the same structure reuse the program
    assert float(kept(_Spring(jnp.asarray([1.0, 1.0, 1.0]), "single"), x, power=2)[0]) == pytest.approx(5.25, rel=1e-15)
    assert _energy.traces == 1


def test_each_static_field_shape_and_static_argument_is_its_own_program(kept, tmp_path):
    x = jnp.asarray([0.5, -1.0, 2.0])
    kept(_Spring(jnp.ones(3), "single"), x, power=2)
    assert float(kept(_Spring(jnp.ones(3), "double"), x, power=2)[0]) == pytest.approx(2 * 5.25, rel=1e-15)
    assert float(kept(_Spring(jnp.ones(3), "single"), x, power=3)[0]) == pytest.approx(0.125 - 1.0 + 8.0, rel=1e-15)
    assert float(kept(_Spring(jnp.ones(2), "single"), x[:2], power=2)[0]) == pytest.approx(1.25, rel=1e-15)
    assert _energy.traces == 4 and len(list(tmp_path.glob("*.jaxexport"))) == 4


def test_a_key_changes_with_the_sources(monkeypatch):
    args = (_Spring(jnp.ones(3), "single"), jnp.ones(3))
    before = _programs.program_key("f", args, {"power": 2})
    monkeypatch.setattr(_programs, "source_fingerprint", lambda: "edited")
    assert _programs.program_key("f", args, {"power": 2}) != before


def test_an_unreadable_file_is_traced_again_with_a_warning(kept, tmp_path, monkeypatch):
    spring, x = _Spring(jnp.ones(3), "single"), jnp.ones(3)
    kept(spring, x, power=2)
    (path,) = tmp_path.glob("*.jaxexport")
    path.write_bytes(path.read_bytes()[:100])
    monkeypatch.setattr(_programs, "_LOADED", {})
    with pytest.warns(UserWarning, match="not a readable exported program"):
        assert float(kept(spring, x, power=2)[0]) == pytest.approx(3.0, rel=1e-15)
    assert _energy.traces == 2


def test_a_program_with_a_host_callback_falls_back_to_jit(tmp_path, monkeypatch):
    monkeypatch.setattr(_programs, "user_program_dir", lambda: tmp_path)
    monkeypatch.setattr(_programs, "_LOADED", {})

    def halve_on_host(x):
        return jax.pure_callback(lambda v: np.asarray(v) / 2, jax.ShapeDtypeStruct(x.shape, x.dtype), x)

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = _programs.persistent_jit(halve_on_host)(jnp.asarray([2.0, 4.0]))
    np.testing.assert_array_equal(np.asarray(out), [1.0, 2.0])
    assert not list(tmp_path.glob("*.jaxexport"))


def test_the_default_experiments_fit_program_is_shipped_for_these_sources():
    """Fails after any change to the package's sources until ``tools/ship_programs.py`` runs."""
    config = load_config(ROOT / "configs" / "paper.toml")
    options = config.estimator_options
    session = load_session(config.sessions[0])
    problem = build_problem(
        session,
        options_forward_model(session, options),
        start_pressure=1e3,
        start_modulus=1e6,
        depth_noise=None,
        nuisance=options.nuisance,
    )
    padded, _, _ = padded_problem(problem)
    key = _programs.program_key(
        _solve.__qualname__, (padded, jnp.zeros(len(ALL_NAMES)), 1e-8, 1e-8), {"max_steps": 200}
    )
    path = _programs.SHIPPED_DIR / (key + _programs.SUFFIX)
    assert path.is_file(), f"{path.name} is not shipped: run python tools/ship_programs.py"
    exported = jax.export.deserialize(bytearray(path.read_bytes()))
    leaves = jax.tree_util.tree_leaves((padded, jnp.zeros(len(ALL_NAMES)), 1e-8, 1e-8))
    assert [a.shape for a in exported.in_avals] == [np.shape(leaf) for leaf in leaves]


def test_a_cache_that_cannot_be_written_costs_a_warning_not_the_result(tmp_path, monkeypatch):
    blocked = tmp_path / "file"
    blocked.write_text("not a directory")
    monkeypatch.setattr(_programs, "user_program_dir", lambda: blocked / "programs")
    monkeypatch.setattr(_programs, "_LOADED", {})
    _energy.traces = 0
    with pytest.warns(UserWarning, match="cannot keep the traced program"):
        out = _programs.persistent_jit(_energy)(_Spring(jnp.ones(3), "single"), jnp.ones(3), power=2)
    assert float(out[0]) == pytest.approx(3.0, rel=1e-15)


def test_compiler_options_the_installed_xla_does_not_know_are_dropped(kept, tmp_path):
    # jaxlib releases add and remove XLA flags (0.11 dropped xla_cpu_use_fusion_emitters): an
    # unknown flag in a program's options would fail its every compile, so only known ones are kept
    options = {"xla_backend_optimization_level": 1, "xla_flag_no_jaxlib_has": True}
    assert _programs._known_options(options) == {"xla_backend_optimization_level": 1}
    double = _programs.persistent_jit(lambda x: 2.0 * x, cpu_compiler_options=options)
    assert float(double(jnp.asarray(1.5))) == 3.0
