"""Running a :class:`Scenario` (``shelljax simulate``): build the 3D shell, calibrate the contact
damping to the measured COR and write every run's ``results.json``, figures and mesh frames."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import equinox as eqx
import numpy as np

from .. import dynamics as d
from .. import shell3d as s3
from .._errors import InvalidInputError, NoConvergenceError
from .._files import atomic_write_text, check_output_dir
from .._placement import Placement, StageKind, current_device, is_accelerator, requested_placement, to_device
from ..object_estimate import estimated_parameters
from ..physics import ShellProperties, gas_law
from ..report import write_scenario_report
from ..runner import stage
from ..session import load_session
from . import _figures
from ._load import Scenario


@dataclasses.dataclass(frozen=True)
class ObjectModel:
    """What a scenario's object resolves to: the shell, its ``properties`` (P_g [Pa], E [Pa], the
    shell's h [m], ν [-], R [m]), the mass [kg] (or wall density [kg/m³]) and their source."""

    shell: object
    properties: ShellProperties
    mass: float | None
    wall_density: float | None
    source: dict


def resolve_object(scenario: Scenario, session_path: str | Path | None = None) -> ObjectModel:
    """The scenario's shell and parameters, from its session (or ``session_path``, which overrides it)."""

    path = Path(session_path) if session_path is not None else scenario.session
    session = load_session(path) if path is not None else None
    source = {"session": None if path is None else str(path)}
    given = scenario.properties
    if given.gauge_pressure is not None and session_path is None:
        p_g, e = given.gauge_pressure, given.young_modulus
        source["parameters"] = "given in the config"
    elif session is None:
        raise InvalidInputError(
            f"{scenario.source}: no session to estimate P_g and E from. Fix: set object.session or pass --session"
        )
    else:
        p_g, e, source["estimate"] = estimated_parameters(
            session, scenario.estimate, scenario.estimator_options, scenario.rig
        )
        source["parameters"] = f"estimator '{scenario.estimate}' of {path}"
        source["estimator_options"] = {
            k: list(v) if isinstance(v, tuple) else v for k, v in scenario.estimator_options.items()
        }

    def pick(given, field, name, unit):
        value = given if given is not None else (getattr(session, field) if session is not None else None)
        if value is None:
            raise InvalidInputError(
                f"{scenario.source}: field 'object.{name}' is missing and no session gives it. Fix: add object.{name} ({unit}) or object.session"
            )
        return float(value)

    thickness = pick(given.thickness, "thickness", "thickness_m", "m")
    nu = pick(given.poisson_ratio, "poisson_ratio", "poisson_ratio", "-")
    radius = pick(given.radius, "radius", "radius_m", "m")
    mesh_path = scenario.mesh or (getattr(session, "mesh_path", None) if session is not None else None)
    if mesh_path:
        shell = s3.load(mesh_path, thickness)
        if scenario.mesh_faces is not None and scenario.mesh_faces != shell.mesh.n_faces:
            shell = d.remeshed(shell, scenario.mesh_faces)
    else:
        shell = s3.ball(radius, thickness, n_triangles=scenario.mesh_faces or 2000)
    mass = scenario.mass if scenario.mass is not None else (session.mass if session is not None else None)
    if mass is None and scenario.wall_density is None:
        where = f"the session {path} has no `mass`" if session is not None else "no session gives it"
        raise InvalidInputError(
            f"{scenario.source}: the object's mass is missing ({where}). Fix: add object.mass_kg (kg) or object.wall_density_kg_per_m3 to the config, or `mass` to the session"
        )
    if scenario.wall_density is not None:
        mass = None
    properties = ShellProperties(
        gauge_pressure=p_g, young_modulus=e, thickness=shell.thickness, poisson_ratio=nu, radius=radius
    )
    return ObjectModel(shell, properties, mass, scenario.wall_density, source)


def build_system(scenario: Scenario, obj: ObjectModel, damping: float = 0.0):
    """The scenario's :class:`shelljax.dynamics.ShellDynamicSystem` with contact damping c [N·s/m] on every plane."""
    planes = [
        d.Plane(
            p.point,
            p.normal,
            d.BarrierContact(p.activation_distance, p.barrier_stiffness),
            friction=p.friction,
            slip_tolerance=p.slip_tolerance,
            damping=damping,
            name=p.name,
        )
        for p in scenario.planes
    ]
    return d.shell_system(
        obj.shell,
        obj.properties,
        gas=gas_law(scenario.gas),
        mass=obj.mass,
        wall_density=obj.wall_density,
        planes=planes,
    )


def _integrator(scenario: Scenario):
    return {"newmark": d.Newmark, "backward-euler": d.BackwardEuler, "tr-bdf2": d.TRBDF2}[scenario.scheme]()


def _rayleigh(scenario: Scenario):
    alpha, beta = scenario.rayleigh
    return d.Rayleigh(alpha, beta) if alpha or beta else None


#: Steps per compiled chunk: one length for the calibration drops and the runs, so they share one program.
SCENARIO_CHUNK = 25


def _minimiser(scenario: Scenario) -> d.AbstractMinimiser:
    """The Newton minimiser of the stage's device: CG solves in JAX on an accelerator (no host
    round trip per iteration), the host's sparse factorisation on the CPU."""
    if is_accelerator(current_device()):
        return d.KrylovNewton(step_tolerance=scenario.step_tolerance)
    return d.SparseNewton(step_tolerance=scenario.step_tolerance)


def _simulate(scenario: Scenario, system, state, duration: float, progress: bool):
    try:
        return d.simulate(
            system,
            state,
            scenario.dt,
            duration,
            integrator=_integrator(scenario),
            minimiser=_minimiser(scenario),
            rayleigh=_rayleigh(scenario),
            chunk=SCENARIO_CHUNK,
            progress=progress,
        )
    except NoConvergenceError as err:
        raise NoConvergenceError(
            f"{scenario.source}: field 'integrator.dt_s' = {scenario.dt}: {err} Fix: reduce integrator.dt_s",
            err.history,
        ) from err


def initial_state(scenario: Scenario, system, height: float):
    """The state dropped from ``height`` [m] (lowest point above the first plane) at the config's centre and velocity."""
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
    for window in (
        CALIBRATION_WINDOW * textbook + 4.0 * scenario.dt,
        2.0 * CALIBRATION_WINDOW * textbook + 4.0 * scenario.dt,
    ):
        impacts = d.measured_cor(_simulate(scenario, one, state, window, progress))
        if impacts:
            break
    else:
        return 0.0  # still on the plane: the dashpot is overdamped and nothing bounces
    first = impacts[0]
    return math.sqrt(max(first.bounce_height_m, 0.0) / (first.speed_in_m_per_s**2 / (2.0 * g)))


def eqx_replace_damping(plane, damping: float):
    """``plane`` with contact damping c [N·s/m]."""

    return eqx.tree_at(lambda p: p.damping, plane, np.asarray(float(damping)))


def _check_time_step(scenario: Scenario, system) -> None:
    """Raise InvalidInputError when Δt cannot resolve the contact: ≥ 10 steps per textbook contact time."""
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
            f'{len(x)}-vertex mesh. Fix: give indices below {len(x)}, or select = "lowest"'
        )
    return held


def hold(scenario: Scenario, system):
    """``system`` with its ``[prescribed]`` vertices turned on the schedule (angles in rad), from the inflated shape."""
    spec, held = scenario.prescribed, held_vertices(scenario, system)
    return system.with_prescribed(held, spec.axis_point, spec.axis_direction, spec.times, np.radians(spec.angles))


def _swing(scenario: Scenario, system, out: Path, progress: bool) -> dict:
    """Run a held object once from its posed start into ``out``/swing; what the run shows."""
    trajectory = _simulate(scenario, system, d.initial_state(system, system.posed(0.0)), scenario.duration, progress)
    run_dir = out / "swing"
    d.write_results(
        trajectory,
        run_dir,
        max_frames=scenario.max_frames,
        mesh_format=scenario.mesh_frames,
        figures=scenario.figures,
        preview_gif=scenario.preview_gif,
    )
    positions, times = trajectory["position_m"], trajectory["time_s"]
    held = np.asarray(system.prescribed_vertices)
    rigid = np.stack([np.asarray(system.posed(t)) for t in times])
    schedule = np.stack([np.asarray(system.prescribed_positions(t)) for t in times])
    deviation = np.linalg.norm((positions - rigid).reshape(len(times), -1, 3), axis=2).max(axis=1)
    force = np.linalg.norm(trajectory["contact_force_N"], axis=2)
    figures = []
    if scenario.figures and trajectory.faces is not None:
        steps = _figures.keyframe_steps(times, deviation)
        swing = _figures.digest(trajectory, "swing")
        swing.frames.update({int(k): positions[k].reshape(-1, 3) for k in steps})
        _figures.keyframes_figure(
            swing,
            {int(k): rigid[k].reshape(-1, 3) for k in steps},
            np.asarray(scenario.prescribed.axis_direction),
            out / "keyframes.png",
        )
        figures.append("keyframes.png")
    return {
        "directory": str(run_dir),
        "held_vertices": held.tolist(),
        "figures": figures,
        "held_error_m": float(
            np.max(np.abs(positions.reshape(len(times), -1, 3)[:, held].reshape(len(times), -1) - schedule))
        ),
        "max_deviation_from_rigid_m": float(deviation.max()),
        "time_of_max_deviation_s": float(times[np.argmax(deviation)]),
        "peak_gas_pressure_Pa": float(np.max(trajectory["gas_pressure_Pa"])),
        "time_of_peak_pressure_s": float(times[np.argmax(trajectory["gas_pressure_Pa"])]),
        "planes": {
            name: {
                "min_gap_m": float(np.min(trajectory["min_gap_m"][:, i])),
                "peak_force_N": float(np.max(force[:, i])),
                "first_contact_s": _first_contact(trajectory, i),
            }
            for i, name in enumerate(trajectory.plane_names)
        },
        "impacts": [m.to_dict() for m in d.measured_cor(trajectory)],
    }


def _first_contact(trajectory, plane: int) -> float | None:
    """Time [s] at which a contact point first comes within the plane's contact distance (None if never)."""
    near = np.flatnonzero(trajectory["min_gap_m"][:, plane] < trajectory.contact_distances_m[plane])
    return float(trajectory["time_s"][near[0]]) if near.size else None


def _calibrate(scenario: Scenario, system, progress: bool) -> tuple[float, dict]:
    """Contact damping c [N·s/m] at which a drop from ``calibration_height`` bounces with the
    config's COR, and its record; one progress bar over the calibration drops."""
    from tqdm.auto import tqdm

    with tqdm(desc=f"calibrating the contact damping to COR {scenario.cor}", unit="drop", disable=not progress) as bar:

        def cor(c):
            value = calibration_cor(scenario, system, c)
            bar.update(1)
            bar.set_postfix_str(f"c = {c:.4g} N·s/m: COR {value:.4f}")
            return value

        cal = d.calibrate_contact_damping(cor, scenario.cor, scenario.bracket, rtol=1e-2)
    return cal.damping, {
        "target_cor": scenario.cor,
        "damping_N_s_per_m": cal.damping,
        "cor": cal.cor,
        "evaluations": [list(e) for e in cal.evaluations],
    }


def _scenario_figures(scenario: Scenario, out: Path, digests: list) -> list[str]:
    """The scenario's own figures across its drops (``_figures``): their names in ``out``."""
    written = []
    if scenario.figures and digests and digests[0].faces is not None:
        if _figures.max_deformation_figure(digests, out / "max_deformation.png") is not None:
            written.append("max_deformation.png")
        _figures.trajectory_figure(digests, out / "trajectory.png")
        written.append("trajectory.png")
    return written


def run_scenario(
    scenario: Scenario,
    out_dir: str | Path | None = None,
    *,
    session: str | Path | None = None,
    progress: bool = True,
    verbose: bool = False,
) -> dict:
    """Run every drop of ``scenario`` into ``out_dir`` (default: its output_dir/name); the summary it writes.

    Writes ``scenario.json`` (parameters, calibration, every run's impacts), ``report.md`` (the
    summary with the figures inline), the scenario's figures (``max_deformation.png``: every drop's
    most deformed cross-section; ``trajectory.png``; ``keyframes.png`` of a swing) and per drop height a
    directory ``h<H>m/`` with ``results.json``, figures, mesh frames and ``preview.gif``; a held
    object (``[prescribed]``) runs once into ``swing/``. ``progress``: a bar per stage on stderr;
    ``verbose``: each stage's wall time and what JAX compiled in it, on stderr.
    """
    out = check_output_dir(out_dir if out_dir is not None else scenario.output_dir / scenario.name, "--out")
    placement = requested_placement(scenario.device)  # 'gpu' without one is refused before any work
    with placement.stage(StageKind.LATENCY):  # the object's estimate (one session's fit) and its shell, on the host
        obj = resolve_object(scenario, session)
        system = build_system(scenario, obj)
        if scenario.prescribed is not None:
            system = hold(scenario, system)
        _check_time_step(scenario, system)
    out.mkdir(parents=True, exist_ok=True)  # only once the config is accepted: a refused one leaves nothing
    calibration, stages = None, []
    damping = scenario.contact_damping or 0.0
    if scenario.cor is not None:
        with (
            placement.stage(StageKind.SPARSE, sparse_dofs(system)) as device,
            stage("calibration", verbose, stages, device),
        ):
            damping, calibration = _calibrate(scenario, to_device(system, device), progress)
    system = system.with_planes([eqx_replace_damping(p, damping) for p in system.planes])
    runs, digests = _run_all(scenario, system, out, progress, (verbose, stages), placement)
    with stage("scenario figures", verbose, stages):
        figures = _scenario_figures(scenario, out, digests)
    summary = _summary(scenario, obj, system, {"damping": damping, "calibration": calibration}, runs, figures, stages)
    summary["placement"] = placement.describe()
    atomic_write_text(out / "scenario.json", json.dumps(summary, indent=1))
    write_scenario_report(summary, out)
    return summary


def sparse_dofs(system) -> int:
    """Unknowns [count] of a dynamic system's Newton solves (3 per node): its sparse stage's size."""
    return 3 * int(np.asarray(system.node_masses).shape[0])


def _run_all(
    scenario: Scenario, system, out: Path, progress: bool, log: tuple[bool, list], placement: Placement
) -> tuple[list, list]:
    """Every drop (and the swing of a held object) into ``out``: the runs' records and the drops'
    digests for the scenario figures; ``log``: (verbose, the stages' list to append to); each run a
    sparse stage where ``placement`` puts it."""
    from tqdm.auto import tqdm

    verbose, stages = log
    runs, digests = [], []
    labels = [f"drop {h:.2f} m" for h in scenario.drop_heights] + (["swing"] if scenario.prescribed is not None else [])
    with tqdm(total=len(labels), desc=f"simulating {scenario.name}", unit="run", disable=not progress) as bar:
        for h, label in zip(scenario.drop_heights, labels):
            bar.set_postfix_str(label)
            with (
                placement.stage(StageKind.SPARSE, sparse_dofs(system)) as device,
                stage(label, verbose, stages, device),
            ):
                on_device = to_device(system, device)  # the shell enters its stage's device once
                trajectory = _simulate(
                    scenario, on_device, initial_state(scenario, on_device, h), scenario.duration, progress
                )
                run_dir = out / f"h{h:.2f}m"
                d.write_results(
                    trajectory,
                    run_dir,
                    max_frames=scenario.max_frames,
                    mesh_format=scenario.mesh_frames,
                    figures=scenario.figures,
                    preview_gif=scenario.preview_gif,
                )
            runs.append(
                {
                    "drop_height_m": h,
                    "directory": str(run_dir),
                    "impacts": [m.to_dict() for m in d.measured_cor(trajectory)],
                }
            )
            if trajectory.faces is not None:
                digests.append(_figures.digest(trajectory, label))
            bar.update(1)
        if scenario.prescribed is not None:
            bar.set_postfix_str("swing")
            with (
                placement.stage(StageKind.SPARSE, sparse_dofs(system)) as device,
                stage("swing", verbose, stages, device),
            ):
                runs.append(_swing(scenario, to_device(system, device), out, progress))
            bar.update(1)
    return runs, digests


def _summary(scenario: Scenario, obj: ObjectModel, system, contact: dict, runs: list, figures: list, stages: list):
    """``scenario.json``'s content: the object, its parameters (the documented ``youngs_modulus_Pa``
    key is E), the contact damping and its ``contact`` calibration, the runs, figures and stages."""
    p = obj.properties
    return {
        "scenario": str(scenario.source),
        "name": scenario.name,
        "object": obj.source,
        "parameters": {
            "gauge_pressure_Pa": p.gauge_pressure,
            "youngs_modulus_Pa": p.young_modulus,
            "poisson_ratio": p.poisson_ratio,
            "thickness_m": obj.shell.thickness,
            "mass_kg": float(np.sum(np.asarray(system.node_masses))),
            "gas": scenario.gas,
            "mesh_faces": int(obj.shell.mesh.n_faces),
            "dt_s": scenario.dt,
            "scheme": scenario.scheme,
        },
        "contact_damping_N_s_per_m": contact["damping"],
        "calibration": contact["calibration"],
        "runs": runs,
        "figures": figures + [f for run in runs for f in run.get("figures", [])],
        "compilation": {"stages": stages, "unit": "s", "total_seconds": sum(s["total_seconds"] for s in stages)},
    }
