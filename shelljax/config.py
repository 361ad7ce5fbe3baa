"""Experiment configs: which sessions, which estimators, which outputs (TOML, validated).

Paths in a config are relative to the config file, or start with ``bundled:`` to name files
shipped inside the package (``bundled:sessions/pezzi.toml``); both may contain glob patterns.
See docs/configs.md for the format.
"""

from __future__ import annotations

import dataclasses
import glob
import tomllib
from importlib import resources
from pathlib import Path

from ._errors import InvalidInputError
from .paper import PAPER_KS

METHODS = ("closed-form", "fit", "bayes")
FORWARD_MODELS = ("axisym", "scaling")
GAS_MODELS = ("prescribed", "isothermal")
WRINKLE_LAWS = ("mechanics", "scaling")  # as shelljax.estimate._forward (kept JAX-free here)
NUISANCE = ("depth_offset", "force_gain")
_TOP_KEYS = {"name", "description", "output_dir", "seed", "estimators", "calibration", "sessions", "outputs", "rig"}
ESTIMATOR_KEYS = {"methods", "bootstrap_samples", "through_origin", "forward_model", "gas", "wrinkle_law", "nuisance",
                   "bayes_walkers", "bayes_max_steps", "bayes_surrogate"}  # fmt: skip
_CALIBRATION_KEYS = {"sessions", "k_s", "k_s_std"}
_SESSION_KEYS = {"paths"}
_OUTPUT_KEYS = {"figures"}
_RIG_KEYS = {"path"}


def bundled_data_dir() -> Path:
    """Directory of the data shipped inside the installed package."""
    return Path(str(resources.files("shelljax") / "data"))


@dataclasses.dataclass(frozen=True)
class ExperimentConfig:
    """A validated experiment config.

    ``calibration_sessions`` (k_s from Procedure 1) or ``k_s``/``k_s_std`` [-] (None: the
    paper's, ``shelljax.paper.PAPER_KS``); ``sessions`` to estimate; ``methods``; ``bootstrap_samples``; ``seed``;
    ``figures`` (write PNGs); ``output_dir`` where run directories are created; for ``fit`` and
    ``bayes``: ``forward_model`` ("axisym" or "scaling"), ``gas`` ("prescribed" or "isothermal"),
    ``wrinkle_law`` of the axisym model ("mechanics" or "scaling"),
    ``nuisance`` parameters, ``bayes_walkers``, ``bayes_max_steps`` and ``bayes_surrogate``
    (sample the axisym engine through its checked Chebyshev surrogate; default true); ``rig``: a
    rig file (``shelljax rig calibrate``) that fit and bayes estimate through, or None.
    """

    source: Path
    name: str
    description: str
    output_dir: Path
    seed: int
    methods: tuple[str, ...]
    bootstrap_samples: int
    through_origin: bool
    calibration_sessions: tuple[Path, ...]
    k_s: float | None
    k_s_std: float | None
    sessions: tuple[Path, ...]
    figures: bool
    forward_model: str = "axisym"
    gas: str = "prescribed"
    wrinkle_law: str = "mechanics"
    nuisance: tuple[str, ...] = ()
    bayes_walkers: int = 32
    bayes_max_steps: int = 20_000
    bayes_surrogate: bool = True
    rig: Path | None = None


def _fail(path: Path, field: str, problem: str, fix: str) -> InvalidInputError:
    return InvalidInputError(f"{path}: field '{field}': {problem}. Fix: {fix}")


def _check_keys(path: Path, table: dict, allowed: set[str], prefix: str = "") -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise _fail(path, prefix + unknown[0], "unknown key",
                    f"remove it or fix its spelling; allowed keys here: {', '.join(sorted(allowed))}")  # fmt: skip


def _table(path: Path, data: dict, name: str, allowed: set[str]) -> dict:
    table = data.get(name, {})
    if not isinstance(table, dict):
        raise _fail(path, name, f"expected a table, got {table!r}", f"write it as [{name}]")
    _check_keys(path, table, allowed, f"{name}.")
    return table


def resolve_paths(path: Path, field: str, patterns) -> tuple[Path, ...]:
    """Expand a list of path patterns (relative or ``bundled:``) into existing files, in order."""
    if not isinstance(patterns, list) or not all(isinstance(p, str) for p in patterns):
        raise _fail(path, field, f"expected a list of paths, got {patterns!r}", 'write ["a.toml", "dir/*.toml"]')
    out: list[Path] = []
    for pattern in patterns:
        if pattern.startswith("bundled:"):
            full = bundled_data_dir() / pattern.removeprefix("bundled:")
        else:
            full = path.parent / pattern
        matches = sorted(Path(m) for m in glob.glob(str(full)))
        if not matches:
            raise _fail(path, field, f"{pattern!r} matches no file (looked for {full})",
                        "fix the path: relative to the config file, or 'bundled:sessions/...'")  # fmt: skip
        out.extend(m for m in matches if m not in out)
    return tuple(out)


def load_config(path: str | Path) -> ExperimentConfig:
    """Read and validate an experiment config TOML; raise InvalidInputError naming the field."""
    path = Path(path)
    data = _read_toml(path)
    _check_keys(path, data, _TOP_KEYS)
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name or any(c in name for c in "/\\ "):
        raise _fail(path, "name", f"{name!r} is not a usable run name", "use letters, digits, '-' and '_'")
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise _fail(path, "seed", f"{seed!r} is not a non-negative integer", "write seed = 0")
    estimators_table = _table(path, data, "estimators", ESTIMATOR_KEYS)
    rig = rig_settings(path, _table(path, data, "rig", _RIG_KEYS), estimators_table)
    if rig is not None:
        estimators_table = {**estimators_table, **rig[1]}
    estimators = estimator_settings(path, estimators_table)
    calibration = _calibration_settings(path, _table(path, data, "calibration", _CALIBRATION_KEYS))
    sessions_table = _table(path, data, "sessions", _SESSION_KEYS)
    if "paths" not in sessions_table:
        raise _fail(path, "sessions.paths", "missing", 'add [sessions] paths = ["bundled:sessions/pezzi.toml"]')
    sessions = resolve_paths(path, "sessions.paths", sessions_table["paths"])
    outputs = _table(path, data, "outputs", _OUTPUT_KEYS)
    figures = outputs.get("figures", True)
    if not isinstance(figures, bool):
        raise _fail(path, "outputs.figures", f"{figures!r} is not true/false", "write true or false")
    output_dir = data.get("output_dir", "runs")
    if not isinstance(output_dir, str):
        raise _fail(path, "output_dir", f"{output_dir!r} is not a path", 'write output_dir = "runs"')
    return ExperimentConfig(
        source=path, name=name, description=str(data.get("description", "")), output_dir=Path(output_dir),
        seed=seed, sessions=sessions, figures=figures, **estimators, **calibration, rig=None if rig is None else rig[0],
    )  # fmt: skip


def rig_settings(path: Path, table: dict, estimators: dict) -> tuple[Path, dict] | None:
    """(the rig file, its forward-model options) of a [rig] table (experiment and scenario configs),
    or None without one; the [estimators] table may repeat the rig's gas and wrinkle law but not
    contradict them."""
    if not table:
        return None
    if "path" not in table:
        raise _fail(path, "rig.path", "missing", 'write path = "rig.toml" (a file from `shelljax rig calibrate`)')
    (rig_path,) = resolve_paths(path, "rig.path", [table["path"]])[:1]
    try:
        forward = tomllib.loads(rig_path.read_text()).get("forward_model", {})
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise _fail(path, "rig.path", f"{rig_path} is not a readable rig file ({err})",
                    "re-create it with `shelljax rig calibrate`") from None  # fmt: skip
    options = {}
    for key in ("gas", "wrinkle_law"):
        made = forward.get(key)
        if made is None:
            raise _fail(path, "rig.path", f"{rig_path} names no forward_model.{key}", "re-create it with `shelljax rig calibrate`")
        if key in estimators and estimators[key] != made:
            raise _fail(path, f"estimators.{key}", f"{estimators[key]!r}, but the rig {rig_path} was calibrated with {made!r}",
                        f"write {key} = {made!r}, or calibrate a rig with this {key}")  # fmt: skip
        options[key] = made
    return rig_path, options


def _read_toml(path: Path) -> dict:
    if not path.is_file():
        raise InvalidInputError(f"{path}: config file does not exist. Fix: check the path (e.g. configs/paper.toml)")
    try:
        return tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise InvalidInputError(f"{path}: not valid TOML ({err}). Fix: correct the syntax") from None


def estimator_settings(path: Path, estimators: dict, *, gas: str = "prescribed") -> dict:
    """The ExperimentConfig fields of the [estimators] table, checked (``gas``: its default)."""
    methods = estimators.get("methods", ["closed-form"])
    if not isinstance(methods, list) or not methods:
        raise _fail(path, "estimators.methods", f"expected a non-empty list, got {methods!r}", 'write methods = ["closed-form"]')
    for m in methods:
        if m not in METHODS:
            raise _fail(path, "estimators.methods", f"unknown method {m!r}", f"available: {', '.join(METHODS)}")
    boot = estimators.get("bootstrap_samples", 2000)
    if isinstance(boot, bool) or not isinstance(boot, int) or boot < 0:
        raise _fail(path, "estimators.bootstrap_samples", f"{boot!r} is not a non-negative integer", "e.g. 2000 (0 disables)")
    through_origin = estimators.get("through_origin", False)
    if not isinstance(through_origin, bool):
        raise _fail(path, "estimators.through_origin", f"{through_origin!r} is not true/false", "write true or false")
    choices = {}
    for key, default, allowed, what in (("forward_model", "axisym", FORWARD_MODELS, "model"),
                                        ("gas", gas, GAS_MODELS, "gas model"),
                                        ("wrinkle_law", "mechanics", WRINKLE_LAWS, "wrinkle law")):  # fmt: skip
        choices[key] = estimators.get(key, default)
        if choices[key] not in allowed:
            raise _fail(path, f"estimators.{key}", f"unknown {what} {choices[key]!r}", f"available: {', '.join(allowed)}")
    nuisance = estimators.get("nuisance", [])
    if not isinstance(nuisance, list) or any(n not in NUISANCE for n in nuisance):
        raise _fail(path, "estimators.nuisance", f"{nuisance!r} is not a list of known nuisance parameters",
                    f"choose from {', '.join(NUISANCE)}")  # fmt: skip
    counts = {}
    for key, default, minimum in (("bayes_walkers", 32, 8), ("bayes_max_steps", 20_000, 100)):
        value = estimators.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise _fail(path, f"estimators.{key}", f"{value!r} is not an integer >= {minimum}", f"e.g. {default}")
        counts[key] = value
    surrogate = estimators.get("bayes_surrogate", True)
    if not isinstance(surrogate, bool):
        raise _fail(path, "estimators.bayes_surrogate", f"{surrogate!r} is not true/false", "write true or false")
    return dict(methods=tuple(methods), bootstrap_samples=boot, through_origin=through_origin, **choices,
                nuisance=tuple(nuisance), bayes_surrogate=surrogate, **counts)  # fmt: skip


_OPTION_NAMES = {"bayes_walkers": "walkers", "bayes_max_steps": "max_steps", "bayes_surrogate": "surrogate"}


def estimator_option_fields(settings) -> dict:
    """``shelljax.estimate.EstimatorOptions`` keyword arguments, all but ``k_s`` and ``seed``, from
    [estimators] settings: the dict of :func:`estimator_settings` or an ExperimentConfig."""
    get = settings.get if isinstance(settings, dict) else lambda key: getattr(settings, key)
    keys = ("through_origin", "bootstrap_samples", "forward_model", "gas", "wrinkle_law", "nuisance", *_OPTION_NAMES)
    return {_OPTION_NAMES.get(key, key): get(key) for key in keys}


def _calibration_settings(path: Path, calibration: dict) -> dict:
    """The ExperimentConfig fields of the [calibration] table: sessions, or k_s and its std [-]."""
    calibration_sessions = resolve_paths(path, "calibration.sessions", calibration["sessions"]) if "sessions" in calibration else ()
    k_s = calibration.get("k_s")
    k_s_std = calibration.get("k_s_std")
    if calibration_sessions and k_s is not None:
        raise _fail(path, "calibration.k_s", "given together with calibration sessions", "use one of them")
    for field, value in (("k_s", k_s), ("k_s_std", k_s_std)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0
                                  or value == float("inf")):  # fmt: skip
            raise _fail(path, f"calibration.{field}", f"{value!r} is not a finite non-negative number",
                        f"e.g. k_s = {PAPER_KS}")  # fmt: skip
    if k_s is not None and k_s == 0:
        raise _fail(path, "calibration.k_s", "k_s = 0 divides by zero", f"the paper's value is {PAPER_KS}")
    return dict(calibration_sessions=calibration_sessions, k_s=None if k_s is None else float(k_s),
                k_s_std=None if k_s_std is None else float(k_s_std))  # fmt: skip
