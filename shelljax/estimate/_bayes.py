"""Posterior of P_g and E by MCMC (emcee's affine-invariant ensemble) through a forward model.

The walkers move by emcee's stretch move, compiled as one loop per block of steps (``_ensemble``),
and the depth noise σ_w is sampled as an extra unknown. Sampling runs in blocks; after each, emcee
estimates the integrated autocorrelation time τ of every parameter, and sampling stops once the
chain is longer than ``autocorr_factor`` (50) τ and τ changed by less than ``tau_tolerance``
(5 %) since the last check (emcee's documentation uses 100 τ and 1 %; 50 τ already bounds the
Monte-Carlo error of τ to ~10 %), and never before ``min_steps`` (1000): on shorter chains τ
itself is underestimated. Otherwise a warning says the chain has not converged. The chain is kept
by an emcee backend, in memory or in an HDF5 file (emcee's HDFBackend layout, written a block at a
time) that a later call with the same file resumes. Forward solves that fail map to log p = −∞ and
are counted.

The sampler starts from a least-squares fit (:class:`FitResult`): its inverse problem, and, with
the surrogate, its optimum and Laplace covariance.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import warnings
from pathlib import Path

import emcee
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from .._errors import InvalidInputError
from .._placement import on_current_device
from ._ensemble import stretch_block
from ._fit import FitResult
from ._forward import AxisymForwardModel
from ..session import Session
from ._problem import ALL_NAMES, PaddedProblem, build_problem, padded_problem
from ._surrogate import (
    DEFAULT_NODES,
    SURROGATE_AXES,
    build_surrogate,
    engine_predictions,
    surrogate_error,
    surrogate_from_values,
)
from ._result import Estimate

_UNITS = {
    "gauge_pressure": "Pa",
    "young_modulus": "Pa",
    "thickness": "m",
    "radius": "m",
    "depth_offset": "m",
    "force_gain": "1",
    "depth_noise": "m",
}


class ConvergenceWarning(UserWarning):
    """An MCMC chain stopped before its autocorrelation-time criterion was met."""


class SurrogateWarning(UserWarning):
    """The surrogate of the forward model differs from it by more than SURROGATE_TOLERANCE."""


SURROGATE_SIGMAS = 6.0  # half-width of the surrogate box in Laplace standard deviations
SURROGATE_MIN_HALF_WIDTH = 0.03  # [-] in log space: never narrower than ±3 %
SURROGATE_CHECKS = 8  # engine solves that check the surrogate
SURROGATE_TOLERANCE = 0.2  # of σ_w (depth) and of one wrinkle (count)


@dataclasses.dataclass(frozen=True)
class PosteriorResult:
    """Result of :func:`sample_posterior`.

    ``estimates``: posterior median with std, 95 % interval (and ``ci68`` in ``intervals68``) of
    every unknown, in SI (gauge_pressure [Pa], young_modulus [Pa], depth_noise [m], nuisances);
    ``samples``: flat physical samples per name after burn-in and thinning; ``autocorr_time``
    τ [steps] per unknown; ``n_steps``; ``effective_samples`` = walkers · (steps − burn-in) / max τ;
    ``converged``; ``failed_forward``: walker proposals whose forward solve failed;
    ``acceptance_fraction``: mean over walkers; ``chain``: the raw chain (steps, walkers, dim);
    ``surrogate``: None when the model itself was sampled, else how the Chebyshev surrogate was
    built and its largest error against the engine (``depth_error`` [m] at the recorded forces,
    ``depth_error_in_noise`` [-] relative to σ_w, ``wrinkle_count_error`` [-], ``curves`` solved,
    ``box``: log-space half-widths [-]).
    """

    estimates: dict[str, Estimate]
    intervals68: dict[str, tuple[float, float]]
    samples: dict[str, np.ndarray]
    autocorr_time: dict[str, float]
    n_steps: int
    effective_samples: float
    converged: bool
    failed_forward: int
    acceptance_fraction: float
    chain: np.ndarray
    names: tuple[str, ...]
    surrogate: dict | None = None

    def to_dict(self) -> dict:
        """JSON-ready: ``estimates`` by name (each with its 68 % interval ``ci68``), convergence,
        steps, effective samples, autocorrelation times [steps], failed forward solves,
        acceptance fraction and the ``surrogate`` report (None when the model itself was sampled)."""
        return {
            "estimates": {
                name: {**est.to_dict(), "ci68": list(self.intervals68[name])} for name, est in self.estimates.items()
            },
            "converged": self.converged,
            "steps": self.n_steps,
            "effective_samples": self.effective_samples,
            "autocorr_time": {"value": self.autocorr_time, "unit": "steps"},
            "failed_forward_solves": self.failed_forward,
            "acceptance_fraction": self.acceptance_fraction,
            "surrogate": self.surrogate,
        }


@jax.jit
def _batched_physical(problem: PaddedProblem, u):
    return jax.vmap(problem.physical)(u)


def _physical(problem: PaddedProblem, columns: np.ndarray, u: np.ndarray) -> dict[str, np.ndarray]:
    """Physical values (SI) by name of every parameter of ``u`` (samples, unknowns), whose
    unknowns sit at ``columns`` of the padded u (the fixed ones at their measured values)."""
    padded_u = np.zeros((u.shape[0], len(ALL_NAMES)))
    padded_u[:, columns] = u
    return {name: np.asarray(value) for name, value in _batched_physical(problem, jnp.asarray(padded_u)).items()}


def _surrogate_around_fit(fit: FitResult, nodes, progress):
    """(surrogate model, report) of the fit's engine model, in a box around the fit."""
    problem, model = fit.problem, fit.problem.model
    u_std = np.sqrt(np.diag(fit.covariance))
    center = {k: float(v) for k, v in problem.physical(jnp.asarray(fit.u)).items()}
    half_width = {
        name: max(SURROGATE_SIGMAS * u_std[i], SURROGATE_MIN_HALF_WIDTH)
        for i, name in enumerate(problem.names)
        if name in SURROGATE_AXES
    }
    built = build_surrogate(model, center, half_width, nodes, progress=progress)
    # check points: Laplace draws, pulled into the box
    rng = np.random.default_rng(0)
    draws = rng.multivariate_normal(fit.u, fit.covariance, size=SURROGATE_CHECKS)
    padded, columns, _ = padded_problem(problem)
    phys = _physical(padded, columns, draws)
    points = np.stack([np.asarray(phys[name]) for name in SURROGATE_AXES], axis=1)
    points = np.exp(np.clip(np.log(points), np.asarray(built.log_lower), np.asarray(built.log_upper)))
    error = surrogate_error(built, model, points, np.asarray(problem.force))
    report = {
        "depth_error": {"value": error["depth"], "unit": "m"},
        "depth_error_in_noise": error["depth"] / problem.depth_noise,
        "wrinkle_count_error": error["wrinkle_count"],
        "check_points": SURROGATE_CHECKS,
        "fit_converged": fit.converged,
        "curves": int(np.prod(built.coefficients.shape[:4])),
        "box": {"half_width_log": half_width, "center": center},
    }
    if error["depth"] > SURROGATE_TOLERANCE * problem.depth_noise or error["wrinkle_count"] > SURROGATE_TOLERANCE:
        warnings.warn(
            f"{fit.source}: the surrogate differs from the engine by up to {error['depth'] * 1e3:.3g} mm in depth "
            f"({error['depth'] / problem.depth_noise:.2f} σ_w) and {error['wrinkle_count']:.2g} wrinkles; "
            "Fix: more surrogate_nodes, or surrogate=False",
            SurrogateWarning,
            stacklevel=3,
        )
    return built, report


def _open_backend(backend_path, source: Path, n_walkers: int, ndim: int):
    """emcee's backend: in memory (``backend_path`` None), else its HDF5 file, reset unless it
    holds a chain of this shape."""
    if backend_path is None:
        backend = emcee.backends.Backend()
        backend.reset(n_walkers, ndim)
        return backend
    backend = emcee.backends.HDFBackend(str(backend_path), name=f"shelljax-{source.stem}")
    if Path(backend_path).is_file() and backend.initialized and backend.iteration > 0:
        if backend.shape != (n_walkers, ndim):
            raise InvalidInputError(
                f"{backend_path}: holds a chain of shape {backend.shape}, this problem needs "
                f"{(n_walkers, ndim)}. Fix: use a new file or the same n_walkers and nuisance"
            )
    else:
        backend.reset(n_walkers, ndim)
    return backend


def _append(backend, chain: np.ndarray, log_prob: np.ndarray, accepted: np.ndarray, random_state) -> None:
    """A block of steps (steps, walkers, …) added to emcee's ``backend`` as that many of its
    ``save_step`` calls would add them (the HDF5 file is opened once, not at every step)."""
    start, steps = backend.iteration, chain.shape[0]
    backend.grow(steps, None)
    if isinstance(backend, emcee.backends.HDFBackend):
        with backend.open("a") as f:
            group = f[backend.name]
            group["chain"][start : start + steps] = chain
            group["log_prob"][start : start + steps] = log_prob
            group["accepted"][:] += accepted.sum(axis=0)
            for i, value in enumerate(random_state):
                group.attrs[f"random_state_{i}"] = value
            group.attrs["iteration"] = start + steps
    else:
        backend.chain[start : start + steps] = chain
        backend.log_prob[start : start + steps] = log_prob
        backend.accepted += accepted.sum(axis=0)
        backend.random_state = random_state
        backend.iteration = start + steps


@dataclasses.dataclass(frozen=True)
class ChainOptions:
    """When a chain stops: after ``max_steps``, or once it is ``min_steps`` long, longer than
    ``autocorr_factor`` τ, and τ moved by less than ``tau_tolerance`` (relative) since the last of
    the checks made every ``check_every`` steps."""

    max_steps: int = 20_000
    check_every: int = 250
    autocorr_factor: float = 50.0
    tau_tolerance: float = 0.05
    min_steps: int = 1000


class _Ensemble:
    """The walkers of a padded problem, stepped a block at a time into emcee's ``backend``.

    ``columns``: where the problem's unknowns and log σ_w sit in the padded (u, log σ_w); the
    backend holds those columns only. ``random``: the stream the blocks' seeds are drawn from,
    kept in the backend as emcee keeps its sampler's; ``length``: steps of the compiled block.
    """

    def __init__(
        self, problem: PaddedProblem, columns: np.ndarray, backend, random: np.random.RandomState, length: int
    ):
        self.problem, self.columns, self.backend, self.random, self.length = problem, columns, backend, random, length
        self.free = np.zeros(len(ALL_NAMES) + 1, bool)
        self.free[columns] = True
        self.failed_forward = 0

    def padded(self, coords: np.ndarray) -> np.ndarray:
        out = np.zeros((coords.shape[0], self.free.size))
        out[:, self.columns] = coords
        return out

    def log_prob(self, coords: np.ndarray) -> np.ndarray:
        """log p [-] of each walker of ``coords`` (walkers, unknowns + 1)."""
        # the sampling program itself, for no steps: no second program to compile
        return np.asarray(
            stretch_block(self.problem, self.padded(coords), 0, self.free, 0, self.length)["initial_log_prob"]
        )

    def run(self, coords: np.ndarray, steps: int) -> np.ndarray:
        """``steps`` (≤ ``length``) steps from ``coords`` into the backend; the last walkers."""
        seed = int(self.random.randint(2**31))
        out = stretch_block(self.problem, self.padded(coords), seed, self.free, steps, self.length)
        chain = np.asarray(out["chain"])[:steps][:, :, self.columns]
        log_prob, accepted = np.asarray(out["log_prob"])[:steps], np.asarray(out["accepted"])[:steps]
        _append(self.backend, chain, log_prob, accepted, self.random.get_state())
        self.failed_forward += int(out["failed_forward"])
        return chain[-1]


def _fresh_walkers(ensemble: _Ensemble, center: np.ndarray, n_walkers: int, rng, source: Path, model_name: str):
    """A small ball around ``center`` (unknowns and log σ_w), checked to have p > 0."""
    initial = center + 1e-3 * rng.standard_normal((n_walkers, center.size))
    if not np.all(np.isfinite(ensemble.log_prob(initial))):
        raise InvalidInputError(
            f"{source}: the posterior is zero at the closed-form start; the forward "
            f"model {model_name} fails there or the data are outside the priors"
        )
    return initial


def _run_until_converged(ensemble: _Ensemble, coords, chain: ChainOptions, source: Path, progress) -> tuple[bool, int]:
    """Sample in blocks until the autocorrelation criterion holds or ``max_steps``: (converged, steps)."""
    backend = ensemble.backend
    tau_old = np.full(backend.shape[1], np.inf)
    converged = False
    done = backend.iteration
    disable = None if progress is None else not progress
    with tqdm(total=chain.max_steps, initial=done, desc=f"bayes {source.stem}", disable=disable) as bar:
        while done < chain.max_steps:
            step = min(chain.check_every, chain.max_steps - done)
            coords = ensemble.run(coords, step)
            done = backend.iteration
            bar.update(step)
            tau = backend.get_autocorr_time(tol=0)
            converged = bool(
                done >= chain.min_steps
                and np.all(chain.autocorr_factor * tau < done)
                and np.all(np.abs(tau_old - tau) < chain.tau_tolerance * tau)
            )
            bar.set_postfix(tau=f"{np.max(tau):.0f}")
            if converged:
                break
            tau_old = tau
    if not converged:
        tau = backend.get_autocorr_time(tol=0)
        warnings.warn(
            f"{source}: MCMC stopped at {done} steps before convergence (max τ = {np.max(tau):.0f} steps "
            f"needs > {chain.autocorr_factor * np.max(tau):.0f} steps and τ stable within {chain.tau_tolerance:.0%}); "
            "treat the intervals as rough or raise max_steps",
            ConvergenceWarning,
            stacklevel=3,
        )
    return converged, done


def _summarise(
    ensemble: _Ensemble, names: tuple[str, ...], model_name: str, converged: bool, done: int, surrogate_info
) -> PosteriorResult:
    """The posterior's estimates after burn-in (2 max τ) and thinning (½ min τ)."""
    backend = ensemble.backend
    tau = backend.get_autocorr_time(tol=0)
    n_walkers = backend.shape[0]
    burn = int(min(2 * np.max(tau), done // 2))
    thin = max(1, int(0.5 * np.min(tau)))
    flat = backend.get_chain(discard=burn, thin=thin, flat=True)
    samples = {**_physical(ensemble.problem, ensemble.columns[:-1], flat[:, :-1]), "depth_noise": np.exp(flat[:, -1])}
    method = f"bayes: emcee ({n_walkers} walkers, {done} steps) through {model_name}, posterior median"
    estimates, intervals68 = {}, {}
    for name in names:
        x = samples[name]
        q = np.percentile(x, [2.5, 16, 50, 84, 97.5])
        estimates[name] = Estimate(
            float(q[2]), float(np.std(x, ddof=1)), (float(q[0]), float(q[4])), _UNITS[name], method
        )
        intervals68[name] = (float(q[1]), float(q[3]))
    return PosteriorResult(
        estimates=estimates,
        intervals68=intervals68,
        samples=samples,
        autocorr_time=dict(zip(names, map(float, tau))),
        n_steps=int(done),
        effective_samples=float(n_walkers * (done - burn) / np.max(tau)),
        converged=converged,
        failed_forward=ensemble.failed_forward,
        acceptance_fraction=float(np.mean(backend.accepted / done)),
        chain=backend.get_chain(),
        names=names,
        surrogate=surrogate_info,
    )


def sample_posterior(
    fit: FitResult,
    *,
    n_walkers: int = 32,
    max_steps: int = 20_000,
    check_every: int = 250,
    autocorr_factor: float = 50.0,
    tau_tolerance: float = 0.05,
    min_steps: int = 1000,
    backend_path: str | Path | None = None,
    seed: int = 0,
    progress: bool | None = None,
    surrogate: bool = True,
    surrogate_nodes: tuple[int, int, int, int] = DEFAULT_NODES,
) -> PosteriorResult:
    """Sample the posterior of the unknowns of ``fit``'s session, model and nuisances.

    ``fit``: :func:`fit_session`'s result (``raise_on_failure=False`` will do: the fit only
    supplies the inverse problem and places the surrogate). The chain starts at the closed form
    (u = 0), or at the fit when a surrogate is used, with σ_w from the fit's problem.

    ``backend_path``: HDF5 file for the chain; if it already holds a chain for this problem, it
    is resumed. ``progress``: None shows a bar on terminals only. Warns with
    :class:`ConvergenceWarning` when ``max_steps`` is reached before the τ criterion (module
    docstring) holds. ``surrogate`` (axisymmetric engine models only): sample
    through a Chebyshev surrogate of the engine (``surrogate_nodes`` per axis P_g, E, h, R) built
    in a box of ±``SURROGATE_SIGMAS`` Laplace standard deviations around the fit; its error
    against the engine is in ``PosteriorResult.surrogate``, and a :class:`SurrogateWarning` says
    when it exceeds ``SURROGATE_TOLERANCE`` of the depth noise. False samples the engine itself
    (slow: docs/fit-and-bayes.md).
    """
    chain = ChainOptions(max_steps, check_every, autocorr_factor, tau_tolerance, min_steps)
    problem, source = fit.problem, fit.source
    u_start = np.zeros(problem.ndim)
    surrogate_info = None
    if surrogate and isinstance(problem.model, AxisymForwardModel):
        built, surrogate_info = _surrogate_around_fit(fit, surrogate_nodes, progress)
        problem, u_start = eqx.tree_at(lambda q: q.model, problem, built), np.asarray(fit.u)
    ndim = problem.ndim + 1  # + log σ_w
    if n_walkers < 2 * ndim:
        raise InvalidInputError(f"n_walkers = {n_walkers} is too few for {ndim} unknowns. Fix: use at least {2 * ndim}")
    padded, columns, _ = padded_problem(problem)
    backend = _open_backend(backend_path, source, n_walkers, ndim)
    rng = np.random.default_rng(seed)
    model_name = type(problem.model).__name__
    if backend.iteration == 0:
        random = np.random.RandomState(int(rng.integers(2**31)))
        ensemble = _Ensemble(padded, np.append(columns, len(ALL_NAMES)), backend, random, chain.check_every)
        center = np.append(u_start, math.log(problem.depth_noise))
        initial = _fresh_walkers(ensemble, center, n_walkers, rng, source, model_name)
    else:
        random = np.random.RandomState()
        random.set_state(backend.random_state)
        ensemble = _Ensemble(padded, np.append(columns, len(ALL_NAMES)), backend, random, chain.check_every)
        initial = backend.get_last_sample().coords
    converged, done = _run_until_converged(ensemble, initial, chain, source, progress)
    return _summarise(ensemble, (*problem.names, "depth_noise"), model_name, converged, done, surrogate_info)


_COMPILED_AHEAD: set = set()


def compile_posterior_ahead(
    session: Session,
    model: AxisymForwardModel,
    *,
    n_walkers: int = 32,
    check_every: int = 250,
    nuisance: tuple[str, ...] = (),
    surrogate_nodes: tuple[int, int, int, int] = DEFAULT_NODES,
) -> threading.Thread | None:
    """Compile, on a background thread, the programs a surrogate posterior of ``session`` through
    ``model`` will run (the engine's curves and the sampler), while its fit compiles on this one.

    XLA compiles a program on one core; started before the fit, the two compile at once. The
    thread evaluates a placeholder surrogate's posterior and solves the engine at one point,
    which is what compiles them; the programs a structure needs are compiled once per process.
    None when there is nothing to compile ahead. Best effort: an error on the thread is dropped,
    since the same programs run, and raise, on the caller's thread.
    """
    if not isinstance(model, AxisymForwardModel) or session.wrinkle_counts is None:
        return None
    structure = (
        model.setup,
        model.wrinkle_law,
        model.n_grid,
        n_walkers,
        check_every,
        nuisance,
        surrogate_nodes,
        session.force.size,
        len(session.wrinkle_counts),
    )
    if structure in _COMPILED_AHEAD:
        return None
    _COMPILED_AHEAD.add(structure)

    def compile_programs():
        try:
            # the sampler first: it compiles in seconds, the engine's curves in tens of them
            start = np.array([[1e3, 1e6, session.thickness, session.radius]])
            log_center = np.log(start[0])
            placeholder = surrogate_from_values(
                np.zeros((*surrogate_nodes, model.n_grid + 1)),
                log_center - 1.0,
                log_center + 1.0,
                np.linspace(model.force_min, model.force_max, model.n_grid),
                model.poisson_ratio,
                model.wrinkle_law,
                surrogate_nodes,
            )
            problem = build_problem(session, placeholder, start_pressure=1e3, start_modulus=1e6, nuisance=nuisance)
            padded, columns, _ = padded_problem(problem)
            free = np.zeros(len(ALL_NAMES) + 1, bool)
            free[np.append(columns, len(ALL_NAMES))] = True
            stretch_block(padded, np.zeros((n_walkers, free.size)), 0, free, 0, check_every)
            engine_predictions(model, start, np.asarray(session.force), workers=1)
        except Exception:  # noqa: BLE001 (the caller's thread runs the same programs and raises)
            pass

    # compiled for the device the caller's stage runs on (jax.default_device is thread-local)
    thread = threading.Thread(target=on_current_device(compile_programs), name="shelljax-compile-ahead", daemon=True)
    thread.start()
    return thread
