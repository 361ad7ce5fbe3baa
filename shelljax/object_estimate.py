"""P_g and E of one object for what is built on it (a replica, a scenario), through a rig or not."""

from __future__ import annotations

from pathlib import Path

from ._errors import InvalidInputError


def estimated_parameters(
    session, method: str, options: dict, rig: str | Path | None = None
) -> tuple[float, float, dict]:
    """(P_g [Pa], E [Pa], their values and standard deviations) from the session's ``method`` estimate
    with ``options`` (EstimatorOptions keyword arguments); with ``rig`` (a rig file), fit and bayes go
    through it (``shelljax.rig``), whose gas and wrinkle law ``options`` must not contradict."""
    from .estimate import EstimatorOptions, run_estimator

    if rig is not None and method != "closed-form":
        from .rig import estimate_with_rig, load_rig

        result = estimate_with_rig(
            session, load_rig(rig), method=method, gas=options.get("gas"), wrinkle_law=options.get("wrinkle_law")
        )
    else:
        result = run_estimator(method, session, EstimatorOptions(**options), progress=False)
    missing = [k for k in ("gauge_pressure", "young_modulus") if k not in result.estimates]
    if missing:
        raise InvalidInputError(
            f"{session.source}: the '{method}' estimator gives no {', '.join(missing)}. Fix: use object.estimate = \"fit\" or give "
            "object.gauge_pressure_Pa and object.youngs_modulus_Pa"
        )
    p, e = result.estimates["gauge_pressure"], result.estimates["young_modulus"]
    out = {"gauge_pressure_Pa": {"value": p.value, "std": p.std}, "youngs_modulus_Pa": {"value": e.value, "std": e.std}}
    if rig is not None and method != "closed-form":
        out["rig"] = str(rig)
    return p.value, e.value, out
