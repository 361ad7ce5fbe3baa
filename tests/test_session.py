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
from shelljax.session import SHAPE_OBSERVABLES, load_session, write_session

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
        (
            {"indentation__depth": [0.0] + BASE["indentation"]["depth"][1:]},
            r"indentation.depth\[0\]'.*must be positive",
        ),
        ({"indentation__force": [5.0, 10.0] * 7}, r"only 2 distinct force level"),
        ({"indentation__depth_unit": "m"}, r"millimetres written as metres: set depth_unit"),
        ({"wrinkles__counts": [8.5, 9]}, r"wrinkles.counts\[0\]'.*not a non-negative integer"),
        ({"wrinkles__counts": [8, -1]}, r"wrinkles.counts\[1\]'.*not a non-negative integer"),
        ({"wrinkles__counts": [8]}, r"1 counts for 2 trials"),
        ({"colour": "red"}, r"field 'colour': unknown key"),
        ({"wall__thicknes": 1.0}, r"field 'wall.thicknes': unknown key"),
        ({"indentation__depth_unit": "inch"}, r"unknown length unit 'inch'"),
        ({"wall__thickness_unit": "m"}, r"wall.thickness'.*0.9 m is implausibly large.*thickness_unit = \"mm\""),
        ({"indentation__trial": [1, 2]}, r"arrays differ in length"),
        ({"poisson_ratio": 0.7}, r"poisson_ratio'.*outside"),
    ],
)
def test_bad_input_is_named(tmp_path, changes, pattern):
    path = write(tmp_path, variant(**changes))
    with pytest.raises(InvalidInputError, match=pattern) as info:
        load_session(path)
    assert str(path) in str(info.value) and "Fix:" in str(info.value)


_DEPTH = BASE["indentation"]["depth"]


@pytest.mark.parametrize(
    "changes, pattern",
    [
        # the wall 1000x too thin: 0.0009 written in mm, meant in m
        (
            {"wall__thickness": 0.0009, "wall__thickness_std": 0.00005},
            r"wall.thickness' = 0.0009: 0.0009 mm is implausibly small for a wall thickness \(0.05–10 mm\).*thickness_unit = \"m\"",
        ),
        (
            {"wall__thickness": 2.0, "wall__thickness_std": 0.1, "wall__thickness_unit": "um"},
            r"wall.thickness' = 2.0: 2 um is implausibly small for a wall thickness.*thickness_unit = \"mm\"",
        ),
        ({"wall__thickness_std": 1.5}, r"wall.thickness_std' = 1.5: 1.5 mm is not smaller than the thickness 0.9 mm"),
        (
            {"geometry__radius": 13000.0},
            r"geometry.radius' = 13000.0: 13000 mm is implausibly large for a radius.*length_unit",
        ),
        (
            {"geometry__radius": 5.0, "geometry__radius_std": 0.1, "indentation__depth": [d / 20 for d in _DEPTH]},
            r"geometry.radius' = 5.0: 5 mm is implausibly small for a radius of curvature \(0.01–2 m\)",
        ),
        (
            {"indentation__force": [f * 1000 for f in FORCES * 2]},
            r"indentation.force\[0\]' = 5000.0: 5000 N is implausibly large for a finger's force.*force_unit = \"mN\"",
        ),
        (
            {"indentation__depth": [d / 1000 for d in _DEPTH]},
            r"indentation.depth\[0\]' = 0.015: 0.015 mm is implausibly small for an indentation depth.*depth_unit = \"m\"",
        ),
        (
            {"manometer_gauge_pressure": 130.0, "pressure_unit": "kPa"},
            r"manometer_gauge_pressure' = 130.0: 130 kPa is implausibly large for an inflated object's gauge pressure",
        ),
        ({"mass": 800.0}, r"mass' = 800.0: 800 kg is implausibly large.*mass_unit = \"g\""),
        # one depth of trial 1 changed from 45 to 12 mm: it runs backwards while the force rises
        (
            {"indentation__depth": _DEPTH[:4] + [12.0] + _DEPTH[5:]},
            r"indentation.depth\[4\]' = 12.0: trial 1 runs backwards: 12 mm at 15 N after 37.5 mm at 12.5 N \(sample 3\)",
        ),
    ],
)
def test_implausible_values_are_refused_with_the_unit_written(tmp_path, changes, pattern):
    path = write(tmp_path, variant(**changes))
    with pytest.raises(InvalidInputError, match=pattern) as info:
        load_session(path)
    message = str(info.value)
    assert str(path) in message and "Fix:" in message and "\n" not in message


def test_a_backwards_depth_in_a_csv_names_its_line_and_a_fix(tmp_path):
    rows = "".join(f"1,{f},{f * 3}\n" for f in FORCES).replace("1,17.5,52.5", "1,17.5,12")
    (tmp_path / "t.csv").write_text("trial,force,depth\n" + rows)
    path = write(tmp_path, variant(indentation={"depth_unit": "mm", "trials_csv": "t.csv"}, wrinkles={"counts": [8]}))
    with pytest.raises(
        InvalidInputError,
        match=r"indentation.depth\[5\]' = 12.0: \(in t.csv, line 7\) trial 1 runs backwards"
        r".*Fix: re-measure or delete that sample",
    ):
        load_session(path)


def test_a_new_sweep_within_one_trial_is_not_a_backwards_depth(tmp_path):
    # trial defaults to 1: two sweeps 5 -> 20 N in one trial, the force falls back between them
    doc = variant(indentation__trial=_DELETE, wrinkles__counts=[8])
    assert load_session(write(tmp_path, doc)).trial_ids.tolist() == [1]


def test_every_bundled_session_loads():
    from shelljax.session import bundled_sessions, load_rigid_press, session_kind

    paths = bundled_sessions("**/*.toml")
    assert len(paths) >= 26
    for path in paths:
        (load_rigid_press if session_kind(path) == "rigid_press" else load_session)(path)


def test_bad_csv_row_names_line(tmp_path):
    (tmp_path / "t.csv").write_text("trial,force,depth\n1,5,15\n1,oops,22\n")
    path = write(tmp_path, variant(indentation={"depth_unit": "mm", "trials_csv": "t.csv"}))
    with pytest.raises(InvalidInputError, match=r"t.csv, line 3, column 'force': 'oops'"):
        load_session(path)


def test_csv_nan_is_rejected_not_dropped(tmp_path):
    rows = "".join(f"1,{f},{f * 3}\n" for f in FORCES) + "1,20,nan\n"
    (tmp_path / "t.csv").write_text("trial,force,depth\n" + rows)
    path = write(tmp_path, variant(indentation={"depth_unit": "mm", "trials_csv": "t.csv"}, wrinkles={"counts": [8]}))
    with pytest.raises(InvalidInputError, match=r"indentation.depth\[7\]'.*\(in t.csv, line 9\).*not finite"):
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


# The paper's evaluation rig: the deformed ball's shape at some (trial, force) points, in mm.
SHAPE_CSV = """trial,force,height,upper_diameter,contact_diameter,sunken_depth
1,5,250.5,40.0,60.5,2.0
1,10,248.0,,70.0,
2,10,247.5,55.0,71.0,0
"""


def shape_session(tmp_path: Path, shape: dict, csv_text: str | None = None) -> Path:
    if csv_text is not None:
        (tmp_path / "shape.csv").write_text(csv_text)
    return write(tmp_path, variant(shape=shape))


def test_shape_from_csv_keeps_missing_cells_as_nan(tmp_path):
    s = load_session(shape_session(tmp_path, {"length_unit": "mm", "shape_csv": "shape.csv"}, SHAPE_CSV))
    np.testing.assert_array_equal(s.shape_trial, [1, 1, 2])
    assert s.shape_trial.dtype == s.trial.dtype
    np.testing.assert_array_equal(s.shape_force, [5.0, 10.0, 10.0])
    assert tuple(s.shape) == SHAPE_OBSERVABLES
    np.testing.assert_allclose(s.shape["height"], [0.2505, 0.248, 0.2475])
    np.testing.assert_allclose(s.shape["upper_diameter"], [0.04, np.nan, 0.055])
    np.testing.assert_allclose(s.shape["sunken_depth"], [2e-3, np.nan, 0.0])
    assert str(tmp_path / "shape.csv") in s.input_files


def test_shape_inline_with_a_subset_of_observables(tmp_path):
    shape = {
        "length_unit": "cm",
        "force_unit": "mN",
        "trial": [1, 2],
        "force": [5000.0, 10000.0],
        "contact_diameter": [6.0, 7.0],
    }
    s = load_session(shape_session(tmp_path, shape))
    np.testing.assert_array_equal(s.shape_trial, [1, 2])
    np.testing.assert_allclose(s.shape_force, [5.0, 10.0])
    assert list(s.shape) == ["contact_diameter"]
    np.testing.assert_allclose(s.shape["contact_diameter"], [0.06, 0.07])


def test_session_without_shape_has_none(tmp_path):
    s = load_session(write(tmp_path, BASE))
    assert s.shape is None and s.shape_trial is None and s.shape_force is None


_INLINE = {"trial": [1, 2], "force": [5.0, 10.0], "height": [0.25, 0.24]}


@pytest.mark.parametrize(
    "shape, pattern",
    [
        ({**_INLINE, "hieght": [0.2, 0.2]}, r"field 'shape.hieght': unknown key"),
        ({**_INLINE, "shape_csv": "shape.csv"}, r"field 'shape': give exactly one of shape_csv or inline.*'trial'"),
        ({"length_unit": "m"}, r"field 'shape': give exactly one of shape_csv or inline.*neither"),
        ({**_INLINE, "height": [0.25]}, r"field 'shape': arrays differ in length \(trial 2, force 2, height 1\)"),
        ({"trial": [1], "force": [5.0]}, r"field 'shape': no observable given"),
        ({"force": [5.0], "height": [0.2]}, r"field 'shape.trial': missing"),
        ({**_INLINE, "height": [0.25, math.nan]}, r"field 'shape.height\[1\]'.*value nan is not finite"),
        ({**_INLINE, "height": [0.25, 0.0]}, r"field 'shape.height\[1\]'.*value 0.0 must be positive"),
        (
            {**_INLINE, "sunken_depth": [0.0, -0.01]},
            r"field 'shape.sunken_depth\[1\]'.*value -0.01 must be non-negative",
        ),
        ({**_INLINE, "force": [5.0, -10.0]}, r"field 'shape.force\[1\]'.*value -10.0 must be positive"),
        (
            {**_INLINE, "trial": [1, 3]},
            r"field 'shape.trial\[1\]'.*trial id 3 is not among the \[indentation\] trial ids \[1, 2\]",
        ),
        ({**_INLINE, "trial": [1, 1.5]}, r"field 'shape.trial\[1\]'.*trial id 1.5 is not an integer"),
        ({**_INLINE, "height": [250.0, 240.0]}, r"field 'shape.height\[0\]'.*250 m is implausibly large.*length_unit"),
        ({**_INLINE, "length_unit": "inch"}, r"field 'shape.length_unit'.*unknown length unit 'inch'"),
        ({**_INLINE, "height": []}, r"field 'shape.height'.*expected a non-empty array"),
        ({"shape_csv": "absent.csv"}, r"field 'shape.shape_csv'.*absent.csv does not exist"),
    ],
)
def test_bad_shape_is_named(tmp_path, shape, pattern):
    path = shape_session(tmp_path, shape)
    with pytest.raises(InvalidInputError, match=pattern) as info:
        load_session(path)
    assert str(path) in str(info.value) and "Fix:" in str(info.value)


@pytest.mark.parametrize(
    "csv_text, pattern",
    [
        ("trial,force,height,height\n1,5,250,250\n", r"header column 'height' appears 2 times"),
        ("trial,height\n1,250\n", r"header \['trial', 'height'\] has no 'force' column"),
        ("trial,force\n1,5\n", r"has no observable column"),
        ("trial,force,hight\n1,5,250\n", r"header column 'hight' is unknown"),
        ("trial,force,height\n1,5,250\n1,10\n", r"shape.csv, line 3: expected 3 cells \(trial,force,height\), got 2"),
        ("trial,force,height\n1,5,250\n1,10,tall\n", r"shape.csv, line 3, column 'height': 'tall' is not a number"),
        ("trial,force,height\n1,,250\n", r"shape.csv, line 2, column 'force': '' is not a number"),
        ("trial,force,height,sunken_depth\n1,5,250,\n1,10,240,\n", r"column 'sunken_depth' is empty in every row"),
        (
            "trial,force,height,sunken_depth\n1,5,250,2\n1,10,,\n",
            r"field 'shape\[1\]'.*line 3.*\(trial 1, force 10\) has no measured observable",
        ),
        (
            "trial,force,height\n1,5,250\n1,10,nan\n",
            r"field 'shape.height\[1\]'.*\(in shape.csv, line 3\) value nan is not finite",
        ),
        ("trial,force,height\n1,5,250\n7,10,240\n", r"field 'shape.trial\[1\]'.*line 3.*trial id 7 is not among"),
        ("trial,force,height\n", r"no shape points"),
    ],
)
def test_bad_shape_csv_is_named(tmp_path, csv_text, pattern):
    path = shape_session(tmp_path, {"length_unit": "mm", "shape_csv": "shape.csv"}, csv_text)
    with pytest.raises(InvalidInputError, match=pattern) as info:
        load_session(path)
    assert "Fix:" in str(info.value)


def _written_session_arguments() -> dict:
    rng = np.random.default_rng(0)
    forces = np.array(FORCES * 2)
    return dict(
        object_name="written-ball",
        radius=0.13,
        radius_std=0.002,
        thickness=0.9e-3,
        thickness_std=5e-5,
        trial=np.repeat([1, 2], 7),
        force=forces,
        depth=forces * 3e-3 * (1 + 0.01 * rng.standard_normal(forces.size)),
        wrinkle_counts=[8, 9],
        manometer_gauge_pressure=1300.0,
        mass=0.85,
        poisson_ratio=0.45,
        notes="written by a test",
    )


def test_write_session_round_trips_with_shape(tmp_path):
    args = _written_session_arguments()
    shape = {
        "trial": [1, 1, 2],
        "force": [5.0, 10.0, 10.0],
        "height": [0.2505, 0.2480, 0.2475],
        "sunken_depth": [2e-3, np.nan, 0.0],
    }
    written = write_session(tmp_path / "w.toml", **args, shape=shape)
    s = load_session(tmp_path / "w.toml")
    assert (tmp_path / "w_shape.csv").is_file() and str(tmp_path / "w_shape.csv") in s.input_files
    assert s.source == written.source == tmp_path / "w.toml"
    for name in (
        "radius",
        "radius_std",
        "thickness",
        "thickness_std",
        "manometer_gauge_pressure",
        "mass",
        "poisson_ratio",
        "notes",
    ):
        assert getattr(s, name) == args[name], name
    assert s.object_name == args["object_name"]
    np.testing.assert_array_equal(s.trial, args["trial"])
    np.testing.assert_array_equal(s.force, args["force"])
    np.testing.assert_array_equal(s.depth, args["depth"])  # exact: floats are written in full
    np.testing.assert_array_equal(s.wrinkle_counts, args["wrinkle_counts"])
    np.testing.assert_array_equal(s.shape_trial, shape["trial"])
    np.testing.assert_array_equal(s.shape_force, shape["force"])
    assert list(s.shape) == ["height", "sunken_depth"]
    np.testing.assert_array_equal(s.shape["height"], shape["height"])
    np.testing.assert_array_equal(s.shape["sunken_depth"], shape["sunken_depth"])  # NaN stays NaN


def test_write_session_without_shape_writes_no_csv(tmp_path):
    s = write_session(tmp_path / "w.toml", **_written_session_arguments())
    assert s.shape is None and list(tmp_path.iterdir()) == [tmp_path / "w.toml"]


@pytest.mark.parametrize(
    "shape, pattern",
    [
        ({"trial": [1], "force": [5.0], "hieght": [0.2]}, r"argument 'shape': unknown key 'hieght'"),
        ({"trial": [1], "force": [5.0]}, r"argument 'shape': no observable"),
        ({"trial": [1, 2], "force": [5.0], "height": [0.2, 0.2]}, r"argument 'shape': arrays differ in length"),
        (
            {"trial": [1, 1], "force": [5.0, 10.0], "height": [0.2, np.nan], "sunken_depth": [0.0, np.nan]},
            r"field 'shape\[1\]'.*has no measured observable",
        ),
        ({"trial": [3], "force": [5.0], "height": [0.2]}, r"field 'shape.trial\[0\]'.*trial id 3 is not among"),
    ],
)
def test_write_session_rejects_bad_shape_and_writes_nothing(tmp_path, shape, pattern):
    with pytest.raises(InvalidInputError, match=pattern) as info:
        write_session(tmp_path / "w.toml", **_written_session_arguments(), shape=shape)
    assert "Fix:" in str(info.value) and ".write_session-" not in str(info.value)
    assert list(tmp_path.iterdir()) == []
