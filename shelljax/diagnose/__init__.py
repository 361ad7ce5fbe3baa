"""Sim-to-real gap diagnosis: where a study's data leave the shell model, which candidate effect
explains it, and how far the gap shrinks once it is added (docs/sim-to-real.md)."""

from ._diagnose import BASELINES, Diagnosis, diagnose
from ._effects import EFFECTS, Effect
from ._study import Study, build_study
