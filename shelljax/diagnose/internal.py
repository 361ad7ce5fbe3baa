"""What the diagnosis lends the measuring-chain calibration (``shelljax.rig``) and the runner: its
priors, its joint model's pieces, its noise model and its search over combinations of terms (with
its scoring and its pseudo-BMA+ averaging), shared so the rig fits, searches and weighs the very
models the diagnosis scores. Not for users: these names may change with the diagnosis; the public ones are in
``shelljax.diagnose``.
"""

from ._diagnose import WIN_NATS, WIN_SE
from ._effects import LINEAR_SCALE, MANOMETER_STD, MIN_INDENTER_FRACTION, PRIOR_STD, UNITS, check_effect_names
from ._loo import held_out_units, laplace_interval
from ._measurement import widened_grid, with_measurement
from ._search import ANY_GAIN, Margin, elpd_difference, forward_search, pseudo_bma_plus
from ._model import engine_inputs, log_prior, physical, predict, solve_curves, unit_log_likelihood
from ._study import DEPTH_NOISE_FLOOR, depth_whitening, force_level_of_samples, object_unknowns, trial_anova

__all__ = [
    "ANY_GAIN",
    "Margin",
    "elpd_difference",
    "forward_search",
    "pseudo_bma_plus",
    "DEPTH_NOISE_FLOOR",
    "LINEAR_SCALE",
    "MANOMETER_STD",
    "MIN_INDENTER_FRACTION",
    "PRIOR_STD",
    "UNITS",
    "WIN_NATS",
    "WIN_SE",
    "check_effect_names",
    "depth_whitening",
    "engine_inputs",
    "force_level_of_samples",
    "held_out_units",
    "laplace_interval",
    "log_prior",
    "object_unknowns",
    "physical",
    "predict",
    "solve_curves",
    "trial_anova",
    "unit_log_likelihood",
    "widened_grid",
    "with_measurement",
]
