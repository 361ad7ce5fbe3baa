"""Session format: a valid file loads in SI units, every listed bad input fails with a clear message."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from shelljax import InvalidInputError
from shelljax.geometry import make_ball_mesh
from shelljax.session import load_session

FORCES = [5.0, 7.5, 10.0, 12.5, 15.0, 17.5, 20.0]
BASE = {
    "schema_version": 1,
    "object": "test-ball",
    "geometry": {"radius": 130.0, "radius_std": 2.0, "length_unit": "mm"},
    "wall": {"thickness": 0.9, "thickness_std": 0.05, "thickness_unit": "mm"},
    "indentation": {
        "depth_unit": "mm",
        "trial": [1] * 7 + [2] * 7,
        "force": FORCES * 2,
        "depth": [f * 3.0 for f in FORCES] + [f * 3.1 for f in FORCES],
    },
    "wrinkles": {"counts": [8, 9]},
}


def write(tmp_path: Path, doc: dict, name: str = "s.toml") -> Path:
    path = tmp_path / name
    path.write_text(tomli_w.dumps(doc))
    return path


def variant(**changes) -> dict:
    doc = copy.deepcopy(BASE)
    for dotted, value in changes.items():
        *parents, key = dotted.split("__")
        table = doc
        for p in parents:
            table = table[p]
        if value is _DELETE:
            del table[key]
        else:
            table[key] = value
    return doc


_DELETE = object()


def test_valid_session_is_converted_to_si_and_keeps_order(tmp_path):
    s = load_session(write(tmp_path, BASE))
    assert s.radius == pytest.approx(0.13) and s.radius_std == pytest.approx(0.002)
    assert s.thickness == pytest.approx(0.9e-3) and s.thickness_std == pytest.approx(5e-5)
    assert s.poisson_ratio == 0.4  # the paper's default
    np.testing.assert_allclose(s.depth, np.array(BASE["indentation"]["depth"]) * 1e-3)
    np.testing.assert_array_equal(s.force, BASE["indentation"]["force"])
    np.testing.assert_array_equal(s.trial_ids, [1, 2])
    np.testing.assert_array_equal(s.wrinkle_counts, [8, 9])
    assert set(s.input_files) == {str(tmp_path / "s.toml")}


def test_trials_from_csv_beside_the_toml(tmp_path):
    rows = "".join(f"{t},{f},{f * 3}\n" for t in (1, 2) for f in FORCES)
    (tmp_path / "t.csv").write_text("trial,force,depth\n" + rows)
    doc = variant(indentation={"depth_unit": "mm", "trials_csv": "t.csv"})
    s = load_session(write(tmp_path, doc))
    assert s.force.size == 14 and s.depth[0] == pytest.approx(15e-3)
    assert str(tmp_path / "t.csv") in s.input_files


@pytest.mark.parametrize(
    "changes, pattern",
    [
        ({"object": _DELETE}, r"field 'object': missing"),
        ({"wall": _DELETE}, r"field 'wall': missing table"),
        ({"wall__thickness_std": _DELETE}, r"field 'wall.thickness_std': missing"),
        ({"indentation__depth": _DELETE}, r"field 'indentation.depth': missing"),
        ({"geometry__radius": _DELETE}, r"exactly one of 'radius' or 'mesh'"),
        ({"indentation__force": [math.nan] + FORCES[1:] + FORCES}, r"indentation.force\[0\]'.*not finite"),
        ({"indentation__depth": [math.inf] + BASE["indentation"]["depth"][1:]}, r"indentation.depth\[0\]'.*not finite"),
        ({"wall__thickness": math.nan}, r"wall.thickness'.*not finite"),
        ({"indentation__force": [-5.0] + FORCES[1:] + FORCES}, r"indentation.force\[0\]'.*must be positive"),
        ({"indentation__depth": [0.0] + BASE["indentation"]["depth"][1:]}, r"indentation.depth\[0\]'.*must be positive"),
        ({"indentation__force": [5.0, 10.0] * 7}, r"only 2 distinct force level"),
        ({"indentation__depth_unit": "m"}, r"millimetres written as metres: set depth_unit"),
        ({"wrinkles__counts": [8.5, 9]}, r"wrinkles.counts\[0\]'.*not a non-negative integer"),
        ({"wrinkles__counts": [8, -1]}, r"wrinkles.counts\[1\]'.*not a non-negative integer"),
        ({"wrinkles__counts": [8]}, r"1 counts for 2 trials"),
        ({"colour": "red"}, r"field 'colour': unknown key"),
        ({"wall__thicknes": 1.0}, r"field 'wall.thicknes': unknown key"),
        ({"indentation__depth_unit": "inch"}, r"unknown length unit 'inch'"),
        ({"wall__thickness_unit": "m"}, r"wall.thickness'.*if you wrote millimetres"),
        ({"indentation__trial": [1, 2]}, r"arrays differ in length"),
        ({"poisson_ratio": 0.7}, r"poisson_ratio'.*outside"),
    ],
)
def test_bad_input_is_named(tmp_path, changes, pattern):
    path = write(tmp_path, variant(**changes))
    with pytest.raises(InvalidInputError, match=pattern) as info:
        load_session(path)
    assert str(path) in str(info.value) and "Fix:" in str(info.value)


def test_bad_csv_row_names_line(tmp_path):
    (tmp_path / "t.csv").write_text("trial,force,depth\n1,5,15\n1,oops,22\n")
    path = write(tmp_path, variant(indentation={"depth_unit": "mm", "trials_csv": "t.csv"}))
    with pytest.raises(InvalidInputError, match=r"t.csv, line 3, column 'force': 'oops'"):
        load_session(path)


def test_csv_nan_is_rejected_not_dropped(tmp_path):
    rows = "".join(f"1,{f},{f * 3}\n" for f in FORCES) + "1,20,nan\n"
    (tmp_path / "t.csv").write_text("trial,force,depth\n" + rows)
    path = write(tmp_path, variant(indentation={"depth_unit": "mm", "trials_csv": "t.csv"}, wrinkles={"counts": [8]}))
    with pytest.raises(InvalidInputError, match=r"indentation.depth\[7\]'.*\(in t.csv\).*not finite"):
        load_session(path)


def test_mesh_session_fits_radius(tmp_path):
    make_ball_mesh(0.2, subdivisions=4).export(tmp_path / "ball.ply")
    geometry = {"mesh": "ball.ply", "poke_point": [0.0, 0.0, 0.2], "fit_radius": 0.05}
    s = load_session(write(tmp_path, variant(geometry=geometry)))
    # icosphere vertices lie on the sphere: the fit recovers R up to round-off of the PLY export
    assert s.radius == pytest.approx(0.2, rel=1e-4)
    assert str(tmp_path / "ball.ply") in s.input_files


@pytest.mark.parametrize(
    "make, pattern",
    [
        (lambda d: None, r"geometry.mesh'.*(does not exist|not found|missing)"),
        (lambda d: _holey_ball().export(d / "ball.ply"), r"geometry.mesh'.*watertight"),
        (lambda d: make_ball_mesh(200.0, subdivisions=3).export(d / "ball.ply"), r"geometry.mesh'.*(mm|millimet)"),
    ],
)
def test_bad_mesh_is_named(tmp_path, make, pattern):
    make(tmp_path)
    geometry = {"mesh": "ball.ply", "poke_point": [0.0, 0.0, 0.2]}
    with pytest.raises(InvalidInputError, match=pattern):
        load_session(write(tmp_path, variant(geometry=geometry)))


def _holey_ball():
    mesh = make_ball_mesh(0.2, subdivisions=3)
    mesh.update_faces(np.arange(len(mesh.faces)) > 3)
    return mesh
