"""Loop carries that vmap treats as batched from the start.

``jax.vmap`` of a ``while_loop`` or ``scan`` finds which carries are batched by batching the body
again until that set stops growing; a counter or constant starts unbatched, so the body is batched
once more. Nested loops multiply these passes (the curve's scan holds the Newton loop, which holds
the line search, the contact passes and two block-Thomas scans): tying every initial carry to a
batched value lets vmap batch each body once.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def tied_to(ref, *values):
    """``values`` unchanged, each made to depend on the array ``ref`` (batched under vmap if it is).

    ``select(p, v, v)`` is ``v`` for any p; XLA folds it away, so it costs nothing at run time.
    """
    flag = jnp.isnan(jnp.ravel(ref)[0])
    out = tuple(jax.tree_util.tree_map(lambda v: jnp.where(flag, v, v), v) for v in values)
    return out[0] if len(out) == 1 else out
