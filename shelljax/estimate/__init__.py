"""Estimators of gauge pressure and Young's modulus from a measurement session.

Each estimator returns a result with ``estimates`` (name → :class:`Estimate`) and ``to_dict()``;
:func:`run_estimator` runs any of them by name.
"""

from ._bayes import ConvergenceWarning, PosteriorResult, SurrogateWarning, compile_posterior_ahead, sample_posterior
from ._closed_form import (
    ClosedFormResult,
    KsCalibration,
    Regression,
    calibrate_ks,
    estimate_session,
    modulus_from_critical_depth,
    modulus_from_wrinkles,
    paper_k_s,
    pressure_slope,
    regress_force_on_depth,
)
from ._dispatch import DEFAULT_OPTIONS, METHODS, EstimatorOptions, EstimatorResult, options_forward_model, run_estimator
from ._fit import FitResult, fit_session, solve_least_squares
from ._forward import AbstractForwardModel, AxisymForwardModel, Prediction, ScalingLawModel, forward_model_for
from ._problem import (
    FAILED_RESIDUAL,
    InverseProblem,
    PaddedProblem,
    build_problem,
    count_log_likelihood,
    depth_noise_from_scatter,
    padded_problem,
)
from ._result import Estimate
from ._surrogate import SurrogateForwardModel, build_surrogate, surrogate_error
