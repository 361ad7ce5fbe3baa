"""emcee's affine-invariant ensemble sampler, a block of steps compiled as one loop.

The move is emcee's default, Goodman & Weare's stretch move (scale a = 2): each step splits the
walkers at random into two halves and moves each walker of one half towards or away from a
random walker of the other, y = c + z (x − c) with z ~ g(z) ∝ 1/√z on [1/a, a], accepted with
probability min(1, z^(d−1) p(y) / p(x)). Driven by emcee, every step is a Python dispatch of the
log posterior, which costs more than the posterior itself when that is a surrogate; here a block
of steps is one ``lax.scan``, and emcee keeps the chain (its backends) and judges it (its
integrated autocorrelation time).

The walkers live in a padded space: a coordinate that is not sampled is exactly 0 in every
walker, and a stretch between walkers that agree in a coordinate keeps it there; the move's
factor z^(d−1) counts only the sampled coordinates (``free``). So one compiled program serves
every session of a forward model's structure, as one compiled fit does.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, UInt32

from ._problem import PaddedProblem
from .._programs import persistent_jit

STRETCH_SCALE = 2.0  # emcee's default a


def _stretch(
    key: UInt32[Array, " 2"], coords, log_prob, moving, others, problem: PaddedProblem, sampled: Float[Array, ""]
):
    """One half-step: the walkers ``moving`` stretched against ``others``; (coords, log_prob,
    accepted of ``moving``, forward solves that failed)."""
    key_z, key_partner, key_accept = jax.random.split(key, 3)
    walkers = moving.shape[0]
    z = ((STRETCH_SCALE - 1.0) * jax.random.uniform(key_z, (walkers,)) + 1.0) ** 2 / STRETCH_SCALE
    partner = coords[others][jax.random.randint(key_partner, (walkers,), 0, others.shape[0])]
    here = coords[moving]
    proposal = partner - (partner - here) * z[:, None]
    proposed_log_prob, converged = jax.vmap(problem.log_posterior)(proposal)
    log_ratio = (sampled - 1.0) * jnp.log(z) + proposed_log_prob - log_prob[moving]
    accept = log_ratio > jnp.log(jax.random.uniform(key_accept, (walkers,)))
    coords = coords.at[moving].set(jnp.where(accept[:, None], proposal, here))
    log_prob = log_prob.at[moving].set(jnp.where(accept, proposed_log_prob, log_prob[moving]))
    return coords, log_prob, accept, jnp.sum(~converged, dtype=jnp.int32)


def _block(
    problem: PaddedProblem,
    coords: Float[Array, "w 7"],
    key: UInt32[Array, " 2"],
    free: Bool[Array, " 7"],
    steps: Int[Array, ""],
    length: int,
):
    walkers = coords.shape[0]
    half = (walkers + 1) // 2  # emcee splits an odd ensemble the same way
    sampled = jnp.sum(free).astype(coords.dtype)
    initial_log_prob, _ = jax.vmap(problem.log_posterior)(coords)

    def move(carry):
        coords, log_prob, key, failed = carry
        key, key_split, key_first, key_second = jax.random.split(key, 4)
        order = jax.random.permutation(key_split, walkers)
        first, second = order[:half], order[half:]
        coords, log_prob, accept_first, failed_first = _stretch(
            key_first, coords, log_prob, first, second, problem, sampled
        )
        coords, log_prob, accept_second, failed_second = _stretch(
            key_second, coords, log_prob, second, first, problem, sampled
        )
        accepted = jnp.zeros(walkers, bool).at[first].set(accept_first).at[second].set(accept_second)
        return (coords, log_prob, key, failed + failed_first + failed_second), accepted

    def step(carry, index):
        # the block's length is fixed (one program); steps past ``steps`` leave the state as it is
        carry, accepted = jax.lax.cond(index < steps, move, lambda c: (c, jnp.zeros(walkers, bool)), carry)
        return carry, (carry[0], carry[1], accepted)

    start = (coords, initial_log_prob, key, jnp.zeros((), jnp.int32))
    (_, _, _, failed), (chain, log_prob, accepted) = jax.lax.scan(step, start, jnp.arange(length, dtype=jnp.int32))
    return {
        "initial_log_prob": initial_log_prob,
        "chain": chain,
        "log_prob": log_prob,
        "accepted": accepted,
        "failed_forward": failed,
    }


_block_kept = persistent_jit(_block)


def stretch_block(problem: PaddedProblem, coords, seed: int, free, steps: int, length: int) -> dict:
    """``steps`` ≤ ``length`` stretch-move steps of the ensemble ``coords`` (walkers, 7) of
    (u, log σ_w) under ``problem.log_posterior``, in a program compiled once per ``length``.

    ``seed``: the block's random stream (an integer); ``free`` (7,): the sampled coordinates
    (the others must be 0 in every walker). Returns ``initial_log_prob`` (walkers,) of
    ``coords``, ``chain`` (length, walkers, 7), ``log_prob`` (length, walkers) and ``accepted``
    (length, walkers), valid for the first ``steps`` rows, and ``failed_forward``: proposals
    whose forward model failed.
    """
    key = jax.random.PRNGKey(seed)
    return _block_kept(
        problem,
        jnp.asarray(coords, jnp.float64),
        key,
        jnp.asarray(free),
        jnp.asarray(steps, jnp.int32),
        length=int(length),
    )


__all__ = ["STRETCH_SCALE", "stretch_block"]
