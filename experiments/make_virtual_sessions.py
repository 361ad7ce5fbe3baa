"""Virtual indentation experiments from the 3D shell engine (issue 4, item 3).

Two stages (SI units throughout):

1. ``--curves``: for each parameter set of ``PARAMETER_SETS`` (ball of inflated radius R = 0.13 m,
   ν = 0.4, prescribed gauge pressure), a 3D indentation (``shelljax.shell3d``, 8 mm finger, rigid
   ground) at the paper's 5–20 N in 2.5 N steps (FORCES). Each level is solved under displacement
   control at the indenter travel whose force matches it to FORCE_MATCH (``_force_levels_by_travel``:
   force control lost the indenter past 15 N). The local dimple depth
   w0 = Δz(equator) − Δz(top pole) [m] (both vertical displacements from the inflated reference
   state, the axisymmetric engine's definition) is computed from the vertices and written, with the
   mesh size and each level's wrinkle spectrum (dominant angular mode of the normal displacement and
   its amplitude, ``shelljax.shell3d.wrinkle_spectrum``), to ``shelljax/data/virtual/curves.json``
   (one entry per set, appended as each set is solved so that an interrupted run keeps its work).
2. ``draw_sessions`` (library function, used by ``experiments/compare_estimators.py`` and the tests):
   noisy sessions from the noise-free curves: 3 trials per force level, force noise N(0, 0.05 N)
   rounded to 0.01 N, depth noise N(0, σ_w) rounded to 0.5 mm, one wrinkle count per trial from
   Vella et al.'s n = 1.33 τ^½ with N(0, 1) reading noise, rounded. The 3D meshes affordable here
   do not resolve the wrinkles to a converged count (docs/estimators.md), so the count comes from
   the same law the closed form inverts (limitation).

Usage::

    python experiments/make_virtual_sessions.py --curves [--n-triangles 12000] [--sets 0,1,2] [--watchdog 600]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the checkout's shelljax, not an installed one
CURVES_PATH = ROOT / "shelljax" / "data" / "virtual" / "curves.json"
RADIUS = 0.13  # m
POISSON = 0.4
FORCES = tuple(5.0 + 2.5 * i for i in range(7))  # N: the paper's protocol, 5–20 N in 2.5 N steps
# N: a level's 3D force matches its target to this; the sessions' force noise is 10× larger. At
# 1 mN the search stalled on set 0: states 0.01 mm of travel apart differed by 1–3 mN, the force's
# scatter at Newton's tolerance (FORCE_TOLERANCE per vertex).
FORCE_MATCH = 5e-3
# [N]: Newton's tolerance for the 3D curves, 1e-5 of the forces here. The engine's default
# (1e-8 E h L ≈ 1e-5 N at τ = 10) sits at the round-off floor of the deep states: Newton stalled at
# 2.2e-5 N on the τ = 10 ball at 55 mm (experiments/report_wrinkles3d.py).
FORCE_TOLERANCE = 1e-4
# Deep wrinkling states converge linearly (≈ 5 % per iteration at 2e-4 N on the τ = 100 icosphere
# at 78 mm, where 60 iterations ran out)
NEWTON_ITERATIONS = 250
# (P_g [Pa], E [Pa], h [m]); τ = P R² / √(E h B) between ~25 and ~200 (the axisym fit's range).
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
NOISE_LEVELS = (0.5e-3, 1.0e-3, 2.0e-3)  # m, depth noise per sample
FORCE_NOISE = 0.05  # N
DEPTH_ROUNDING = 0.5e-3  # m
FORCE_ROUNDING = 0.01  # N
N_TRIALS = 3
COUNT_NOISE = 1.0  # wrinkles, reading noise per trial
WRINKLE_RINGS = (0.1, 0.005)  # m: outer radius and width of the rings of the 3D wrinkle spectrum
CURVES_DESCRIPTION = (
    "Noise-free 3D-engine (shelljax.shell3d) force curves of virtual balls; made by experiments/make_virtual_sessions.py "
    "--curves. SI units: force [N] (the indenter force of the displacement-controlled state found for each of the "
    "paper's 5-20 N levels, within 5 mN), w0/top_drop/travel/edges/wrinkle_amplitude [m], pressures and moduli [Pa]; "
    "wrinkle_mode [-] is the dominant angular mode of the normal displacement (shelljax.shell3d.wrinkle_spectrum), "
    "mode_amplitude [m] its amplitude per mode in modes (summed in quadrature over the rings); "
    "observables: the 3D engine's own (shelljax.shell3d.observables: w0 = top-vertex drop, H, D_u, D_l, D_l_mesh, d [m])."
)


def tau(gauge_pressure, young_modulus, thickness, radius=RADIUS, poisson_ratio=POISSON):
    """τ = P_g R² / √(E h B) [-], B = E h³ / (12 (1 − ν²))."""
    bending = young_modulus * thickness**3 / (12.0 * (1.0 - poisson_ratio**2))
    return gauge_pressure * radius**2 / np.sqrt(young_modulus * thickness * bending)


def local_dimple_depth(reference: np.ndarray, deformed: np.ndarray, top: int, band: float) -> float:
    """w0 [m] = Δz(equator ring) − Δz(top vertex), displacements from ``reference`` (V, 3) [m].

    The equator ring: reference vertices within ``band`` [m] of the height of the ball's centre.
    """
    zc = 0.5 * (reference[:, 2].max() + reference[:, 2].min())
    ring = np.abs(reference[:, 2] - zc) < band
    dz = deformed[:, 2] - reference[:, 2]
    return float(dz[ring].mean() - dz[top])


def _load_checkpoint(checkpoint: Path | None) -> list[tuple[float, float, np.ndarray]]:
    """Solved (travel [m], force [N], state) triples saved by an earlier run, by travel."""
    if checkpoint is None or not checkpoint.exists():
        return []
    saved = np.load(checkpoint)
    if "travels" not in saved:
        raise SystemExit(f"{checkpoint}: a checkpoint of an older version of this script (no travels); delete it")
    return [(float(t), float(f), q) for t, f, q in zip(saved["travels"], saved["forces"], saved["states"])]


def _save_checkpoint(checkpoint: Path | None, solved) -> None:
    _WATCHDOG["last"] = time.monotonic()
    if checkpoint is not None:
        np.savez(checkpoint, travels=[s[0] for s in solved], forces=[s[1] for s in solved],
                 states=np.stack([s[2] for s in solved]))  # fmt: skip


def _solve_travel(sim, solved, travel: float, halvings: int = 3):
    """Equilibrium at indenter ``travel`` [m], started from the solved states just below it (the
    secant predictor and Newton of ``Indentation.curve``, in its sub-steps); the new
    (travel, force, state) triples are added to ``solved`` (kept sorted by travel). A step whose
    Newton fails is retried as two half steps, up to ``halvings`` times."""
    import shelljax.shell3d as s3
    from shelljax import NoConvergenceError

    below = [s for s in solved if s[0] < travel]
    history = [(0.0, sim.q_reference)] + [(t, q) for t, _, q in below]
    for d in sim._substeps(history[-1][0], travel):
        try:
            res, _, _ = sim._depth_step(history[-2:], d)
        except NoConvergenceError:
            if halvings == 0:
                raise
            print(f"  travel {d * 1e3:.3f} mm: Newton failed, halving the step", flush=True)
            _solve_travel(sim, solved, 0.5 * (history[-1][0] + d), halvings - 1)
            _solve_travel(sim, solved, d, halvings - 1)
            history = [(0.0, sim.q_reference)] + [(t, q) for t, _, q in solved if t <= d]
            continue
        history.append((d, np.asarray(res.x)))
        force = float(s3.observables(sim, res.x, sim._params_for(res.x))["force"])
        solved.append((d, force, history[-1][1]))
        solved.sort(key=lambda s: s[0])


def _force_levels_by_travel(sim, forces, checkpoint: Path | None, max_solves: int = 40):
    """[(force [N], state)] at each of ``forces`` (increasing), solved under displacement control.

    Why not force control: its Newton lost the indenter (residual = F) past 15 N on 3 of 3 balls
    tried. F(travel) increases smoothly, so
    each level is found by secant steps on the travel (at most ``sim.max_step`` forward), then
    regula falsi inside the bracket, until |F − target| ≤ FORCE_MATCH. Every solved state is
    checkpointed (a restarted run reuses them). Raises RuntimeError when a level takes more than
    ``max_solves`` solves.
    """
    solved = _load_checkpoint(checkpoint)
    out = []
    for target in forces:
        for _ in range(max_solves):
            hit = [s for s in solved if abs(s[1] - target) <= FORCE_MATCH]
            if hit:
                out.append((hit[0][1], hit[0][2]))
                print(f"  level {target:.4g} N solved (travel {hit[0][0] * 1e3:.3f} mm)", flush=True)
                break
            lower = [s for s in solved if s[1] < target]
            upper = [s for s in solved if s[1] > target]
            if upper:  # bracketed: regula falsi between the nearest states on either side
                (ta, fa, _), (tb, fb, _) = (lower[-1] if lower else (0.0, 0.0, None)), upper[0]
                travel = ta + (target - fa) * (tb - ta) / (fb - fa)
            else:  # secant extrapolation of the last two states (first touch: F = 0), at most one step
                (ta, fa), (tb, fb) = ([(0.0, 0.0), (0.0, 0.0)] + [s[:2] for s in lower])[-2:]
                slope = (fb - fa) / (tb - ta) if tb > ta and fb > fa else 0.0
                travel = tb + min((target - fb) / slope if slope > 0 else np.inf, sim.max_step)
            _solve_travel(sim, solved, travel)
            _save_checkpoint(checkpoint, solved)
        else:
            raise RuntimeError(f"force level {target} N: no state within {FORCE_MATCH} N after {max_solves} solves")
    return out


def _curve_checkpointed(sim, travels, checkpoint: Path | None):
    """[(travel [m], state)] of ``Indentation.curve`` through ``travels`` (same secant predictor and
    Newton steps), with the solved states saved to ``checkpoint`` (npz) after every level so that a
    restarted process resumes there.

    Why: XLA's CPU runtime wedged mid-curve (a kernel never signalled completion) in 6 of 6 long runs on
    this box; the caller's watchdog kills such a process and a restart continues from the last level.
    """
    solved = _load_checkpoint(checkpoint)
    for travel in travels:
        if not any(s[0] == travel for s in solved):
            _solve_travel(sim, solved, travel)
            _save_checkpoint(checkpoint, solved)
            print(f"  level {travel:.4g} m solved", flush=True)
    return [(t, q) for t, _, q in solved if t in travels]


_WATCHDOG = {"last": time.monotonic()}


def _start_watchdog(limit: float):
    """Exit the process (status 3) when no force level finished for ``limit`` s (a wedged XLA run)."""
    import os
    import threading

    def watch():
        while True:
            time.sleep(5)
            if time.monotonic() - _WATCHDOG["last"] > limit:
                print(f"watchdog: no progress for {limit:.0f} s, exiting for a restart", flush=True)
                os._exit(3)

    threading.Thread(target=watch, daemon=True).start()


def run_with_restarts(cmd: list[str], restarts: int, label: str) -> bool:
    """Run a child process that checkpoints per level; restart it (up to ``restarts`` times) when
    it exits abnormally (the watchdog's exit after a wedged XLA run). True when it succeeded."""
    import subprocess

    for attempt in range(restarts + 1):
        if subprocess.run(cmd).returncode == 0:
            return True
        print(f"{label}: child exited abnormally (attempt {attempt + 1}), restarting from its checkpoint", flush=True)
    return False


def _icosphere(thickness: float, n_triangles: int, seed: int = 0):
    """Icosphere shell of ≈ ``n_triangles`` faces (20·4^k) with a seeded random vertex at the top."""
    import trimesh

    import shelljax.shell3d as s3

    subdivisions = max(0, int(round(np.log(n_triangles / 20.0) / np.log(4.0))))
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=RADIUS)
    top = np.random.default_rng(seed).integers(len(sphere.vertices))
    sphere.apply_transform(trimesh.geometry.align_vectors(sphere.vertices[top], [0.0, 0.0, 1.0]))
    return s3.Shell(s3.ShellMesh.from_arrays(sphere.vertices, sphere.faces, name="icosphere"), thickness)


RANDOM_MESH_REFINED_ARC = 0.06  # [m] finest edges out to 6 cm of arc from the top pole (the wrinkled zone)
RANDOM_MESH_MAX_SPACING = 8e-3  # [m]


def _random_graded(thickness: float, n_triangles: int, seed: int = 0):
    """Shell on ``s3.random_sphere_mesh`` (no rings, sectors or spirals), refined about the top
    pole, of ≈ ``n_triangles`` faces: its top edge length is searched for the count (bottom pole
    edges twice as long; F = 2V − 4 is fixed before the smoothing, so the search skips it)."""
    import shelljax.shell3d as s3

    def mesh(top, smoothing_iterations=25):
        return s3.random_sphere_mesh(RADIUS, top_spacing=top, bottom_spacing=min(2.0 * top, RANDOM_MESH_MAX_SPACING),
                                     max_spacing=RANDOM_MESH_MAX_SPACING, refined_arc=RANDOM_MESH_REFINED_ARC,
                                     growth=0.15, seed=seed, smoothing_iterations=smoothing_iterations)  # fmt: skip

    low, high = np.log(3e-4), np.log(RANDOM_MESH_MAX_SPACING)
    for _ in range(16):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if mesh(np.exp(mid), 0).n_faces > n_triangles else (low, mid)
    shell = s3.Shell(mesh(np.exp(0.5 * (low + high))), thickness)
    if abs(shell.mesh.n_faces / n_triangles - 1.0) > 0.1:
        raise SystemExit(f"random mesh: {n_triangles} faces is out of reach with edges of "
                         f"{RANDOM_MESH_MAX_SPACING * 1e3:g} mm away from the poles (got {shell.mesh.n_faces})")
    return shell


def solve_curve(params, n_triangles: int, pole_refinement: float, checkpoint: Path | None = None,
                forces: tuple[float, ...] = FORCES, travels: tuple[float, ...] | None = None,
                force_tolerance: float | None = None, mesh: str = "ball", max_newton_iterations: int = 60) -> dict:
    """3D force curve of one parameter set at ``forces`` [N] (each within FORCE_MATCH, see
    ``_force_levels_by_travel``), or, when ``travels`` [m] are given, at those indenter travels
    (both displacement-controlled); ``force_tolerance`` [N]: Newton's (None: the engine's
    default 1e-8 E h L); ``mesh`` "ball" (``s3.ball``: rings about the poles, refined there),
    "icosphere" (uniform, no rings or sectors: ≈ ``n_triangles`` faces by subdivision, turned so
    that a seeded random vertex is the top) or "random" (no rings, sectors or spirals, refined
    about the top: ``_random_graded``). Returns a JSON-ready dict (SI)."""
    import shelljax.shell3d as s3

    pg, e, h = params
    meshes = {"ball": lambda: s3.ball(RADIUS, h, n_triangles, pole_refinement=pole_refinement),
              "icosphere": lambda: _icosphere(h, n_triangles), "random": lambda: _random_graded(h, n_triangles)}
    ball = meshes[mesh]()
    t0 = time.perf_counter()
    sim = s3.Indentation(ball, young_modulus=e, poisson_ratio=POISSON, gauge_pressure=pg, gas="prescribed",
                         indenter_radius=0.008, ground=True, progress=False, force_tolerance=force_tolerance,
                         max_newton_iterations=max_newton_iterations)  # fmt: skip
    reference = sim.q_reference[:-3].reshape(-1, 3)
    edges = ball.mesh.vertices[ball.mesh.faces[:, [0, 1, 2]]] - ball.mesh.vertices[ball.mesh.faces[:, [1, 2, 0]]]
    edge_len = np.linalg.norm(edges, axis=-1)
    top = sim.top
    pole_edge = float(edge_len[np.any(ball.mesh.faces == top, axis=1)].mean())
    band = 0.6 * float(np.median(edge_len))
    if travels is None:
        solved = _force_levels_by_travel(sim, tuple(forces), checkpoint)
    else:
        solved = _curve_checkpointed(sim, tuple(travels), checkpoint)
    out = []
    for _, q in solved:
        x = q[:-3].reshape(-1, 3)
        spectrum = s3.wrinkle_spectrum(reference, x, ball.mesh.faces, reference[top], max_radius=WRINKLE_RINGS[0],
                                       ring_width=WRINKLE_RINGS[1])  # fmt: skip
        obs = s3.observables(sim, q, sim._params_for(q))
        out.append({"force": float(obs["force"]),
                    "w0": local_dimple_depth(reference, x, top, band),
                    "observables": {k: float(obs[k]) for k in ("w0", "H", "D_u", "D_l", "D_l_mesh", "d")},
                    "wrinkle_mode": spectrum.count, "wrinkle_amplitude": spectrum.count_amplitude,
                    # per mode, summed in quadrature over the rings (what ``count`` maximises)
                    "mode_amplitude": np.sqrt(np.nansum(spectrum.amplitude**2, axis=0)).tolist(),
                    "modes": spectrum.modes.tolist(),
                    "top_drop": float(reference[top, 2] - x[top, 2]),
                    "travel": float(sim.touch_center[2] - q[-1])})  # fmt: skip
    return {
        "gauge_pressure": pg, "young_modulus": e, "thickness": h, "radius": RADIUS, "poisson_ratio": POISSON,
        "tau": float(tau(pg, e, h)), "gas": "prescribed", "indenter_radius": 0.008,
        "n_faces": int(ball.mesh.faces.shape[0]), "n_vertices": int(ball.mesh.n_vertices),
        "mesh": mesh, "pole_refinement": pole_refinement if mesh == "ball" else 1.0, "pole_edge": pole_edge, "median_edge": float(np.median(edge_len)),
        "equator_band": band, "force": [c["force"] for c in out], "w0": [c["w0"] for c in out],
        "top_drop": [c["top_drop"] for c in out], "travel": [c["travel"] for c in out],
        "wrinkle_mode": [c["wrinkle_mode"] for c in out], "wrinkle_amplitude": [c["wrinkle_amplitude"] for c in out],
        "observables": [c["observables"] for c in out], "modes": out[0]["modes"] if out else [],
        "mode_amplitude": [c["mode_amplitude"] for c in out],
        "force_tolerance": sim.atol, "solve_seconds": time.perf_counter() - t0, "machine": f"{platform.machine()} ({platform.system()})",
    }  # fmt: skip


def load_curves(path: Path = CURVES_PATH) -> list[dict]:
    """The bundled noise-free 3D curves (list of dicts, SI)."""
    return json.loads(Path(path).read_text())["curves"]


def _session(curve: dict, force, depth, counts, *, name: str, notes: str, manometer: bool = False):
    from shelljax.session import Session

    trial = np.repeat(np.arange(1, N_TRIALS + 1), len(curve["force"]))
    return Session(
        source=Path(f"virtual/{name or 'session'}.toml"), object_name=name or "virtual ball",
        radius=curve["radius"], radius_std=0.0, thickness=curve["thickness"], thickness_std=0.0,
        poisson_ratio=curve["poisson_ratio"], trial=trial, force=force, depth=depth,
        wrinkle_counts=counts, manometer_gauge_pressure=curve["gauge_pressure"] if manometer else None,
        notes=f"virtual (3D engine, {curve['n_faces']} faces); truth P_g={curve['gauge_pressure']} Pa, "
              f"E={curve['young_modulus']} Pa; {notes}",
    )  # fmt: skip


def draw_session(curve: dict, depth_noise: float, seed: int, *, manometer: bool = False, name: str = ""):
    """One noisy :class:`shelljax.session.Session` from a noise-free ``curve`` (see module doc).

    ``depth_noise`` [m] is the standard deviation per depth sample; ``seed`` makes it reproducible.
    """
    rng = np.random.default_rng(seed)
    level = np.tile(np.asarray(curve["force"]), N_TRIALS)
    w = np.tile(np.asarray(curve["w0"]), N_TRIALS)
    # The recorded force is the scale reading; the true force is the solved level.
    force = np.round((level + rng.normal(0.0, FORCE_NOISE, level.size)) / FORCE_ROUNDING) * FORCE_ROUNDING
    depth = np.round((w + rng.normal(0.0, depth_noise, w.size)) / DEPTH_ROUNDING) * DEPTH_ROUNDING
    n_true = 1.33 * np.sqrt(curve["tau"])
    counts = np.round(n_true + rng.normal(0.0, COUNT_NOISE, N_TRIALS))
    return _session(curve, force, depth, counts, name=name, manometer=manometer,
                    notes=f"depth noise {depth_noise} m; seed {seed}")


def noise_free_session(curve: dict, *, name: str = ""):
    """The session of ``curve`` without any noise or rounding: exact forces and depths, and the
    continuous count 1.33 τ^½ for every trial (what a fit of it gets wrong is the model's bias)."""
    level = np.tile(np.asarray(curve["force"]), N_TRIALS)
    depth = np.tile(np.asarray(curve["w0"]), N_TRIALS)
    counts = np.full(N_TRIALS, 1.33 * np.sqrt(curve["tau"]))
    return _session(curve, level, depth, counts, name=name, notes="no noise")


def draw_sessions(curves: list[dict], *, realisations: int = 2, base_seed: int = 2026) -> list[tuple[dict, object]]:
    """Test sessions: every curve × NOISE_LEVELS × ``realisations``; list of (truth, Session)."""
    out = []
    for i, c in enumerate(curves):
        k = c.get("set", i)  # seeds and names follow the parameter set, not the list position
        for j, sigma in enumerate(NOISE_LEVELS):
            for r in range(realisations):
                seed = base_seed + 1000 * k + 100 * j + r
                name = f"set{k}_noise{sigma * 1e3:.1f}mm_r{r}"
                truth = {"set": k, "depth_noise": sigma, "realisation": r, "seed": seed, "name": name,
                         "gauge_pressure": c["gauge_pressure"], "young_modulus": c["young_modulus"]}  # fmt: skip
                out.append((truth, draw_session(c, sigma, seed, name=name)))
    return out


def calibration_sessions(curves: list[dict], *, base_seed: int = 7000) -> list:
    """One calibration session (manometer = true P_g, 1 mm depth noise) per curve."""
    return [draw_session(c, 1.0e-3, base_seed + c.get("set", i), manometer=True, name=f"calib_set{c.get('set', i)}")
            for i, c in enumerate(curves)]  # fmt: skip


def main():
    import jax

    # XLA's CPU runtime wedged (every thread in a futex wait, the main thread in
    # CpuPjRtRawLoadedExecutable::Execute → BlockUntilReady, no CPU use) in every long run on this
    # 2-core box, with or without asynchronous dispatch (cf. jax-ml/jax#25861) and single-threaded
    # Eigen. Synchronous dispatch is kept; the real remedy is the per-level checkpoint + watchdog.
    jax.config.update("jax_cpu_enable_async_dispatch", False)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--curves", action="store_true", help="solve the 3D curves (slow: minutes per set)")
    ap.add_argument("--n-triangles", type=int, default=12000)
    ap.add_argument("--pole-refinement", type=float, default=6.0)
    ap.add_argument("--sets", default="", help="comma-separated indices (default: all)")
    ap.add_argument("--out", type=Path, default=CURVES_PATH)
    ap.add_argument("--restarts", type=int, default=10, help="child restarts per set after a wedged run")
    ap.add_argument("--watchdog", type=float, default=600.0,
                    help="seconds without a solved level before a child is restarted (raise it for fine meshes)")
    ap.add_argument("--child", action="store_true", help="(internal) solve the given sets in this process")
    args = ap.parse_args()
    if not args.curves:
        ap.error("nothing to do: pass --curves")
    sets = [int(s) for s in args.sets.split(",")] if args.sets else range(len(PARAMETER_SETS))
    if not args.child:
        for i in sets:
            cmd = [sys.executable, __file__, "--curves", "--child", "--sets", str(i), "--out", str(args.out),
                   "--n-triangles", str(args.n_triangles), "--pole-refinement", str(args.pole_refinement),
                   "--watchdog", str(args.watchdog)]  # fmt: skip
            run_with_restarts(cmd, args.restarts, f"set {i}")
        return
    _start_watchdog(args.watchdog)
    data = json.loads(args.out.read_text()) if args.out.exists() else {"description": CURVES_DESCRIPTION, "curves": []}
    done = {(c["gauge_pressure"], c["young_modulus"], c["thickness"], c["n_faces"]) for c in data["curves"]}
    for i in sets:
        p = PARAMETER_SETS[i]
        t0 = time.perf_counter()
        try:
            ckpt = Path(f"/tmp/shelljax_virtual_set{i}_{args.n_triangles}_travel.npz")
            c = solve_curve(p, args.n_triangles, args.pole_refinement, ckpt, force_tolerance=FORCE_TOLERANCE,
                            max_newton_iterations=NEWTON_ITERATIONS)
        except Exception as err:  # record and continue: one failed set must not lose the others
            print(f"set {i} {p}: FAILED ({type(err).__name__}: {str(err)[:200]})", flush=True)
            continue
        if (c["gauge_pressure"], c["young_modulus"], c["thickness"], c["n_faces"]) in done:
            continue
        c["set"] = i
        data["curves"].append(c)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(data, indent=1))
        print(f"set {i} {p}: tau={c['tau']:.0f} faces={c['n_faces']} pole_edge={c['pole_edge'] * 1e3:.2f} mm "
              f"w0={[round(w * 1e3, 1) for w in c['w0']]} mm ({time.perf_counter() - t0:.0f} s)", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
