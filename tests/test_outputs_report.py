"""What a run leaves to look at: coloured frames and previews, the scenario figures, report.md, a quiet terminal.

The pictures are checked for existing and holding data, never pixel by pixel (docs/gallery.md
shows them). Most tests draw a synthetic squashed ball (no dynamics); the last one runs the tiny
``shelljax simulate`` config of tests/test_dynamics_shell.py through the CLI.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import trimesh

from shelljax import dynamics as d
from shelljax.geometry import sphere_mesh
from shelljax.report import diagnosis_markdown, scenario_markdown
from shelljax.scenario._figures import (
    digest,
    keyframe_steps,
    keyframes_figure,
    max_deformation_figure,
    trajectory_figure,
)

R = 0.05  # [m]


def _ball(steps=8, squash=0.3, wall: bool = False, dx: float = 0.0) -> d.Trajectory:
    """A ball falling onto the ground (and, with ``wall``, moving toward a wall at x = 0.3 m), flattened
    by up to ``squash`` of its height (and a flat patch) at the middle step; the records a run writes, made up."""
    nodes, faces = sphere_mesh(R, layout="icosphere", subdivisions=2)
    t = np.arange(steps) * 1e-3
    flat = squash * np.sin(np.pi * np.arange(steps) / (steps - 1))
    lift = np.maximum(0.02 * (1 - 2 * np.arange(steps) / (steps - 1)), 0.0)
    positions = []
    for k in range(steps):
        x = nodes * [1 + flat[k] / 2, 1 + flat[k] / 2, 1 - flat[k]]
        x[:, 2] = np.maximum(x[:, 2], -R * (1 - 2 * flat[k]))  # a flat patch where it presses
        x[:, 2] -= x[:, 2].min() - lift[k]
        x[:, 0] += dx * k
        positions.append(x.ravel())
    positions = np.array(positions)
    n_planes = 2 if wall else 1
    gaps = np.stack(
        [positions.reshape(steps, -1, 3)[:, :, 2].min(axis=1)]
        + ([0.3 - positions.reshape(steps, -1, 3)[:, :, 0].max(axis=1)] if wall else []),
        axis=1,
    )
    force = np.zeros((steps, n_planes, 3))
    force[:, 0, 2] = 50.0 * flat
    com = positions.reshape(steps, -1, 3).mean(axis=1)
    records = {
        "time_s": t,
        "com_position_m": com,
        "com_velocity_m_per_s": np.gradient(com, t, axis=0),
        "contact_force_N": force,
        "min_gap_m": gaps,
        "gas_pressure_Pa": 1000.0 + 2000.0 * flat,
        "gas_volume_m3": np.full(steps, 4e-4),
        "position_m": positions,
        "converged": np.ones(steps, bool),
        "feasible_start": np.ones(steps, bool),
        "newton_iterations": np.ones(steps, int),
        "newton_matrices": np.ones(steps, int),
        "residual_history_N": np.zeros((steps, 2)),
        **{f"{k}_energy_J": np.zeros(steps) for k in ("kinetic", "elastic", "gas", "gravity", "contact", "total")},
    }
    normals = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])[:n_planes]
    return d.Trajectory(
        records=records,
        plane_names=("ground", "wall")[:n_planes],
        plane_normals=normals,
        contact_distances_m=np.full(n_planes, 1e-3),
        gravity_m_per_s2=np.array([0.0, 0.0, -9.81]),
        dt_s=1e-3,
        faces=faces,
    )


@pytest.mark.parametrize("mesh_format", ["ply", "glb"])
def test_frames_carry_strain_colours_and_the_pictures_are_written(tmp_path, mesh_format):
    written = d.write_results(_ball(), tmp_path, max_frames=4, mesh_format=mesh_format)
    for name in (
        "preview.gif",
        "figures/closeup.png",
        "figures/max_deformation.png",
        f"frames/frame_0000.{mesh_format}",
    ):
        assert tmp_path / name in written and (tmp_path / name).stat().st_size > 2_000, name
    frames = sorted((tmp_path / "frames").glob(f"*.{mesh_format}"))
    meshes = [trimesh.load(f, force="mesh", process=False) for f in frames]
    colours = [np.asarray(m.visual.vertex_colors) for m in meshes]
    assert all(c.shape == (m.vertices.shape[0], 4) for c, m in zip(colours, meshes))
    # the free ball at t = 0 is its own reference (one colour); squashed, it is coloured unevenly, its patch dark
    assert len(np.unique(colours[0][:, :3], axis=0)) == 1
    assert max(len(np.unique(c[:, :3], axis=0)) for c in colours) > 5
    assert min(int(c[:, :3].astype(int).sum(axis=1).min()) for c in colours) < 150


def test_scenario_figures_of_drops_a_wall_and_a_swing(tmp_path):
    drops = [digest(_ball(squash=s), f"drop {h} m") for s, h in ((0.2, 0.5), (0.3, 1.0), (0.4, 1.5))]
    assert max_deformation_figure(drops, tmp_path / "max_deformation.png").stat().st_size > 10_000
    assert trajectory_figure(drops, tmp_path / "drops.png").stat().st_size > 10_000  # height against time
    bounce = [digest(_ball(wall=True, dx=0.03), "bounce")]
    assert trajectory_figure(bounce, tmp_path / "bounce.png").stat().st_size > 10_000  # path in the x-z plane
    swing = _ball(steps=10)
    positions = swing["position_m"].reshape(10, -1, 3)
    rigid = positions[0] + np.zeros_like(positions)
    steps = keyframe_steps(swing["time_s"], np.linalg.norm(positions - rigid, axis=2).max(axis=1))
    assert len(steps) >= 4
    run = digest(swing, "swing")
    run.frames.update({int(k): positions[k] for k in steps})
    assert (
        keyframes_figure(run, {int(k): rigid[k] for k in steps}, np.array([0.0, 1.0, 0.0]), tmp_path / "k.png")
        .stat()
        .st_size
        > 10_000
    )


def _links(markdown: str) -> list[str]:
    return re.findall(r"\]\(([^)]+)\)", markdown)


def test_the_scenario_report_links_files_that_exist(tmp_path):
    run_dir = tmp_path / "h0.50m"
    d.write_results(_ball(), run_dir, max_frames=3)
    drops = [digest(_ball(), "drop 0.5 m")]
    max_deformation_figure(drops, tmp_path / "max_deformation.png")
    impact = {
        "plane": "ground",
        "onset_s": 0.01,
        "cor": 0.6,
        "contact_time_s": 0.02,
        "peak_force_N": 40.0,
        "max_compression_m": 0.01,
        "max_contact_diameter_m": 0.05,
    }
    summary = {
        "name": "synthetic",
        "scenario": "x.toml",
        "object": {"parameters": "given"},
        "contact_damping_N_s_per_m": 1.0,
        "parameters": {
            "gauge_pressure_Pa": 1e3,
            "youngs_modulus_Pa": 2e6,
            "poisson_ratio": 0.4,
            "thickness_m": 1e-3,
            "mass_kg": 0.1,
            "gas": "adiabatic",
            "mesh_faces": 320,
            "dt_s": 1e-3,
            "scheme": "backward-euler",
        },
        "calibration": None,
        "figures": ["max_deformation.png"],
        "runs": [{"drop_height_m": 0.5, "directory": str(run_dir), "impacts": [impact]}],
    }
    markdown = scenario_markdown(summary, tmp_path)
    links = _links(markdown)
    assert {"max_deformation.png", "h0.50m/preview.gif", "h0.50m/figures/closeup.png", "h0.50m/results.json"} <= set(
        links
    )
    assert all((tmp_path / link).is_file() for link in links if link != "scenario.json"), links
    assert "| drop 0.5 m | ground | 0.0100 | 0.6000 |" in markdown


def test_the_diagnosis_report_has_the_verdict_and_its_figure():
    gap = {"rms_standardized": 2.0, "by_observable": {"depth": {"rms": 1e-3, "unit": "m", "rms_percent": 5.0}}}
    report = {
        "verdict": "depth_offset",
        "ranking": [
            {"effect": "depth_offset", "status": "ok", "score": -10.0, "score_se": 1.0, "delta": 5.0, "delta_se": 1.0}
        ],
        "gap_before": gap,
        "gap_after": gap,
        "shrink": 1.0,
        "where": {"misfit_groups": [], "misfit_threshold_p": 0.01},
    }
    markdown = diagnosis_markdown(report)
    assert "**Verdict:** depth_offset" in markdown and {"diagnosis.png", "diagnosis.json"} <= set(_links(markdown))


@pytest.mark.slow
def test_simulate_writes_report_and_scenario_figures_and_keeps_compile_logs_for_verbose(tmp_path, capsys):
    from test_dynamics_shell import TINY

    from shelljax.cli import main

    config = tmp_path / "tiny.toml"
    config.write_text(TINY)
    # no --quiet: the progress bars go to stderr, the compile log does not, stdout keeps its results
    assert main(["simulate", str(config), "--out", str(tmp_path / "out")]) == 0
    captured = capsys.readouterr()
    assert "jit(" not in captured.err and "programs compiled" not in captured.err
    assert "results:" in captured.out and "simulating tiny" in captured.err and "%|" not in captured.out
    out = tmp_path / "out"
    for name in ("report.md", "max_deformation.png", "trajectory.png"):
        assert (out / name).stat().st_size > 1_000, name
    links = _links((out / "report.md").read_text())
    assert "h0.00m/preview.gif" in links and all((out / link).is_file() for link in links), links
    assert json.loads((out / "scenario.json").read_text())["figures"] == ["max_deformation.png", "trajectory.png"]
    mesh = trimesh.load(out / "h0.00m" / "frames" / "frame_0000.ply", process=False)
    assert mesh.visual.kind == "vertex"
    assert main(["simulate", str(config), "--out", str(tmp_path / "again"), "--quiet", "--verbose"]) == 0
    err = capsys.readouterr().err
    assert "drop 0.00 m: " in err and "scenario figures: " in err and "%|" not in err  # the stage log, no bars


def test_the_run_report_has_the_table_and_the_figures(tmp_path):
    from test_runner_cli import paper_variant

    from shelljax.runner import run_experiment, summary_table

    config = paper_variant(tmp_path, ["closed-form"], ["bundled:sessions/pezzi.toml"])
    run_dir = run_experiment(config, output_dir=tmp_path, progress=False)
    markdown = (run_dir / "report.md").read_text()
    assert summary_table(json.loads((run_dir / "results.json").read_text())) in markdown
    links = _links(markdown)
    assert "figures/force_depth_pezzi.png" in links and all((run_dir / link).is_file() for link in links), links
