"""Posterior of P_g and E by MCMC (emcee's affine-invariant ensemble) through a forward model.

The log posterior (priors and likelihoods: see ``_problem.py``) is jit-compiled and vmapped over
the walkers (emcee's ``vectorize=True``), and the depth noise σ_w is sampled as an extra unknown.
Sampling runs in chunks; after each, the integrated autocorrelation time τ of every parameter is
estimated and sampling stops once the chain is longer than ``autocorr_factor`` (50) τ and τ
changed by less than ``tau_tolerance`` (5 %) since the last check (emcee's documentation uses
100 τ and 1 %; 50 τ already bounds the Monte-Carlo error of τ to ~10 %), and never before
``min_steps`` (1000): on shorter chains τ itself is underestimated. Otherwise a warning says the
chain has not converged. Chains can live in an HDF5 file (emcee's HDFBackend layout, written 250
steps at a time) and a later call with the same file resumes them. Forward solves that fail map to log p = −∞ and are counted.

The sampler starts from a least-squares fit (:class:`FitResult`): its inverse problem, and, with
the surrogate, its optimum and Laplace covariance.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from pathlib import Path

import emcee
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from .._errors import InvalidInputError
from .._parallel import map_batch
from ._fit import FitResult
from ._forward import AxisymForwardModel
from ._problem import InverseProblem
from ._surrogate import DEFAULT_NODES, SURROGATE_AXES, build_surrogate, surrogate_error
from ._result import Estimate

_UNITS = {"gauge_pressure": "Pa", "young_modulus": "Pa", "thickness": "m", "radius": "m",
          "depth_offset": "m", "force_gain": "1", "depth_noise": "m"}  # fmt: skip


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
            "estimates": {name: {**est.to_dict(), "ci68": list(self.intervals68[name])}
                          for name, est in self.estimates.items()},
            "converged": self.converged, "steps": self.n_steps, "effective_samples": self.effective_samples,
            "autocorr_time": {"value": self.autocorr_time, "unit": "steps"},
            "failed_forward_solves": self.failed_forward, "acceptance_fraction": self.acceptance_fraction,
            "surrogate": self.surrogate,
        }  # fmt: skip


@jax.jit
def _batched_log_posterior(problem: InverseProblem, coords):
    return jax.vmap(problem.log_posterior)(coords)


@jax.jit
def _batched_physical(problem: InverseProblem, u):
    return jax.vmap(problem.physical)(u)


class LogPosterior:
    """emcee's vectorized log-probability: a jit(vmap) of the problem's log posterior.

    The compiled function is module-level and takes the problem as an argument, so a second
    session of the same shape reuses the compilation. For the engine model the walkers are split
    over the CPU cores (``shelljax._parallel``); cheap models (surrogate, scaling law) stay on one
    thread, where a thread pool would cost more than it saves.
    """

    def __init__(self, problem: InverseProblem):
        self.problem = problem
        self.failed_forward = 0
        self.evaluations = 0
        self.workers = None if isinstance(problem.model, AxisymForwardModel) else 1

    def __call__(self, coords: np.ndarray) -> np.ndarray:
        """log p [-] of each row of ``coords``: (walkers, unknowns + 1) scaled unknowns and log σ_w."""
        log_p, converged = map_batch(lambda c: _batched_log_posterior(self.problem, c), coords, self.workers)
        self.failed_forward += int(np.sum(~np.asarray(converged)))
        self.evaluations += coords.shape[0]
        return np.asarray(log_p)


def _physical_samples(problem: InverseProblem, flat: np.ndarray) -> dict[str, np.ndarray]:
    phys = _batched_physical(problem, jnp.asarray(flat[:, :-1]))
    out = {name: np.asarray(phys[name]) for name in problem.names}
    out["depth_noise"] = np.exp(flat[:, -1])
    return out


def _surrogate_around_fit(fit: FitResult, nodes, progress):
    """(surrogate model, report) of the fit's engine model, in a box around the fit."""
    problem, model = fit.problem, fit.problem.model
    u_std = np.sqrt(np.diag(fit.covariance))
    center = {k: float(v) for k, v in problem.physical(jnp.asarray(fit.u)).items()}
    half_width = {name: max(SURROGATE_SIGMAS * u_std[i], SURROGATE_MIN_HALF_WIDTH)
                  for i, name in enumerate(problem.names) if name in SURROGATE_AXES}  # fmt: skip
    built = build_surrogate(model, center, half_width, nodes, progress=progress)
    # check points: Laplace draws, pulled into the box
    rng = np.random.default_rng(0)
    draws = rng.multivariate_normal(fit.u, fit.covariance, size=SURROGATE_CHECKS)
    phys = _batched_physical(problem, jnp.asarray(draws))
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
    }  # fmt: skip
    if error["depth"] > SURROGATE_TOLERANCE * problem.depth_noise or error["wrinkle_count"] > SURROGATE_TOLERANCE:
        warnings.warn(
            f"{fit.source}: the surrogate differs from the engine by up to {error['depth'] * 1e3:.3g} mm in depth "
            f"({error['depth'] / problem.depth_noise:.2f} σ_w) and {error['wrinkle_count']:.2g} wrinkles; "
            "Fix: more surrogate_nodes, or surrogate=False",
            SurrogateWarning, stacklevel=3,
        )  # fmt: skip
    return built, report


class _BlockHDFBackend(emcee.backends.HDFBackend):
    """emcee's HDF5 chain file, written a block of ``block`` steps at a time: emcee's backend opens
    the file at every step, which costs more than the step itself. Whatever reads the file (τ
    checks, the summary, a resumed run) writes the pending steps first. The posterior has no blobs."""

    def __init__(self, *args, block: int = 250, **kwargs):
        super().__init__(*args, **kwargs)
        self._block, self._pending, self._random_state = block, [], None

    def save_step(self, state, accepted):
        self._pending.append((np.array(state.coords), np.array(state.log_prob), np.asarray(accepted, dtype=float)))
        self._random_state = state.random_state
        if len(self._pending) >= self._block:
            self.flush()

    def flush(self) -> None:
        """Write the pending steps, as emcee's ``save_step`` would one by one."""
        if not self._pending:
            return
        pending, self._pending = self._pending, []
        with self.open("a") as f:
            group = f[self.name]
            start = int(group.attrs["iteration"])
            stop = start + len(pending)
            group["chain"][start:stop] = np.stack([p[0] for p in pending])
            group["log_prob"][start:stop] = np.stack([p[1] for p in pending])
            group["accepted"][:] += np.sum([p[2] for p in pending], axis=0)
            for i, value in enumerate(self._random_state):
                group.attrs[f"random_state_{i}"] = value
            group.attrs["iteration"] = stop

    def grow(self, ngrow, blobs):
        self.flush()
        super().grow(ngrow, blobs)

    def get_value(self, name, flat=False, thin=1, discard=0):
        self.flush()
        return super().get_value(name, flat=flat, thin=thin, discard=discard)

    @property
    def iteration(self):
        self.flush()
        return super().iteration

    @property
    def accepted(self):
        self.flush()
        return super().accepted

    @property
    def random_state(self):
        self.flush()
        return super().random_state


def _open_backend(backend_path, source: Path, n_walkers: int, ndim: int):
    """emcee's HDF5 backend at ``backend_path`` (written in blocks), reset unless it holds a chain of this shape."""
    backend = _BlockHDFBackend(str(backend_path), name=f"shelljax-{source.stem}")
    if Path(backend_path).is_file() and backend.initialized and backend.iteration > 0:
        if backend.shape != (n_walkers, ndim):
            raise InvalidInputError(
                f"{backend_path}: holds a chain of shape {backend.shape}, this problem needs "
                f"{(n_walkers, ndim)}. Fix: use a new file or the same n_walkers and nuisance"
            )
    else:
        backend.reset(n_walkers, ndim)
    return backend


def _fresh_walkers(log_prob: LogPosterior, u_start: np.ndarray, n_walkers: int, rng, source: Path):
    """A small ball around ``u_start`` and the scatter-based σ_w, checked to have p > 0."""
    problem = log_prob.problem
    center = np.concatenate([u_start, [math.log(problem.depth_noise)]])
    initial = center + 1e-3 * rng.standard_normal((n_walkers, center.size))
    if not np.all(np.isfinite(log_prob(initial))):
        raise InvalidInputError(
            f"{source}: the posterior is zero at the closed-form start; the forward "
            f"model {type(problem.model).__name__} fails there or the data are outside the priors"
        )
    return initial


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


def _run_until_converged(sampler, state, chain: ChainOptions, source: Path, progress) -> tuple[bool, int]:
    """Sample in chunks until the autocorrelation criterion holds or ``max_steps``: (converged, steps)."""
    tau_old = np.full(sampler.ndim, np.inf)
    converged = False
    done = sampler.iteration
    disable = None if progress is None else not progress
    with tqdm(total=chain.max_steps, initial=done, desc=f"bayes {source.stem}", disable=disable) as bar:
        while done < chain.max_steps:
            step = min(chain.check_every, chain.max_steps - done)
            state = sampler.run_mcmc(state, step, progress=False)
            done = sampler.iteration
            bar.update(step)
            tau = sampler.get_autocorr_time(tol=0)
            converged = bool(done >= chain.min_steps and np.all(chain.autocorr_factor * tau < done)
                             and np.all(np.abs(tau_old - tau) < chain.tau_tolerance * tau))  # fmt: skip
            bar.set_postfix(tau=f"{np.max(tau):.0f}")
            if converged:
                break
            tau_old = tau
    if not converged:
        tau = sampler.get_autocorr_time(tol=0)
        warnings.warn(
            f"{source}: MCMC stopped at {done} steps before convergence (max τ = {np.max(tau):.0f} steps "
            f"needs > {chain.autocorr_factor * np.max(tau):.0f} steps and τ stable within {chain.tau_tolerance:.0%}); "
            "treat the intervals as rough or raise max_steps",
            ConvergenceWarning, stacklevel=3,
        )  # fmt: skip
    return converged, done


def _summarise(sampler, problem: InverseProblem, log_prob: LogPosterior, converged: bool, done: int,
               surrogate_info) -> PosteriorResult:  # fmt: skip
    """The posterior's estimates after burn-in (2 max τ) and thinning (½ min τ)."""
    tau = sampler.get_autocorr_time(tol=0)
    n_walkers = sampler.nwalkers
    burn = int(min(2 * np.max(tau), done // 2))
    thin = max(1, int(0.5 * np.min(tau)))
    flat = sampler.get_chain(discard=burn, thin=thin, flat=True)
    samples = _physical_samples(problem, flat)
    names = (*problem.names, "depth_noise")
    method = f"bayes: emcee ({n_walkers} walkers, {done} steps) through {type(problem.model).__name__}, posterior median"
    estimates, intervals68 = {}, {}
    for name in names:
        x = samples[name]
        q = np.percentile(x, [2.5, 16, 50, 84, 97.5])
        estimates[name] = Estimate(float(q[2]), float(np.std(x, ddof=1)), (float(q[0]), float(q[4])), _UNITS[name], method)
        intervals68[name] = (float(q[1]), float(q[3]))
    return PosteriorResult(
        estimates=estimates, intervals68=intervals68, samples=samples,
        autocorr_time=dict(zip(names, map(float, tau))), n_steps=int(done),
        effective_samples=float(n_walkers * (done - burn) / np.max(tau)), converged=converged,
        failed_forward=log_prob.failed_forward, acceptance_fraction=float(np.mean(sampler.acceptance_fraction)),
        chain=sampler.get_chain(), names=names, surrogate=surrogate_info,
    )  # fmt: skip


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
    log_prob = LogPosterior(problem)
    backend = None if backend_path is None else _open_backend(backend_path, source, n_walkers, ndim)
    rng = np.random.default_rng(seed)
    if backend is None or backend.iteration == 0:
        initial = _fresh_walkers(log_prob, u_start, n_walkers, rng, source)
    else:
        initial = backend.get_last_sample()
    sampler = emcee.EnsembleSampler(n_walkers, ndim, log_prob, vectorize=True, backend=backend)
    sampler.random_state = np.random.RandomState(int(rng.integers(2**31))).get_state()
    converged, done = _run_until_converged(sampler, initial, chain, source, progress)
    if backend is not None:
        backend.flush()
    return _summarise(sampler, problem, log_prob, converged, done, surrogate_info)
