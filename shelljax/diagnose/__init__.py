"""Sim-to-real gap diagnosis: where a study's data leave the shell model, which candidate effect
explains it, and how far the gap shrinks once it is added (docs/sim-to-real.md).

The steps are public for studies of the method itself: :func:`build_study` and
:func:`study_arrays` turn sessions into one joint problem (:class:`JointProblem`),
:func:`candidate_data` frees one candidate's parameters, :func:`fit_candidate` fits it and
:func:`loo_score` scores it out of sample. A calibrated measuring chain
(:class:`MeasurementPrior`, from ``shelljax.rig``) can be the baseline. The paper's real-ball case is in :func:`ks_scan`,
:func:`reconcile` and :func:`shape_sensitivity`.
"""

from ._diagnose import BASELINES, Diagnosis, candidate_data, diagnose
from ._effects import EFFECTS, GLOBAL_PARAMETERS, Effect
from ._loo import CandidateFit, LooScore, fit_candidate, loo_score, unit_log_jacobian
from ._measurement import MeasurementPrior
from ._model import JointProblem, StudyArrays, study_arrays
from ._paper_case import (
    KS_SCANS,
    PAPER_BALLS,
    PAPER_SHAPE_ERROR,
    SHAPE_VARIANTS,
    ks_scan,
    paper_calibration_sessions,
    reconcile,
    reconciliation_table,
    shape_sensitivity,
)
from ._study import Study, build_study
