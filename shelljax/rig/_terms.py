"""The terms of a rig model: how the measuring chain sits between an engine's prediction and the
recorded numbers.

A rig is the person's finger, the thin-film force sensor on it and the depth gauge. Each term
frees some entries of the diagnosis's unknown vector (``shelljax.diagnose``, its module table
gives the scaled coordinates); the engine never sees a term:

| term | family | model of a sample recorded at force F [N] | frees |
|---|---|---|---|
| pad_linear | pad | depth += c F_t (a linear pad) | finger_compliance c [m/N] |
| pad_hertz | pad | depth += c F_ref (F_t/F_ref)^(2/3) (a Hertzian pad) | c |
| pad_power | pad | depth += c F_ref (F_t/F_ref)^q | c, pad_exponent q [-] |
| finger_radius | finger | the finger's contact sphere has radius a, not 8 mm | indenter_radius a [m] |
| depth_offset | depth | depth += δ (the gauge's zero error) | depth_offset δ [m] |
| sensor_gain | sensor | F_t = g F | force_gain g [-] |
| sensor_power | sensor_law | F_t = F_ref (F/F_ref)^p | force_exponent p [-] |

F_t is the true force, F_ref the rig's reference force (the calibration's mid force). A rig model
is a set of terms with at most one of each family; several are on at once where the evidence
asks for them.
"""

from __future__ import annotations

import dataclasses

from .._errors import InvalidInputError
from ..diagnose import GLOBAL_PARAMETERS
from ..diagnose.internal import LINEAR_SCALE

HERTZ_EXPONENT = 2.0 / 3.0  # [-] a Hertzian contact's compression grows as F^(2/3)


@dataclasses.dataclass(frozen=True)
class RigTerm:
    """One imperfection of the measuring chain: ``name``, ``family`` (one term per family in a
    model), the diagnosis parameters it ``frees``, the scaled values it ``fixes`` (name → u) and
    a ``description``."""

    name: str
    family: str
    frees: tuple[str, ...]
    fixes: tuple[tuple[str, float], ...]
    description: str


RIG_TERMS: dict[str, RigTerm] = {
    t.name: t
    for t in (
        RigTerm("pad_linear", "pad", ("finger_compliance",), (), "the finger pad compresses by c F: depth = w0 + c F"),
        RigTerm(
            "pad_hertz",
            "pad",
            ("finger_compliance",),
            (("pad_exponent", (HERTZ_EXPONENT - 1.0) / LINEAR_SCALE["pad_exponent"]),),
            "a Hertzian finger pad: depth = w0 + c F_ref (F/F_ref)^(2/3)",
        ),
        RigTerm(
            "pad_power",
            "pad",
            ("finger_compliance", "pad_exponent"),
            (),
            "a finger pad with a power-law response: depth = w0 + c F_ref (F/F_ref)^q",
        ),
        RigTerm(
            "finger_radius",
            "finger",
            ("indenter_radius",),
            (),
            "the finger's contact radius a differs from the assumed 8 mm sphere",
        ),
        RigTerm(
            "depth_offset", "depth", ("depth_offset",), (), "a zero-point error of the depth gauge: depth = w0 + δ"
        ),
        RigTerm("sensor_gain", "sensor", ("force_gain",), (), "the force sensor's gain: F_true = g F_recorded"),
        RigTerm(
            "sensor_power",
            "sensor_law",
            ("force_exponent",),
            (),
            "the force sensor responds as a power law: F_true = F_ref (F_recorded/F_ref)^p",
        ),
    )
}
FAMILIES = tuple(dict.fromkeys(t.family for t in RIG_TERMS.values()))
# every diagnosis parameter a rig may hold, in the diagnosis's order
RIG_PARAMETERS = tuple(p for p in GLOBAL_PARAMETERS if any(p in t.frees for t in RIG_TERMS.values()))


def check_terms(terms, where: str = "terms") -> tuple[str, ...]:
    """``terms`` sorted in :data:`RIG_TERMS` order, after checking names and one term per family."""
    terms = tuple(terms)
    unknown = [t for t in terms if t not in RIG_TERMS]
    if unknown:
        raise InvalidInputError(
            f"{where}: unknown rig term(s) {', '.join(map(repr, unknown))}. Fix: choose from {', '.join(RIG_TERMS)}"
        )
    families = [RIG_TERMS[t].family for t in terms]
    doubled = sorted({f for f in families if families.count(f) > 1})
    if doubled:
        raise InvalidInputError(
            f"{where}: {list(terms)} has more than one term of family {doubled[0]!r}. Fix: keep one of them"
        )
    return tuple(t for t in RIG_TERMS if t in terms)


def freed_parameters(terms) -> tuple[str, ...]:
    """The diagnosis parameters a model with ``terms`` fits, in :data:`RIG_PARAMETERS` order."""
    freed = {p for t in terms for p in RIG_TERMS[t].frees}
    return tuple(p for p in RIG_PARAMETERS if p in freed)


def fixed_values(terms) -> dict[str, float]:
    """Scaled values (u) a model with ``terms`` fixes away from the diagnosis's baseline."""
    return {name: value for t in terms for name, value in RIG_TERMS[t].fixes}
