"""The tests' parameter sets are rows (…, 4) of P_g [Pa], E [Pa], h [m], ν [-] that they perturb,
stack and compare; the engines take them as one ShellProperties."""

import jax
import numpy as np

from shelljax.physics import ShellProperties


def shell(rows, radius=None) -> ShellProperties:
    """``rows`` (4,) or (batch, 4) as a ShellProperties of scalar or (batch,) fields."""
    rows = rows if isinstance(rows, jax.Array) else np.asarray(rows, dtype=float)
    return ShellProperties(
        gauge_pressure=rows[..., 0],
        young_modulus=rows[..., 1],
        thickness=rows[..., 2],
        poisson_ratio=rows[..., 3],
        radius=radius,
    )
