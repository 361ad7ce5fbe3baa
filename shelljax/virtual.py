"""Virtual indentation experiments: noise-free 3D-engine curves and noisy sessions drawn from them.

Two stages (SI units throughout):

1. :func:`solve_curve`: for one parameter set (P_g [Pa], E [Pa], h [m]) of a ball of inflated
   radius ``RADIUS`` with ν = 0.4 and prescribed gauge pressure, a 3D indentation
   (:mod:`shelljax.shell3d`, 8 mm finger, rigid ground) at the paper's force levels, each solved
   under displacement control at the indenter travel whose force matches it to ``FORCE_MATCH``
   (:meth:`shelljax.shell3d.Indentation.states_at_forces`). The local dimple depth
   w0 = Δz(equator) − Δz(top pole) [m] (both vertical displacements from the inflated reference
   state, the axisymmetric engine's definition) is written with the mesh size and each level's
   wrinkle spectrum. The bundled curves (``CURVES_PATH``) are made by
   ``tools/make_virtual_sessions.py``, which runs every set in a child process under a watchdog
   and resumes from a checkpoint (``experiments/long_runs.py``): XLA's CPU runtime
   wedged in long runs (docs/shell3d.md, *XLA:CPU hangs*).
2. :func:`draw_sessions`: noisy sessions from the noise-free curves: ``N_TRIALS`` trials per force
   level, force noise N(0, ``FORCE_NOISE``) rounded to ``FORCE_ROUNDING``, depth noise N(0, σ_w)
   rounded to ``DEPTH_ROUNDING``, one wrinkle count per trial from Vella et al.'s law
   (:func:`shelljax.physics.scaling_wrinkle_count`) with N(0, ``COUNT_NOISE``) reading noise,
   rounded. The 3D meshes affordable here do not resolve the wrinkles to a converged count
   (docs/estimators.md), so the count comes from the same law the closed form inverts (limitation).
   :func:`write_sessions` writes such sessions to files in bulk, one work item per session with its
   own seed (``shelljax.executor``: in-process or on Dask workers, the same files either way).
"""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path
from typing import Protocol

import numpy as np

from .paper import DEFAULT_POISSON_RATIO, PAPER_FORCES, PAPER_INDENTER_RADIUS
from .physics import PrescribedGas, ShellProperties, scaling_wrinkle_count, tau

CURVES_PATH = Path(__file__).resolve().parent / "data" / "virtual" / "curves.json"
RADIUS = 0.13  # [m]
#: [N]: a level's 3D force matches its target to this, 10× below the sessions' force noise (finer
#: matches stall on the force's scatter at Newton's tolerance).
FORCE_MATCH = 5e-3
#: [N]: Newton's tolerance for the 3D curves, 1e-5 of the forces; the engine's default sits at the
#: round-off floor of the deep states.
FORCE_TOLERANCE = 1e-4
#: Newton iterations per load step: deep wrinkling states converge only linearly.
NEWTON_ITERATIONS = 250
#: (P_g [Pa], E [Pa], h [m]); τ between ~25 and ~200 (the axisymmetric fit's range).
PARAMETER_SETS = (
    (1300.0, 2.34e6, 0.9e-3),
    (1600.0, 1.5e6, 0.7e-3),
    (1000.0, 3.0e6, 0.6e-3),
    (2000.0, 4.0e6, 0.8e-3),
    (1200.0, 1.0e6, 1.0e-3),
    (1800.0, 2.0e6, 0.5e-3),
    (1500.0, 5.0e6, 0.6e-3),
    (1100.0, 1.5e6, 1.2e-3),
    (1700.0, 3.0e6, 1.0e-3),
    (1400.0, 2.5e6, 0.5e-3),
)
NOISE_LEVELS = (0.5e-3, 1.0e-3, 2.0e-3)  # [m], depth noise per sample
FORCE_NOISE = 0.05  # [N]
DEPTH_ROUNDING = 0.5e-3  # [m]
FORCE_ROUNDING = 0.01  # [N]
N_TRIALS = 3
COUNT_NOISE = 1.0  # [wrinkles], reading noise per trial
WRINKLE_RINGS = (0.1, 0.005)  # [m]: outer radius and width of the rings of the 3D wrinkle spectrum
RANDOM_MESH_REFINED_ARC = 0.06  # [m]: finest edges out to 6 cm of arc from the top pole (the wrinkled zone)
RANDOM_MESH_MAX_SPACING = 8e-3  # [m]
CURVES_DESCRIPTION = (
    "Noise-free 3D-engine (shelljax.shell3d) force curves of virtual balls; made by tools/make_virtual_sessions.py "
    "--curves. SI units: force [N] (the indenter force of the displacement-controlled state found for each of the "
    "paper's 5-20 N levels, within 5 mN), w0/top_drop/travel/edges/wrinkle_amplitude [m], pressures and moduli [Pa]; "
    "wrinkle_mode [-] is the dominant angular mode of the normal displacement (shelljax.shell3d.wrinkle_spectrum), "
    "mode_amplitude [m] its amplitude per mode in modes (summed in quadrature over the rings); "
    "observables: the 3D engine's own (shelljax.shell3d.observables: w0 = top-vertex drop, H, D_u, D_l, D_l_mesh, d [m])."
)
#: The estimated quantities that :func:`summarise` reports.
QUANTITIES = ("gauge_pressure", "young_modulus")


# --- curves at force levels or travels -------------------------------------------------------
class SolvedLevelStore(Protocol):
    """Where a long run keeps a curve's solved (travel [m], force [N], state) triples, so that a
    restarted run resumes there (``Checkpoint`` in ``experiments/long_runs.py``: an npz file)."""

    def load(self) -> list: ...

    def save(self, solved: list) -> None: ...


def _resumed(checkpoint: SolvedLevelStore | None) -> dict:
    return {} if checkpoint is None else {"solved": checkpoint.load(), "on_solve": checkpoint.save}


def force_levels_by_travel(sim, forces, checkpoint: SolvedLevelStore | None = None, max_solves: int = 40):
    """[(force [N], state)] of ``sim`` (an Indentation) at each of ``forces`` within
    ``FORCE_MATCH``, resumed from and saved to ``checkpoint``
    (:func:`shelljax.shell3d.match_forces`)."""
    from .shell3d import match_forces

    return match_forces(sim, tuple(forces), tolerance=FORCE_MATCH, max_solves=max_solves, **_resumed(checkpoint))


def travel_levels(sim, travels, checkpoint: SolvedLevelStore | None = None):
    """[(travel [m], state)] of ``sim`` at each of ``travels``, resumed from and saved to
    ``checkpoint`` (:func:`shelljax.shell3d.solve_travels`)."""
    from .shell3d import solve_travels

    return solve_travels(sim, tuple(travels), **_resumed(checkpoint))


# --- meshes -------------------------------------------------------------------------------------
def random_graded_shell(thickness: float, n_triangles: int, seed: int = 0):
    """Shell on :func:`shelljax.geometry.sphere_mesh`'s random layout (no rings, sectors or
    spirals), refined about the top pole, of ≈ ``n_triangles`` faces: its top edge length is
    searched for the count (bottom pole edges twice as long). Raises SystemExit when the count is
    out of reach."""
    from . import shell3d as s3

    def mesh(top, smoothing_iterations=25):
        return s3.ShellMesh.sphere(
            RADIUS,
            layout="random",
            top_spacing=top,
            max_spacing=RANDOM_MESH_MAX_SPACING,
            bottom_spacing=min(2.0 * top, RANDOM_MESH_MAX_SPACING),
            refined_arc=RANDOM_MESH_REFINED_ARC,
            growth=0.15,
            seed=seed,
            smoothing_iterations=smoothing_iterations,
        )

    # F = 2V − 4 is fixed before the smoothing, so the search skips it.
    low, high = np.log(3e-4), np.log(RANDOM_MESH_MAX_SPACING)
    for _ in range(16):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if mesh(np.exp(mid), 0).n_faces > n_triangles else (low, mid)
    shell = s3.Shell(mesh(np.exp(0.5 * (low + high))), thickness)
    if abs(shell.mesh.n_faces / n_triangles - 1.0) > 0.1:
        raise SystemExit(
            f"random mesh: {n_triangles} faces is out of reach with edges of "
            f"{RANDOM_MESH_MAX_SPACING * 1e3:g} mm away from the poles (got {shell.mesh.n_faces})"
        )
    return shell


# --- curves -------------------------------------------------------------------------------------
def local_dimple_depth(reference: np.ndarray, deformed: np.ndarray, top: int, band: float) -> float:
    """w0 [m] = Δz(equator ring) − Δz(top vertex), displacements from ``reference`` (V, 3) [m].

    The equator ring: reference vertices within ``band`` [m] of the height of the ball's centre.
    """
    zc = 0.5 * (reference[:, 2].max() + reference[:, 2].min())
    ring = np.abs(reference[:, 2] - zc) < band
    dz = deformed[:, 2] - reference[:, 2]
    return float(dz[ring].mean() - dz[top])


def _level_record(sim, shell, reference, top, band, q) -> dict:
    """One solved level of a curve: force, dimple depth, observables and wrinkle spectrum (SI)."""
    from . import shell3d as s3

    x = q[:-3].reshape(-1, 3)
    spectrum = s3.wrinkle_spectrum(
        reference, x, shell.mesh.faces, reference[top], max_radius=WRINKLE_RINGS[0], ring_width=WRINKLE_RINGS[1]
    )
    obs = s3.observables(sim, q, sim.params_at(q))
    return {
        "force": float(obs["force"]),
        "w0": local_dimple_depth(reference, x, top, band),
        "observables": {k: float(obs[k]) for k in ("w0", "H", "D_u", "D_l", "D_l_mesh", "d")},
        "wrinkle_mode": spectrum.count,
        "wrinkle_amplitude": spectrum.count_amplitude,
        # per mode, summed in quadrature over the rings (what ``count`` maximises)
        "mode_amplitude": np.sqrt(np.nansum(spectrum.amplitude**2, axis=0)).tolist(),
        "modes": spectrum.modes.tolist(),
        "top_drop": float(reference[top, 2] - x[top, 2]),
        "travel": float(sim.touch_center[2] - q[-1]),
    }


def _make_shell(mesh: str, thickness: float, n_triangles: int, pole_refinement: float):
    from . import shell3d as s3

    if mesh == "ball":
        return s3.ball(RADIUS, thickness, n_triangles, pole_refinement=pole_refinement)
    if mesh == "icosphere":
        # a seeded random vertex on top: no symmetry axis of the icosahedron under the indenter
        return s3.Shell(s3.ShellMesh.sphere(RADIUS, n_triangles, layout="icosphere", seed=0), thickness)
    return random_graded_shell(thickness, n_triangles)


def solve_curve(
    params,
    n_triangles: int,
    pole_refinement: float,
    checkpoint: SolvedLevelStore | None = None,
    forces: tuple[float, ...] = PAPER_FORCES,
    travels: tuple[float, ...] | None = None,
    force_tolerance: float | None = None,
    mesh: str = "ball",
    max_newton_iterations: int = 60,
) -> dict:
    """3D force curve of one parameter set (P_g [Pa], E [Pa], h [m]) at ``forces`` [N] (each
    within ``FORCE_MATCH``), or, when ``travels`` [m] are given, at those indenter travels (both
    displacement-controlled); ``force_tolerance`` [N]: Newton's (None: the engine's default);
    ``mesh`` "ball" (``shell3d.ball``: rings about the poles, refined there), "icosphere"
    (``shelljax.geometry.sphere_mesh``'s, turned) or "random" (:func:`random_graded_shell`). Returns a JSON-ready dict (SI)."""
    from . import shell3d as s3

    pg, e, h = params
    shell = _make_shell(mesh, h, n_triangles, pole_refinement)
    t0 = time.perf_counter()
    properties = ShellProperties(
        gauge_pressure=pg, young_modulus=e, thickness=shell.thickness, poisson_ratio=DEFAULT_POISSON_RATIO
    )
    sim = s3.Indentation(
        shell,
        properties,
        gas=PrescribedGas(),
        indenter_radius=PAPER_INDENTER_RADIUS,
        ground=True,
        progress=False,
        force_tolerance=force_tolerance,
        max_newton_iterations=max_newton_iterations,
    )
    reference = sim.q_reference[:-3].reshape(-1, 3)
    faces = shell.mesh.faces
    edge_len = np.linalg.norm(
        shell.mesh.vertices[faces[:, [0, 1, 2]]] - shell.mesh.vertices[faces[:, [1, 2, 0]]], axis=-1
    )
    pole_edge = float(edge_len[np.any(faces == sim.top, axis=1)].mean())
    band = 0.6 * float(np.median(edge_len))
    if travels is None:
        solved = force_levels_by_travel(sim, forces, checkpoint)
    else:
        solved = travel_levels(sim, travels, checkpoint)
    out = [_level_record(sim, shell, reference, sim.top, band, q) for _, q in solved]
    return {
        "gauge_pressure": pg,
        "young_modulus": e,
        "thickness": h,
        "radius": RADIUS,
        "poisson_ratio": DEFAULT_POISSON_RATIO,
        "tau": float(tau(pg, RADIUS, e, h, DEFAULT_POISSON_RATIO)),
        "gas": "prescribed",
        "indenter_radius": PAPER_INDENTER_RADIUS,
        "n_faces": int(faces.shape[0]),
        "n_vertices": int(shell.mesh.n_vertices),
        "mesh": mesh,
        "pole_refinement": pole_refinement if mesh == "ball" else 1.0,
        "pole_edge": pole_edge,
        "median_edge": float(np.median(edge_len)),
        "equator_band": band,
        **{
            key: [c[key] for c in out]
            for key in (
                "force",
                "w0",
                "top_drop",
                "travel",
                "wrinkle_mode",
                "wrinkle_amplitude",
                "observables",
                "mode_amplitude",
            )
        },
        "modes": out[0]["modes"] if out else [],
        "force_tolerance": sim.atol,
        "solve_seconds": time.perf_counter() - t0,
        "machine": f"{platform.machine()} ({platform.system()})",
    }


def load_curves(path: Path = CURVES_PATH) -> list[dict]:
    """The bundled noise-free 3D curves (list of dicts, SI)."""
    return json.loads(Path(path).read_text())["curves"]


# --- sessions -----------------------------------------------------------------------------------
def _true_count(curve: dict) -> float:
    """Vella et al.'s wrinkle count of the curve's ball (continuous)."""
    return float(
        scaling_wrinkle_count(
            curve["gauge_pressure"], curve["radius"], curve["young_modulus"], curve["thickness"], curve["poisson_ratio"]
        )
    )


def _session(curve: dict, force, depth, counts, *, name: str, notes: str, manometer: bool = False):
    from .session import Session

    trial = np.repeat(np.arange(1, N_TRIALS + 1), len(curve["force"]))
    return Session(
        source=Path(f"virtual/{name or 'session'}.toml"),
        object_name=name or "virtual ball",
        radius=curve["radius"],
        radius_std=0.0,
        thickness=curve["thickness"],
        thickness_std=0.0,
        poisson_ratio=curve["poisson_ratio"],
        trial=trial,
        force=force,
        depth=depth,
        wrinkle_counts=counts,
        manometer_gauge_pressure=curve["gauge_pressure"] if manometer else None,
        notes=f"virtual (3D engine, {curve['n_faces']} faces); truth P_g={curve['gauge_pressure']} Pa, "
        f"E={curve['young_modulus']} Pa; {notes}",
    )


def draw_session(curve: dict, depth_noise: float, seed: int, *, manometer: bool = False, name: str = ""):
    """One noisy :class:`shelljax.session.Session` from a noise-free ``curve`` (module docstring).

    ``depth_noise`` [m] is the standard deviation per depth sample; ``seed`` makes it reproducible.
    """
    rng = np.random.default_rng(seed)
    level = np.tile(np.asarray(curve["force"]), N_TRIALS)
    w = np.tile(np.asarray(curve["w0"]), N_TRIALS)
    # The recorded force is the scale reading; the true force is the solved level.
    force = np.round((level + rng.normal(0.0, FORCE_NOISE, level.size)) / FORCE_ROUNDING) * FORCE_ROUNDING
    depth = np.round((w + rng.normal(0.0, depth_noise, w.size)) / DEPTH_ROUNDING) * DEPTH_ROUNDING
    counts = np.round(_true_count(curve) + rng.normal(0.0, COUNT_NOISE, N_TRIALS))
    return _session(
        curve, force, depth, counts, name=name, manometer=manometer, notes=f"depth noise {depth_noise} m; seed {seed}"
    )


def noise_free_session(curve: dict, *, name: str = ""):
    """The session of ``curve`` without any noise or rounding: exact forces and depths, and the
    continuous wrinkle count of the scaling law for every trial (what a fit of it gets wrong is the
    model's bias)."""
    level = np.tile(np.asarray(curve["force"]), N_TRIALS)
    depth = np.tile(np.asarray(curve["w0"]), N_TRIALS)
    counts = np.full(N_TRIALS, _true_count(curve))
    return _session(curve, level, depth, counts, name=name, notes="no noise")


def _draws(curves: list[dict], realisations: int, base_seed: int):
    """(curve, truth) of every test session: each curve × ``NOISE_LEVELS`` × ``realisations``."""
    for i, c in enumerate(curves):
        k = c.get("set", i)  # seeds and names follow the parameter set, not the list position
        for j, sigma in enumerate(NOISE_LEVELS):
            for r in range(realisations):
                seed = base_seed + 1000 * k + 100 * j + r
                name = f"set{k}_noise{sigma * 1e3:.1f}mm_r{r}"
                yield (
                    c,
                    {
                        "set": k,
                        "depth_noise": sigma,
                        "realisation": r,
                        "seed": seed,
                        "name": name,
                        "gauge_pressure": c["gauge_pressure"],
                        "young_modulus": c["young_modulus"],
                    },
                )


def draw_sessions(curves: list[dict], *, realisations: int = 2, base_seed: int = 2026) -> list[tuple[dict, object]]:
    """Test sessions: every curve × ``NOISE_LEVELS`` × ``realisations``; list of (truth, Session)."""
    return [
        (truth, draw_session(c, truth["depth_noise"], truth["seed"], name=truth["name"]))
        for c, truth in _draws(curves, realisations, base_seed)
    ]


def write_drawn_session(curve: dict, truth: dict, path: str, *, seed: int) -> dict:
    """The work item of one session: drawn from ``curve`` with ``seed`` (:func:`draw_session`) and
    written to ``path`` (a session TOML); returns ``truth`` with the file's path (JSON, SI)."""
    from .session import write_session

    s = draw_session(curve, truth["depth_noise"], seed, name=truth["name"])
    write_session(
        path,
        object_name=s.object_name,
        radius=s.radius,
        radius_std=s.radius_std,
        thickness=s.thickness,
        thickness_std=s.thickness_std,
        trial=s.trial,
        force=s.force,
        depth=s.depth,
        wrinkle_counts=s.wrinkle_counts.astype(int),
        poisson_ratio=s.poisson_ratio,
        notes=s.notes,
    )
    return {**truth, "path": str(path), "units": {"gauge_pressure": "Pa", "young_modulus": "Pa", "depth_noise": "m"}}


def write_sessions(
    curves: list[dict],
    out_dir: str | Path,
    *,
    realisations: int = 2,
    base_seed: int = 2026,
    executor=None,
    progress: bool | None = None,
) -> list[dict]:
    """Write :func:`draw_sessions`' sessions (the same seeds and names) to ``out_dir/<name>.toml``,
    one work item each (``shelljax.executor``; ``executor``: an ``ExecutorOptions``, None for
    in-process), with ``out_dir/items/`` holding each finished one's record and
    ``out_dir/sessions.json`` the index: per session its truth, path and status (a failed one with
    its error). Returns the index's entries."""
    from ._files import atomic_write_text
    from .executor import WorkItem, run_items

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    draws = list(_draws(curves, realisations, base_seed))
    items = [
        WorkItem(truth["name"], write_drawn_session, (c, truth, str(out / f"{truth['name']}.toml")), seed=truth["seed"])
        for c, truth in draws
    ]
    results = run_items(items, run_dir=out, options=executor, progress=progress, desc="drawing sessions")
    index = [
        {**truth, "status": r.status, **({"path": r.value["path"]} if r.status == "done" else {"error": r.error})}
        for (_, truth), r in zip(draws, results)
    ]
    atomic_write_text(
        out / "sessions.json",
        json.dumps(
            {
                "description": "virtual sessions drawn from shelljax.virtual's curves "
                "(SI: gauge_pressure, young_modulus [Pa], depth_noise [m])",
                "sessions": index,
            },
            indent=1,
        ),
    )
    return index


def draw_calibration_sessions(curves: list[dict], *, base_seed: int = 7000) -> list:
    """One calibration session (manometer = true P_g, 1 mm depth noise) per curve."""
    return [
        draw_session(c, 1.0e-3, base_seed + c.get("set", i), manometer=True, name=f"calib_set{c.get('set', i)}")
        for i, c in enumerate(curves)
    ]


def summarise(rows: list[dict], method: str) -> dict:
    """Bias, median |rel. err.|, RMS rel. err. and 95 % coverage per quantity for ``method``.

    ``rows``: per-session records as ``experiments/compare_estimators.py`` writes them, each
    ``{method: {quantity: {"rel_error": …, "covered": …}}}`` (or ``{"error": …}`` for a failure).
    """
    out = {}
    for q in QUANTITIES:
        recs = [r[method][q] for r in rows if method in r and isinstance(r[method], dict) and q in r[method]]
        if not recs:
            continue
        err = np.array([x["rel_error"] for x in recs])
        cov = np.array([x["covered"] for x in recs])
        out[q] = {
            "n": int(err.size),
            "bias": float(err.mean()),
            "median_abs": float(np.median(np.abs(err))),
            "rms": float(np.sqrt(np.mean(err**2))),
            "coverage95": float(cov.mean()),
        }
    out["failed"] = sum(1 for r in rows if isinstance(r.get(method), dict) and "error" in r[method])
    return out
