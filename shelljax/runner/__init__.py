"""Run an experiment config into a fresh run directory (results.json + figures), and diagnose many studies.

``_run`` holds the run; ``_memory_mappings`` (keeping a long run under Linux's mapping limit) serves it
alone; ``_compile_log``'s :func:`stage` (what JAX compiled in a stage: the commands' ``--verbose`` log)
serves every command; ``_diagnoses`` runs ``shelljax diagnose`` over many studies, one work item per study.
"""

from ._compile_log import CompileLog, stage
from ._diagnoses import diagnose_studies, diagnoses_table, diagnosis_baseline, study_groups
from ._run import run_experiment, summary_table

__all__ = [
    "CompileLog",
    "diagnose_studies",
    "diagnoses_table",
    "diagnosis_baseline",
    "run_experiment",
    "stage",
    "study_groups",
    "summary_table",
]
