"""Prescribed motion on the 3D shell: the inflatable hammer held by its handle's base and swung into a wall.

The coarse hammer (bundled meshes/hammer-coarse.stl, 370 faces, the session's 0.3 mm wall, 0.09 kg,
the paper's P_g = 3955 Pa and E = 53.98 MPa, sealed isothermal gas) turned 5° forward about its
handle's base in 40 ms into a wall 5 mm in front of its head, through ``shelljax simulate``.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from shelljax import InvalidInputError
from shelljax.cli import main
from shelljax.geometry import sphere_mesh
from shelljax.scenario import build_system, hold, load_scenario, resolve_object

pytestmark = pytest.mark.slow  # the 3D hammer held and swung: dynamics runs

R = 0.05  # the icosphere of _FakeShell [m]
HEAD_FRONT = 0.16  # the hammer head's +x end [m]
SWING = f"""
name = "swing"
[object]
session = "bundled:sessions/hammer.toml"
mesh = "bundled:meshes/hammer-coarse.stl"
gauge_pressure_Pa = 3955.0
youngs_modulus_Pa = 53.98e6
gas = "isothermal"
[integrator]
scheme = "backward-euler"
dt_s = 1e-3
duration_s = 0.04
newton_step_tolerance_m = 1e-8
[dissipation]
contact_damping_N_s_per_m = 5.0
[[planes]]
name = "wall"
point_m = [{HEAD_FRONT + 0.005}, 0.0, 0.0]
normal = [-1.0, 0.0, 0.0]
activation_distance_m = 1e-3
barrier_stiffness_J_per_m2 = 1e3
[prescribed]
select = "lowest"
within_m = 0.01
axis_point_m = [0.0, 0.0, -0.43]
axis_direction = [0.0, 1.0, 0.0]
times_s = [0.0, 0.04]
angles_deg = [0.0, 5.0]
[outputs]
figures = true
max_frames = 3
preview_gif = true
"""


@pytest.fixture(scope="module")
def swing(tmp_path_factory):
    """The swing run through the CLI: (its summary, its results.json, the directory)."""
    out = tmp_path_factory.mktemp("swing")
    config = out / "swing.toml"
    config.write_text(SWING)
    assert main(["simulate", str(config), "--out", str(out / "run"), "--quiet"]) == 0
    summary = json.loads((out / "run" / "scenario.json").read_text())
    results = json.loads((out / "run" / "swing" / "results.json").read_text())
    return summary, results, out / "run" / "swing"


def test_held_vertices_follow_the_rotation_schedule(swing):
    summary, _, _ = swing
    run = summary["runs"][0]
    # The held positions are set, not solved for: only the rotation's round-off remains (~1e-17 m).
    assert run["held_error_m"] < 1e-12
    # The handle's end cap within 1 cm (17 of the 187 vertices), not the whole hammer.
    assert 3 <= len(run["held_vertices"]) < 40


def test_swing_into_the_wall_converges_without_crossing_it(swing):
    summary, results, run_dir = swing
    steps = results["steps"]
    assert all(steps["converged"])
    gaps = np.asarray(steps["min_gap_m"])[:, 0]
    # The barrier keeps every vertex strictly on the free side; the head starts 5 mm away.
    assert np.all(gaps > 0.0) and gaps[0] > 4e-3
    force = np.asarray(steps["contact_force_N"])[:, 0, 0]
    touching = gaps < 1e-3  # the barrier pushes within its activation distance ĝ = 1 mm, nowhere else
    # The rigid swing would push the head's end 0.08 cos 5° + 0.43 sin 5° + 0.08 − 0.165 = 3.2 cm into the wall: it touches and is pushed back (−x).
    assert touching.any() and np.all(force[~touching] == 0.0) and force.min() < -0.1
    run = summary["runs"][0]
    # Held back by the wall, the head leaves the rigid swing by centimetres (the barrier's range is 1 mm).
    assert run["max_deviation_from_rigid_m"] > 1e-2
    assert run["planes"]["wall"]["first_contact_s"] is not None
    for name in ("figures/trajectory.png", "frames/frame_0000.ply", "preview.gif"):
        assert (run_dir / name).is_file(), name


def test_free_vertices_are_not_prescribed(swing, tmp_path):
    config = tmp_path / "swing.toml"
    config.write_text(SWING)
    scenario = load_scenario(config)
    # The swing's own hammer, built as `shelljax simulate` builds it: its rest-shape solve is the
    # program the swing compiled (a ball of its own would compile another).
    system = hold(scenario, build_system(scenario, resolve_object(scenario)))
    held = set(system.prescribed_vertices)
    dofs = set(system.prescribed_dofs())
    top = int(np.argmax(np.asarray(system.inflated).reshape(-1, 3)[:, 2]))
    assert top not in held and not {3 * top, 3 * top + 1, 3 * top + 2} & dofs
    assert dofs == {3 * i + k for i in held for k in range(3)}
    # At 5° the held vertices are the rest ones turned about y through z₀ = −0.43 m: x' = x cos θ + (z − z₀) sin θ (rounding only).
    rest = np.asarray(system.inflated).reshape(-1, 3)[list(system.prescribed_vertices)]
    turned = np.asarray(system.prescribed_positions(0.04)).reshape(-1, 3)
    c, s = math.cos(math.radians(5.0)), math.sin(math.radians(5.0))
    assert np.max(np.abs(turned[:, 0] - (rest[:, 0] * c + (rest[:, 2] + 0.43) * s))) < 1e-15


@pytest.mark.parametrize(
    "change, field, hint",
    [
        (("within_m = 0.01", "within_m = 1e-6"), "prescribed.within_m", "raise prescribed.within_m"),
        (("times_s = [0.0, 0.04]", "times_s = [0.04, 0.0]"), "prescribed.times_s", "increase strictly"),
        (("angles_deg = [0.0, 5.0]", "angles_deg = [0.0, 5.0, 10.0]"), "prescribed.angles_deg", "one angle"),
        (('select = "lowest"', 'select = "top"'), "prescribed.select", "unknown selection"),
        (('select = "lowest"', "select = [0, 100000]"), "prescribed.select", "not in the"),
        (
            ("axis_direction = [0.0, 1.0, 0.0]", "axis_direction = [0.0, 0.0, 0.0]"),
            "prescribed.axis_direction",
            "nonzero",
        ),
        (("[prescribed]", "[prescribed]\nspin = 1"), "prescribed.spin", "unknown key"),
        (("[outputs]", "[initial]\ndrop_heights_m = [0.1]\n[outputs]"), "initial.drop_heights_m", "not dropped"),
    ],
)
def test_bad_prescribed_input_names_file_field_and_fix(tmp_path, change, field, hint):
    config = tmp_path / "bad.toml"
    config.write_text(SWING.replace(*change))
    with pytest.raises(InvalidInputError) as err:
        scenario = load_scenario(config)
        # Vertex selections are checked against the mesh: use a fake inflated shape instead of a rest solve.
        hold(scenario, _FakeShell())
    message = str(err.value)
    assert str(config) in message and field in message and hint in message and "Fix" in message


class _FakeShell:
    """Just what ``held_vertices`` reads: a 12-vertex icosphere as the inflated shape, gravity −z."""

    inflated = sphere_mesh(R, layout="icosphere", subdivisions=0)[0].reshape(-1)
    gravity = np.array([0.0, 0.0, -9.80665])
