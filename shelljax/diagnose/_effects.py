"""The library of candidate effects: named model extensions the diagnosis refits one at a time.

Every unknown of a study lives in one scaled vector ``u`` (O(1) near the start), the same layout
for every candidate, so one compiled program fits them all: a candidate only frees some entries
(the others stay at their baseline value) and changes some priors. The unknowns after the
per-session gauge pressures:

| parameter | physical value from u | unit | baseline | prior when free (in u) |
|---|---|---|---|---|
| young_modulus | E_ref · e^u | Pa | free | flat |
| thickness | h_cal · e^u | m | free if the calliper has a std | normal(0, σ_h/h), or (0, 0.5) under ``wall_thickness`` |
| radius | R_meas · e^u | m | free if R has a std | normal(0, σ_R/R) |
| finger_compliance | 0.1 mm/N · u | m/N | 0 | normal(0, 10) |
| pad_exponent | 1 + 0.1 u | - | 1 (a linear pad) | normal(0, 4) |
| depth_offset | 1 mm · u | m | 0 | normal(0, 10) |
| force_gain | e^u | - | 1 | normal(0, 0.3) |
| force_exponent | 1 + 0.1 u | - | 1 | normal(0, 3) |
| indenter_radius | a₀ (f + (1 − f) e^u), f = 1/2 | m | a₀ (8 mm) | normal(0, 1) |
| gas_exponent | κ₀ + 0.5 u | - | κ₀ (1 isothermal, 0 prescribed, 1.4 adiabatic) | normal(0, 2) |
| stiffening | 10 u | - | 0 (Neo-Hookean) | normal(0, 3) |
| body_mass | m_ref · e^u | kg | no gravity | normal(0, 0.1) with the session's mass, else (0, 1.5) |
| friction_coefficient | 0.5 · e^u | - | frictionless ground | normal(0, 1.5) |

The priors are weakly informative: a few times wider than any plausible value, so the data decide,
and proper, so the posterior and its leave-one-out predictive densities exist.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._errors import InvalidInputError

GLOBAL_PARAMETERS = (
    "young_modulus",
    "thickness",
    "radius",
    "finger_compliance",
    "depth_offset",
    "force_gain",
    "force_exponent",
    "indenter_radius",
    "gas_exponent",
    "stiffening",
    "body_mass",
    "friction_coefficient",
    "pad_exponent",
)
UNITS = {
    "gauge_pressure": "Pa",
    "young_modulus": "Pa",
    "thickness": "m",
    "radius": "m",
    "finger_compliance": "m/N",
    "depth_offset": "m",
    "force_gain": "1",
    "force_exponent": "1",
    "indenter_radius": "m",
    "gas_exponent": "1",
    "stiffening": "1",
    "body_mass": "kg",
    "friction_coefficient": "1",
    "pad_exponent": "1",
}
LOG_PARAMETERS = frozenset(
    {
        "gauge_pressure",
        "young_modulus",
        "thickness",
        "radius",
        "force_gain",
        "indenter_radius",
        "body_mass",
        "friction_coefficient",
    }
)
# the finger never shrinks below half its nominal radius: a fingertip is no needle, and a contact
# patch smaller than the engine's elements makes the depth a kinked function of the radius, on
# which Levenberg–Marquardt stalls (docs/rig.md)
MIN_INDENTER_FRACTION = 0.5
# (scale of u, prior std of u) of the effect parameters that are linear in u
LINEAR_SCALE = {
    "finger_compliance": 1e-4,
    "depth_offset": 1e-3,
    "force_exponent": 0.1,
    "gas_exponent": 0.5,
    "stiffening": 10.0,
    "pad_exponent": 0.1,
}
PRIOR_STD = {
    "finger_compliance": 10.0,
    "depth_offset": 10.0,
    "force_gain": 0.3,
    "force_exponent": 3.0,
    "indenter_radius": 1.0,
    "gas_exponent": 2.0,
    "stiffening": 3.0,
    "friction_coefficient": 1.5,
    "pad_exponent": 4.0,
}
FRICTION_REFERENCE = 0.5  # [-] μ at u = 0: rubber on a table
FREE_THICKNESS_STD = 0.5  # [-] prior std of log h under ``wall_thickness``: h within ×/÷ 2.7 at 2σ
WEIGHED_MASS_STD = 0.1  # [-] prior std of log m when the session states the mass
UNWEIGHED_MASS_STD = 1.5  # [-] ... and when it does not (m_ref = 0.5 kg then)
UNWEIGHED_MASS = 0.5  # [kg]
MANOMETER_STD = 0.02  # [-] relative std of a manometer reading, the gauge pressure's prior


@dataclasses.dataclass(frozen=True)
class Effect:
    """A candidate model extension.

    ``name``; ``layer``: where it acts ("measurement", "contact" or "physics"); ``parameters``:
    the global unknowns it frees (see the module table); ``description``: what it models.
    """

    name: str
    layer: str
    parameters: tuple[str, ...]
    description: str


EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in (
        Effect(
            "finger_compliance",
            "measurement",
            ("finger_compliance",),
            "the finger pad compresses by c·F, and the depth read from the finger includes it: "
            "depth = w0 + c F [c in m/N] (a linear pad; a rig may give it a power law, shelljax.rig)",
        ),
        Effect(
            "depth_offset",
            "measurement",
            ("depth_offset",),
            "a zero-point error of the depth reading, the same for every sample: depth = w0 + δ [m]",
        ),
        Effect(
            "force_sensor_gain",
            "measurement",
            ("force_gain",),
            "the thin-film sensor's calibration is off by a factor: F_true = g F_recorded",
        ),
        Effect(
            "force_sensor_nonlinearity",
            "measurement",
            ("force_exponent",),
            "the thin-film sensor responds as a power law about the mid force F_ref: "
            "F_true = F_ref (F_recorded / F_ref)^p",
        ),
        Effect(
            "indenter_size",
            "contact",
            ("indenter_radius",),
            "the finger's contact radius a differs from the assumed 8 mm sphere",
        ),
        Effect(
            "gas",
            "physics",
            ("gas_exponent",),
            "the gas law: p V^κ constant, κ = 0 a prescribed pressure, 1 isothermal, 1.4 adiabatic",
        ),
        Effect(
            "material_stiffening",
            "physics",
            ("stiffening",),
            "a Gent wall instead of Neo-Hookean: the shear energy −μ/(2s) ln(1 − s I₁) stiffens with "
            "stretch, s = 1/J_m",
        ),
        Effect(
            "wall_thickness",
            "physics",
            ("thickness",),
            "the wall thickness h is off its calliper value (the calliper prior is widened to ×/÷ 1.6 at 1σ)",
        ),
        Effect(
            "self_weight",
            "physics",
            ("body_mass",),
            "gravity on the object: its weight m g, spread over the wall, presses it on the ground",
        ),
        Effect(
            "ground_friction",
            "contact",
            ("friction_coefficient",),
            "Coulomb friction μ between the object and the ground (lagged, smoothed): the contact disc "
            "cannot slide freely as it grows",
        ),
    )
}


def check_effect_names(names) -> tuple[str, ...]:
    """``names`` as a tuple, after checking each is in :data:`EFFECTS`."""
    names = tuple(names)
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise InvalidInputError(
            f"unknown effect(s) {', '.join(map(repr, unknown))}. Fix: choose from {', '.join(EFFECTS)}"
        )
    if len(set(names)) != len(names):
        raise InvalidInputError(f"effects {list(names)} name one effect twice. Fix: list each once")
    return names


def parameter_names(n_sessions: int) -> tuple[str, ...]:
    """Names of the entries of u: one gauge pressure per session, then :data:`GLOBAL_PARAMETERS`."""
    return tuple(f"gauge_pressure[{i}]" for i in range(n_sessions)) + GLOBAL_PARAMETERS


def combination_name(effects) -> str:
    """The name of a model with several ``effects``: their names in :data:`EFFECTS` order, joined by
    "+" (``force_sensor_gain+force_sensor_nonlinearity``)."""
    order = list(EFFECTS)
    return "+".join(sorted(effects, key=order.index))


def effects_of(name: str) -> tuple[str, ...]:
    """The effects a model's ``name`` (one effect, or a :func:`combination_name`) holds."""
    return tuple(name.split("+"))


def effect_parameters(name: str) -> tuple[str, ...]:
    """The global unknowns a model's ``name`` (one effect or a combination) frees, in order."""
    return tuple(p for e in effects_of(name) for p in EFFECTS[e].parameters)


def free_mask(n_sessions: int, baseline_free: tuple[str, ...], effect: str | None) -> np.ndarray:
    """Which entries of u a fit frees: P_g of every session, the baseline's and the effect's (one
    effect or a combination)."""
    free = set(baseline_free) | (set(effect_parameters(effect)) if effect else set())
    return np.array([True] * n_sessions + [name in free for name in GLOBAL_PARAMETERS])
