"""Rest-shape inverse problem: the stress-free shape whose pressurized equilibrium is the scan.

A scan (photogrammetry) shows the object inflated. We seek rest vertices X such that the scan x_s
is an equilibrium of the shell under the prescribed gauge pressure: r(X) = ∇ₓE(x_s; X) = 0 on the
free dofs. Newton on X with the sparse, nonsymmetric Jacobian ∂r/∂X (per-face 18×18 blocks by
autodiff, same sparsity as the Hessian) converges quadratically from the small-strain guess
X₀ = c + (x_s − c) / (1 + P R (1−ν) / (2 E h)) (c the centroid, R = 3V/A: the scan shrunk by the
membrane strain of a thin sphere whose wall carries the stress P R / (2h) both ways). The rigid
motions of X (which leave r unchanged) are removed by holding X at the same pinned dofs as x; the
matching equations (net force and torque) hold identically.

Stops when max |r| ≤ ``atol`` [N]; then the forward solve from X reproduces the scan up to
``atol`` divided by the shell's stiffness. A failure raises NoConvergenceError with the history
of max |r| [N]. (A plain fixed point X ← X + x_s − x*(X) diverges: a pressurized membrane
amplifies short-wavelength bumps of its rest shape.)
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from .._errors import InvalidInputError, NoConvergenceError
from ..geometry import signed_volume
from ._config import ModelConfig
from ._hessian import rest_jacobian_values
from ._model import ShellModel, rigid_mode_pins
from ._newton import AbstractRootProblem, newton
from ._params import ShellParams
from ._sparse import release_factorizations


def membrane_strain(scan, faces, params) -> tuple[float, float]:
    """(small-strain membrane strain P R (1−ν) / (2 E h) [-] of the scan's equivalent sphere,
    R = 3V/A, the scan's area A [m²])."""
    edges1, edges2 = scan[faces[:, 1]] - scan[faces[:, 0]], scan[faces[:, 2]] - scan[faces[:, 0]]
    area = 0.5 * np.linalg.norm(np.cross(edges1, edges2), axis=1).sum()
    radius = 3.0 * signed_volume(scan, faces) / area
    p, nu, e, h = (
        float(params.gauge_pressure),
        float(params.poisson_ratio),
        float(params.young_modulus),
        float(params.thickness),
    )
    return p * radius * (1 - nu) / (2 * e * h), area


def solve_rest_shape(model, scan, params, *, atol: float, max_steps: int = 30):
    """Rest vertices (V, 3) [m] of ``model``'s mesh for which ``scan`` (V, 3) [m] is in equilibrium.

    ``model``: a :class:`ShellModel` without contacts, pins fixing the rigid modes, prescribed
    gas; ``params``: its parameters (gauge pressure P_g [Pa], E [Pa], ν, h [m]); ``atol`` [N];
    ``max_steps``: Newton iterations per pressure level.
    """
    scan = np.asarray(scan, dtype=np.float64)
    strain, _ = membrane_strain(scan, model.mesh.faces, params)
    centroid = scan.mean(axis=0)
    rest = centroid + (scan - centroid) / (1.0 + strain)
    q_scan = np.concatenate([scan.ravel(), np.zeros(3)])
    # Continuation in pressure: at full pressure, Newton from the small-strain guess can stall on
    # coarse meshes; each level starts from the previous level's rest shape.
    target = float(params.gauge_pressure)
    for level in (0.25, 0.5, 0.75, 1.0):
        level_params = params.replace(gauge_pressure=target * level)
        rest = _newton_rest(model, scan, q_scan, rest, level_params, atol, max_steps, level == 1.0)
    return rest


class RestShapeProblem(AbstractRootProblem):
    """r(X) = ∇ₓE(x_s; X) [N] on the free dofs, as a function of the rest vertices X (flattened, with
    the model's 3 indenter dofs, fixed, at the end), at the scan's state ``q_scan``."""

    model: ShellModel
    scan: np.ndarray
    q_scan: np.ndarray
    params: ShellParams
    free: np.ndarray

    def __init__(self, model: ShellModel, scan, q_scan, params: ShellParams):
        self.model, self.scan, self.q_scan, self.params = model, scan, q_scan, params
        self.free = model.free

    def _rest(self, x) -> np.ndarray:
        return x[: 3 * self.model.mesh.n_vertices].reshape(-1, 3)

    def residual(self, x) -> np.ndarray:
        return self.model.with_rest(self._rest(x)).host_gradient(self.q_scan, self.params)

    def jacobian(self, x):
        stencil = jnp.asarray(self.model.mesh.stencil)
        data = rest_jacobian_values(
            jnp.asarray(self.scan), jnp.asarray(self._rest(x)), stencil, self.params, self.model.pattern
        )
        return self.model.pattern.matrix(data)


def _newton_rest(model, scan, q_scan, rest, params, atol, max_steps, final):
    """Newton on the rest vertices from ``rest`` to max |r| ≤ ``atol`` [N] (1000 ``atol`` unless
    ``final``: a pressure level on the way only needs to get close). Backtracking on ‖r‖: the first
    steps can overshoot on stiff short modes."""
    problem = RestShapeProblem(model, scan, q_scan, params)
    x0 = np.concatenate([np.asarray(rest).ravel(), np.zeros(3)])
    res = newton(
        problem,
        x0,
        atol=atol if final else 1e3 * atol,
        max_steps=max_steps,
        max_halvings=20,
        armijo=0.0,
        reuse_factorization=False,
        name="rest shape",
        throw=False,
    )
    if not bool(res.converged):
        last = res.history[-1] if res.history else float("nan")
        raise NoConvergenceError(
            f"rest shape: the scan is not an equilibrium of any rest shape found (max force residual "
            f"{last:.3e} N, tolerance {atol:.3e} N); the pressure may be too high for the given "
            "E and h.",
            res.history,
        )
    return problem._rest(res.value)


def solve_rest_scale(model, scan, params, *, atol: float, rtol: float = 1e-6, max_steps: int = 20):
    """Rest shape as the scan shrunk uniformly about its centroid, scaled so that the pressurized
    equilibrium encloses the scan's volume to ``rtol``.

    Exact for a sphere (the equilibrium of a uniformly shrunk sphere is a uniformly inflated one,
    up to mesh effects); for other shapes it is the small-strain guess of :func:`solve_rest_shape`
    (the scan shrunk by 1 + P R (1−ν) / (2 E h)) generalised to a volume match. Returns ``(rest (V, 3) [m], q_equilibrium, max vertex
    mismatch from the scan [m])``. Robust where the exact inverse (:func:`solve_rest_shape`)
    stalls. The fixed point s ← s (V_scan / V(s))^(1/3) contracts by about the membrane strain.
    """
    scan = np.asarray(scan, dtype=np.float64)
    v_scan = signed_volume(scan, model.mesh.faces)
    strain, area = membrane_strain(scan, model.mesh.faces, params)
    pressure = float(params.gauge_pressure)
    if pressure > 0:
        # A force residual δ per vertex moves the volume by ≈ 3 strain δ / (p A_v): bound δ so
        # that the volume can reach rtol on fine meshes, whose vertex loads p A_v are small.
        atol = min(atol, rtol * pressure * area / len(scan))
    bottom = int(np.argmin(scan[:, 2]))
    anchor = scan[bottom].copy()  # the pinned bottom vertex stays put
    scale = 1.0 / (1.0 + strain)
    q = np.concatenate([scan.ravel(), np.zeros(3)])
    history = []
    for _ in range(max_steps):
        rest = anchor + (scan - anchor) * scale
        q = model.with_rest(rest).equilibrium(q, params, atol=atol, name="rest-scale forward solve").value
        vol = float(model.volume(jnp.asarray(q)))
        history.append(abs(vol / v_scan - 1.0))
        if history[-1] <= rtol:
            mismatch = float(np.max(np.linalg.norm(q[:-3].reshape(-1, 3) - scan, axis=1)))
            return rest, q, mismatch
        scale *= (v_scan / vol) ** (1.0 / 3.0)
    raise NoConvergenceError(
        f"rest shape: the pressurized volume misses the scan's by {history[-1]:.3e} (relative) "
        f"after {max_steps} iterations.",
        history,
    )


@dataclasses.dataclass(frozen=True, eq=False)
class InflatedReference:
    """A free shell's stress-free shape and its pressurized equilibrium (no contacts).

    ``rest`` (V, 3) [m]: the rest vertices; ``inflated`` (V, 3) [m]: the equilibrium at the
    gauge pressure, in the frame of the vertices it was solved from (the bottom vertex stays
    put); ``reference_volume`` [m³]: its enclosed volume, where a sealed gas holds P_g;
    ``rest_mismatch`` [m]: the largest distance between ``inflated`` and the scan.
    """

    rest: np.ndarray
    inflated: np.ndarray
    reference_volume: float
    rest_mismatch: float


def inflated_reference(
    shell, params: ShellParams, *, vertices=None, rest_shape: str = "solve", atol: float | None = None
) -> InflatedReference:
    """The rest shape and pressurized reference state of ``shell`` (a :class:`Shell`; its mesh is
    the pressurized scan [m]) under ``params`` (E [Pa], ν, h [m], P_g [Pa], mass), free of contacts.

    ``vertices`` (V, 3) [m]: the scan in the caller's frame (default: the mesh's own);
    ``rest_shape``: "solve" (the scan shrunk uniformly to its pressurized volume), "exact" (the
    inverse problem on every rest vertex) or "scan" (the scan taken as stress-free); ``atol`` [N]:
    Newton's force tolerance (default 1e-8 E h L, L the shell's size). The horizontal rigid modes
    are pinned as :func:`rigid_mode_pins` does and the bottom vertex's height is held, so the
    inflated state stays in the scan's frame. Frees the free shell's kept factorizations.
    """
    if rest_shape not in ("solve", "exact", "scan"):
        raise InvalidInputError(f"rest_shape: use 'solve', 'exact' or 'scan', got {rest_shape!r}.")
    mesh = shell.mesh
    scan = np.asarray(mesh.vertices if vertices is None else vertices, dtype=np.float64)
    if atol is None:
        atol = 1e-8 * float(params.young_modulus) * float(params.thickness) * float(np.ptp(scan, axis=0).max())
    fixed = rigid_mode_pins(scan)
    # The bottom vertex's height is pinned only to remove the vertical translation.
    fixed[3 * int(np.argmin(scan[:, 2])) + 2] = True
    free_model = ShellModel(mesh, scan, ModelConfig(mesh.n_vertices), fixed)
    q_scan = np.concatenate([scan.ravel(), np.zeros(3)])
    pressurized = float(params.gauge_pressure) > 0
    rest = scan
    if rest_shape == "exact" and pressurized:
        rest = solve_rest_shape(free_model, scan, params, atol=atol)
    elif rest_shape == "solve" and pressurized:
        rest, q_scan, _ = solve_rest_scale(free_model, scan, params, atol=atol)
    free_model = free_model.with_rest(rest)
    q = free_model.equilibrium(q_scan, params, atol=atol, name="reference state").value
    inflated = q[:-3].reshape(-1, 3)
    volume = float(free_model.volume(jnp.asarray(q)))
    # The free shell is done with: its factor would otherwise live on through the caller's
    # contact model's compilation, until that model's first factorization.
    release_factorizations()
    return InflatedReference(
        rest=rest,
        inflated=inflated,
        reference_volume=volume,
        rest_mismatch=float(np.max(np.linalg.norm(inflated - scan, axis=1))),
    )
