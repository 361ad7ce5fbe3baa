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


import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float
from tqdm.auto import tqdm

from .._errors import InvalidInputError, NoConvergenceError
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
            count = ScalingLawModel(self.poisson_ratio)(
                gauge_pressure, young_modulus, thickness, radius, forces
            ).wrinkle_count
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


def surrogate_from_values(
    values: np.ndarray,
    lower,
    upper,
    force_grid,
    poisson_ratio: float,
    wrinkle_law: str = "mechanics",
    nodes: tuple[int, ...] | None = None,
) -> SurrogateForwardModel:
    """The interpolant of ``values`` (n_P, n_E, n_h, n_R, k + 1) given at the ``node_axes``.

    ``nodes``: the series' lengths per axis (default: the values'); an axis held fixed (one
    node) gets zero coefficients beyond its first, the same interpolant, so that every box of
    ``nodes`` samples in one compiled program.
    """
    coefficients = _values_to_coefficients(np.asarray(values))
    if nodes is not None:
        coefficients = np.pad(coefficients, [(0, n - c) for n, c in zip(nodes, coefficients.shape)] + [(0, 0)])
    return SurrogateForwardModel(
        poisson_ratio=poisson_ratio,
        force_grid=jnp.asarray(force_grid),
        log_lower=jnp.asarray(lower),
        log_upper=jnp.asarray(upper),
        coefficients=jnp.asarray(coefficients),
        wrinkle_law=wrinkle_law,
    )


ROWS_PER_CALL = 128  # engine curves per compiled call: one program for every box, check and retry


@jax.jit
def _engine_inputs(model: AxisymForwardModel, points):
    return jax.vmap(model.engine_inputs)(points[:, 0], points[:, 1], points[:, 2], points[:, 3])


@jax.jit
def _predictions(model: AxisymForwardModel, depth, count, converged, points, forces):
    columns = (points[:, 0], points[:, 1], points[:, 2], points[:, 3])
    return jax.vmap(model.prediction, in_axes=(0, 0, 0, 0, 0, 0, 0, None))(depth, count, converged, *columns, forces)


def engine_predictions(model: AxisymForwardModel, points: np.ndarray, forces, workers: int | None = None) -> Prediction:
    """``model``'s predictions at ``points`` (m, 4) of physical (P_g [Pa], E [Pa], h [m], R [m]),
    at ``forces`` (k,) [N]: the model's own call for each point, its engine curves solved as one
    batch (``ROWS_PER_CALL`` curves a compiled call over ``workers`` host threads). Fields (m, …)."""
    from ..axisym import indentation_curves

    points = jnp.asarray(points, jnp.float64)
    shell, engine_forces, physics = _engine_inputs(model, points)
    setup_fields = {f: getattr(model.setup, f) for f in model.setup.__dataclass_fields__ if f != "radius"}
    curves = indentation_curves(
        shell,
        engine_forces,
        radius=model.setup.radius,
        raise_on_failure=False,
        workers=workers,
        physics=physics,
        rows_per_call=ROWS_PER_CALL,
        **setup_fields,
    )
    converged = np.all(curves.converged, axis=1)
    return _predictions(
        model, curves.w0, curves.wrinkle_count[:, -1], converged, points, jnp.asarray(forces, jnp.float64)
    )


def build_surrogate(
    model: AxisymForwardModel,
    center: dict[str, float],
    half_width: dict[str, float],
    nodes: tuple[int, int, int, int] = DEFAULT_NODES,
    workers: int | None = None,
    progress: bool | None = None,
) -> SurrogateForwardModel:
    """Solve ``model``'s engine on the Chebyshev nodes of a box and return the interpolant.

    ``center``/``half_width``: see :func:`node_axes`; ``workers``: host threads of the batched
    solves; ``progress``: None shows a bar (one step per radius node) on terminals only.
    Raises NoConvergenceError if the engine fails at a node (the box reaches parameters the
    engine cannot solve: narrow it, or sample the exact model).
    """
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
    bar = tqdm(
        axes[3], desc=f"surrogate ({int(np.prod(counts))} curves)", disable=None if progress is None else not progress
    )
    # one radius a batch: the engine's walk through a batch starts each curve from a neighbour's
    # equilibrium, which is closest at the same radius
    for r_index, log_radius in enumerate(bar):
        points = np.exp(np.column_stack([mesh, np.full(len(mesh), log_radius)]))
        pred = engine_predictions(model, points, grid, workers)
        converged = np.asarray(pred.converged)
        if not converged.all():
            bad = points[np.argmin(converged)]
            raise NoConvergenceError(
                f"surrogate: the engine did not converge at P_g = {bad[0]:.4g} Pa, E = {bad[1]:.4g} Pa, "
                f"h = {bad[2]:.4g} m, R = {bad[3]:.4g} m ({int((~converged).sum())} of "
                f"{converged.size} nodes). Fix: narrow the box or sample the exact model (surrogate=False)"
            )
        block = np.concatenate([np.asarray(pred.depth), np.asarray(pred.wrinkle_count)[:, None]], axis=1)
        values[:, :, :, r_index, :] = block.reshape(counts[0], counts[1], counts[2], -1)
    return surrogate_from_values(values, lower, upper, grid, model.poisson_ratio, model.wrinkle_law, nodes)


@jax.jit
def _evaluate(model: AbstractForwardModel, points, forces):
    # module-level, the model an argument: one compilation per model structure, not per session
    return jax.vmap(lambda q: model(q[0], q[1], q[2], q[3], forces))(points)


def surrogate_error(
    surrogate: SurrogateForwardModel, model: AxisymForwardModel, points: np.ndarray, forces: np.ndarray
) -> dict[str, float]:
    """Largest |surrogate − engine| over ``points`` (m, 4) of physical (P_g, E, h, R).

    Returns ``depth`` [m] (at ``forces`` [N]) and ``wrinkle_count`` [-]. The engine's side is
    :func:`engine_predictions`: the engine model's own mapping, its curves solved by the
    surrogate's own compiled program.
    """
    exact = engine_predictions(model, np.asarray(points), forces)
    approx = _evaluate(surrogate, jnp.asarray(points), jnp.asarray(forces))
    if not bool(jnp.all(exact.converged)):
        raise NoConvergenceError("surrogate check: the engine failed at a check point inside the box")
    return {
        "depth": float(jnp.max(jnp.abs(exact.depth - approx.depth))),
        "wrinkle_count": float(jnp.max(jnp.abs(exact.wrinkle_count - approx.wrinkle_count))),
    }


__all__ = [
    "SurrogateForwardModel",
    "build_surrogate",
    "engine_predictions",
    "node_axes",
    "surrogate_error",
    "surrogate_from_values",
]
