"""Dynamic scenarios from TOML configs: load, validate and run them (``shelljax simulate``).

A scenario config (docs/dynamics.md, *Scenarios*) names the object (a session, with P_g and E
from one of its estimators or given directly), the integrator, the dissipation (a measured COR
that the contact damping is calibrated to, or the damping itself), the planes, optionally held
vertices and their rotation schedule (``[prescribed]``: the hammer's swing, run once), the
initial states (one run per drop height) and the outputs. ``load_scenario`` validates it, naming the
file, the field, the value and the fix; ``run_scenario`` builds the 3D shell, calibrates the
contact damping and writes every run's ``results.json``, figures and mesh frames.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from pathlib import Path

import numpy as np

from ._errors import InvalidInputError, NoConvergenceError
from .config import ESTIMATOR_KEYS, bundled_data_dir, estimator_option_fields, estimator_settings, rig_settings
from .object_estimate import estimated_parameters

_TABLES = {
    "object": {"session", "estimate", "gauge_pressure_Pa", "youngs_modulus_Pa", "gas", "mesh", "mesh_faces", "mass_kg", "wall_density_kg_per_m3",
               "radius_m", "thickness_m", "poisson_ratio"},
    "integrator": {"scheme", "dt_s", "duration_s", "newton_step_tolerance_m"},
    "dissipation": {"cor", "calibration_bracket_N_s_per_m", "calibration_height_m", "contact_damping_N_s_per_m",
                    "rayleigh_mass_per_s", "rayleigh_stiffness_s"},
    "initial": {"drop_heights_m", "centre_m", "velocity_m_per_s"},
    "outputs": {"figures", "mesh_frames", "max_frames", "preview_gif"},
    "prescribed": {"select", "within_m", "axis_point_m", "axis_direction", "times_s", "angles_deg"},
    "estimators": ESTIMATOR_KEYS - {"methods"},  # object.estimate names the method
    "rig": {"path"},
}  # fmt: skip
_PLANE_KEYS = {"name", "point_m", "normal", "contact", "activation_distance_m", "barrier_stiffness_J_per_m2", "friction", "slip_tolerance_m"}
_TOP_KEYS = {"name", "description", "output_dir", *_TABLES, "planes"}


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
    gauge_pressure: float | None
    youngs_modulus: float | None
    gas: str
    mesh_faces: int | None
    mass: float | None
    wall_density: float | None
    radius: float | None
    thickness: float | None
    poisson_ratio: float | None
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


class _Reader:
    """Typed field access that raises InvalidInputError naming the file, field, value and fix."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, field: str, value, problem: str, fix: str) -> InvalidInputError:
        return InvalidInputError(f"{self.path}: field '{field}' = {value!r}: {problem}. Fix: {fix}")

    def number(self, table: dict, key: str, prefix: str, *, default=None, positive=False, nonnegative=False, fix=""):
        field = prefix + key
        if key not in table:
            if default is None:
                raise InvalidInputError(f"{self.path}: field '{field}' is missing. Fix: {fix or 'add it'}")
            return default
        value = table[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(field, value, "expected a finite number", fix or "write a number")
        if positive and value <= 0:
            raise self.fail(field, value, "must be > 0", fix or "give a positive value")
        if nonnegative and value < 0:
            raise self.fail(field, value, "must be ≥ 0", fix or "give a value ≥ 0")
        return float(value)

    def vector(self, table: dict, key: str, prefix: str, size: int, default=None) -> tuple[float, ...]:
        value = table.get(key, default)
        ok = isinstance(value, list) and len(value) == size and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        if not ok:
            raise self.fail(prefix + key, value, f"expected a list of {size} numbers", f"write e.g. {[0.0] * size}")
        return tuple(float(v) for v in value)

    def choice(self, table: dict, key: str, prefix: str, options, default):
        value = table.get(key, default)
        if value not in options:
            raise self.fail(prefix + key, value, "unknown value", f"use one of {', '.join(map(str, options))}")
        return value


def _table(reader: _Reader, data: dict, name: str) -> dict:
    table = data.get(name, {})
    if not isinstance(table, dict):
        raise reader.fail(name, table, "expected a table", f"write it as [{name}]")
    unknown = sorted(set(table) - _TABLES[name])
    if unknown:
        raise reader.fail(f"{name}.{unknown[0]}", table[unknown[0]], "unknown key", f"allowed keys: {', '.join(sorted(_TABLES[name]))}")
    return table


def _session_path(reader: _Reader, value, field: str = "object.session", example: str = "sessions/pezzi.toml") -> Path | None:
    if value is None:
        return None
    if not isinstance(value, str):
        raise reader.fail(field, value, "expected a path", f"write 'bundled:{example}' or a path relative to the config")
    path = bundled_data_dir() / value.removeprefix("bundled:") if value.startswith("bundled:") else reader.path.parent / value
    if not path.is_file():
        raise reader.fail(field, value, f"no such file ({path})", f"fix the path: relative to the config, or 'bundled:{example}'")
    return path


def _plane(reader: _Reader, i: int, table) -> PlaneSpec:
    prefix = f"planes[{i}]."
    if not isinstance(table, dict):
        raise reader.fail(f"planes[{i}]", table, "expected a table", "write it as [[planes]]")
    unknown = sorted(set(table) - _PLANE_KEYS)
    if unknown:
        raise reader.fail(prefix + unknown[0], table[unknown[0]], "unknown key", f"allowed keys: {', '.join(sorted(_PLANE_KEYS))}")
    reader.choice(table, "contact", prefix, ("barrier",), "barrier")
    normal = reader.vector(table, "normal", prefix, 3)
    if np.linalg.norm(normal) == 0.0:
        raise reader.fail(prefix + "normal", list(normal), "must be nonzero", "give the unit normal pointing to the free side")
    return PlaneSpec(
        name=str(table.get("name", f"plane{i}")), point=reader.vector(table, "point_m", prefix, 3), normal=normal,
        activation_distance=reader.number(table, "activation_distance_m", prefix, default=1e-3, positive=True),
        barrier_stiffness=reader.number(table, "barrier_stiffness_J_per_m2", prefix, default=1e3, positive=True),
        friction=reader.number(table, "friction", prefix, default=0.0, nonnegative=True),
        slip_tolerance=reader.number(table, "slip_tolerance_m", prefix, default=1e-4, positive=True),
    )  # fmt: skip


def _numbers(r: _Reader, table: dict, key: str, prefix: str, example: str) -> tuple[float, ...]:
    value = table.get(key)
    ok = isinstance(value, list) and len(value) >= 2 and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    if not ok:
        raise r.fail(prefix + key, value, "expected a list of at least 2 finite numbers", f"write e.g. {example}")
    return tuple(float(v) for v in value)


def _prescribed(r: _Reader, table: dict) -> PrescribedSpec:
    """The validated ``[prescribed]`` table (held vertices and their rotation schedule)."""
    p = "prescribed."
    select = table.get("select", "lowest")
    if isinstance(select, list):
        if not select or not all(isinstance(i, int) and not isinstance(i, bool) and i >= 0 for i in select) or len(set(select)) != len(select):
            raise r.fail(p + "select", select, "expected distinct vertex indices ≥ 0", 'write e.g. [0, 1, 2], or select = "lowest"')
        select = tuple(select)
    elif select != "lowest":
        raise r.fail(p + "select", select, "unknown selection", 'use "lowest" (with within_m) or a list of vertex indices')
    direction = r.vector(table, "axis_direction", p, 3)
    if np.linalg.norm(direction) == 0.0:
        raise r.fail(p + "axis_direction", list(direction), "must be nonzero", "give the rotation axis, e.g. [0.0, 1.0, 0.0]")
    times = _numbers(r, table, "times_s", p, "[0.0, 0.5, 0.8, 1.5]")
    if times[0] < 0.0 or any(b <= a for a, b in zip(times, times[1:])):
        raise r.fail(p + "times_s", list(times), "times must start at ≥ 0 s and increase strictly", "write e.g. [0.0, 0.5, 0.8, 1.5]")
    angles = _numbers(r, table, "angles_deg", p, "[0.0, -30.0, 30.0, 30.0]")
    if len(angles) != len(times):
        raise r.fail(p + "angles_deg", list(angles), f"{len(angles)} angles for {len(times)} times", "give one angle (deg) per entry of prescribed.times_s")
    return PrescribedSpec(select=select, within=r.number(table, "within_m", p, default=0.01, positive=True),
                          axis_point=r.vector(table, "axis_point_m", p, 3), axis_direction=direction, times=times, angles=angles)  # fmt: skip


def _drop_heights(r: _Reader, init: dict, held: bool) -> tuple[float, ...]:
    """The drop heights [m]; none (one run from the posed start) for a held object without them."""
    heights = init.get("drop_heights_m")
    if held:
        if heights is not None:
            raise r.fail("initial.drop_heights_m", heights, "a held object ([prescribed]) is not dropped", "remove initial.drop_heights_m: the swing runs once")
        return ()
    if not isinstance(heights, list) or not heights or not all(isinstance(h, (int, float)) and not isinstance(h, bool) for h in heights):
        raise r.fail("initial.drop_heights_m", heights, "expected a non-empty list of heights in m", "write e.g. [0.5, 1.0]")
    for h in heights:
        if not (math.isfinite(h) and h >= 0.0):
            raise r.fail("initial.drop_heights_m", heights, f"drop height {h} m is negative", "give the lowest point's height above the ground, ≥ 0 m")
    return tuple(float(h) for h in heights)


def _dissipation(r: _Reader, diss: dict):
    """(target COR or None, contact damping c [N·s/m] or None, calibration bracket [N·s/m])."""
    cor = diss.get("cor")
    damping = diss.get("contact_damping_N_s_per_m")
    if cor is not None and damping is not None:
        raise r.fail("dissipation.cor", cor, "given together with contact_damping_N_s_per_m", "give the measured COR (calibrated) or the damping, not both")
    if cor is not None:
        cor = r.number(diss, "cor", "dissipation.", positive=True)
        if cor > 1.0:
            raise r.fail("dissipation.cor", cor, "a COR is at most 1", "measure it as √(bounce height / drop height)")
    if damping is not None:
        damping = r.number(diss, "contact_damping_N_s_per_m", "dissipation.", nonnegative=True)
    bracket = r.vector(diss, "calibration_bracket_N_s_per_m", "dissipation.", 2, [0.0, 200.0])
    if not 0.0 <= bracket[0] < bracket[1]:
        raise r.fail("dissipation.calibration_bracket_N_s_per_m", list(bracket), "needs 0 ≤ low < high", "write e.g. [0.0, 200.0]")
    return cor, damping, bracket


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario TOML; InvalidInputError names the file, field, value and fix."""
    path = Path(path)
    if not path.is_file():
        raise InvalidInputError(f"{path}: no such scenario config. Fix: give the path of a TOML file, e.g. configs/drop.toml")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise InvalidInputError(f"{path}: not valid TOML ({err}). Fix: correct the syntax at that line") from err
    r = _Reader(path)
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise r.fail(unknown[0], data[unknown[0]], "unknown key", f"allowed keys: {', '.join(sorted(_TOP_KEYS))}")
    obj, integ, diss, init, outs = (_table(r, data, t) for t in ("object", "integrator", "dissipation", "initial", "outputs"))
    prescribed = _prescribed(r, _table(r, data, "prescribed")) if "prescribed" in data else None
    direct = [k for k in ("gauge_pressure_Pa", "youngs_modulus_Pa") if k in obj]
    if len(direct) == 1:
        raise r.fail(f"object.{direct[0]}", obj[direct[0]], "P_g and E are given together or not at all", "give both gauge_pressure_Pa and youngs_modulus_Pa, or neither (then they come from the session's estimate)")
    session = _session_path(r, obj.get("session"))
    if session is None and not direct:
        raise InvalidInputError(f"{path}: field 'object.session' is missing and P_g, E are not given. Fix: name a session, or give object.gauge_pressure_Pa and object.youngs_modulus_Pa")
    gas = r.choice(obj, "gas", "object.", ("prescribed", "isothermal", "adiabatic"), "adiabatic")
    # a poke is slow, so a sealed object's gas is isothermal while it is estimated, whatever its law in the impact
    estimators_table = _table(r, data, "estimators")
    rig = rig_settings(path, _table(r, data, "rig"), estimators_table)
    estimators = estimator_settings(path, {**estimators_table, **(rig[1] if rig else {})},
                                    gas="prescribed" if gas == "prescribed" else "isothermal")  # fmt: skip
    dt = r.number(integ, "dt_s", "integrator.", positive=True, fix="give the time step in s, e.g. 1e-3")
    duration = r.number(integ, "duration_s", "integrator.", positive=True, fix="give the duration in s, e.g. 1.0")
    if dt > duration:
        raise r.fail("integrator.dt_s", dt, f"longer than integrator.duration_s = {duration}", "give dt_s ≤ duration_s")
    cor, damping, bracket = _dissipation(r, diss)
    if prescribed is not None and cor is not None:
        raise r.fail("dissipation.cor", cor, "a held object is not calibrated on a free drop", "give dissipation.contact_damping_N_s_per_m instead")
    velocity = r.vector(init, "velocity_m_per_s", "initial.", 3, [0.0, 0.0, 0.0])
    if prescribed is not None and any(velocity):
        raise r.fail("initial.velocity_m_per_s", list(velocity), "a held object starts at rest (its held vertices follow the schedule)", "write [0.0, 0.0, 0.0]")
    planes = data.get("planes", [])
    if not isinstance(planes, list) or not planes:
        raise r.fail("planes", planes, "no plane to collide with", "add a [[planes]] table (the ground)")
    return Scenario(
        source=path, name=str(data.get("name", path.stem)), description=str(data.get("description", "")),
        output_dir=path.parent / str(data.get("output_dir", "runs")), session=session,
        mesh=_session_path(r, obj.get("mesh"), "object.mesh", "meshes/hammer-coarse.stl"),
        estimate=r.choice(obj, "estimate", "object.", ("closed-form", "fit", "bayes"), "fit"), estimator_options=estimator_option_fields(estimators),
        gauge_pressure=r.number(obj, "gauge_pressure_Pa", "object.", positive=True) if direct else None,
        youngs_modulus=r.number(obj, "youngs_modulus_Pa", "object.", positive=True) if direct else None,
        gas=gas,
        mesh_faces=int(r.number(obj, "mesh_faces", "object.", positive=True)) if "mesh_faces" in obj else None,
        mass=r.number(obj, "mass_kg", "object.", positive=True) if "mass_kg" in obj else None,
        wall_density=r.number(obj, "wall_density_kg_per_m3", "object.", positive=True) if "wall_density_kg_per_m3" in obj else None,
        radius=r.number(obj, "radius_m", "object.", positive=True) if "radius_m" in obj else None,
        thickness=r.number(obj, "thickness_m", "object.", positive=True) if "thickness_m" in obj else None,
        poisson_ratio=r.number(obj, "poisson_ratio", "object.", positive=True) if "poisson_ratio" in obj else None,
        scheme=r.choice(integ, "scheme", "integrator.", ("newmark", "backward-euler"), "newmark"), dt=dt, duration=duration,
        step_tolerance=r.number(integ, "newton_step_tolerance_m", "integrator.", default=1e-10, positive=True),
        cor=cor, bracket=bracket, contact_damping=damping,
        calibration_height=r.number(diss, "calibration_height_m", "dissipation.", default=1.0, positive=True),
        rayleigh=(r.number(diss, "rayleigh_mass_per_s", "dissipation.", default=0.0, nonnegative=True),
                  r.number(diss, "rayleigh_stiffness_s", "dissipation.", default=0.0, nonnegative=True)),
        planes=tuple(_plane(r, i, p) for i, p in enumerate(planes)), drop_heights=_drop_heights(r, init, prescribed is not None),
        centre=r.vector(init, "centre_m", "initial.", 2, [0.0, 0.0]), velocity=velocity, prescribed=prescribed, rig=rig[0] if rig else None,
        figures=bool(outs.get("figures", True)), mesh_frames=r.choice(outs, "mesh_frames", "outputs.", ("ply", "glb"), "ply"),
        max_frames=int(r.number(outs, "max_frames", "outputs.", default=60, nonnegative=True)), preview_gif=bool(outs.get("preview_gif", True)),
    )  # fmt: skip


@dataclasses.dataclass(frozen=True)
class ObjectModel:
    """What a scenario's object resolves to: the shell, E [Pa], ν, P_g [Pa], mass [kg], their source."""

    shell: object
    young_modulus: float
    poisson_ratio: float
    gauge_pressure: float
    mass: float | None
    wall_density: float | None
    source: dict


def resolve_object(scenario: Scenario, session_path: str | Path | None = None) -> ObjectModel:
    """The scenario's shell and parameters, from its session (or ``session_path``, which overrides it)."""
    from . import shell3d as s3
    from .dynamics import remeshed
    from .session import load_session

    path = Path(session_path) if session_path is not None else scenario.session
    session = load_session(path) if path is not None else None
    source = {"session": None if path is None else str(path)}
    if scenario.gauge_pressure is not None and session_path is None:
        p_g, e = scenario.gauge_pressure, scenario.youngs_modulus
        source["parameters"] = "given in the config"
    elif session is None:
        raise InvalidInputError(f"{scenario.source}: no session to estimate P_g and E from. Fix: set object.session or pass --session")
    else:
        p_g, e, source["estimate"] = estimated_parameters(session, scenario.estimate, scenario.estimator_options, scenario.rig)
        source["parameters"] = f"estimator '{scenario.estimate}' of {path}"
        source["estimator_options"] = {k: list(v) if isinstance(v, tuple) else v for k, v in scenario.estimator_options.items()}
    def pick(given, field, name, unit):
        value = given if given is not None else (getattr(session, field) if session is not None else None)
        if value is None:
            raise InvalidInputError(f"{scenario.source}: field 'object.{name}' is missing and no session gives it. Fix: add object.{name} ({unit}) or object.session")
        return float(value)

    thickness = pick(scenario.thickness, "thickness", "thickness_m", "m")
    nu = pick(scenario.poisson_ratio, "poisson_ratio", "poisson_ratio", "-")
    radius = pick(scenario.radius, "radius", "radius_m", "m")
    mesh_path = scenario.mesh or (getattr(session, "mesh_path", None) if session is not None else None)
    if mesh_path:
        shell = s3.load(mesh_path, thickness)
        if scenario.mesh_faces is not None and scenario.mesh_faces != shell.mesh.n_faces:
            shell = remeshed(shell, scenario.mesh_faces)
    else:
        shell = s3.ball(radius, thickness, n_triangles=scenario.mesh_faces or 2000)
    mass = scenario.mass if scenario.mass is not None else (session.mass if session is not None else None)
    if mass is None and scenario.wall_density is None:
        where = f"the session {path} has no `mass`" if session is not None else "no session gives it"
        raise InvalidInputError(f"{scenario.source}: the object's mass is missing ({where}). Fix: add object.mass_kg (kg) or object.wall_density_kg_per_m3 to the config, or `mass` to the session")
    if scenario.wall_density is not None:
        mass = None
    return ObjectModel(shell, e, nu, p_g, mass, scenario.wall_density, source)


def build_system(scenario: Scenario, obj: ObjectModel, damping: float = 0.0):
    """The scenario's :class:`shelljax.dynamics.ShellDynamicSystem` with contact damping c [N·s/m] on every plane."""
    from . import dynamics as d

    planes = [
        d.Plane(p.point, p.normal, d.BarrierContact(p.activation_distance, p.barrier_stiffness),
                friction=p.friction, slip_tolerance=p.slip_tolerance, damping=damping, name=p.name)
        for p in scenario.planes
    ]  # fmt: skip
    return d.shell_system(obj.shell, obj.young_modulus, obj.poisson_ratio, obj.gauge_pressure, gas=scenario.gas,
                          mass=obj.mass, wall_density=obj.wall_density, planes=planes)  # fmt: skip


def _integrator(scenario: Scenario):
    from . import dynamics as d

    return d.Newmark() if scenario.scheme == "newmark" else d.BackwardEuler()


def _rayleigh(scenario: Scenario):
    from . import dynamics as d

    alpha, beta = scenario.rayleigh
    return d.Rayleigh(alpha, beta) if alpha or beta else None


#: Steps per compiled chunk: one length for the calibration drops and the runs, so they share one program.
SCENARIO_CHUNK = 25


def _simulate(scenario: Scenario, system, state, duration: float, progress: bool):
    from . import dynamics as d

    try:
        return d.simulate(system, state, scenario.dt, duration, integrator=_integrator(scenario), minimiser=d.SparseNewton(step_tolerance=scenario.step_tolerance),
                          rayleigh=_rayleigh(scenario), chunk=SCENARIO_CHUNK, progress=progress)  # fmt: skip
    except NoConvergenceError as err:
        raise NoConvergenceError(f"{scenario.source}: field 'integrator.dt_s' = {scenario.dt}: {err} Fix: reduce integrator.dt_s", err.history) from err


def initial_state(scenario: Scenario, system, height: float):
    """The state dropped from ``height`` [m] (lowest point above the first plane) at the config's centre and velocity."""
    from . import dynamics as d

    x = np.asarray(system.inflated).reshape(-1, 3)
    x = x - np.array([*x.mean(axis=0)[:2], 0.0]) + np.array([*scenario.centre, 0.0])
    return d.drop_state(system, x.reshape(-1), height, velocity=list(scenario.velocity))


#: Calibration drops run this many textbook contact times π√(m / 2πR P_g), twice that if the shell has
#: not left the plane; a shell still on it then has COR 0 (an overdamped dashpot).
CALIBRATION_WINDOW = 3.0


def calibration_cor(scenario: Scenario, system, damping: float, *, progress: bool = False) -> float:
    """Height COR [-] of a ground drop from ``calibration_height`` with contact damping c [N·s/m].

    The run starts just above the plane at the impact speed √(2 g (H − g₀)) (free flight is
    integrated exactly, so skipping it changes nothing) and ends once the shell has left the
    plane; the COR is √(bounce / drop) with the drop height v_in² / 2g at contact onset, 0 if the
    shell has not left the plane after ``2 CALIBRATION_WINDOW`` textbook contact times.
    """
    from . import dynamics as d

    ground = eqx_replace_damping(system.planes[0], damping)
    one = system.with_planes([ground])
    g = float(np.linalg.norm(np.asarray(system.gravity)))
    gap0 = 2.0 * float(ground.law.contact_distance())
    speed = math.sqrt(2.0 * g * max(scenario.calibration_height - gap0, 0.0))
    x = np.asarray(one.inflated)
    state = d.drop_state(one, x, gap0, velocity=list(-speed * np.asarray(ground.normal)))
    mass = float(np.sum(np.asarray(one.node_masses)))
    radius = (3.0 * float(one.volume(one.inflated)) / (4.0 * math.pi)) ** (1.0 / 3.0)
    textbook = d.pressurized_ball_contact_time(mass, radius, float(one.params.gauge_pressure))
    # The shell's contact outlasts the textbook spring's (docs/dynamics.md): widen the window once.
    for window in (CALIBRATION_WINDOW * textbook + 4.0 * scenario.dt, 2.0 * CALIBRATION_WINDOW * textbook + 4.0 * scenario.dt):
        impacts = d.measured_cor(_simulate(scenario, one, state, window, progress))
        if impacts:
            break
    else:
        return 0.0  # still on the plane: the dashpot is overdamped and nothing bounces
    first = impacts[0]
    return math.sqrt(max(first.bounce_height_m, 0.0) / (first.speed_in_m_per_s**2 / (2.0 * g)))


def eqx_replace_damping(plane, damping: float):
    """``plane`` with contact damping c [N·s/m]."""
    import equinox as eqx

    return eqx.tree_at(lambda p: p.damping, plane, np.asarray(float(damping)))


def _check_time_step(scenario: Scenario, system) -> None:
    """Raise InvalidInputError when Δt cannot resolve the contact: ≥ 10 steps per textbook contact time."""
    from . import dynamics as d

    mass = float(np.sum(np.asarray(system.node_masses)))
    radius = (3.0 * float(system.volume(system.inflated)) / (4.0 * math.pi)) ** (1.0 / 3.0)
    contact = d.pressurized_ball_contact_time(mass, radius, float(system.params.gauge_pressure))
    if scenario.dt > contact / 10.0:
        raise InvalidInputError(
            f"{scenario.source}: field 'integrator.dt_s' = {scenario.dt}: too large to resolve a contact of about "
            f"{1e3 * contact:.3g} ms (π√(m / 2πR P_g)); the step would not converge or would miss the impact. "
            f"Fix: use integrator.dt_s ≤ {contact / 10.0:.2g} s"
        )


def held_vertices(scenario: Scenario, system) -> np.ndarray:
    """Indices of the vertices ``[prescribed]`` holds: its list, or those within ``within_m`` [m] of the lowest point along gravity."""
    spec = scenario.prescribed
    x = np.asarray(system.inflated).reshape(-1, 3)
    if spec.select == "lowest":
        down = np.asarray(system.gravity) / np.linalg.norm(np.asarray(system.gravity))
        depth = x @ down
        held = np.flatnonzero(depth >= depth.max() - spec.within)
        if held.size < 3:
            raise InvalidInputError(
                f"{scenario.source}: field 'prescribed.within_m' = {spec.within}: selects {held.size} vertex(es) of the "
                f"{len(x)}-vertex mesh; fewer than 3 leave the body free to pivot about them. Fix: raise prescribed.within_m"
            )
        return held
    held = np.asarray(spec.select, dtype=int)
    if held.max() >= len(x):
        raise InvalidInputError(
            f"{scenario.source}: field 'prescribed.select' = {list(spec.select)}: vertex {int(held.max())} is not in the "
            f"{len(x)}-vertex mesh. Fix: give indices below {len(x)}, or select = \"lowest\""
        )
    return held


def hold(scenario: Scenario, system):
    """``system`` with its ``[prescribed]`` vertices turned on the schedule (angles in rad), from the inflated shape."""
    spec, held = scenario.prescribed, held_vertices(scenario, system)
    return system.with_prescribed(held, spec.axis_point, spec.axis_direction, spec.times, np.radians(spec.angles))


def _swing(scenario: Scenario, system, out: Path, progress: bool) -> dict:
    """Run a held object once from its posed start into ``out``/swing; what the run shows."""
    from . import dynamics as d

    trajectory = _simulate(scenario, system, d.initial_state(system, system.posed(0.0)), scenario.duration, progress)
    run_dir = out / "swing"
    d.write_results(trajectory, run_dir, max_frames=scenario.max_frames, mesh_format=scenario.mesh_frames,
                    figures=scenario.figures, preview_gif=scenario.preview_gif)  # fmt: skip
    positions, times = trajectory["position_m"], trajectory["time_s"]
    held = np.asarray(system.prescribed_vertices)
    rigid = np.stack([np.asarray(system.posed(t)) for t in times])
    schedule = np.stack([np.asarray(system.prescribed_positions(t)) for t in times])
    deviation = np.linalg.norm((positions - rigid).reshape(len(times), -1, 3), axis=2).max(axis=1)
    force = np.linalg.norm(trajectory["contact_force_N"], axis=2)
    return {
        "directory": str(run_dir), "held_vertices": held.tolist(),
        "held_error_m": float(np.max(np.abs(positions.reshape(len(times), -1, 3)[:, held].reshape(len(times), -1) - schedule))),
        "max_deviation_from_rigid_m": float(deviation.max()), "time_of_max_deviation_s": float(times[np.argmax(deviation)]),
        "peak_gas_pressure_Pa": float(np.max(trajectory["gas_pressure_Pa"])), "time_of_peak_pressure_s": float(times[np.argmax(trajectory["gas_pressure_Pa"])]),
        "planes": {name: {"min_gap_m": float(np.min(trajectory["min_gap_m"][:, i])), "peak_force_N": float(np.max(force[:, i])),
                          "first_contact_s": _first_contact(trajectory, i)} for i, name in enumerate(trajectory.plane_names)},
        "impacts": [m.to_dict() for m in d.measured_cor(trajectory)],
    }  # fmt: skip


def _first_contact(trajectory, plane: int) -> float | None:
    """Time [s] at which a contact point first comes within the plane's contact distance (None if never)."""
    near = np.flatnonzero(trajectory["min_gap_m"][:, plane] < trajectory.contact_distances_m[plane])
    return float(trajectory["time_s"][near[0]]) if near.size else None


def run_scenario(scenario: Scenario, out_dir: str | Path | None = None, *, session: str | Path | None = None, progress: bool = True) -> dict:
    """Run every drop of ``scenario`` into ``out_dir`` (default: its output_dir/name); the summary it writes.

    Writes ``scenario.json`` (parameters, calibration, every run's impacts) and per drop height a
    directory ``h<H>m/`` with ``results.json``, figures, mesh frames and ``preview.gif``; a held
    object (``[prescribed]``) runs once into ``swing/``.
    """
    from . import dynamics as d

    out = Path(out_dir) if out_dir is not None else scenario.output_dir / scenario.name
    obj = resolve_object(scenario, session)
    system = build_system(scenario, obj)
    if scenario.prescribed is not None:
        system = hold(scenario, system)
    _check_time_step(scenario, system)
    out.mkdir(parents=True, exist_ok=True)  # only once the config is accepted: a refused one leaves nothing
    calibration = None
    damping = scenario.contact_damping or 0.0
    if scenario.cor is not None:
        def cor(c):
            value = calibration_cor(scenario, system, c, progress=progress)
            if progress:
                print(f"  calibration: contact damping c = {c:.4g} N·s/m → COR {value:.4f} (target {scenario.cor})", flush=True)
            return value

        cal = d.calibrate_contact_damping(cor, scenario.cor, scenario.bracket, rtol=1e-2)
        damping = cal.damping
        calibration = {"target_cor": scenario.cor, "damping_N_s_per_m": cal.damping, "cor": cal.cor, "evaluations": [list(e) for e in cal.evaluations]}
    system = system.with_planes([eqx_replace_damping(p, damping) for p in system.planes])
    runs = []
    for h in scenario.drop_heights:
        trajectory = _simulate(scenario, system, initial_state(scenario, system, h), scenario.duration, progress)
        run_dir = out / f"h{h:.2f}m"
        d.write_results(trajectory, run_dir, max_frames=scenario.max_frames, mesh_format=scenario.mesh_frames,
                        figures=scenario.figures, preview_gif=scenario.preview_gif)  # fmt: skip
        runs.append({"drop_height_m": h, "directory": str(run_dir), "impacts": [m.to_dict() for m in d.measured_cor(trajectory)]})
    if scenario.prescribed is not None:
        runs.append(_swing(scenario, system, out, progress))
    summary = {
        "scenario": str(scenario.source), "name": scenario.name, "object": obj.source,
        "parameters": {"gauge_pressure_Pa": obj.gauge_pressure, "youngs_modulus_Pa": obj.young_modulus, "poisson_ratio": obj.poisson_ratio,
                       "thickness_m": obj.shell.thickness, "mass_kg": float(np.sum(np.asarray(system.node_masses))), "gas": scenario.gas,
                       "mesh_faces": int(obj.shell.mesh.n_faces), "dt_s": scenario.dt, "scheme": scenario.scheme},
        "contact_damping_N_s_per_m": damping, "calibration": calibration, "runs": runs,
    }  # fmt: skip
    (out / "scenario.json").write_text(json.dumps(summary, indent=1))
    return summary
