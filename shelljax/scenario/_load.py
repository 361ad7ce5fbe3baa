"""Scenario configs (docs/dynamics.md, *Scenarios*): read and validate one into a :class:`Scenario`.

A scenario names the object (a session, with P_g and E from one of its estimators or given
directly), the integrator, the dissipation (a measured COR that the contact damping is calibrated
to, or the damping itself), the planes, optionally held vertices and their rotation schedule
(``[prescribed]``: the hammer's swing, run once), the initial states (one run per drop height) and
the outputs; optionally a ``[sweep]`` over one of ``SWEEP_PARAMETERS`` (one whole scenario per
value, ``_sweep``). Every refusal names the file, the field, the value and the fix.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from .._errors import InvalidInputError
from .._toml import TomlReader, read_toml
from ..config import COMPUTE_KEYS, ESTIMATOR_KEYS, bundled_data_dir, compute_device, estimator_settings, rig_settings
from ..estimate import METHODS, EstimatorOptions
from ..physics import GAS_LAWS, ShellProperties, gas_law

_TABLES = {
    "object": {
        "session",
        "estimate",
        "gauge_pressure_Pa",
        "youngs_modulus_Pa",
        "gas",
        "mesh",
        "mesh_faces",
        "mass_kg",
        "wall_density_kg_per_m3",
        "radius_m",
        "thickness_m",
        "poisson_ratio",
    },
    "integrator": {"scheme", "dt_s", "duration_s", "newton_step_tolerance_m"},
    "dissipation": {
        "cor",
        "calibration_bracket_N_s_per_m",
        "calibration_height_m",
        "contact_damping_N_s_per_m",
        "rayleigh_mass_per_s",
        "rayleigh_stiffness_s",
    },
    "initial": {"drop_heights_m", "centre_m", "velocity_m_per_s"},
    "outputs": {"figures", "mesh_frames", "max_frames", "preview_gif"},
    "prescribed": {"select", "within_m", "axis_point_m", "axis_direction", "times_s", "angles_deg"},
    "estimators": ESTIMATOR_KEYS - {"methods"},  # object.estimate names the method
    "rig": {"path"},
    "compute": COMPUTE_KEYS,
}
#: ``integrator.scheme`` values: ``shelljax.dynamics`` Newmark(), BackwardEuler(), TRBDF2() (docs/dynamics.md).
SCHEMES = ("newmark", "backward-euler", "tr-bdf2")
_PLANE_KEYS = {
    "name",
    "point_m",
    "normal",
    "contact",
    "activation_distance_m",
    "barrier_stiffness_J_per_m2",
    "friction",
    "slip_tolerance_m",
}
_TOP_KEYS = {"name", "description", "output_dir", *_TABLES, "planes", "sweep"}
#: ``[sweep] parameter`` values: the scalar fields a sweep may vary, one whole scenario per value
#: (a drop height becomes that scenario's only one).
SWEEP_PARAMETERS = (
    "object.gauge_pressure_Pa",
    "object.youngs_modulus_Pa",
    "object.mass_kg",
    "object.thickness_m",
    "object.mesh_faces",
    "dissipation.cor",
    "dissipation.contact_damping_N_s_per_m",
    "integrator.dt_s",
    "initial.drop_heights_m",
)


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    """The ``[sweep]`` table: ``parameter`` (one of ``SWEEP_PARAMETERS``, "table.key", in that
    field's SI unit) and its ``values``, one scenario run per value."""

    parameter: str
    values: tuple[float, ...]


@dataclasses.dataclass(frozen=True)
class PlaneSpec:
    """One ``[[planes]]`` table: point [m], unit normal, barrier ĝ [m] and κ [J/m²], μ [-], ε [m]."""

    name: str
    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    activation_distance: float
    barrier_stiffness: float
    friction: float
    slip_tolerance: float


@dataclasses.dataclass(frozen=True)
class PrescribedSpec:
    """The ``[prescribed]`` table: held vertices (``"lowest"``: within ``within`` [m] of the lowest
    point along gravity; or explicit indices) turned about the axis through ``axis_point`` [m]
    along ``axis_direction`` by ``angles`` [deg] at ``times`` [s]."""

    select: str | tuple[int, ...]
    within: float
    axis_point: tuple[float, float, float]
    axis_direction: tuple[float, float, float]
    times: tuple[float, ...]
    angles: tuple[float, ...]


@dataclasses.dataclass(frozen=True)
class Scenario:
    """A validated scenario config (SI units; see the module docstring)."""

    source: Path
    name: str
    description: str
    output_dir: Path
    session: Path | None
    mesh: Path | None
    estimate: str
    estimator_options: dict  # EstimatorOptions keyword arguments, from [estimators]
    properties: ShellProperties  # P_g [Pa], E [Pa], h [m], ν [-], R [m] as given (None: from the session)
    gas: str
    mesh_faces: int | None
    mass: float | None
    wall_density: float | None
    scheme: str
    dt: float
    duration: float
    step_tolerance: float
    cor: float | None
    bracket: tuple[float, float]
    calibration_height: float
    contact_damping: float | None
    rayleigh: tuple[float, float]
    planes: tuple[PlaneSpec, ...]
    drop_heights: tuple[float, ...]
    centre: tuple[float, float]
    velocity: tuple[float, float, float]
    figures: bool
    mesh_frames: str
    max_frames: int
    preview_gif: bool
    prescribed: PrescribedSpec | None = None
    rig: Path | None = None  # fit and bayes estimate through this rig (shelljax.rig)
    sweep: SweepSpec | None = None  # one scenario per value (scenario._sweep); None: this one scenario
    device: str = "auto"  # [compute] device: where its stages run (shelljax.Placement, docs/gpu.md)


def _table(reader: TomlReader, data: dict, name: str) -> dict:
    return reader.table(data, name, _TABLES[name]) or {}


def _option_fields(options: EstimatorOptions) -> dict:
    """``options`` as EstimatorOptions keyword arguments, all but ``k_s`` and ``seed`` (what a scenario records)."""
    return {f.name: getattr(options, f.name) for f in dataclasses.fields(options) if f.name not in ("k_s", "seed")}


def _session_path(
    reader: TomlReader, value, field: str = "object.session", example: str = "sessions/pezzi.toml"
) -> Path | None:
    if value is None:
        return None
    if not isinstance(value, str):
        raise reader.fail(
            field, "expected a path", f"write 'bundled:{example}' or a path relative to the config", value=value
        )
    path = (
        bundled_data_dir() / value.removeprefix("bundled:")
        if value.startswith("bundled:")
        else reader.path.parent / value
    )
    if not path.is_file():
        raise reader.fail(
            field,
            f"no such file ({path})",
            f"fix the path: relative to the config, or 'bundled:{example}'",
            value=value,
        )
    return path


def _plane(reader: TomlReader, i: int, table) -> PlaneSpec:
    prefix = reader.entry(table, "planes", i, _PLANE_KEYS)
    reader.choice(table, "contact", prefix, ("barrier",), "barrier")
    normal = reader.direction(table, "normal", prefix, fix="give the unit normal pointing to the free side")
    return PlaneSpec(
        name=str(table.get("name", f"plane{i}")),
        point=reader.vector(table, "point_m", prefix, 3),
        normal=normal,
        activation_distance=reader.number(table, "activation_distance_m", prefix, default=1e-3, positive=True),
        barrier_stiffness=reader.number(table, "barrier_stiffness_J_per_m2", prefix, default=1e3, positive=True),
        friction=reader.number(table, "friction", prefix, default=0.0, nonnegative=True),
        slip_tolerance=reader.number(table, "slip_tolerance_m", prefix, default=1e-4, positive=True),
    )


def _numbers(r: TomlReader, table: dict, key: str, prefix: str, example: str) -> tuple[float, ...]:
    value = table.get(key)
    ok = (
        isinstance(value, list)
        and len(value) >= 2
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    )
    if not ok:
        raise r.fail(prefix + key, "expected a list of at least 2 finite numbers", f"write e.g. {example}", value=value)
    return tuple(float(v) for v in value)


def _prescribed(r: TomlReader, table: dict) -> PrescribedSpec:
    """The validated ``[prescribed]`` table (held vertices and their rotation schedule)."""
    p = "prescribed."
    select = table.get("select", "lowest")
    if isinstance(select, list):
        if (
            not select
            or not all(isinstance(i, int) and not isinstance(i, bool) and i >= 0 for i in select)
            or len(set(select)) != len(select)
        ):
            raise r.fail(
                p + "select",
                "expected distinct vertex indices ≥ 0",
                'write e.g. [0, 1, 2], or select = "lowest"',
                value=select,
            )
        select = tuple(select)
    elif select != "lowest":
        raise r.fail(
            p + "select", "unknown selection", 'use "lowest" (with within_m) or a list of vertex indices', value=select
        )
    direction = r.direction(table, "axis_direction", p, fix="give the rotation axis, e.g. [0.0, 1.0, 0.0]")
    times = _numbers(r, table, "times_s", p, "[0.0, 0.5, 0.8, 1.5]")
    if times[0] < 0.0 or any(b <= a for a, b in zip(times, times[1:])):
        raise r.fail(
            p + "times_s",
            "times must start at ≥ 0 s and increase strictly",
            "write e.g. [0.0, 0.5, 0.8, 1.5]",
            value=list(times),
        )
    angles = _numbers(r, table, "angles_deg", p, "[0.0, -30.0, 30.0, 30.0]")
    if len(angles) != len(times):
        raise r.fail(
            p + "angles_deg",
            f"{len(angles)} angles for {len(times)} times",
            "give one angle (deg) per entry of prescribed.times_s",
            value=list(angles),
        )
    return PrescribedSpec(
        select=select,
        within=r.number(table, "within_m", p, default=0.01, positive=True),
        axis_point=r.vector(table, "axis_point_m", p, 3),
        axis_direction=direction,
        times=times,
        angles=angles,
    )


def _drop_heights(r: TomlReader, init: dict, held: bool) -> tuple[float, ...]:
    """The drop heights [m]; none (one run from the posed start) for a held object without them."""
    heights = init.get("drop_heights_m")
    if held:
        if heights is not None:
            raise r.fail(
                "initial.drop_heights_m",
                "a held object ([prescribed]) is not dropped",
                "remove initial.drop_heights_m: the swing runs once",
                value=heights,
            )
        return ()
    if (
        not isinstance(heights, list)
        or not heights
        or not all(isinstance(h, (int, float)) and not isinstance(h, bool) for h in heights)
    ):
        raise r.fail(
            "initial.drop_heights_m",
            "expected a non-empty list of heights in m",
            "write e.g. [0.5, 1.0]",
            value=heights,
        )
    for h in heights:
        if not (math.isfinite(h) and h >= 0.0):
            raise r.fail(
                "initial.drop_heights_m",
                f"drop height {h} m is negative",
                "give the lowest point's height above the ground, ≥ 0 m",
                value=heights,
            )
    return tuple(float(h) for h in heights)


def _dissipation(r: TomlReader, diss: dict):
    """(target COR or None, contact damping c [N·s/m] or None, calibration bracket [N·s/m])."""
    cor = diss.get("cor")
    damping = diss.get("contact_damping_N_s_per_m")
    if cor is not None and damping is not None:
        raise r.fail(
            "dissipation.cor",
            "given together with contact_damping_N_s_per_m",
            "give the measured COR (calibrated) or the damping, not both",
            value=cor,
        )
    if cor is not None:
        cor = r.number(diss, "cor", "dissipation.", positive=True)
        if cor > 1.0:
            raise r.fail(
                "dissipation.cor", "a COR is at most 1", "measure it as √(bounce height / drop height)", value=cor
            )
    if damping is not None:
        damping = r.number(diss, "contact_damping_N_s_per_m", "dissipation.", nonnegative=True)
    bracket = r.vector(diss, "calibration_bracket_N_s_per_m", "dissipation.", 2, [0.0, 200.0])
    if not 0.0 <= bracket[0] < bracket[1]:
        raise r.fail(
            "dissipation.calibration_bracket_N_s_per_m",
            "needs 0 ≤ low < high",
            "write e.g. [0.0, 200.0]",
            value=list(bracket),
        )
    return cor, damping, bracket


def _swept(data: dict, parameter: str, value: float) -> dict:
    """``data`` without its [sweep] table and with ``parameter`` ("table.key") set to ``value``."""
    table, key = parameter.split(".")
    field = [value] if parameter == "initial.drop_heights_m" else (int(value) if key == "mesh_faces" else value)
    if key == "contact_damping_N_s_per_m":  # the swept damping replaces a calibration to a COR
        data = {**data, table: {k: v for k, v in data.get(table, {}).items() if k != "cor"}}
    if key == "cor":
        data = {**data, table: {k: v for k, v in data.get(table, {}).items() if k != "contact_damping_N_s_per_m"}}
    return {**{k: v for k, v in data.items() if k != "sweep"}, table: {**data.get(table, {}), key: field}}


def _sweep(r: TomlReader, data: dict) -> SweepSpec | None:
    """The validated ``[sweep]`` table, each value checked as its own scenario; None without one."""
    if "sweep" not in data:
        return None
    table = r.table(data, "sweep", {"parameter", "values"})
    parameter = r.choice(table, "parameter", "sweep.", SWEEP_PARAMETERS, what="sweep parameter")
    values = table.get("values")
    if (
        not isinstance(values, list)
        or not values
        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values)
    ):
        raise r.fail(
            "sweep.values",
            "expected a non-empty list of finite numbers",
            "write e.g. values = [0.5, 1.0, 1.5]",
            value=values,
        )
    if len(set(values)) != len(values):
        raise r.fail("sweep.values", "a value is repeated", "list each value once", value=values)
    if parameter == "initial.drop_heights_m" and "prescribed" in data:
        raise r.fail(
            "sweep.parameter", "a held object ([prescribed]) is not dropped", "sweep another parameter", value=parameter
        )
    for value in values:
        _validated(r.path, _swept(data, parameter, float(value)), r)
    return SweepSpec(parameter=parameter, values=tuple(float(v) for v in values))


def load_scenario(path: str | Path, *, value: float | None = None) -> Scenario:
    """Read and validate a scenario TOML; InvalidInputError names the file, field, value and fix.

    ``value``: the scenario of one value of its ``[sweep]`` (the parameter set to it, no sweep left).
    """
    path = Path(path)
    data = read_toml(
        path,
        "scenario config",
        fix_missing="give the path of a TOML file, e.g. configs/drop.toml",
        fix_syntax="correct the syntax at that line",
    )
    r = TomlReader(path, doc="docs/dynamics.md")
    r.no_unknown_keys(data, _TOP_KEYS)
    sweep = _sweep(r, data)
    if value is None:
        return dataclasses.replace(_validated(path, data, r), sweep=sweep)
    if sweep is None:
        raise InvalidInputError(
            f"{path}: a sweep value ({value}) was asked for but the config has no [sweep] table. "
            'Fix: add [sweep] parameter = "..." and values = [...]'
        )
    return _validated(path, _swept(data, sweep.parameter, float(value)), r)


def _object_source(r: TomlReader, obj: dict) -> tuple[Path | None, bool]:
    """The object's session path (or None) and whether P_g and E are given directly (both or neither)."""
    direct = [k for k in ("gauge_pressure_Pa", "youngs_modulus_Pa") if k in obj]
    if len(direct) == 1:
        raise r.fail(
            f"object.{direct[0]}",
            "P_g and E are given together or not at all",
            "give both gauge_pressure_Pa and youngs_modulus_Pa, or neither (then they come from the session's estimate)",
            value=obj[direct[0]],
        )
    session = _session_path(r, obj.get("session"))
    if session is None and not direct:
        raise r.fail(
            "object.session",
            "missing and P_g, E are not given",
            "name a session, or give object.gauge_pressure_Pa and object.youngs_modulus_Pa",
        )
    return session, bool(direct)


def _properties(r: TomlReader, obj: dict, direct: bool) -> ShellProperties:
    """The object's properties as the config gives them (the documented ``youngs_modulus_Pa`` key is
    E); None where the session or its estimate gives them."""
    return ShellProperties(
        gauge_pressure=r.number(obj, "gauge_pressure_Pa", "object.", positive=True) if direct else None,
        young_modulus=r.number(obj, "youngs_modulus_Pa", "object.", positive=True) if direct else None,
        thickness=r.number(obj, "thickness_m", "object.", default=None, positive=True),
        poisson_ratio=r.number(obj, "poisson_ratio", "object.", default=None, positive=True),
        radius=r.number(obj, "radius_m", "object.", default=None, positive=True),
    )


def _time_span(r: TomlReader, integ: dict) -> tuple[float, float]:
    """The integrator's time step and duration [s], the step no longer than the duration."""
    dt = r.number(integ, "dt_s", "integrator.", positive=True, fix="give the time step in s, e.g. 1e-3")
    duration = r.number(integ, "duration_s", "integrator.", positive=True, fix="give the duration in s, e.g. 1.0")
    if dt > duration:
        raise r.fail(
            "integrator.dt_s", f"longer than integrator.duration_s = {duration}", "give dt_s ≤ duration_s", value=dt
        )
    return dt, duration


def _held_object_checked(r: TomlReader, init: dict, prescribed, cor) -> tuple[float, float, float]:
    """The initial velocity [m/s]; a held object (``prescribed``) is neither calibrated nor thrown."""
    if prescribed is not None and cor is not None:
        raise r.fail(
            "dissipation.cor",
            "a held object is not calibrated on a free drop",
            "give dissipation.contact_damping_N_s_per_m instead",
            value=cor,
        )
    velocity = r.vector(init, "velocity_m_per_s", "initial.", 3, [0.0, 0.0, 0.0])
    if prescribed is not None and any(velocity):
        raise r.fail(
            "initial.velocity_m_per_s",
            "a held object starts at rest (its held vertices follow the schedule)",
            "write [0.0, 0.0, 0.0]",
            value=list(velocity),
        )
    return velocity


def _validated(path: Path, data: dict, r: TomlReader) -> Scenario:
    """The :class:`Scenario` of a parsed config (its [sweep] table, if any, left to :func:`_sweep`)."""
    obj, integ, diss, init, outs = (
        _table(r, data, t) for t in ("object", "integrator", "dissipation", "initial", "outputs")
    )
    prescribed = _prescribed(r, _table(r, data, "prescribed")) if "prescribed" in data else None
    session, direct = _object_source(r, obj)
    gas = r.choice(obj, "gas", "object.", GAS_LAWS, "adiabatic")
    # a poke is slow, so a sealed object's gas is isothermal while it is estimated, whatever its law in the impact
    estimators_table = _table(r, data, "estimators")
    rig = rig_settings(path, _table(r, data, "rig"), estimators_table)
    _, estimators = estimator_settings(
        path, {**estimators_table, **(rig[1] if rig else {})}, gas="isothermal" if gas_law(gas).sealed else "prescribed"
    )
    dt, duration = _time_span(r, integ)
    cor, damping, bracket = _dissipation(r, diss)
    velocity = _held_object_checked(r, init, prescribed, cor)
    planes = data.get("planes", [])
    if not isinstance(planes, list) or not planes:
        raise r.fail("planes", "no plane to collide with", "add a [[planes]] table (the ground)", value=planes)
    return Scenario(
        source=path,
        name=str(data.get("name", path.stem)),
        description=str(data.get("description", "")),
        output_dir=path.parent / str(data.get("output_dir", "runs")),
        session=session,
        mesh=_session_path(r, obj.get("mesh"), "object.mesh", "meshes/hammer-coarse.stl"),
        estimate=r.choice(obj, "estimate", "object.", METHODS, "fit"),
        estimator_options=_option_fields(estimators),
        properties=_properties(r, obj, direct),
        gas=gas,
        mesh_faces=int(r.number(obj, "mesh_faces", "object.", positive=True)) if "mesh_faces" in obj else None,
        mass=r.number(obj, "mass_kg", "object.", default=None, positive=True),
        wall_density=r.number(obj, "wall_density_kg_per_m3", "object.", default=None, positive=True),
        scheme=r.choice(integ, "scheme", "integrator.", SCHEMES, "newmark", what="scheme"),
        dt=dt,
        duration=duration,
        step_tolerance=r.number(integ, "newton_step_tolerance_m", "integrator.", default=1e-10, positive=True),
        cor=cor,
        bracket=bracket,
        contact_damping=damping,
        calibration_height=r.number(diss, "calibration_height_m", "dissipation.", default=1.0, positive=True),
        rayleigh=(
            r.number(diss, "rayleigh_mass_per_s", "dissipation.", default=0.0, nonnegative=True),
            r.number(diss, "rayleigh_stiffness_s", "dissipation.", default=0.0, nonnegative=True),
        ),
        planes=tuple(_plane(r, i, p) for i, p in enumerate(planes)),
        drop_heights=_drop_heights(r, init, prescribed is not None),
        centre=r.vector(init, "centre_m", "initial.", 2, [0.0, 0.0]),
        velocity=velocity,
        prescribed=prescribed,
        rig=rig[0] if rig else None,
        figures=bool(outs.get("figures", True)),
        mesh_frames=r.choice(outs, "mesh_frames", "outputs.", ("ply", "glb"), "ply"),
        max_frames=int(r.number(outs, "max_frames", "outputs.", default=60, nonnegative=True)),
        preview_gif=bool(outs.get("preview_gif", True)),
        device=compute_device(path, _table(r, data, "compute")),
    )
