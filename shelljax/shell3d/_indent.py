"""Indentation of a pressurized shell resting on the ground: the user-facing simulation.

``Indentation(shell, ...)`` sets up a shell (from :func:`ball` or a scanned closed mesh), solves
for its stress-free rest shape (the scan is the *pressurized* shape), and poses it on a rigid
ground plane under a rigid spherical indenter (the finger) above its top vertex. ``solve(depth=…)``
moves the indenter down by ``depth`` [m] from first touch (displacement control) in continuation
steps; ``solve(force=…)`` pushes it with a prescribed force [N] (force control, the indenter height
becomes an unknown). Both return an :class:`IndentationState` with the observables of the paper's
elasticity figure (panel b) and OBJ/PNG export.

Rigid-body modes: the ground and the indenter fix the vertical motion; the horizontal ones
(x/y translation, rotations) are removed by pins on the top and bottom vertices (x, y) and on the
+x-most vertex (y), see :func:`rigid_mode_pins`. The force balance test checks that the pins carry
no vertical load. Friction does not replace the pins: a centred poke has no net tangential load,
so the ground's total friction force vanishes by symmetry and cannot hold the rigid modes.

Ground friction (``friction=μ > 0``) is the smoothed Coulomb potential of IPC, lagged (Li et al.
2020; :func:`shelljax.physics.friction_energy`). Each load step (continuation sub-step) takes its
anchors x̂ (the slip origin) and normal forces λ from the converged state at the start of the step,
solves, then re-solves up to ``friction_iterations`` times with λ recomputed from the last
solution (anchors kept), stopping early once λ changes by less than ``FRICTION_LAG_TOLERANCE``
(1 %) of its largest value. The friction force of a vertex is therefore bounded by μ times its
lagged normal force exactly, and by μ times its current one to within that lag change
(``IndentationState.friction_lag_change``). Friction makes the response path dependent: the
result depends on the continuation steps (``max_step``), as a real poke depends on its history.
"""

from __future__ import annotations

import copy
import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import InvalidInputError
from ..paper import PAPER_INDENTER_RADIUS
from ..physics import ATMOSPHERIC_PRESSURE, AbstractGasLaw, Plane, PrescribedGas, ShellProperties
from ._config import ContactConfig, ModelConfig, check_config
from ._continuation import continuation
from ._implicit import implicit_equilibrium
from ._linear import AbstractLinearSolver, DirectSolver
from ._mesh import ShellMesh
from ._model import ShellModel, rigid_mode_pins
from ._observables import observables as _observables
from ._params import ShellParams
from ._rest import inflated_reference
from ._search import match_forces, solve_travels
from ._steps import accumulate_slip, feasible_start, initial_slip, secant_predict
from ._wrinkles import wrinkle_spectrum

#: Lagging stops once the normal forces change by less than this fraction of their largest value.
FRICTION_LAG_TOLERANCE = 0.01


@dataclasses.dataclass(frozen=True, eq=False)
class Shell:
    """A closed shell surface: ``mesh`` (its vertices are the pressurized/scanned shape [m]) and
    wall ``thickness`` h [m]."""

    mesh: ShellMesh
    thickness: float

    def __post_init__(self):
        if not (self.thickness > 0 and math.isfinite(self.thickness)):
            raise InvalidInputError(f"thickness: must be a positive length in m, got {self.thickness}.")


def ball(
    radius: float, thickness: float, n_triangles: int = 5000, *, pole_refinement: float = 3.0, growth: float = 0.25
) -> Shell:
    """A spherical ball of ``radius`` [m] and wall ``thickness`` [m], meshed with about
    ``n_triangles`` faces refined ``pole_refinement``× at the top (indenter) and bottom (ground)."""
    if not radius > 0:
        raise InvalidInputError(f"radius: must be a positive length in m, got {radius}.")
    mesh = ShellMesh.sphere(radius, n_triangles, pole_refinement=pole_refinement, growth=growth, name="ball")
    return Shell(mesh=mesh, thickness=float(thickness))


def load(path, thickness: float) -> Shell:
    """A shell from a closed triangle mesh file (any format trimesh reads), in m, z up."""
    import trimesh

    try:
        tm = trimesh.load(str(path), force="mesh", process=True)
    except Exception as err:  # trimesh raises many types for unreadable files
        raise InvalidInputError(f"{path}: could not read a triangle mesh ({err}).") from err
    return Shell(mesh=ShellMesh.from_arrays(tm.vertices, tm.faces, name=str(path)), thickness=float(thickness))


@dataclasses.dataclass(frozen=True, eq=False)
class IndentationState:
    """A solved equilibrium: ``q`` (3V + 3,) [m] (vertex positions then indenter center), the
    simulation it belongs to, the indenter travel ``depth`` [m] and Newton ``iterations``.

    With ground friction: ``friction`` holds the lagged data of the last solve
    (``friction_anchor`` (V, 3) [m], ``friction_normal_force`` (n_planes, V) [N]; empty without
    friction), ``friction_lag_change`` the relative change [-] of the normal forces between the
    lagged values and this state's. ``ground_slip`` (V, 3) [m] (None without ground): each vertex's
    tangential displacement along the ground accumulated over the load steps at whose end it
    touched the ground (gap < activation distance), with or without friction. ``factorizations``:
    Hessian factorizations of the last load step's Newton solves (≤ ``iterations``: Newton reuses
    a factorization while it keeps converging fast); ``products``: the Hessian-vector products of
    its conjugate-gradient steps (:func:`shelljax.shell3d.newton`); ``krylov_iterations``: the CG
    iterations of a :class:`KrylovSolver`'s solves in that load step (0 with the direct solver).
    """

    sim: "Indentation"
    q: np.ndarray
    depth: float
    iterations: int
    history: list
    friction: dict = dataclasses.field(default_factory=dict)
    friction_lag_change: float = 0.0
    ground_slip: np.ndarray | None = None
    factorizations: int = 0
    products: int = 0
    krylov_iterations: int = 0

    @property
    def vertices(self) -> np.ndarray:
        """Deformed vertex positions (V, 3) [m]."""
        return self.q[:-3].reshape(-1, 3)

    @property
    def indenter_center(self) -> np.ndarray:
        """Indenter center (3,) [m]."""
        return self.q[-3:]

    def observables(self) -> dict:
        """Observables (SI): see :func:`shelljax.shell3d.observables`."""
        return _observables(self.sim, self.q, self.sim.params_at(self.q, **self.friction))

    def wrinkles(self, max_radius: float, ring_width: float, max_mode: int = 60):
        """Angular spectrum of the normal displacement from the inflated reference state, on rings
        of ``ring_width`` [m] up to ``max_radius`` [m] from the indentation axis: see
        :func:`shelljax.shell3d.wrinkle_spectrum` (``.count`` is the wrinkle count)."""
        reference = self.sim.q_reference[:-3].reshape(-1, 3)
        return wrinkle_spectrum(
            reference,
            self.vertices,
            self.sim.model.mesh.faces,
            reference[self.sim.top],
            max_radius=max_radius,
            ring_width=ring_width,
            max_mode=max_mode,
        )

    def export(self, path) -> None:
        """Write the deformed mesh (OBJ, PLY, STL: by suffix) [m]."""
        import trimesh

        trimesh.Trimesh(self.vertices, self.sim.model.mesh.faces, process=False).export(str(path))

    def plot(self, path) -> None:
        """PNG: deformed shell (3D view) and its x–z cross-section with indenter and ground."""
        from ._export import plot_state

        plot_state(self, path)


def _is_count(value, least: int) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= least


def _shell_properties(properties, shell: Shell) -> tuple[float, float, float]:
    """(E [Pa], ν [-], P_g [Pa]) of ``properties``, whose thickness must be the shell's: the two
    are one wall, and a silent choice between them would change the answer."""
    if not isinstance(properties, ShellProperties):
        raise InvalidInputError(
            f"Indentation: expected a physics.ShellProperties, got {type(properties).__name__}. Fix: Indentation("
            "shell, ShellProperties(gauge_pressure=…, young_modulus=…, thickness=shell.thickness, poisson_ratio=…))"
        )
    if float(properties.thickness) != float(shell.thickness):
        raise InvalidInputError(
            f"Indentation: properties.thickness = {properties.thickness!r} m is not the shell's thickness "
            f"{shell.thickness!r} m. Fix: build both from the same h"
        )
    return float(properties.young_modulus), float(properties.poisson_ratio), float(properties.gauge_pressure)


def _check_linear_solver(linear_solver) -> None:
    if not isinstance(linear_solver, AbstractLinearSolver):
        raise InvalidInputError(
            f"linear_solver: expected shell3d.DirectSolver() or shell3d.KrylovSolver(...), got {linear_solver!r}."
        )


def _check_arguments(
    young_modulus,
    poisson_ratio,
    gauge_pressure,
    indenter_radius,
    rest_shape,
    friction_iterations,
    max_newton_iterations,
) -> None:
    """Raise InvalidInputError, naming the argument, for a value :class:`Indentation` rejects."""
    if not young_modulus > 0:
        raise InvalidInputError(f"young_modulus: must be > 0 Pa, got {young_modulus}.")
    if not -1.0 < poisson_ratio < 0.5:
        raise InvalidInputError(f"poisson_ratio: must be in (-1, 0.5), got {poisson_ratio}.")
    if not gauge_pressure >= 0:
        raise InvalidInputError(f"gauge_pressure: must be ≥ 0 Pa, got {gauge_pressure}.")
    if not indenter_radius > 0:
        raise InvalidInputError(f"indenter_radius: must be > 0 m, got {indenter_radius}.")
    if rest_shape not in ("solve", "exact", "scan"):
        raise InvalidInputError(f"rest_shape: use 'solve', 'exact' or 'scan', got {rest_shape!r}.")
    if not _is_count(friction_iterations, 0):
        raise InvalidInputError(
            f"friction_iterations: must be an integer ≥ 0 (re-solves per load step), got {friction_iterations!r}."
        )
    if not _is_count(max_newton_iterations, 1):
        raise InvalidInputError(f"max_newton_iterations: must be an integer ≥ 1, got {max_newton_iterations!r}.")


class Indentation:
    """Poke a pressurized shell on the ground with a rigid sphere.

    Arguments (SI units): ``shell`` (:class:`Shell`), ``properties``
    (:class:`shelljax.physics.ShellProperties`: E [Pa], ν [-], the gauge pressure P_g [Pa] of the
    scanned state, and the shell's thickness h [m]; its radius is not read, the mesh is the
    geometry); ``gas``: a ``physics.AbstractGasLaw``, ``PrescribedGas()`` (constant P_g, the paper's
    model), ``IsothermalGas()`` or ``AdiabaticGas()`` (sealed ideal gas that holds P_g at the scanned
    volume);
    ``indenter_radius`` [m]; ``ground``: put a rigid plane under the shell;
    ``mass`` [kg] adds gravity; ``contact``: "barrier" (default; IPC log barrier, no
    penetration, surfaces stop within ``activation_distance`` [m] of a body) or "penalty"
    (penetration ≈ ``activation_distance`` × local contact pressure / reference pressure);
    ``rest_shape``: "solve" (default: the scan shrunk uniformly so that its pressurized
    equilibrium encloses the scan's volume to 1e-6; exact for spheres, the achieved shape
    mismatch is ``rest_mismatch`` [m]), "exact" (Newton on all rest vertices so that the scan is
    an equilibrium; can stall on coarse meshes at high pressure, then raises) or "scan" (take
    the scan as stress-free, i.e. inflate it a second time);
    ``force_tolerance`` [N]: Newton tolerance on the largest nodal force residual (default
    1e-8 E h L, L the shell's size); ``max_newton_iterations``: Newton iterations per load step
    before it raises (default 60; deep, wrinkling states can converge linearly and need more;
    Newton's ``max_steps``, named apart from ``max_step``, the continuation step in depth);
    ``max_step`` [m]: largest continuation step in depth;
    ``friction`` μ [-] ≥ 0: Coulomb coefficient between shell and ground (default 0: frictionless;
    the indenter is always frictionless); ``slip_tolerance`` ε [m] > 0: slip below which a ground
    contact sticks (default activation_distance / 100); ``friction_iterations``: at most this many
    re-solves per load step with updated lagged normal forces (default 2, see the module docstring).
    ``linear_solver``: Newton's and the implicit tangents' solver, :class:`DirectSolver` (default:
    host CHOLMOD) or :class:`KrylovSolver` (CG in JAX on the default device; rest shape on the host).
    :meth:`with_friction` and :meth:`with_linear_solver` change μ or the solver, keeping the rest shape.
    """

    def __init__(
        self,
        shell: Shell,
        properties: ShellProperties,
        *,
        gas: AbstractGasLaw = PrescribedGas(),
        indenter_radius: float = PAPER_INDENTER_RADIUS,
        ground: bool = True,
        mass: float | None = None,
        contact: str = "barrier",
        activation_distance: float | None = None,
        rest_shape: str = "solve",
        force_tolerance: float | None = None,
        max_newton_iterations: int = 60,
        max_step: float | None = None,
        progress: bool | None = None,
        friction: float = 0.0,
        slip_tolerance: float | None = None,
        friction_iterations: int = 2,
        linear_solver: AbstractLinearSolver = DirectSolver(),
    ):
        young_modulus, poisson_ratio, gauge_pressure = _shell_properties(properties, shell)
        _check_arguments(
            young_modulus,
            poisson_ratio,
            gauge_pressure,
            indenter_radius,
            rest_shape,
            friction_iterations,
            max_newton_iterations,
        )
        _check_linear_solver(linear_solver)
        ContactConfig(friction=friction, slip_tolerance=slip_tolerance)  # validate before the rest solve
        check_config(ModelConfig(shell.mesh.n_vertices, gas=gas))
        self.max_newton_iterations = int(max_newton_iterations)
        self.friction_iterations = int(friction_iterations)
        self.shell, self.progress, self.linear_solver = shell, progress, linear_solver
        scan = self._place_scan(shell.mesh, contact, activation_distance)
        self.atol = force_tolerance or 1e-8 * young_modulus * shell.thickness * self.size
        self.max_step = max_step or 0.02 * self.size
        #: The model parameters at the indenter's start (:class:`ShellParams`, SI).
        self.base_params = ShellParams(
            young_modulus=young_modulus,
            poisson_ratio=poisson_ratio,
            thickness=float(shell.thickness),
            gauge_pressure=gauge_pressure,
            mass=None if mass is None else float(mass),
        )
        self.top, self.bottom = int(np.argmax(scan[:, 2])), int(np.argmin(scan[:, 2]))
        self._fixed = rigid_mode_pins(scan)
        reference = inflated_reference(shell, self.base_params, vertices=scan, rest_shape=rest_shape, atol=self.atol)
        self.rest, self.reference_volume = reference.rest, reference.reference_volume
        #: Largest distance [m] between the pressurized reference state and the scan.
        self.rest_mismatch = reference.rest_mismatch
        if gas.sealed:
            self.base_params = self.base_params.replace(
                reference_volume=self.reference_volume, atmospheric_pressure=ATMOSPHERIC_PRESSURE
            )
        self.indenter_radius = float(indenter_radius)
        #: The indenter's start (3,) [m], at first touch above the inflated top vertex.
        self.top_height = float(reference.inflated[self.top, 2])
        x_top = reference.inflated[self.top]
        self.touch_center = np.array([x_top[0], x_top[1], self.top_height + indenter_radius + 0.5 * self.gap0])
        self.q_reference = np.concatenate([reference.inflated.ravel(), self.touch_center])
        planes = (Plane((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), name="ground"),) if ground else ()
        contact_cfg = ContactConfig(
            indenter_radius=float(indenter_radius),
            planes=planes,
            kind=contact,
            activation_distance=float(self.activation_distance),
            reference_pressure=float(max(gauge_pressure, 1e3)),
            friction=friction,
            slip_tolerance=slip_tolerance,
        )
        self.friction = contact_cfg.friction
        self.model = ShellModel(
            shell.mesh, self.rest, ModelConfig(shell.mesh.n_vertices, gas=gas, contact=contact_cfg), self._fixed
        )
        self._force_model = None
        self._kept_factorization = (None, None)

    def _place_scan(self, mesh: ShellMesh, contact: str, activation_distance: float | None) -> np.ndarray:
        """The scan (V, 3) [m] standing on the ground (half the barrier's range ĝ above it); sets
        the shell's ``size`` [m], the barrier's initial gap ``gap0`` and ``activation_distance`` ĝ."""
        scan = mesh.vertices - np.array([0.0, 0.0, mesh.vertices[:, 2].min()])
        size = float(np.ptp(scan, axis=0).max())
        self.size = size
        self.gap0 = (activation_distance or 2e-4 * size / 0.13) if contact == "barrier" else 0.0
        ghat = activation_distance or (2e-4 * size / 0.13 if contact == "barrier" else 2e-5 * size / 0.13)
        self.activation_distance = ghat
        return scan + np.array([0.0, 0.0, 0.5 * ghat if contact == "barrier" else 0.0])

    def with_friction(self, friction: float, slip_tolerance: float | None = None) -> "Indentation":
        """The same simulation (shell, rest shape, reference state, settings) with another ground
        friction μ [-] and slip tolerance ε [m] (None: the default). Skips the rest-shape solve
        and keeps the sparsity pattern; μ is a traced value in the compiled functions, so every
        μ > 0 with the same ε shares one compilation."""
        contact = dataclasses.replace(self.model.config.contact, friction=friction, slip_tolerance=slip_tolerance)
        other = copy.copy(self)
        other.model = self.model.with_config(dataclasses.replace(self.model.config, contact=contact))
        other.friction = contact.friction
        other._force_model = None
        other._kept_factorization = (None, None)
        return other

    def with_linear_solver(self, linear_solver: AbstractLinearSolver) -> "Indentation":
        """The same simulation with another ``linear_solver`` (e.g. :class:`KrylovSolver` where the
        arrays live on a GPU), without redoing the rest shape."""
        _check_linear_solver(linear_solver)
        other = copy.copy(self)
        other.linear_solver = linear_solver
        other._kept_factorization = (None, None)
        return other

    @property
    def force_model(self) -> ShellModel:
        """The force-control model (built on first use): the indenter height is an unknown."""
        if self._force_model is None:
            fixed_force = self._fixed.copy()
            fixed_force[-1] = False
            cfg = dataclasses.replace(self.model.config, force_control=True)
            self._force_model = ShellModel(self.model.mesh, self.rest, cfg, fixed_force)
        return self._force_model

    # ------------------------------------------------------------------------------------------
    def params_at(self, q, **extra) -> ShellParams:
        """The model parameters (:class:`ShellParams`, SI) at state ``q`` (3V + 3,) [m]: the
        simulation's, with the indenter center of ``q`` and the ``extra`` entries (e.g. a state's
        lagged ``friction`` data, or ``indenter_force`` [N])."""
        return self.base_params.replace(indenter_center=q[-3:], **extra)

    def _step(self, model, q_guess, params, label, q_prev=None):
        q0 = feasible_start(q_guess, model.config, self.activation_distance, q_prev)
        # The last load step's last factorization preconditions this one (same control mode only).
        control = "force" if model.config.force_control else "depth"
        kept_control, kept = self._kept_factorization
        res = model.equilibrium(
            q0,
            params,
            atol=self.atol,
            max_steps=self.max_newton_iterations,
            factorization=kept if kept_control == control else None,
            name=label,
            linear_solver=self.linear_solver,
        )
        self._kept_factorization = (control, res.state)
        return res

    def _lagged_step(self, model, q_guess, params, label, q_start):
        """One load step from the converged ``q_start``, with lagged friction if μ > 0.

        Returns (:class:`shelljax.Solution`, friction params dict, relative lag change of the normal
        forces); its ``iterations`` and ``stats`` counts add up the re-solves.
        """
        if not model.config.contact.has_friction:
            return self._step(model, q_guess, params, label, q_start), {}, 0.0
        lagged = {
            "friction_anchor": np.array(q_start[:-3].reshape(-1, 3)),
            "friction_normal_force": model.plane_normal_forces(q_start),
        }
        res = self._step(model, q_guess, params.replace(**lagged), label, q_start)
        iterations, factorizations, products = res.iterations, res.stats["factorizations"], res.stats["products"]
        krylov = res.stats["krylov_iterations"]
        for k in range(self.friction_iterations + 1):
            current = model.plane_normal_forces(res.value)
            change = float(np.max(np.abs(current - lagged["friction_normal_force"])))
            change /= max(float(np.max(np.abs(current))), 1e-300)
            if change < FRICTION_LAG_TOLERANCE or k == self.friction_iterations:
                break
            lagged = {**lagged, "friction_normal_force": current}
            res = self._step(model, res.value, params.replace(**lagged), f"{label} (friction lag {k + 1})", res.value)
            iterations += res.iterations
            factorizations += res.stats["factorizations"]
            products += res.stats["products"]
            krylov += res.stats["krylov_iterations"]
        stats = {**res.stats, "factorizations": factorizations, "products": products, "krylov_iterations": krylov}
        res = dataclasses.replace(res, iterations=iterations, stats=stats)
        return res, lagged, change

    def solve(
        self, depth: float | None = None, *, force: float | None = None, steps: int | None = None
    ) -> IndentationState:
        """Equilibrium at indenter travel ``depth`` [m] (from first touch) or at ``force`` [N]."""
        if (depth is None) == (force is None):
            raise InvalidInputError("solve: give exactly one of depth= [m] or force= [N].")
        if depth is not None:
            return self.curve(self._levels(depth, steps))[-1]
        return self.force_curve(self._force_levels(force, steps))[-1]

    def _levels(self, depth, steps):
        if not (0 <= depth < 0.9 * self.top_height):
            raise InvalidInputError(f"depth: must be in [0, {0.9 * self.top_height:.3g}) m, got {depth}.")
        n = steps or max(1, int(math.ceil(depth / self.max_step)))
        return [depth * (i + 1) / n for i in range(n)]

    def _force_levels(self, force, steps):
        if not force >= 0:
            raise InvalidInputError(f"force: must be ≥ 0 N, got {force}.")
        n = steps or 8
        return [force * (i + 1) / n for i in range(n)]

    def curve(self, depths) -> list[IndentationState]:
        """Displacement-controlled continuation through increasing ``depths`` [m]; one state each.

        Each level is warm-started by linear extrapolation of the previous two (secant predictor).
        """
        depths = [float(d) for d in depths]
        if any(b < a for a, b in zip(depths[:-1], depths[1:])) or depths[0] < 0:
            raise InvalidInputError("depths: must be non-negative and increasing.")
        history = [(0.0, self.q_reference)]
        slip = [initial_slip(self.model.config)]

        def step(depth, _prev):
            for d in self._substeps(history[-1][0], depth):
                q_start = history[-1][1]
                res, lagged, change = self._depth_step(history, d)
                slip[0] = accumulate_slip(slip[0], self.model.config, self.activation_distance, q_start, res.value)
                history.append((d, res.value))
            return IndentationState(
                self,
                res.value,
                depth,
                res.iterations,
                res.history,
                lagged,
                change,
                slip[0],
                res.stats["factorizations"],
                res.stats["products"],
                res.stats["krylov_iterations"],
            )

        return continuation(depths, step, progress=self.progress, desc="indentation")

    def _substeps(self, d_prev: float, depth: float) -> list[float]:
        """Travels [m] from ``d_prev`` to ``depth`` in sub-steps of at most ``max_step``."""
        n_sub = max(1, int(math.ceil((depth - d_prev) / self.max_step - 1e-9)))
        # the last one is ``depth`` itself, not a rounded d_prev + (depth − d_prev)·1
        return [d_prev + (depth - d_prev) * k / n_sub for k in range(1, n_sub)] + [depth]

    def _depth_step(self, history, depth: float):
        """One displacement-controlled load step to travel ``depth`` [m] from the last state of
        ``history`` [(travel, q)], secant-predicted: (Solution, friction params, lag change)."""
        guess = secant_predict(history, depth)
        guess[-3:] = self.touch_center - np.array([0.0, 0.0, depth])
        return self._lagged_step(
            self.model, guess, self.params_at(guess), f"indentation depth {depth:.4g} m", history[-1][1]
        )

    def force_curve(self, forces) -> list[IndentationState]:
        """Force-controlled continuation through increasing indenter ``forces`` [N]."""
        forces = [float(f) for f in forces]
        history = [(0.0, self.q_reference)]
        slip = [initial_slip(self.model.config)]

        def step(force, _prev):
            guess = secant_predict(history, force)
            params = self.params_at(guess, indenter_force=force)
            q_start = history[-1][1]
            res, lagged, change = self._lagged_step(
                self.force_model, guess, params, f"indentation force {force:.4g} N", q_start
            )
            slip[0] = accumulate_slip(slip[0], self.model.config, self.activation_distance, q_start, res.value)
            history.append((force, res.value))
            depth = float(self.touch_center[2] - res.value[-1])
            return IndentationState(
                self,
                res.value,
                depth,
                res.iterations,
                res.history,
                lagged,
                change,
                slip[0],
                res.stats["factorizations"],
                res.stats["products"],
                res.stats["krylov_iterations"],
            )

        return continuation(forces, step, progress=self.progress, desc="indentation (force)")

    def travel_states(self, travels, *, solved=None, on_solve=None) -> list[tuple[float, np.ndarray]]:
        """[(travel [m], state q)] at each of the indenter ``travels`` (increasing), solved as
        :meth:`curve` does; see :func:`shelljax.shell3d.solve_travels` for ``solved`` and
        ``on_solve`` (resuming and checkpointing a long run)."""
        return solve_travels(self, travels, solved=solved, on_solve=on_solve)

    def states_at_forces(
        self, forces, *, tolerance: float, solved=None, on_solve=None, max_solves: int = 40
    ) -> list[tuple[float, np.ndarray]]:
        """[(force [N], state q)] at each of the indenter ``forces`` (increasing) to within
        ``tolerance`` [N], solved under displacement control at the travel that matches each
        force: see :func:`shelljax.shell3d.match_forces`."""
        return match_forces(self, forces, tolerance=tolerance, solved=solved, on_solve=on_solve, max_solves=max_solves)

    # ------------------------------------------------------------------------------------------
    def force_function(self, depth: float):
        """Differentiable map θ ↦ indenter force F [N] at indenter travel ``depth`` [m].

        θ is a dict with any of ``gauge_pressure`` [Pa], ``young_modulus`` [Pa], ``thickness`` [m]
        (others keep their values). The equilibrium is differentiated implicitly (forward and
        reverse mode, see :func:`shelljax.shell3d.implicit_equilibrium`). The rest shape (and a sealed
        gas's reference volume) are held at their values for the nominal parameters: this is the
        sensitivity of the forward model with a fixed stress-free shape. With friction, the lagged
        anchors and normal forces of the nominal solve are held fixed too (the last load step's
        sensitivity).
        """
        model = self.model
        state0 = self.solve(depth=depth)
        cache = {"q": state0.q}

        def params_of(theta):
            return self.params_at(state0.q, **state0.friction).replace(**theta)

        def minimise_at(theta):
            q = self._step(model, cache["q"], params_of(theta), "implicit-diff primal", cache["q"])
            cache["q"] = q.value
            return q.value

        def residual(q, theta):
            return model.gradient(q, params_of(theta))

        def hessian_host(q, theta):
            return model.host_hessian(q, params_of(theta), project=False)

        def hessian_device(q, theta):
            return model.device_operator(q, params_of(theta))

        equilibrium = implicit_equilibrium(
            minimise_at,
            residual,
            hessian_host,
            model.free,
            model.n_dofs,
            linear_solver=self.linear_solver,
            hessian_device=hessian_device,
        )

        def force(theta):
            q = equilibrium(theta)
            return -jax.grad(lambda c: model.energy(jnp.concatenate([q[:-3], c]), params_of(theta)))(q[-3:])[2]

        return force
