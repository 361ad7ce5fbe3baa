"""The paper's real balls as a case for the diagnosis: which candidate effect reconciles the engine
with their one k_s = 0.64, and how each effect moves the deformed shape (docs/sim-to-real.md).

The paper reports only summary statistics of its real balls: one calibrated k_s for a Pezzi and a
yoga ball at all pressures, and the simulated shapes' errors. :func:`ks_scan` gives the engine's
k_s at the bundled calibration states of a ball for a scan of each candidate's magnitude;
:func:`reconcile` picks the magnitude that brings them closest to the paper's k_s;
:func:`shape_sensitivity` moves the shape observables of a Pezzi-like ball.

k_s of a state: the slope s of the closed form's regression F = s w(0) + c over the session's
noise-free depths, k_s = s / (π R P_g).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..paper import DEFAULT_POISSON_RATIO, PAPER_INDENTER_RADIUS, PAPER_KS
from ._effects import EFFECTS, GLOBAL_PARAMETERS
from ._model import JointProblem, study_arrays
from ._study import build_study

PAPER_BALLS = {"pezzi": 2.34e6, "yoga": 1.34e6}  # E [Pa]: the paper's estimates (Section 4.2)
# candidate → magnitudes scanned, in the diagnosis's scaled units (``_effects``)
KS_SCANS = {
    "finger_compliance": np.linspace(0.0, 20.0, 6),  # 0 … 2 mm/N
    "force_sensor_gain": np.linspace(-0.8, 0.8, 9),  # g = e^u
    "force_sensor_nonlinearity": np.linspace(-4.0, 4.0, 9),  # p = 1 + 0.1 u
    "indenter_size": np.linspace(-1.0, 2.0, 7),  # a = 8 mm (1/2 + e^u / 2): 5.5-33.6 mm
    "gas": np.linspace(-2.0, 0.8, 8),  # κ = 1 + 0.5 u: 0 (prescribed) … 1.4 (adiabatic)
    "material_stiffening": np.linspace(0.0, 4.0, 5),  # s = 10 u
    "wall_thickness": np.linspace(-1.0, 1.0, 9),  # h = h_cal e^u
}
# the paper's |simulated − real| / real of H, D_u, D_l and d [%]
PAPER_SHAPE_ERROR = {"height": 6.2, "upper_diameter": 2.1, "contact_diameter": 10.1, "sunken_depth": 7.2}
SHAPE_VARIANTS = (  # label, CurvePhysics overrides / parameter changes, force factor
    ("baseline (sealed isothermal, 8 mm finger)", {}, 1.0),
    ("gas: prescribed pressure (κ = 0)", {"gas_exponent": 0.0}, 1.0),
    ("gas: adiabatic (κ = 1.4)", {"gas_exponent": 1.4}, 1.0),
    ("indenter_size: a = 30 mm", {"indenter_radius": 30e-3}, 1.0),
    ("material_stiffening: s = 30", {"stiffening": 30.0}, 1.0),
    ("wall_thickness: h × 0.6", {"thickness_factor": 0.6}, 1.0),
    ("wall_thickness: h × 1.7", {"thickness_factor": 1.7}, 1.0),
    ("self_weight: m = 0.8 kg", {"body_mass": 0.8}, 1.0),
    ("force_sensor_gain: g = 1.25", {}, 1.25),
    ("ground_friction: μ = 0.5", {"friction_coefficient": 0.5}, 1.0),
)


def paper_calibration_sessions(ball: str) -> list:
    """The bundled calibration sessions of ``ball`` ("pezzi" or "yoga"), by pressure."""
    from ..session import bundled_sessions, load_session

    return [load_session(p) for p in bundled_sessions(f"calib_{ball}_*.toml")]


def _scan_rows(study, data, ball: str, scans: dict):
    """(u of every scanned state, its (effect, magnitude) label); the baseline first."""
    n_s = study.n_sessions
    base = np.zeros(data.free.shape[0])
    base[n_s + GLOBAL_PARAMETERS.index("young_modulus")] = math.log(PAPER_BALLS[ball] / float(data.start_modulus))
    base[:n_s] = np.log(study.manometer / study.start_pressure)
    rows, labels = [base], [("baseline", 0.0)]
    for effect, values in scans.items():
        index = n_s + GLOBAL_PARAMETERS.index(EFFECTS[effect].parameters[0])
        for v in values:
            u = base.copy()
            u[index] = v
            rows.append(u)
            labels.append((effect, float(v)))
    return np.array(rows), labels


def ks_scan(ball: str, scans: dict = KS_SCANS) -> dict:
    """The engine's k_s [-] at each calibration state of ``ball`` for every (effect, magnitude) of
    ``scans``: {"pressures": P_g [Pa], "rows": [{effect, u, k_s, converged}]}."""
    study = build_study(paper_calibration_sessions(ball))
    data = study_arrays(study)
    n_s = study.n_sessions
    free = np.ones(data.free.shape[0], bool)
    free[n_s + GLOBAL_PARAMETERS.index("body_mass")] = False  # gravity stays off
    data = eqx.tree_at(lambda d: d.free, data, jnp.asarray(free))
    rows, labels = _scan_rows(study, data, ball, scans)
    problem = JointProblem(data, "scaling")
    pred, ok = jax.jit(jax.vmap(lambda u: problem.residuals_and_prediction(u)[1]))(jnp.asarray(rows))
    depth = np.asarray(pred["depth"])
    out = []
    for k, (effect, value) in enumerate(labels):
        ks = []
        for s in range(n_s):
            sel = study.depth_session == s
            slope = np.polyfit(depth[k][sel], study.force[sel], 1)[0]
            ks.append(float(slope / (math.pi * study.radius[s] * study.manometer[s])))
        out.append({"effect": effect, "u": value, "k_s": ks, "converged": bool(ok[k])})
    return {"pressures": study.manometer.tolist(), "rows": out}


def reconcile(scans_by_ball: dict, effects=tuple(KS_SCANS)) -> list[dict]:
    """Per effect, the magnitude shared by the balls of ``scans_by_ball`` (ball → :func:`ks_scan`)
    that brings every state's k_s closest to the paper's (least squares in log k_s), best first."""
    result = []
    n_states = sum(len(s["pressures"]) for s in scans_by_ball.values())
    for effect in ("baseline", *effects):
        candidates = {}
        for scan in scans_by_ball.values():
            for row in scan["rows"]:
                if row["effect"] == effect and row["converged"]:
                    candidates.setdefault(row["u"], []).extend(row["k_s"])
        full = {u: ks for u, ks in candidates.items() if len(ks) == n_states}
        if not full:
            continue
        misfit = {u: float(np.sqrt(np.mean(np.log(np.asarray(ks) / PAPER_KS) ** 2))) for u, ks in full.items()}
        best = min(misfit, key=misfit.get)
        result.append(
            {
                "effect": effect,
                "best_u": best,
                "rms_log_error": misfit[best],
                "k_s_at_best": full[best],
                "k_s_range_at_best": [min(full[best]), max(full[best])],
            }
        )
    return sorted(result, key=lambda r: r["rms_log_error"])


def reconciliation_table(title: str, table: list[dict]) -> str:
    """:func:`reconcile`'s result as lines of text under ``title``."""
    lines = [title, f"{'effect':>26s} {'best u':>7s} {'rms |log k_s/0.64|':>19s}  k_s range at best"]
    for r in table:
        lines.append(
            f"{r['effect']:>26s} {r['best_u']:7.2f} {r['rms_log_error']:19.3f}  "
            f"{r['k_s_range_at_best'][0]:.3f} … {r['k_s_range_at_best'][1]:.3f}"
        )
    return "\n".join(lines)


def shape_sensitivity(
    pressure=1300.0,
    force=20.0,
    radius=0.13,
    thickness=0.9e-3,
    young_modulus=2.34e6,
    poisson_ratio=DEFAULT_POISSON_RATIO,
) -> list[dict]:
    """Change [%] of H, D_u, D_l and d of a ball (P_g [Pa], R [m], h [m], E [Pa], ν [-]) at
    ``force`` [N] under each of :data:`SHAPE_VARIANTS`, with the values [m]."""
    from ..axisym import CurvePhysics, indentation_curves, inflation_stretch
    from ..physics import STANDARD_GRAVITY, PolytropicGas, ShellProperties

    rows, keys = [], tuple(PAPER_SHAPE_ERROR)
    for label, change, factor in SHAPE_VARIANTS:
        h = thickness * change.get("thickness_factor", 1.0)
        stretch = float(inflation_stretch(pressure, radius, young_modulus, h, poisson_ratio))
        weight = change.get("body_mass", 0.0) * STANDARD_GRAVITY / (4 * math.pi * (radius / stretch) ** 2)
        physics = CurvePhysics(
            indenter_radius=np.array([change.get("indenter_radius", PAPER_INDENTER_RADIUS)]),
            gas_volume_ratio=np.ones(1),
            gas_exponent=np.array([change.get("gas_exponent", 1.0)]),
            stiffening=np.array([change.get("stiffening", 0.0)]),
            areal_weight=np.array([weight]),
            friction_coefficient=np.array([change.get("friction_coefficient", 0.0)]),
        )
        shell = ShellProperties(
            gauge_pressure=pressure,
            young_modulus=young_modulus,
            thickness=h,
            poisson_ratio=poisson_ratio,
            radius=radius,
        )
        curve = indentation_curves(
            shell, np.array([5.0, force * factor]), gas=PolytropicGas(), physics=physics, workers=1
        )
        rows.append({"label": label, "values_m": {k: float(getattr(curve, k)[0, -1]) for k in keys}})
    base = rows[0]["values_m"]
    for row in rows:
        row["change_percent"] = {k: 100 * (row["values_m"][k] / base[k] - 1) if base[k] else 0.0 for k in keys}
    return rows
