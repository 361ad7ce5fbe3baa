"""One entry point for every estimator, shared by ``shelljax estimate`` and ``shelljax run``."""

from __future__ import annotations

from pathlib import Path

from .._errors import InvalidInputError
from .._options import DEFAULT_OPTIONS, METHODS, EstimatorOptions  # noqa: F401 - re-exported
from ..physics import gas_law
from ..session import Session
from ._bayes import PosteriorResult, compile_posterior_ahead, sample_posterior
from ._closed_form import ClosedFormResult, estimate_session
from ._fit import FitResult, fit_session
from ._forward import AbstractForwardModel, forward_model_for

EstimatorResult = ClosedFormResult | FitResult | PosteriorResult


def options_forward_model(session: Session, options: EstimatorOptions) -> AbstractForwardModel:
    """The forward model ``options`` name, set up for ``session``."""
    engine = (
        {"gas": gas_law(options.gas), "wrinkle_law": options.wrinkle_law} if options.forward_model == "axisym" else {}
    )
    return forward_model_for(session, options.forward_model, **engine)


def run_estimator(
    method: str,
    session: Session,
    options: EstimatorOptions = EstimatorOptions(),
    *,
    model: AbstractForwardModel | None = None,
    fit: FitResult | None = None,
    backend_path: str | Path | None = None,
    progress: bool | None = None,
) -> EstimatorResult:
    """Run ``method`` ("closed-form", "fit" or "bayes") on ``session`` with ``options``.

    fit and bayes run through ``model`` (None: :func:`options_forward_model`). bayes starts from
    ``fit`` when given (a fit of the same session, model and options), otherwise from a fit of its
    own that may stop short of convergence; ``backend_path`` is its HDF5 chain file.
    Every result has ``estimates`` (name → :class:`Estimate`) and ``to_dict()``.
    """
    if method == "closed-form":
        return estimate_session(
            session,
            k_s=options.k_s,
            through_origin=options.through_origin,
            bootstrap_samples=options.bootstrap_samples,
            seed=options.seed,
        )
    if method not in METHODS:
        raise InvalidInputError(f"unknown estimator {method!r}. Fix: use one of {', '.join(METHODS)}")
    if method == "fit" or fit is None:
        model = options_forward_model(session, options) if model is None else model
        if method == "fit":
            return fit_session(session, model, nuisance=options.nuisance)
        if options.surrogate:
            compile_posterior_ahead(session, model, n_walkers=options.walkers, nuisance=options.nuisance)
        fit = fit_session(session, model, nuisance=options.nuisance, raise_on_failure=False)
    return sample_posterior(
        fit,
        n_walkers=options.walkers,
        max_steps=options.max_steps,
        backend_path=backend_path,
        seed=options.seed,
        surrogate=options.surrogate,
        progress=progress,
    )
