"""shelljax.runner._compile_log: what JAX compiled inside a block, from JAX's monitoring events."""

import jax
import jax.numpy as jnp

from shelljax.runner._compile_log import compile_log


def _distinctive_program(x):
    return jnp.cumsum(jnp.sin(x) * 3.0)


def test_a_first_call_is_logged_and_a_second_compiles_nothing():
    program = jax.jit(_distinctive_program)
    with compile_log() as first:
        program(jnp.arange(7.0)).block_until_ready()
    with compile_log() as second:
        program(jnp.arange(7.0)).block_until_ready()
    name = "jit(_distinctive_program)"
    assert first.backend_programs[name] == 1
    assert first.backend_seconds[name] > 0.0 and first.trace_seconds > 0.0
    assert first.total_seconds >= first.backend_seconds[name]
    assert first.to_dict()["backend_seconds_by_program"][name] == first.backend_seconds[name]
    assert name in first.summary()
    # the jit cache serves the second call: no trace, no lowering, no XLA
    assert sum(second.backend_programs.values()) == 0 and second.summary() == "nothing compiled"


def test_listeners_are_removed_after_the_block():
    with compile_log() as log:
        pass
    jax.jit(lambda x: x * 5.0 + 1.0)(jnp.ones(3)).block_until_ready()
    assert log.total_seconds == 0.0 and log.compiled == 0
