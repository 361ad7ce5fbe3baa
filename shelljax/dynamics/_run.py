"""Stepping, differentiable roll-outs and the run driver with its per-step record.

* ``initial_state``: a state at rest or moving, with Newmark's a₀ = M⁻¹ F(x₀).
* ``step``: one implicit step (pure, jit- and grad-able; one minimisation per stage of the
  integrator: two for TR-BDF2); ``rollout``: ``n_steps`` of them in a ``lax.scan``
  (differentiable end to end, each stage implicitly).
* ``simulate``: the driver, in jit-compiled chunks with a progress bar; it raises
  ``NoConvergenceError`` at the first step whose minimisation failed (no step is skipped).
"""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, Scalar

from .._errors import InvalidInputError, NoConvergenceError
from ..physics.internal import check_positive
from ._integrators import AbstractIntegrator, Newmark, Rayleigh
from ._minimise import AbstractMinimiser, DenseNewton, solve_step
from ._potential import incremental_potential, lagged_contact, stage_potential
from ._system import ENERGY_KINDS, AbstractDynamicSystem, DynamicState


class StepRecord(eqx.Module):
    """Observables of one state (SI units; P planes; the names say the units)."""

    time_s: Float[Array, ""]
    com_position_m: Float[Array, "3"]
    com_velocity_m_per_s: Float[Array, "3"]
    contact_force_N: Float[Array, "P 3"]
    min_gap_m: Float[Array, " P"]
    gas_pressure_Pa: Float[Array, ""]
    gas_volume_m3: Float[Array, ""]
    energy_J: dict[str, Float[Array, ""]]
    position_m: Float[Array, " n"]
    converged: Bool[Array, ""]
    feasible_start: Bool[Array, ""]
    newton_iterations: Int[Array, ""]
    newton_matrices: Int[Array, ""]  # Newton matrices assembled and factorised in the step
    residual_history_N: Float[Array, " K"]


def _check_system(system: AbstractDynamicSystem, state: DynamicState) -> None:
    mass = system.lumped_mass()
    check_positive(
        "the lumped mass per degree of freedom [kg]",
        mass,
        "Give the system a mass (e.g. a session's `mass`, or a wall density).",
    )
    n = mass.shape[0]
    for name in ("position", "velocity", "acceleration"):
        shape = getattr(state, name).shape
        if shape != (n,):
            raise InvalidInputError(
                f"the initial {name} has shape {shape}, but the system has {n} degrees of freedom; give one value per degree of freedom."
            )


def initial_state(system: AbstractDynamicSystem, position, velocity=None, time=0.0) -> DynamicState:
    """State at ``time`` [s] from positions [m] and velocities [m/s] (zero if None), with a₀ = M⁻¹F(x₀) [m/s²]."""
    x = jnp.asarray(position, dtype=float).reshape(-1)
    v = (
        jnp.zeros_like(x)
        if velocity is None
        else jnp.broadcast_to(jnp.asarray(velocity, dtype=float).reshape(-1), x.shape)
    )
    state = DynamicState(time, x, v, jnp.zeros_like(x))
    _check_system(system, state)
    if not isinstance(x, jax.core.Tracer) and not np.all(np.isfinite(np.asarray(x))):
        raise InvalidInputError("the initial position has NaN or infinite entries; give finite positions in m.")
    force = -_potential_gradient(system, x, jnp.asarray(time))
    a = force / system.lumped_mass()
    prescribed = list(system.prescribed_dofs())
    if prescribed:
        a = a.at[jnp.asarray(prescribed)].set(0.0)
    return DynamicState(time, x, v, a)


@eqx.filter_jit
def _potential_gradient(system, x, t):
    """∇Φ(x, t) [N], compiled: op by op, the vmapped face energies take longer than a step."""
    return jax.grad(system.potential)(x, t)


def observe(
    system: AbstractDynamicSystem,
    state: DynamicState,
    forces: Float[Array, "P 3"],
    result=None,
    max_steps: int = 1,
    feasible_start=True,
) -> StepRecord:
    """The record of ``state`` with plane forces [N] (and the step's convergence, if any)."""
    x, t = state.position, state.time
    com, com_velocity = jax.jvp(system.centre_of_mass, (x,), (state.velocity,))
    energies = {k: jnp.asarray(0.0) for k in ENERGY_KINDS}
    energies.update(system.internal_energies(x, t))
    energies["contact"] = system.contact_energy(x)
    energies["kinetic"] = 0.5 * jnp.sum(system.lumped_mass() * state.velocity**2)
    energies["total"] = sum(energies.values(), jnp.asarray(0.0))
    points = system.contact_points(x)
    gaps = [jnp.min(p.gap(points)) for p in system.planes]
    pressure, volume = system.gas_state(x)
    if result is None:
        converged, iterations, history, matrices = (
            jnp.asarray(True),
            jnp.asarray(0),
            jnp.full((max_steps,), jnp.nan),
            jnp.asarray(0),
        )
    else:
        converged, iterations, history, matrices = (
            result.converged,
            result.iterations,
            result.history,
            result.stats["assemblies"],
        )
    return StepRecord(
        time_s=t,
        com_position_m=com,
        com_velocity_m_per_s=com_velocity,
        contact_force_N=forces,
        min_gap_m=jnp.stack(gaps) if gaps else jnp.zeros((0,)),
        gas_pressure_Pa=jnp.asarray(pressure, dtype=float),
        gas_volume_m3=jnp.asarray(volume, dtype=float),
        energy_J=energies,
        position_m=x,
        converged=converged,
        feasible_start=jnp.asarray(feasible_start),
        newton_iterations=iterations,
        newton_matrices=matrices,
        residual_history_N=history,
    )


def elastic_plane_forces(system: AbstractDynamicSystem, x: Float[Array, " n"]) -> Float[Array, "P 3"]:
    """Contact force [N] of each plane at x [m], without damping or friction (for the initial state)."""
    points, forces, _ = lagged_contact(system, x)
    rows = [jnp.sum(forces[i][:, None], axis=0) * p.normal for i, p in enumerate(system.planes)]
    return jnp.stack(rows) if rows else jnp.zeros((0, 3))


def step(
    system: AbstractDynamicSystem,
    state: DynamicState,
    dt: Scalar,
    integrator: AbstractIntegrator = Newmark(),
    minimiser: AbstractMinimiser = DenseNewton(),
    rayleigh: Rayleigh | None = None,
) -> tuple[DynamicState, StepRecord]:
    """One implicit step of Δt [s]: the new state and its record (check ``record.converged``)."""
    new_state, record, _ = _step_kept(system, state, dt, integrator, minimiser, rayleigh, None)
    return new_state, record


def _step_kept(system, state, dt, integrator, minimiser, rayleigh, memory):
    """:func:`step` with the minimiser's ``memory`` from the previous step: (state, record, memory).

    A multi-stage scheme minimises one incremental potential per stage, each from the state the
    last one left, the minimiser's memory passed along; the record sums their Newton iterations
    and matrices, is converged if every stage is, and keeps the residual history of the first
    stage that failed (else the last's)."""
    dt = jnp.asarray(dt)
    current = state
    converged, feasible, iterations, matrices, history = jnp.asarray(True), jnp.asarray(True), 0, 0, None
    for k in range(integrator.num_stages()):
        stage = integrator.stage(k, state, current, dt)
        potential = stage_potential(system, stage, current.position, rayleigh)
        # x̂ may cross a barrier; the previous positions (with the new prescribed ones) are a safe start. Where
        # the acceleration staying aₙ gives a lower Φ_inc, Newton starts there instead (exact in free flight;
        # an initial state far from equilibrium can have an aₙ that throws the nodes metres away).
        predicted = potential.free(potential.x_hat)
        start = jnp.where(potential.is_feasible(predicted), predicted, potential.free(current.position))
        extrapolated = potential.free(potential.x_hat + stage.inertia_scale * current.acceleration)
        better = potential.is_feasible(extrapolated) & (potential.value(extrapolated) < potential.value(start))
        start = jnp.where(better, extrapolated, start)
        feasible = feasible & potential.is_feasible(start)
        result = solve_step(potential, minimiser, jax.lax.stop_gradient(start), memory)
        memory = result.state
        x_new = potential.full(result.value)
        current = integrator.finish_stage(k, state, current, x_new, dt)
        history = result.history if history is None else jnp.where(converged, result.history, history)
        converged = converged & result.converged
        iterations = iterations + result.iterations
        matrices = matrices + result.stats["assemblies"]
    record = observe(system, current, potential.plane_forces(x_new), result, feasible_start=feasible)
    record = eqx.tree_at(
        lambda r: (r.converged, r.newton_iterations, r.newton_matrices, r.residual_history_N),
        record,
        (converged, jnp.asarray(iterations), jnp.asarray(matrices), history),
    )
    return current, record, memory


def rollout(
    system: AbstractDynamicSystem,
    state: DynamicState,
    dt: Scalar,
    n_steps: int,
    integrator: AbstractIntegrator = Newmark(),
    minimiser: AbstractMinimiser = DenseNewton(),
    rayleigh: Rayleigh | None = None,
) -> tuple[DynamicState, StepRecord]:
    """``n_steps`` steps of Δt [s] in a scan: the final state and the stacked records (pure,
    differentiable). What the minimiser keeps between steps (a kept Newton matrix) is carried
    along."""
    potential = incremental_potential(system, integrator, state, dt, rayleigh)
    memory = jax.lax.stop_gradient(minimiser.initial_memory(potential, potential.free(state.position)))

    def body(carry, _):
        s, kept = carry
        s, record, kept = _step_kept(system, s, dt, integrator, minimiser, rayleigh, kept)
        return (s, jax.lax.stop_gradient(kept)), record

    (state, _), records = jax.lax.scan(body, (state, memory), None, length=n_steps)
    return state, records


@eqx.filter_jit
def _chunk(system, state, dt, n_steps, integrator, minimiser, rayleigh):
    """``rollout`` compiled once per system structure and chunk length (Δt [s] and parameters traced)."""
    return rollout(system, state, dt, n_steps, integrator, minimiser, rayleigh)


@eqx.filter_jit
def _first_record(system, state):
    """The record of the run's initial state, compiled like the steps' (op by op it costs more than a step)."""
    return observe(system, state, elastic_plane_forces(system, state.position), None, 0)


@dataclasses.dataclass(frozen=True)
class Trajectory:
    """A run's per-step record as NumPy arrays (step 0 is the initial state), with its context.

    ``records`` maps each ``StepRecord`` field to its stacked array; ``plane_names``,
    ``plane_normals`` (P, 3) [-], ``contact_distances_m`` (P,) and ``gravity_m_per_s2`` (3,) say
    how to read them; ``faces`` are the system's triangles (or None); ``dt_s`` the step [s].
    """

    records: dict[str, np.ndarray]
    plane_names: tuple[str, ...]
    plane_normals: np.ndarray
    contact_distances_m: np.ndarray
    gravity_m_per_s2: np.ndarray
    dt_s: float
    faces: np.ndarray | None = None

    def __getitem__(self, key: str) -> np.ndarray:
        return self.records[key]


def _flatten(record: StepRecord) -> dict[str, np.ndarray]:
    out = {}
    for field in dataclasses.fields(record):
        value = getattr(record, field.name)
        if isinstance(value, dict):
            out.update({f"{k}_energy_J": np.asarray(v) for k, v in value.items()})
        else:
            out[field.name] = np.asarray(value)
    return out


def simulate(
    system: AbstractDynamicSystem,
    state: DynamicState,
    dt: float,
    duration: float,
    *,
    integrator: AbstractIntegrator = Newmark(),
    minimiser: AbstractMinimiser = DenseNewton(),
    rayleigh: Rayleigh | None = None,
    chunk: int = 250,
    progress: bool = True,
) -> Trajectory:
    """Advance ``state`` by ``duration`` [s] in steps of ``dt`` [s]; the record of every step.

    Raises ``InvalidInputError`` for a bad Δt or state, and ``NoConvergenceError`` (with the
    residual history) at the first step that did not converge.
    """
    from tqdm.auto import tqdm

    check_positive("dt [s]", dt, "Give a positive time step, e.g. dt = 1e-4 s.")
    check_positive("duration [s]", duration, "Give a positive duration, e.g. 1.0 s.")
    if dt > duration:
        raise InvalidInputError(f"dt = {dt} s is longer than the duration {duration} s; give dt ≤ duration.")
    _check_system(system, state)
    n_steps = int(math.ceil(duration / dt - 1e-9))
    chunk = max(1, min(chunk, n_steps))
    first = _first_record(system, state)
    chunks = []
    done = 0
    with tqdm(total=n_steps, desc="simulate", unit="step", disable=not progress) as bar:
        while done < n_steps:
            state, rec = _chunk(system, state, jnp.asarray(dt), chunk, integrator, minimiser, rayleigh)
            take = min(chunk, n_steps - done)
            rec = jax.tree_util.tree_map(lambda a: np.asarray(a)[:take], rec)
            failed = np.flatnonzero(~rec.converged)
            if failed.size:
                k = int(failed[0])
                history = rec.residual_history_N[k]
                if not rec.feasible_start[k]:
                    raise NoConvergenceError(
                        f"the step to t = {rec.time_s[k]:.6g} s (step {done + k + 1}) starts with contact points "
                        "through a barrier plane: the prescribed motion pushes nodes into a plane. Move the plane or "
                        "change the prescribed schedule.",
                        [float(h) for h in history[np.isfinite(history)]],
                    )
                raise NoConvergenceError(
                    f"the step to t = {rec.time_s[k]:.6g} s (step {done + k + 1}) did not converge in "
                    f"{int(rec.newton_iterations[k])} Newton iterations. Reduce dt (now {dt} s; try dt/4), "
                    "or raise DenseNewton(max_steps=...).",
                    [float(h) for h in history[np.isfinite(history)]],
                )
            chunks.append(rec)
            done += take
            bar.update(take)
    # The initial state has no Newton history: pad it to the minimiser's history length.
    first = eqx.tree_at(
        lambda r: r.residual_history_N, first, jnp.full(chunks[0].residual_history_N.shape[1:], jnp.nan)
    )
    chunks.insert(0, jax.tree_util.tree_map(lambda a: np.asarray(a)[None], first))
    stacked = jax.tree_util.tree_map(lambda *a: np.concatenate(a), *chunks)
    planes = system.planes
    return Trajectory(
        records=_flatten(stacked),
        plane_names=tuple(p.name for p in planes),
        plane_normals=np.array([np.asarray(p.normal) for p in planes]).reshape(-1, 3),
        contact_distances_m=np.array([float(p.law.contact_distance()) for p in planes]),
        gravity_m_per_s2=np.asarray(system.gravity, dtype=float),
        dt_s=float(dt),
        faces=None if system.surface_faces() is None else np.asarray(system.surface_faces()),
    )


def drop_state(
    system: AbstractDynamicSystem, rest_position, height: float, velocity=None, plane: int = 0
) -> DynamicState:
    """The system's ``rest_position`` [m] moved along plane ``plane``'s normal so its lowest contact
    point is ``height`` [m] above it (the drop height), moving at ``velocity`` [m/s] (at rest if None).
    """
    if not np.isfinite(height) or height < 0.0:
        raise InvalidInputError(
            f"drop height must be ≥ 0 m; got {height} m. Give the height of the lowest point above the {system.planes[plane].name if system.planes else 'plane'}."
        )
    if not system.planes:
        raise InvalidInputError("drop_state needs a system with a plane to drop onto; add a ground plane.")
    x = jnp.asarray(rest_position, dtype=float).reshape(-1)
    p = system.planes[plane]
    lowest = jnp.min(p.gap(system.contact_points(x)))
    shift = (height - lowest) * p.normal
    x = (x.reshape(-1, 3) + shift).reshape(-1)
    v = (
        None
        if velocity is None
        else jnp.broadcast_to(jnp.asarray(velocity, dtype=float), (x.shape[0] // 3, 3)).reshape(-1)
    )
    return initial_state(system, x, v)
