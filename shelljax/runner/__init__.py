"""Run an experiment config into a fresh run directory (results.json + figures), and diagnose many studies.

``_run`` holds the run; ``_compile_log`` (what JAX compiled in each stage) and
``_memory_mappings`` (keeping a long run under Linux's mapping limit) serve it alone;
``_diagnoses`` runs ``shelljax diagnose`` over many studies, one work item per study.
"""

from ._diagnoses import diagnose_studies, diagnoses_table, diagnosis_baseline, study_groups
from ._run import run_experiment, summary_table

__all__ = [
    "diagnose_studies",
    "diagnoses_table",
    "diagnosis_baseline",
    "run_experiment",
    "study_groups",
    "summary_table",
]
