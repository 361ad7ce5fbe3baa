"""Estimators of gauge pressure and Young's modulus from a measurement session."""

from ._closed_form import (
    CRITICAL_W,
    PAPER_KS,
    PAPER_KS_STD,
    WRINKLE_PREFACTOR,
    ClosedFormResult,
    KsCalibration,
    Regression,
    calibrate_ks,
    estimate_session,
    modulus_from_critical_depth,
    modulus_from_wrinkles,
    pressure_slope,
    regress_force_on_depth,
    tau,
)
from ._bayes import ConvergenceWarning, PosteriorResult, SurrogateWarning, sample_posterior
from ._fit import FitResult, fit_session
from ._forward import AbstractForwardModel, AxisymForwardModel, Prediction, ScalingLawModel, forward_model_for
from ._result import Estimate
from ._surrogate import SurrogateForwardModel, build_surrogate, surrogate_error
