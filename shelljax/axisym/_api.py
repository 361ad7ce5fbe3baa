"""The one function the fitted estimator calls: batched F → w(0) curves and wrinkle counts."""

from __future__ import annotations


import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._errors import InvalidInputError, NoConvergenceError
from ._hilbert import hilbert_order
from .._parallel import cpu_workers, map_batch
from .._programs import persistent_jit
from ..paper import PAPER_FORCES
from ..physics import ShellProperties
from ._model import CurvePhysics, Setup, _shell, curve_single
from ._observables import wrinkle_count


class CurveResult(eqx.Module):
    """Batched indentation curves; every field has shape (batch, n_forces) unless noted.

    ``force`` [N]; ``w0`` [m] local dimple depth (positive, the paper's −w(0), see
    docs/axisym.md); ``travel`` [m] indenter travel since first contact; ``top_drop`` [m]
    drop of the top pole (the 3D engine's w0); ``height`` H [m];
    ``upper_diameter`` D_u [m]; ``contact_diameter`` D_l [m] (from the ground reaction, see ``_observables``);
    ``contact_diameter_mesh`` [m] geometric edge; ``sunken_depth`` d [m];
    ``pressure`` [Pa] gauge pressure; ``volume`` [m³]; ``ground_reaction`` [N] (F plus the wall's
    weight with a self-weight, ``CurvePhysics.areal_weight``);
    ``min_hoop_tension`` [N/m] most compressive unrelaxed hoop stress resultant of the upper
    half; ``compressive_inner_radius``/``compressive_outer_radius`` [m] of the compressive
    annulus; ``wrinkle_count`` n [-] (continuous model, ``wrinkle_count``); ``wall_gap`` [m] top pole
    height above the bottom pole; ``residual`` [N] worst Newton residual up to this level;
    ``iterations`` [-] Newton iterations of this level's load steps;
    ``converged`` (bool): Newton met ``atol`` up to this level and the walls have not met
    (``wall_gap`` > h: self-contact is not modelled); ``rest_radius`` [m] (batch,).
    """

    force: Float[Array, "b k"]
    w0: Float[Array, "b k"]
    travel: Float[Array, "b k"]
    top_drop: Float[Array, "b k"]
    height: Float[Array, "b k"]
    upper_diameter: Float[Array, "b k"]
    contact_diameter: Float[Array, "b k"]
    contact_diameter_mesh: Float[Array, "b k"]
    sunken_depth: Float[Array, "b k"]
    pressure: Float[Array, "b k"]
    volume: Float[Array, "b k"]
    ground_reaction: Float[Array, "b k"]
    min_hoop_tension: Float[Array, "b k"]
    compressive_inner_radius: Float[Array, "b k"]
    compressive_outer_radius: Float[Array, "b k"]
    wrinkle_count: Float[Array, "b k"]
    wall_gap: Float[Array, "b k"]
    residual: Float[Array, "b k"]
    iterations: Int[Array, "b k"]
    converged: Bool[Array, "b k"]
    rest_radius: Float[Array, " b"]


def _one(setup: Setup, theta, forces, physics: CurvePhysics, nearby_guesses=None):
    """(CurveResult fields, (equilibrium states (1 + k, n_y) [m]: inflated, then each level;
    inflation residual [N])) of one parameter set and its (scalar) physics."""
    young, thick, nu = theta[1], theta[2], theta[3]
    properties = ShellProperties(gauge_pressure=theta[0], young_modulus=young, thickness=thick, poisson_ratio=nu)
    out = curve_single(setup, properties, forces, return_states=True, nearby_guesses=nearby_guesses, physics=physics)
    n = wrinkle_count(out["compressive_inner_radius"], out["compressive_outer_radius"], setup.radius, young, thick, nu)
    fields = {key: out[key] for key in CurveResult.__annotations__ if key in out}
    fields.update(
        force=forces,
        wrinkle_count=n,
        converged=jnp.isfinite(out["residual"]) & (out["residual"] <= setup.atol) & (out["wall_gap"] > thick),
    )
    return fields, (out["state"], out["inflation_residual"])


def _walk_coordinates(params: Float[Array, "b 4"]) -> Float[Array, "b 4"]:
    """(log P_g, log E, log h, ν) [-]: coordinates in which equal steps change a curve about
    equally, for the Hilbert walk and the slopes learnt along it; ν last (often held fixed)."""
    return jnp.column_stack([jnp.log(params[:, :3]), params[:, 3]])


def _curves(params, forces, physics: CurvePhysics, cold, *, setup: Setup, chunk: int):
    b = params.shape[0]
    if b == 1:  # one curve: its Newton loops need no batching, which costs tracing and compiling
        one = _one(setup, params[0], forces[0], jax.tree_util.tree_map(lambda v: v[0], physics))[0]
        return jax.tree_util.tree_map(lambda v: v[None], one)
    if chunk <= 0 or b <= chunk:
        return jax.vmap(lambda th, f, ph: _one(setup, th, f, ph))(params, forces, physics)[0]
    # `chunk` lanes, vmapped, each walking its own stretch of the batch's Hilbert ordering, one
    # curve after the other (lax.scan): the inflation and every level of a curve start from the
    # lowest-energy of the usual start, the lane's last converged state there and that state
    # extrapolated to the new parameters (``curve_single``'s nearby_guesses). A vmapped
    # while_loop runs until its slowest member converges: few lanes waste little. The physics
    # rows and force rows travel with their parameter rows but stay out of the walk's
    # coordinates: a guess from a neighbour with other physics or forces is only a worse guess
    # (the lowest energy one wins). ``cold`` (traced, so the same program) drops every guess:
    # each curve starts from the usual start, for curves a neighbour's guess led astray.
    coords = jax.lax.stop_gradient(_walk_coordinates(params))  # they only order and guess
    order = hilbert_order(coords)
    steps = -(-b // chunk)

    def lanes(v):
        # (b, …) → (steps, chunk, …) in walk order, the last lane padded with the walk's last row
        walked = v[order]
        walked = jnp.concatenate([walked, jnp.broadcast_to(walked[-1:], (chunk * steps - b,) + v.shape[1:])])
        return walked.reshape((chunk, steps) + v.shape[1:]).swapaxes(0, 1)

    def solve_step(walk, step_in):
        # walk: per lane and solve (the inflation, then the k levels) the last converged state
        # (1 + k, n_y) [m], its coordinates (1 + k, 4) and the slope d state / d coordinates
        # (1 + k, n_y, 4) [m] learnt along the way (Broyden's update: the secant condition
        # along each step, the slope unchanged across it). The unextrapolated state stays a
        # guess, for the levels where the extrapolation lands far off.
        states, anchors, slopes = walk
        thetas, here, force_rows, physics_rows = step_in
        delta = here[:, None, :] - anchors
        predicted = states + jnp.einsum("lkyc,lkc->lky", slopes, delta)
        guesses = jnp.where(cold, jnp.nan, jnp.stack([states, predicted], axis=2))
        fields, (solved, inflation_residual) = jax.vmap(lambda theta, f, ph, nearby: _one(setup, theta, f, ph, nearby))(
            thetas, force_rows, physics_rows, guesses
        )
        solved = jax.lax.stop_gradient(solved)  # the walk only guesses: no derivative through it
        inflated = (inflation_residual <= setup.atol)[:, None]
        good = jnp.concatenate([inflated, fields["converged"]], axis=1)[..., None]
        sq = jnp.sum(delta**2, axis=-1, keepdims=True)
        learn = good & (sq > 0.0) & jnp.all(jnp.isfinite(predicted), axis=-1, keepdims=True)
        update = (solved - predicted)[..., None] * (delta / jnp.where(sq > 0.0, sq, 1.0))[:, :, None, :]
        slopes = jnp.where(learn[..., None], slopes + update, slopes)
        states = jnp.where(good, solved, states)
        anchors = jnp.where(good, here[:, None, :], anchors)
        return (states, anchors, slopes), fields

    n_levels, n_unknowns = 1 + forces.shape[1], 2 * len(setup.theta()) + 1
    start = (
        jnp.full((chunk, n_levels, n_unknowns), jnp.nan),
        jnp.zeros((chunk, n_levels, 4)),
        jnp.zeros((chunk, n_levels, n_unknowns, 4)),
    )
    walked_physics = jax.tree_util.tree_map(lanes, physics)
    _, out = jax.lax.scan(solve_step, start, (lanes(params), lanes(coords), lanes(forces), walked_physics))
    unwalk = jnp.zeros(b, order.dtype).at[order].set(jnp.arange(b, dtype=order.dtype))
    return jax.tree_util.tree_map(lambda v: v.swapaxes(0, 1).reshape((chunk * steps,) + v.shape[2:])[unwalk], out)


_batched = jax.jit(_curves, static_argnames=("setup", "chunk"))
# the checked API's calls, made outside any trace: their traced programs are kept across processes
_batched_kept = persistent_jit(_curves)


def _rows(properties: ShellProperties) -> Float[Array, "b 4"]:
    """(batch, 4) columns P_g [Pa], E [Pa], h [m], ν [-]: the compiled program's parameter rows."""
    fields = (properties.gauge_pressure, properties.young_modulus, properties.thickness, properties.poisson_ratio)
    columns = jnp.broadcast_arrays(*(jnp.asarray(v, jnp.float64) for v in fields))
    return jnp.atleast_2d(jnp.stack(columns, axis=-1))


def indentation_curves_raw(
    properties: ShellProperties, forces, setup: Setup, chunk: int = 0, physics: CurvePhysics | None = None, cold=False
) -> CurveResult:
    """Traceable batched curves (no input checks, no raising): jit/vmap/grad friendly.

    ``properties``: :class:`shelljax.physics.ShellProperties` whose P_g [Pa], E [Pa], h [m], ν [-]
    have shape (batch,) (scalars: one curve; its radius, if set, is ``setup.radius``); ``forces``
    (k,) [N], or (batch, k): each curve's own. ``physics``: per-curve traced effects (:class:`CurvePhysics`, fields () or (batch,);
    None: the default physics, the Setup's); with or without it the same program runs, and curves
    are differentiable in its values as in ``properties``.
    ``chunk`` > 0 solves a batch larger than ``chunk`` in that many vmapped lanes, each walking
    a stretch of the batch ordered along a Hilbert curve and starting every curve from its
    predecessor's equilibria (fewer Newton iterations on dense batches, docs/axisym.md); 0 vmaps
    the whole batch at once, every curve from scratch. The results agree to the Newton tolerance
    either way; ``cold`` (a traced flag, the same program) starts every walked curve from the
    usual start instead. Differentiable in ``properties`` (implicit differentiation of every
    equilibrium).
    """
    return _curve_result(properties, forces, setup, chunk, physics, cold, _batched)


def _curve_result(properties, forces, setup, chunk, physics, cold, program) -> CurveResult:
    _shell(properties, setup, "indentation_curves_raw")  # a ShellProperties, of the Setup's radius if it has one
    params = _rows(properties)
    physics = (CurvePhysics() if physics is None else physics).resolved(setup, params.shape[0])
    # a batch that fits in one chunk is solved unwalked: one program whatever the chunk it asked for
    chunk = int(chunk) if params.shape[0] > int(chunk) > 0 else 0
    forces = jnp.asarray(forces, jnp.float64)
    forces = jnp.broadcast_to(forces, (params.shape[0], forces.shape[-1]))
    return CurveResult(**program(params, forces, physics, jnp.asarray(cold), setup=setup, chunk=chunk))


_FIELDS = ("gauge_pressure", "young_modulus", "thickness", "poisson_ratio")


def _check(properties, forces, radius):
    """((batch, 4) rows P_g, E, h, ν, forces [N], radius [m]) of the checked input."""
    if not isinstance(properties, ShellProperties):
        raise InvalidInputError(
            f"indentation_curves: expected a physics.ShellProperties, got {type(properties).__name__}. "
            "Fix: ShellProperties(gauge_pressure=…, young_modulus=…, thickness=…, poisson_ratio=…), "
            "fields () or (batch,)"
        )
    try:
        columns = np.broadcast_arrays(*(np.asarray(getattr(properties, k), float) for k in _FIELDS))
        p = np.atleast_2d(np.stack(columns, -1))
    except ValueError:
        p = None
    if p is None or p.ndim != 2:
        shapes = {k: np.shape(getattr(properties, k)) for k in _FIELDS}
        raise InvalidInputError(
            f"indentation_curves: the properties' fields have shapes {shapes}; expected () or (batch,)."
        )
    for j, name in enumerate(_FIELDS[:3]):
        if not np.all(np.isfinite(p[:, j])) or np.any(p[:, j] <= 0):
            raise InvalidInputError(
                f"indentation_curves: properties.{name} must be finite and > 0; got "
                f"{p[:, j][~(np.isfinite(p[:, j]) & (p[:, j] > 0))][:3]}."
            )
    if np.any(p[:, 3] <= -1.0) or np.any(p[:, 3] >= 0.5):
        raise InvalidInputError("indentation_curves: properties.poisson_ratio must lie in (-1, 0.5).")
    own = None if properties.radius is None else np.unique(np.asarray(properties.radius, float))
    if own is not None and (own.size != 1 or (radius is not None and own[0] != float(radius))):
        raise InvalidInputError(
            f"indentation_curves: properties.radius {own[:3]} m and radius = {radius!r} m disagree (one radius "
            "per batch: the engine's mesh is static). Fix: give the radius once, the same for every curve"
        )
    radius = radius if own is None else float(own[0])
    if radius is None:
        raise InvalidInputError("indentation_curves: no radius. Fix: set properties.radius or pass radius= [m]")
    f = np.asarray(forces, dtype=float)
    if (
        f.ndim not in (1, 2)
        or f.size == 0
        or f.ndim == 2
        and f.shape[0] != p.shape[0]
        or np.any(f <= 0)
        or np.any(np.diff(f, axis=-1) <= 0)
    ):
        raise InvalidInputError(
            f"indentation_curves: forces must be an increasing array of positive values [N], (k,) or one row "
            f"per curve ({p.shape[0]}, k); got {forces!r}."
        )
    if not (np.isfinite(radius) and radius > 0):
        raise InvalidInputError(f"indentation_curves: radius must be > 0 [m]; got {radius!r}.")
    if np.any(p[:, 2] >= 0.2 * radius):
        raise InvalidInputError("indentation_curves: thickness h must be < 0.2 R (thin shell).")
    return p, f, radius


# (lowest allowed value, whether it is excluded) of each CurvePhysics field
_PHYSICS_BOUNDS = {
    "indenter_radius": (0.0, True),
    "gas_volume_ratio": (0.0, True),
    "gas_exponent": (0.0, False),
    "stiffening": (-np.inf, False),
    "areal_weight": (0.0, False),
    "friction_coefficient": (0.0, False),
    "contact_stiffness": (0.0, True),
}


def _check_physics(physics: CurvePhysics, batch: int, setup: Setup) -> np.ndarray:
    """``physics`` as (batch, len(_PHYSICS_BOUNDS)) columns in field order, or InvalidInputError naming the field."""
    columns = []
    for name, (low, strict) in _PHYSICS_BOUNDS.items():
        value = getattr(physics, name)
        v = np.asarray(getattr(setup, name) if value is None else value, dtype=float)
        if v.shape not in ((), (batch,)):
            raise InvalidInputError(
                f"indentation_curves: physics.{name} has shape {v.shape}; expected () or ({batch},) "
                "(one value per row of params)."
            )
        bad = ~np.isfinite(v) | ((v <= low) if strict else (v < low))
        if np.any(bad):
            raise InvalidInputError(
                f"indentation_curves: physics.{name} must be finite and {'>' if strict else '>='} {low}; got "
                f"{np.atleast_1d(v)[np.atleast_1d(bad)][:3]}. Fix: see CurvePhysics for its meaning and units."
            )
        columns.append(np.broadcast_to(v, (batch,)))
    return np.stack(columns, axis=1)


def _retry_from_cold_starts(res: CurveResult, rows, solve, workers, rows_per_call) -> CurveResult:
    """The curves a walked batch lost, solved again each from its own cold start (the same
    program, slices of ``rows_per_call`` rows): a neighbour's equilibrium can lead Newton astray
    where the cold start converges."""
    failed = np.flatnonzero(~np.asarray(res.converged).all(axis=1))
    if failed.size == 0:
        return res
    again = map_batch(solve, rows[failed], workers, rows_per_call)

    def retried(whole, part):
        whole = np.array(whole)
        whole[failed] = part
        return whole

    return jax.tree_util.tree_map(retried, res, again)


def indentation_curves(
    properties: ShellProperties,
    forces=PAPER_FORCES,
    *,
    radius: float | None = None,
    raise_on_failure: bool = True,
    chunk: int = 8,
    workers: int | None = None,
    physics: CurvePhysics | None = None,
    rows_per_call: int | None = None,
    **setup_kwargs,
) -> CurveResult:
    """Force-controlled F → w(0) curves of inflated balls, batched over parameter sets.

    ``properties``: :class:`shelljax.physics.ShellProperties` of fields () or (batch,): P_g [Pa],
    E [Pa], h [m], ν [-], and the inflated radius R [m] (one for the batch) unless ``radius`` [m]
    gives it; ``forces`` [N]: increasing positive forces (default: the paper's 5–20 N in 2.5 N
    steps), (k,) or each curve's own (batch, k). Further keywords go to :class:`Setup` (``n_elements``,
    ``grading``, ``gas`` (a ``physics.AbstractGasLaw``), ``relax``, ``indenter_radius`` [m],
    ``contact_stiffness`` [N/m³], ``atol`` [N], ...). ``physics``: per-curve effects
    (:class:`CurvePhysics`, fields () or (batch,); None: the Setup's defaults).

    Raises :class:`shelljax.NoConvergenceError` if any batch element failed and
    ``raise_on_failure`` (otherwise inspect ``result.converged``). ``chunk``: vmapped lanes
    per host thread, each solving its share of the batch curve after curve from the previous
    curve's equilibria (:func:`indentation_curves_raw`; docs/axisym.md, *Benchmark*). ``workers``:
    host threads the batch is split over (default: every CPU core on the CPU backend, 1 on a
    GPU; see :func:`map_batch`); ``rows_per_call``: curves per compiled call (default: the batch
    split evenly over the workers; fixed, one program serves batches of every size). For use
    inside jit/vmap/grad call :func:`indentation_curves_raw`.
    """
    p, f, radius = _check(properties, forces, radius)
    setup = Setup(radius=float(radius), **setup_kwargs)  # raises InvalidInputError on a bad field
    columns = _check_physics((CurvePhysics() if physics is None else physics).resolved(setup), p.shape[0], setup)

    physics_end = 4 + len(_PHYSICS_BOUNDS)

    def solve(rows, cold=False):
        # the physics and force columns travel with their params through map_batch's split
        shell = ShellProperties(**{name: rows[:, j] for j, name in enumerate(_FIELDS)})
        physics_rows = CurvePhysics(**{name: rows[:, 4 + j] for j, name in enumerate(_PHYSICS_BOUNDS)})
        return _curve_result(shell, rows[:, physics_end:], setup, chunk, physics_rows, cold, _batched_kept)

    rows = np.concatenate([p, columns, np.broadcast_to(f, (p.shape[0], f.shape[-1]))], axis=1)
    workers = cpu_workers() if workers is None else workers
    per_call = -(-rows.shape[0] // max(min(workers, rows.shape[0]), 1)) if rows_per_call is None else rows_per_call
    res = map_batch(solve, rows, workers, per_call)
    if chunk > 0:
        res = _retry_from_cold_starts(res, rows, lambda r: solve(r, True), workers, per_call)
    if raise_on_failure:
        conv = np.asarray(res.converged)
        if not conv.all():
            bad = np.argwhere(~conv)
            b, k = bad[0]
            if float(res.wall_gap[b, k]) <= p[b, 2]:
                raise NoConvergenceError(
                    f"axisymmetric curve: at force {float(res.force[b, k])} N the indenter pushed the top wall onto the "
                    f"bottom wall of curve {b} (P_g, E, h, ν) = {p[b].tolist()} "
                    f"(top pole {float(res.wall_gap[b, k]):.3g} m "
                    "above the bottom pole, thickness h larger); self-contact is not modelled, so this "
                    f"and larger forces have no ball state ({len(bad)} (batch, force) entries failed). "
                    "Fix: use smaller forces, or pass raise_on_failure=False and drop the unconverged levels.",
                    history=np.asarray(res.residual[b]).tolist(),
                )
            raise NoConvergenceError(
                f"axisymmetric Newton did not converge for {len(bad)} (batch, force) entries; "
                f"first: curve {b} (P_g, E, h, ν) = {p[b].tolist()}, force {float(res.force[b, k])} N. Try more elements "
                "(n_elements), a larger max_steps, or a different ramp.",
                history=np.asarray(res.residual[b]).tolist(),
            )
    return res
