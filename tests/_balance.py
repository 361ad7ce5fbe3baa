"""Global vertical balance of a solved 3D indentation state, independent of the observables."""

import jax.numpy as jnp
import numpy as np


def net_vertical_residual(sim, state, model=None) -> float:
    """Σ_v ∂E/∂z_v [N] over the shell's vertices at ``state`` (``model``: the model that solved it,
    default the displacement-controlled one).

    The pins hold only x/y, so the vertical loads on the shell (indenter, ground, weight) balance up
    to exactly this sum, which Newton leaves bounded by its tolerance atol per vertex. Balance tests
    check ``ground_reaction − force − weight = −net_vertical_residual`` to round-off: stronger than
    comparing the two forces to a tolerance, and independent of how far below atol Newton stopped.
    """
    model = model or sim.model
    params = model.host_params(sim.params_at(state.q, **state.friction))
    gradient = np.asarray(model.gradient(jnp.asarray(state.q), params))
    return float(np.sum(gradient[:-3].reshape(-1, 3)[:, 2]))
