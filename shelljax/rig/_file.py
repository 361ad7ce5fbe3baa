"""The rig file: a calibrated rig as readable TOML (docs/rig.md), and its checked reader.

Each model lists its terms, its weight, its evidence (elpd, Δ elpd ± SE against the best model) and
each parameter's value ± std in physical units, and — for the estimates — its mean and covariance
in the diagnosis's scaled coordinates, which are what an estimate reads back.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import tomli_w

from .._files import atomic_write_text
from .._toml import TomlReader, read_toml
from ..diagnose.internal import LINEAR_SCALE, MIN_INDENTER_FRACTION, UNITS
from .._options import ESTIMATOR_GASES, WRINKLE_LAWS
from ._calibrate import Rig, RigModel
from ._terms import RIG_TERMS, check_terms, fixed_values, freed_parameters

FORMAT = 1
_HEADER = (
    "# shelljax rig: the measuring chain (finger pad, finger radius, force sensor, depth gauge), calibrated\n"
    "# on sessions with manometer readings. Written by `shelljax rig calibrate`; see docs/rig.md.\n"
)


def physical_parameter(name: str, u: float, std: float, indenter_radius: float) -> tuple[float, float]:
    """(value, std) in SI of a rig parameter at scaled ``u`` ± ``std`` (the diagnosis's coordinates)."""
    if name == "indenter_radius":
        floor = MIN_INDENTER_FRACTION * indenter_radius
        return floor + (indenter_radius - floor) * math.exp(u), (indenter_radius - floor) * math.exp(u) * std
    if name == "force_gain":
        return math.exp(u), math.exp(u) * std
    offset = 1.0 if name in ("force_exponent", "pad_exponent") else 0.0  # exponents are 1 + scale · u
    return offset + LINEAR_SCALE[name] * u, LINEAR_SCALE[name] * std


def _model_table(model: RigModel, rig: Rig) -> dict:
    stds = np.sqrt(np.diag(model.covariance)) if model.parameters else np.zeros(0)
    parameters = {}
    for name, u, std in zip(model.parameters, model.mean, stds):
        value, err = physical_parameter(name, float(u), float(std), rig.indenter_radius)
        parameters[name] = {"value": value, "std": err, "unit": UNITS[name]}
    for name, u in model.fixes.items():
        parameters[name] = {
            "value": physical_parameter(name, u, 0.0, rig.indenter_radius)[0],
            "std": 0.0,
            "unit": UNITS[name],
            "fixed": True,
        }
    return {
        "terms": list(model.terms),
        "weight": model.weight,
        "evidence": {
            "elpd": model.elpd,
            "elpd_se": model.elpd_se,
            "delta_elpd": model.delta,
            "delta_se": model.delta_se,
            "unit": "nats",
        },
        "parameters": parameters,
        "scaled": {
            "names": list(model.parameters),
            "mean": [float(v) for v in model.mean],
            "covariance": [[float(v) for v in row] for row in model.covariance],
        },
    }


def rig_document(rig: Rig) -> dict:
    """The rig as the TOML document's dict."""
    return {
        "format": FORMAT,
        "shelljax_version": rig.version,
        **({"name": rig.name} if rig.name else {}),
        "manometer_std": rig.manometer_std,
        "forward_model": {"engine": "axisym", "gas": rig.gas, "wrinkle_law": rig.wrinkle_law},
        "reference": {
            "force_ref": rig.force_ref,
            "force_ref_unit": "N",
            "indenter_radius": rig.indenter_radius,
            "indenter_radius_unit": "m",
        },
        "noise": {
            "trial_offset_std": rig.noise[0],
            "trial_offset_std_unit": "m",
            "depth_scatter_a": rig.noise[1][0],
            "depth_scatter_a_unit": "m^2",
            "depth_scatter_b": rig.noise[1][1],
            "depth_scatter_b_unit": "1",
        },
        "selection": {
            "weights": "pseudo-BMA+",
            "inclusion": dict(rig.inclusion),
            "not_identified": list(rig.not_identified),
            "excluded": [
                {"terms": e["terms"], "delta_elpd": e["delta"], "delta_se": e["delta_se"]} for e in rig.excluded
            ],
            "failed": [dict(f) for f in rig.failed],
        },
        "calibration": [dict(c) for c in rig.calibration],
        "objects": [dict(o) for o in rig.objects],
        "model": [_model_table(m, rig) for m in rig.models],
    }


def write_rig(rig: Rig, path: str | Path) -> Path:
    """Write ``rig`` to ``path`` atomically (a file that is read back and checked first)."""
    path = Path(path)
    text = _HEADER + tomli_w.dumps(rig_document(rig))
    path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write_text(path, text, check=load_rig)


def _read_model(check: TomlReader, table: dict, i: int) -> RigModel:
    where = f"model[{i}]"
    terms = check_terms(check.typed(table, "terms", list, f"{where}."), where=f"{check.path}: field '{where}.terms'")
    scaled = check.typed(table, "scaled", dict, f"{where}.")
    names = tuple(check.typed(scaled, "names", list, f"{where}.scaled."))
    if names != freed_parameters(terms):
        raise check.fail(
            f"{where}.scaled.names",
            f"{list(names)} are not the parameters of terms {list(terms)} ({list(freed_parameters(terms))})",
        )
    mean = np.asarray(check.typed(scaled, "mean", list, f"{where}.scaled."), float)
    cov = np.asarray(check.typed(scaled, "covariance", list, f"{where}.scaled."), float).reshape(-1)
    if (
        mean.shape != (len(names),)
        or cov.size != len(names) ** 2
        or not np.all(np.isfinite(cov))
        or not np.all(np.isfinite(mean))
    ):
        raise check.fail(
            f"{where}.scaled",
            f"mean {mean.tolist()} / covariance of {cov.size} entries do not fit {len(names)} parameters",
        )
    cov = cov.reshape(len(names), len(names))
    if names and (not np.allclose(cov, cov.T, rtol=1e-8, atol=0) or np.min(np.linalg.eigvalsh(cov)) <= 0):
        raise check.fail(f"{where}.scaled.covariance", "not symmetric positive definite")
    weight = check.typed(table, "weight", float, f"{where}.")
    if not 0 < weight <= 1:
        raise check.fail(f"{where}.weight", f"{weight!r} is not in (0, 1]")
    ev = check.typed(table, "evidence", dict, f"{where}.")
    num = lambda k: check.typed(ev, k, float, f"{where}.evidence.")  # noqa: E731
    return RigModel(
        terms=terms,
        parameters=names,
        mean=mean,
        covariance=cov,
        fixes=fixed_values(terms),
        elpd=num("elpd"),
        elpd_se=num("elpd_se"),
        delta=num("delta_elpd"),
        delta_se=num("delta_se"),
        weight=weight,
    )


def _checked_version(check: TomlReader, data: dict) -> str:
    """The shelljax version that wrote the rig file, once its format and version are this shelljax's."""
    from .. import __version__

    fmt = data.get("format")
    if fmt is None:
        is_session = "object" in data or "indentation" in data
        what = "this is a measurement session, not a rig file" if is_session else "not a rig file"
        raise check.fail(
            "format",
            f"missing: {what}",
            "make a rig file from sessions with manometer readings: "
            "`shelljax rig calibrate SESSIONS... --out rig.toml`, then pass --rig rig.toml",
        )
    if fmt != FORMAT:
        raise check.fail(
            "format", f"{fmt!r} is not this shelljax's rig format {FORMAT}", "re-calibrate the rig with this version"
        )
    version = check.typed(data, "shelljax_version", str)
    if version.split(".")[:2] != __version__.split(".")[:2]:
        raise check.fail(
            "shelljax_version",
            f"made by shelljax {version}, incompatible with {__version__} (the models may differ)",
            "re-calibrate the rig with this version",
        )
    return version


def _read_reference_and_noise(check: TomlReader, data: dict) -> tuple[float, float, tuple[float, tuple[float, float]]]:
    """(reference force [N], indenter radius [m], depth noise (τ_t [m], (a [m²], b [-]))), checked."""
    ref = check.typed(data, "reference", dict)
    noise = check.typed(data, "noise", dict)
    force_ref = check.typed(ref, "force_ref", float, "reference.")
    radius = check.typed(ref, "indenter_radius", float, "reference.")
    tau = check.typed(noise, "trial_offset_std", float, "noise.")
    a = check.typed(noise, "depth_scatter_a", float, "noise.")
    b = check.typed(noise, "depth_scatter_b", float, "noise.")
    for field, value in (("reference.force_ref", force_ref), ("reference.indenter_radius", radius)):
        if value <= 0:
            raise check.fail(field, f"{value!r} is not positive")
    for field, value in (("noise.trial_offset_std", tau), ("noise.depth_scatter_a", a), ("noise.depth_scatter_b", b)):
        if value < 0:
            raise check.fail(field, f"{value!r} is negative")
    if a + b <= 0:
        raise check.fail("noise.depth_scatter_a", "the depth scatter is zero")
    return force_ref, radius, (tau, (a, b))


def _read_models(check: TomlReader, data: dict) -> tuple[RigModel, ...]:
    """The rig's models, each checked, their weights adding up to 1."""
    tables = check.typed(data, "model", list)
    if not tables:
        raise check.fail("model", "no model")
    models = tuple(_read_model(check, t, i) for i, t in enumerate(tables))
    total = sum(m.weight for m in models)
    if abs(total - 1.0) > 1e-6:
        raise check.fail("model.weight", f"the weights add up to {total:.6g}, not 1")
    return models


def load_rig(path: str | Path) -> Rig:
    """Read and check a rig file written by :func:`write_rig`.

    Raises:
        InvalidInputError: an unreadable file, another format or shelljax version, or any field
            that is missing or makes no sense (the message names the field and the fix).
    """
    path = Path(path)
    data = read_toml(
        path,
        "rig file",
        fix_missing=f"make one with `shelljax rig calibrate SESSIONS... --out {path}`",
        fix_syntax="re-create it with `shelljax rig calibrate`",
    )
    # a rig file is written by `shelljax rig calibrate`, so every field's fix is to write it again
    check = TomlReader(path, fix="re-create the file with `shelljax rig calibrate`", doc="docs/rig.md")
    version = _checked_version(check, data)
    fm = check.typed(data, "forward_model", dict)
    force_ref, radius, (tau, (a, b)) = _read_reference_and_noise(check, data)
    models = _read_models(check, data)
    selection = data.get("selection", {})
    gas = check.typed(fm, "gas", str, "forward_model.")
    law = check.typed(fm, "wrinkle_law", str, "forward_model.")
    if gas not in ESTIMATOR_GASES or law not in WRINKLE_LAWS:
        raise check.fail(
            "forward_model",
            f"gas {gas!r} / wrinkle_law {law!r} unknown",
            f"use a gas of {', '.join(ESTIMATOR_GASES)} and a wrinkle law of {', '.join(WRINKLE_LAWS)}",
        )
    return Rig(
        models=models,
        excluded=tuple(
            {"terms": e.get("terms"), "delta": e.get("delta_elpd"), "delta_se": e.get("delta_se")}
            for e in selection.get("excluded", [])
        ),
        inclusion={t: float(selection.get("inclusion", {}).get(t, 0.0)) for t in RIG_TERMS},
        not_identified=tuple(selection.get("not_identified", [])),
        gas=gas,
        wrinkle_law=law,
        force_ref=force_ref,
        indenter_radius=radius,
        noise=(tau, (a, b)),
        calibration=tuple(data.get("calibration", [])),
        objects=tuple(data.get("objects", [])),
        version=version,
        name=_name(check, data),
        manometer_std=check.typed(data, "manometer_std", float),
        failed=tuple(selection.get("failed", [])),
    )


def _name(check: TomlReader, data: dict) -> str | None:
    name = data.get("name")
    if name is not None and (not isinstance(name, str) or not name.strip()):
        raise check.fail(
            "name", f"{name!r} is not a rig's name", 'write name = "alice-index-film3", or delete the line'
        )
    return name
