"""Experiment configs: which sessions, which estimators, which outputs (TOML, validated).

Paths in a config are relative to the config file, or start with ``bundled:`` to name files
shipped inside the package (``bundled:sessions/pezzi.toml``); both may contain glob patterns.
See docs/configs.md for the format.
"""

from __future__ import annotations

import dataclasses
import glob
from importlib import resources
from pathlib import Path

from ._options import (
    DEFAULT_OPTIONS,
    ESTIMATOR_GASES,
    FORWARD_MODELS,
    METHODS,
    MIN_MAX_STEPS,
    MIN_WALKERS,
    NUISANCE,
    WRINKLE_LAWS,
    EstimatorOptions,
)
from ._placement import DEVICE_REQUESTS
from ._toml import TomlReader, read_toml
from .executor import ExecutorOptions
from .paper import PAPER_KS

_TOP_KEYS = {
    "name",
    "description",
    "output_dir",
    "seed",
    "estimators",
    "calibration",
    "sessions",
    "outputs",
    "rig",
    "executor",
    "compute",
}
ESTIMATOR_KEYS = {
    "methods",
    "bootstrap_samples",
    "through_origin",
    "forward_model",
    "gas",
    "wrinkle_law",
    "nuisance",
    "bayes_walkers",
    "bayes_max_steps",
    "bayes_surrogate",
}
_CALIBRATION_KEYS = {"sessions", "k_s", "k_s_std"}
_SESSION_KEYS = {"paths"}
_OUTPUT_KEYS = {"figures"}
_RIG_KEYS = {"path"}
_EXECUTOR_KEYS = {"workers", "cluster", "cache_dir"}
COMPUTE_KEYS = {"device"}
_DOC = "docs/configs.md"


def bundled_data_dir() -> Path:
    """Directory of the data shipped inside the installed package."""
    return Path(str(resources.files("shelljax") / "data"))


@dataclasses.dataclass(frozen=True)
class ExperimentConfig:
    """A validated experiment config.

    ``calibration_sessions`` (k_s from Procedure 1) or ``k_s``/``k_s_std`` [-] (None: the
    paper's, ``shelljax.paper.PAPER_KS``); ``sessions`` to estimate; ``methods``; ``figures``
    (write PNGs); ``output_dir`` where run directories are created; ``estimator_options``: the
    [estimators] table and the config's ``seed`` as :class:`shelljax.estimate.EstimatorOptions`
    (its ``k_s`` is None: the runner sets the one it calibrates or is given); ``rig``: a rig file
    (``shelljax rig calibrate``) that fit and bayes estimate through, or None; ``executor``: where
    the sessions run (the [executor] table, docs/cluster.md; in-process without one); ``device``:
    the [compute] table's device request, ``auto``, ``cpu`` or ``gpu`` (docs/gpu.md).
    """

    source: Path
    name: str
    description: str
    output_dir: Path
    methods: tuple[str, ...]
    estimator_options: EstimatorOptions
    calibration_sessions: tuple[Path, ...]
    k_s: float | None
    k_s_std: float | None
    sessions: tuple[Path, ...]
    figures: bool
    rig: Path | None = None
    executor: ExecutorOptions = dataclasses.field(default_factory=ExecutorOptions)
    device: str = "auto"


def resolve_paths(path: Path, field: str, patterns) -> tuple[Path, ...]:
    """Expand a list of path patterns (relative or ``bundled:``) into existing files, in order."""
    reader = TomlReader(path, doc=_DOC)
    if not isinstance(patterns, list) or not all(isinstance(p, str) for p in patterns):
        raise reader.fail(field, f"expected a list of paths, got {patterns!r}", 'write ["a.toml", "dir/*.toml"]')
    out: list[Path] = []
    for pattern in patterns:
        if pattern.startswith("bundled:"):
            full = bundled_data_dir() / pattern.removeprefix("bundled:")
        else:
            full = path.parent / pattern
        matches = sorted(Path(m) for m in glob.glob(str(full)))
        if not matches:
            raise reader.fail(
                field,
                f"{pattern!r} matches no file (looked for {full})",
                "fix the path: relative to the config file, or 'bundled:sessions/...'",
            )
        out.extend(m for m in matches if m not in out)
    return tuple(out)


def load_config(path: str | Path) -> ExperimentConfig:
    """Read and validate an experiment config TOML; raise InvalidInputError naming the field."""
    path = Path(path)
    data = read_toml(path, "config file", fix_missing="check the path (e.g. configs/paper.toml)")
    reader = TomlReader(path, doc=_DOC)
    reader.no_unknown_keys(data, _TOP_KEYS)
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name or any(c in name for c in "/\\ "):
        raise reader.fail("name", f"{name!r} is not a usable run name", "use letters, digits, '-' and '_'")
    seed = reader.integer(data, "seed", default=0, fix="write seed = 0")
    estimators_table = reader.table(data, "estimators", ESTIMATOR_KEYS) or {}
    rig = rig_settings(path, reader.table(data, "rig", _RIG_KEYS) or {}, estimators_table)
    if rig is not None:
        estimators_table = {**estimators_table, **rig[1]}
    methods, options = estimator_settings(path, estimators_table, seed=seed)
    calibration = _calibration_settings(path, reader.table(data, "calibration", _CALIBRATION_KEYS) or {})
    sessions_table = reader.table(data, "sessions", _SESSION_KEYS) or {}
    if "paths" not in sessions_table:
        raise reader.fail("sessions.paths", "missing", 'add [sessions] paths = ["bundled:sessions/pezzi.toml"]')
    sessions = resolve_paths(path, "sessions.paths", sessions_table["paths"])
    figures = reader.flag(reader.table(data, "outputs", _OUTPUT_KEYS) or {}, "figures", "outputs.", default=True)
    output_dir = data.get("output_dir", "runs")
    if not isinstance(output_dir, str):
        raise reader.fail("output_dir", f"{output_dir!r} is not a path", 'write output_dir = "runs"')
    return ExperimentConfig(
        source=path,
        name=name,
        description=str(data.get("description", "")),
        output_dir=Path(output_dir),
        methods=methods,
        estimator_options=options,
        sessions=sessions,
        figures=figures,
        **calibration,
        rig=None if rig is None else rig[0],
        executor=executor_settings(path, reader.table(data, "executor", _EXECUTOR_KEYS) or {}),
        device=compute_device(path, reader.table(data, "compute", COMPUTE_KEYS) or {}),
    )


def compute_device(path: Path, table: dict) -> str:
    """The device request of a [compute] table (experiment and scenario configs; docs/gpu.md):
    ``auto`` (the default), ``cpu`` or ``gpu``."""
    reader = TomlReader(path, doc="docs/gpu.md")
    return reader.choice(table, "device", "compute.", DEVICE_REQUESTS, "auto", what="device request")


def executor_settings(path: Path, table: dict) -> ExecutorOptions:
    """The [executor] table (docs/cluster.md): ``workers`` (a local Dask cluster), or ``cluster``
    (a scheduler's address), and ``cache_dir`` (relative to the config)."""
    reader = TomlReader(path, doc="docs/cluster.md")
    workers = reader.integer(table, "workers", "executor.", default=None, minimum=1)
    cluster = (
        None
        if "cluster" not in table
        else reader.typed(table, "cluster", str, "executor.", fix='write cluster = "tcp://HOST:PORT"')
    )
    cache_dir = None if "cache_dir" not in table else path.parent / reader.typed(table, "cache_dir", str, "executor.")
    if workers is not None and cluster is not None:
        raise reader.fail("executor", "both workers and cluster are set", "keep one: a cluster's workers are its own")
    if cluster is not None and "://" not in cluster:
        raise reader.fail(
            "executor.cluster", f"{cluster!r} is not a scheduler address", 'write cluster = "tcp://HOST:PORT"'
        )
    return ExecutorOptions(workers=workers, cluster=cluster, cache_dir=cache_dir)


def rig_settings(path: Path, table: dict, estimators: dict) -> tuple[Path, dict] | None:
    """(the rig file, its forward-model options) of a [rig] table (experiment and scenario configs),
    or None without one; the [estimators] table may repeat the rig's gas and wrinkle law but not
    contradict them."""
    if not table:
        return None
    reader = TomlReader(path, doc=_DOC)
    if "path" not in table:
        raise reader.fail("rig.path", "missing", 'write path = "rig.toml" (a file from `shelljax rig calibrate`)')
    (rig_path,) = resolve_paths(path, "rig.path", [table["path"]])[:1]
    rig_file = TomlReader(rig_path, fix="re-create it with `shelljax rig calibrate`")
    document = read_toml(
        rig_path,
        "rig file",
        fix_missing="re-create it with `shelljax rig calibrate`",
        fix_syntax="re-create it with `shelljax rig calibrate`",
    )
    forward = rig_file.table(document, "forward_model") or {}
    options = {}
    for key in ("gas", "wrinkle_law"):
        made = forward.get(key)
        if made is None:
            raise reader.fail(
                "rig.path", f"{rig_path} names no forward_model.{key}", "re-create it with `shelljax rig calibrate`"
            )
        if key in estimators and estimators[key] != made:
            raise reader.fail(
                f"estimators.{key}",
                f"{estimators[key]!r}, but the rig {rig_path} was calibrated with {made!r}",
                f"write {key} = {made!r}, or calibrate a rig with this {key}",
            )
        options[key] = made
    return rig_path, options


def estimator_settings(
    path: Path, estimators: dict, *, gas: str = DEFAULT_OPTIONS.gas, seed: int = 0
) -> tuple[tuple[str, ...], EstimatorOptions]:
    """(methods, options) of the [estimators] table, checked (``gas``: its default; ``seed``: the
    options' seed); what the table leaves out is ``shelljax.estimate.DEFAULT_OPTIONS``'. The
    options' ``k_s`` is None: whoever runs the closed form sets it."""
    d = DEFAULT_OPTIONS
    reader = TomlReader(path, doc=_DOC)
    p = "estimators."
    methods = estimators.get("methods", ["closed-form"])
    if not isinstance(methods, list) or not methods:
        raise reader.fail(
            p + "methods", f"expected a non-empty list, got {methods!r}", 'write methods = ["closed-form"]'
        )
    for m in methods:
        if m not in METHODS:
            raise reader.fail(p + "methods", f"unknown method {m!r}", f"available: {', '.join(METHODS)}")
    options = EstimatorOptions(  # keyword order is the order of the checks
        bootstrap_samples=reader.integer(
            estimators,
            "bootstrap_samples",
            p,
            default=d.bootstrap_samples,
            fix=f"e.g. {d.bootstrap_samples} (0 disables)",
        ),
        through_origin=reader.flag(estimators, "through_origin", p, default=d.through_origin),
        seed=seed,
        forward_model=reader.choice(estimators, "forward_model", p, FORWARD_MODELS, d.forward_model, what="model"),
        gas=reader.choice(estimators, "gas", p, ESTIMATOR_GASES, gas, what="gas model"),
        wrinkle_law=reader.choice(estimators, "wrinkle_law", p, WRINKLE_LAWS, d.wrinkle_law, what="wrinkle law"),
        nuisance=_nuisance(reader, estimators.get("nuisance", list(d.nuisance))),
        walkers=reader.integer(
            estimators, "bayes_walkers", p, default=d.walkers, minimum=MIN_WALKERS, fix=f"e.g. {d.walkers}"
        ),
        max_steps=reader.integer(
            estimators, "bayes_max_steps", p, default=d.max_steps, minimum=MIN_MAX_STEPS, fix=f"e.g. {d.max_steps}"
        ),
        surrogate=reader.flag(estimators, "bayes_surrogate", p, default=d.surrogate),
    )
    return tuple(methods), options


def _nuisance(reader: TomlReader, nuisance) -> tuple[str, ...]:
    if not isinstance(nuisance, list) or any(n not in NUISANCE for n in nuisance):
        raise reader.fail(
            "estimators.nuisance",
            f"{nuisance!r} is not a list of known nuisance parameters",
            f"choose from {', '.join(NUISANCE)}",
        )
    return tuple(nuisance)


def _calibration_settings(path: Path, calibration: dict) -> dict:
    """The ExperimentConfig fields of the [calibration] table: sessions, or k_s and its std [-]."""
    reader = TomlReader(path, doc=_DOC)
    calibration_sessions = (
        resolve_paths(path, "calibration.sessions", calibration["sessions"]) if "sessions" in calibration else ()
    )
    k_s = calibration.get("k_s")
    k_s_std = calibration.get("k_s_std")
    if calibration_sessions and k_s is not None:
        raise reader.fail("calibration.k_s", "given together with calibration sessions", "use one of them")
    for field, value in (("k_s", k_s), ("k_s_std", k_s_std)):
        if value is not None and (
            isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0 or value == float("inf")
        ):
            raise reader.fail(
                f"calibration.{field}", f"{value!r} is not a finite non-negative number", f"e.g. k_s = {PAPER_KS}"
            )
    if k_s is not None and k_s == 0:
        raise reader.fail("calibration.k_s", "k_s = 0 divides by zero", f"the paper's value is {PAPER_KS}")
    return dict(
        calibration_sessions=calibration_sessions,
        k_s=None if k_s is None else float(k_s),
        k_s_std=None if k_s_std is None else float(k_s_std),
    )
