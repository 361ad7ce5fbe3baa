"""A Chebyshev surrogate of the axisymmetric forward model, for MCMC.

A posterior needs ~10⁵ forward curves, which makes an exact chain through the engine slow
(docs/fit-and-bayes.md, benchmark). The posterior, though, lives in a small box around the
least-squares optimum, where the model is smooth in (log P_g, log E, log h, log R). ``build_surrogate`` solves
the engine once on a tensor grid of Chebyshev nodes in that box (a few hundred curves, batched
over the CPU cores) and interpolates every output — the depth at each force of the model's force
grid and the wrinkle count — by a tensor-product Chebyshev series. ``surrogate_error`` checks it
against the engine at random points of the box; ``sample_posterior`` reports that error next to
the intervals. Outside the box the surrogate reports a failed forward solve (log p = −∞), so
the box truncates the posterior: ``sample_posterior`` makes it wide enough (``SURROGATE_SIGMAS``
Laplace standard deviations) that the truncation is far in the tails.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float
from tqdm.auto import tqdm

from .._errors import InvalidInputError, NoConvergenceError
from ..physics import ShellProperties, Similarity
from ._forward import AbstractForwardModel, AxisymForwardModel, Prediction, ScalingLawModel

SURROGATE_AXES = ("gauge_pressure", "young_modulus", "thickness", "radius")
DEFAULT_NODES = (7, 7, 5, 3)  # Chebyshev nodes per axis of SURROGATE_AXES


def _chebyshev_nodes(count: int) -> np.ndarray:
    """First-kind Chebyshev nodes on [−1, 1] (no end points), (count,)."""
    return np.cos(np.pi * (np.arange(count) + 0.5) / count)


def _chebyshev_basis(t, count: int):
    """T_0(t) … T_{count−1}(t) by the three-term recurrence (smooth everywhere, unlike cos∘arccos)."""
    basis = [jnp.ones_like(t), t][:count]
    while len(basis) < count:
        basis.append(2.0 * t * basis[-1] - basis[-2])
    return jnp.stack(basis)


def _values_to_coefficients(values: np.ndarray) -> np.ndarray:
    """Chebyshev coefficients of the interpolant through values at first-kind nodes (per axis)."""
    coefficients = values
    for axis in range(values.ndim - 1):
        count = values.shape[axis]
        j = np.arange(count)
        transform = 2.0 / count * np.cos(np.pi * np.outer(j, j + 0.5) / count)
        transform[0] *= 0.5
        coefficients = np.moveaxis(np.tensordot(transform, coefficients, axes=(1, axis)), 0, axis)
    return coefficients


class SurrogateForwardModel(AbstractForwardModel):
    """Tensor-product Chebyshev interpolant of an :class:`AxisymForwardModel` over a box.

    ``log_lower``/``log_upper`` (4,): box in log of (P_g [Pa], E [Pa], h [m], R [m]) (equal
    bounds: that axis is held fixed); ``coefficients`` (n_P, n_E, n_h, n_R, k + 1): series of the
    depths [m] at ``force_grid`` (k,) [N] and of the wrinkle count [-]; ``wrinkle_law`` as in the
    engine model ("scaling" counts are computed exactly, not interpolated).
    """

    poisson_ratio: float
    force_grid: Float[Array, " k"]
    log_lower: Float[Array, " 4"]
    log_upper: Float[Array, " 4"]
    coefficients: Float[Array, "a b c d o"]
    wrinkle_law: str = eqx.field(static=True, default="mechanics")

    def __call__(self, gauge_pressure, young_modulus, thickness, radius, forces):
        z = jnp.log(jnp.stack([gauge_pressure, young_modulus, thickness, radius]))
        span = self.log_upper - self.log_lower
        fixed = span <= 0.0
        t = jnp.where(fixed, 0.0, (2.0 * z - self.log_lower - self.log_upper) / jnp.where(fixed, 1.0, span))
        inside = jnp.all(fixed | (jnp.abs(t) <= 1.0))
        out = self.coefficients
        for axis in range(4):
            out = jnp.tensordot(_chebyshev_basis(t[axis], out.shape[0]), out, axes=(0, 0))
        depth = jnp.interp(forces, self.force_grid, out[:-1])
        if self.wrinkle_law == "scaling":
            count = ScalingLawModel(self.poisson_ratio)(gauge_pressure, young_modulus, thickness, radius,
                                                        forces).wrinkle_count  # fmt: skip
        else:
            count = out[-1]
        return Prediction(depth=depth, wrinkle_count=count, converged=inside)


def node_axes(center: dict[str, float], half_width: dict[str, float], nodes=DEFAULT_NODES):
    """Log-space Chebyshev nodes per axis of (P_g, E, h, R) and the box (lower, upper) [-].

    ``center``: physical values (SI); ``half_width``: log-space half-widths (0 or missing: the
    axis is held at its centre, one node).
    """
    log_center = np.log([center[name] for name in SURROGATE_AXES])
    widths = np.array([half_width.get(name, 0.0) for name in SURROGATE_AXES])
    axes = [c + w * _chebyshev_nodes(n) if w > 0 else np.array([c]) for c, w, n in zip(log_center, widths, nodes)]
    return axes, log_center - widths, log_center + widths


def surrogate_from_values(values: np.ndarray, lower, upper, force_grid, poisson_ratio: float,
                          wrinkle_law: str = "mechanics") -> SurrogateForwardModel:  # fmt: skip
    """The interpolant of ``values`` (n_P, n_E, n_h, n_R, k + 1) given at the ``node_axes``."""
    return SurrogateForwardModel(
        poisson_ratio=poisson_ratio, force_grid=jnp.asarray(force_grid), log_lower=jnp.asarray(lower),
        log_upper=jnp.asarray(upper), coefficients=jnp.asarray(_values_to_coefficients(np.asarray(values))),
        wrinkle_law=wrinkle_law,
    )  # fmt: skip


def build_surrogate(model: AxisymForwardModel, center: dict[str, float], half_width: dict[str, float],
                    nodes: tuple[int, int, int, int] = DEFAULT_NODES, workers: int | None = None,
                    progress: bool | None = None) -> SurrogateForwardModel:  # fmt: skip
    """Solve ``model``'s engine on the Chebyshev nodes of a box and return the interpolant.

    ``center``/``half_width``: see :func:`node_axes`; ``workers``: host threads of the batched
    solves; ``progress``: None shows a bar (one step per radius node) on terminals only.
    Raises NoConvergenceError if the engine fails at a node (the box reaches parameters the
    engine cannot solve: narrow it, or sample the exact model).
    """
    from ..axisym import indentation_curves

    if not isinstance(model, AxisymForwardModel):
        raise InvalidInputError(
            f"a surrogate is built for the axisymmetric engine model, not {type(model).__name__}. "
            "Fix: sample that model directly (surrogate=False)"
        )
    axes, lower, upper = node_axes(center, half_width, nodes)
    counts = [len(a) for a in axes]
    grid = np.asarray(jnp.linspace(model.force_min, model.force_max, model.n_grid))
    values = np.empty(counts + [model.n_grid + 1])
    mesh = np.stack(np.meshgrid(*axes[:3], indexing="ij"), axis=-1).reshape(-1, 3)
    setup_fields = {f: getattr(model.setup, f) for f in model.setup.__dataclass_fields__ if f != "radius"}
    bar = tqdm(axes[3], desc=f"surrogate ({int(np.prod(counts))} curves)",
               disable=None if progress is None else not progress)
    for r_index, log_radius in enumerate(bar):
        similarity, physics = model.engine_frame(math.exp(log_radius))
        similarity = Similarity(scale=float(similarity.scale))
        shell = ShellProperties(gauge_pressure=np.exp(mesh[:, 0]), young_modulus=np.exp(mesh[:, 1]),
                                thickness=similarity.length_to_engine(np.exp(mesh[:, 2])), poisson_ratio=model.poisson_ratio)
        curves = indentation_curves(shell, similarity.force_to_engine(grid), radius=model.setup.radius, raise_on_failure=False,
                                    workers=workers, physics=physics, **setup_fields)  # fmt: skip
        converged = np.asarray(curves.converged).all(axis=1)
        if not converged.all():
            bad = np.exp(mesh[np.argmin(converged)])
            raise NoConvergenceError(
                f"surrogate: the engine did not converge at P_g = {bad[0]:.4g} Pa, E = {bad[1]:.4g} Pa, "
                f"h = {bad[2]:.4g} m, R = {math.exp(log_radius):.4g} m ({int((~converged).sum())} of "
                f"{converged.size} nodes). Fix: narrow the box or sample the exact model (surrogate=False)"
            )
        block = np.concatenate([similarity.length_from_engine(np.asarray(curves.w0)), np.asarray(curves.wrinkle_count)[:, -1:]], axis=1)
        values[:, :, :, r_index, :] = block.reshape(counts[0], counts[1], counts[2], -1)
    return surrogate_from_values(values, lower, upper, grid, model.poisson_ratio, model.wrinkle_law)


@jax.jit
def _evaluate(model: AbstractForwardModel, points, forces):
    # module-level, the model an argument: one compilation per model structure, not per session
    return jax.vmap(lambda q: model(q[0], q[1], q[2], q[3], forces))(points)


def surrogate_error(surrogate: SurrogateForwardModel, model: AxisymForwardModel, points: np.ndarray,
                    forces: np.ndarray) -> dict[str, float]:  # fmt: skip
    """Largest |surrogate − engine| over ``points`` (m, 4) of physical (P_g, E, h, R).

    Returns ``depth`` [m] (at ``forces`` [N]) and ``wrinkle_count`` [-]. The engine is evaluated
    through the engine model's own call (the fit's code path), vmapped over the points.
    """
    points, forces = jnp.asarray(points), jnp.asarray(forces)
    exact, approx = _evaluate(model, points, forces), _evaluate(surrogate, points, forces)
    if not bool(jnp.all(exact.converged)):
        raise NoConvergenceError("surrogate check: the engine failed at a check point inside the box")
    return {
        "depth": float(jnp.max(jnp.abs(exact.depth - approx.depth))),
        "wrinkle_count": float(jnp.max(jnp.abs(exact.wrinkle_count - approx.wrinkle_count))),
    }


__all__ = ["SurrogateForwardModel", "build_surrogate", "node_axes", "surrogate_error", "surrogate_from_values"]
