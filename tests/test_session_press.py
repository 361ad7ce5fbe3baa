"""Rigid-surface press files: a valid one loads in SI units, every listed bad input fails clearly."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from shelljax import InvalidInputError
from shelljax.session import (
    RigidPress,
    file_sha256,
    load_rigid_press,
    load_session,
    session_kind,
    write_rigid_press,
    write_session,
)

# Depths in mm: the pad's compression, with a gauge zero error that makes the first one negative.
PRESS = {
    "schema_version": 1,
    "kind": "rigid_press",
    "object": "table",
    "notes": "pad on the oak table",
    "indentation": {
        "force_unit": "mN",
        "depth_unit": "mm",
        "trial": [1, 1, 1, 2, 2, 2],
        "force": [5000.0, 10000.0, 15000.0, 5000.0, 10000.0, 15000.0],
        "depth": [-0.1, 0.0, 1.3, 0.9, 1.2, 1.6],
    },
}
# A minimal valid indentation session of an object (docs/session-format.md).
SESSION = {
    "object": "ball",
    "geometry": {"radius": 0.13},
    "wall": {"thickness": 0.9e-3, "thickness_std": 5e-5},
    "indentation": {"force": [5.0, 10.0, 15.0], "depth": [0.01, 0.02, 0.03]},
}


def write(tmp_path: Path, doc: dict, name: str = "p.toml") -> Path:
    path = tmp_path / name
    path.write_text(tomli_w.dumps(doc))
    return path


def press_variant(**changes) -> dict:
    """PRESS with top-level keys or (``indentation__key``) [indentation] keys replaced; None deletes."""
    doc = copy.deepcopy(PRESS)
    for dotted, value in changes.items():
        table, key = (doc["indentation"], dotted.split("__")[1]) if "__" in dotted else (doc, dotted)
        if value is None:
            del table[key]
        else:
            table[key] = value
    return doc


def test_press_is_converted_to_si_and_keeps_order(tmp_path):
    path = write(tmp_path, PRESS)
    p = load_rigid_press(path)
    assert isinstance(p, RigidPress)
    assert p.source == path and p.object_name == "table" and p.notes == "pad on the oak table"
    np.testing.assert_allclose(p.force, [5.0, 10.0, 15.0, 5.0, 10.0, 15.0])  # mN -> N
    np.testing.assert_allclose(p.depth, np.array(PRESS["indentation"]["depth"]) * 1e-3)  # mm -> m, sign kept
    assert p.trial.dtype == np.int64
    np.testing.assert_array_equal(p.trial, [1, 1, 1, 2, 2, 2])
    np.testing.assert_array_equal(p.trial_ids, [1, 2])
    assert p.sha256 == file_sha256(path)


def test_trial_ids_keep_order_of_first_appearance(tmp_path):
    p = load_rigid_press(write(tmp_path, press_variant(indentation__trial=[3, 3, 3, 1, 1, 1])))
    np.testing.assert_array_equal(p.trial_ids, [3, 1])


def test_press_samples_from_csv_beside_the_toml(tmp_path):
    (tmp_path / "press.csv").write_text("trial,force,depth\n1,5,-0.05\n1,10,0.8\n2,5,0.0\n2,10,0.9\n")
    indentation = {"depth_unit": "mm", "trials_csv": "press.csv"}
    p = load_rigid_press(write(tmp_path, press_variant(indentation=indentation)))
    np.testing.assert_array_equal(p.trial, [1, 1, 2, 2])
    np.testing.assert_allclose(p.force, [5.0, 10.0, 5.0, 10.0])
    np.testing.assert_allclose(p.depth, [-0.05e-3, 0.8e-3, 0.0, 0.9e-3])
    # the press's sha256 (what a rig file records of it) covers its samples: an edited CSV changes it
    (tmp_path / "press.csv").write_text("trial,force,depth\n1,5,-0.05\n1,10,0.8\n2,5,0.0\n2,10,0.95\n")
    assert load_rigid_press(tmp_path / "p.toml").sha256 != p.sha256


def test_write_rigid_press_round_trips_exactly_in_si(tmp_path):
    rng = np.random.default_rng(1)
    force = np.array([5.0, 10.0, 15.0, 20.0] * 2)
    depth = 1e-4 * force + 1e-5 * rng.standard_normal(force.size) - 8e-4  # a negative zero error
    written = write_rigid_press(
        tmp_path / "sub" / "w.toml",
        object_name="table",
        trial=np.repeat([1, 2], 4),
        force=force,
        depth=depth,
        notes="written by a test",
    )
    p = load_rigid_press(tmp_path / "sub" / "w.toml")
    assert p.source == written.source == tmp_path / "sub" / "w.toml"
    assert p.object_name == "table" and p.notes == "written by a test"
    np.testing.assert_array_equal(p.trial, np.repeat([1, 2], 4))
    np.testing.assert_array_equal(p.force, force)
    np.testing.assert_array_equal(p.depth, depth)  # exact: floats are written in full
    assert p.depth.min() < 0 and written.sha256 == p.sha256 == file_sha256(p.source)
    assert session_kind(p.source) == "rigid_press"
    assert list((tmp_path / "sub").iterdir()) == [tmp_path / "sub" / "w.toml"]


@pytest.mark.parametrize(
    "arguments, pattern",
    [
        ({"depth": [1e-3, math.nan, 2e-3]}, r"field 'indentation.depth\[1\]'.*value nan is not finite"),
        ({"force": [5.0, -10.0, 15.0]}, r"field 'indentation.force\[1\]'.*must be positive"),
        ({"depth": [1e-3, 2e-3]}, r"arrays differ in length"),
        ({"object_name": " "}, r"field 'object': missing or empty"),
        ({"depth": [[1e-3, 2e-3, 3e-3]]}, r"write_rigid_press: argument 'depth' must be a non-empty 1-D array"),
    ],
)
def test_write_rigid_press_rejects_bad_input_and_writes_nothing(tmp_path, arguments, pattern):
    args = {"object_name": "table", "trial": [1, 1, 1], "force": [5.0, 10.0, 15.0], "depth": [1e-3, 2e-3, 3e-3]}
    with pytest.raises(InvalidInputError, match=pattern) as info:
        write_rigid_press(tmp_path / "w.toml", **{**args, **arguments})
    assert "Fix:" in str(info.value) and ".write_session-" not in str(info.value)
    assert list(tmp_path.iterdir()) == []


def test_write_rigid_press_keeps_the_old_file_when_the_new_one_is_invalid(tmp_path):
    good = write_rigid_press(
        tmp_path / "w.toml", object_name="table", trial=[1, 1], force=[5.0, 10.0], depth=[1e-3, 2e-3]
    )
    with pytest.raises(InvalidInputError, match="not finite"):
        write_rigid_press(
            tmp_path / "w.toml", object_name="table", trial=[1, 1], force=[5.0, math.inf], depth=[1e-3, 2e-3]
        )
    assert file_sha256(tmp_path / "w.toml") == good.sha256
    assert list(tmp_path.iterdir()) == [tmp_path / "w.toml"]


@pytest.mark.parametrize(
    "changes, pattern",
    [
        (
            {"kind": "rigid_pres"},
            r"field 'kind': unknown session kind 'rigid_pres'.*Fix:.*'indentation', 'rigid_press'",
        ),
        (
            {"wall": {"thickness": 0.9, "thickness_std": 0.05}},
            r"field 'wall':.*rigid-surface press.*has no \[wall\] table",
        ),
        ({"geometry": {"radius": 0.13}}, r"field 'geometry':.*has no \[geometry\] table.*Fix: delete the \[geometry\]"),
        ({"wrinkles": {"counts": [8, 9]}}, r"field 'wrinkles':.*has no \[wrinkles\] table"),
        ({"shape": {"shape_csv": "s.csv"}}, r"field 'shape':.*has no \[shape\] table"),
        ({"mass": 0.85}, r"field 'mass':.*has no 'mass' key.*Fix: delete the 'mass' key"),
        (
            {"manometer_gauge_pressure": 1300.0},
            r"field 'manometer_gauge_pressure':.*has no 'manometer_gauge_pressure' key",
        ),
        ({"colour": "red"}, r"field 'colour': unknown key"),
        ({"object": None}, r"field 'object': missing"),
        ({"indentation": None}, r"field 'indentation': missing table"),
        ({"indentation__depthunit": "mm"}, r"field 'indentation.depthunit': unknown key"),
        ({"indentation__depth_unit": "inch"}, r"unknown length unit 'inch'"),
        (
            {"indentation__depth": [math.nan, 0.0, 1.3, 0.9, 1.2, 1.6]},
            r"'indentation.depth\[0\]'.*value nan is not finite",
        ),
        (
            {"indentation__depth": [0.1, 0.0, 1.3, 0.9, math.inf, 1.6]},
            r"'indentation.depth\[4\]'.*value inf is not finite",
        ),
        (
            {"indentation__force": [5000.0, 0.0, 1.0, 2.0, 3.0, 4.0]},
            r"'indentation.force\[1\]'.*value 0.0 must be positive",
        ),
        (
            {"indentation__depth_unit": "m"},
            r"'indentation.depth\[5\]'.*1.6 m is more than a finger pad compresses.*depth_unit",
        ),
        ({"indentation__trial": [1, 1, 1, 2, 2, 2.5]}, r"'indentation.trial\[5\]'.*trial id 2.5 is not an integer"),
        ({"indentation__trial": [1, 2]}, r"arrays differ in length"),
        ({"schema_version": 2}, r"field 'schema_version': unsupported version 2"),
    ],
)
def test_bad_press_is_named(tmp_path, changes, pattern):
    path = write(tmp_path, press_variant(**changes))
    with pytest.raises(InvalidInputError, match=pattern) as info:
        load_rigid_press(path)
    assert str(path) in str(info.value) and "Fix:" in str(info.value)


def test_press_csv_nan_depth_names_the_csv(tmp_path):
    (tmp_path / "press.csv").write_text("trial,force,depth\n1,5,0.8\n1,10,nan\n")
    path = write(tmp_path, press_variant(indentation={"depth_unit": "mm", "trials_csv": "press.csv"}))
    with pytest.raises(
        InvalidInputError, match=r"'indentation.depth\[1\]'.*\(in press.csv, line 3\) value nan is not finite"
    ):
        load_rigid_press(path)


def test_load_session_on_a_press_points_to_rig_calibrate(tmp_path):
    path = write(tmp_path, PRESS)
    with pytest.raises(InvalidInputError, match=r"field 'kind'.*rigid-surface press") as info:
        load_session(path)
    message = str(info.value)
    assert str(path) in message and "shelljax rig calibrate" in message
    assert "Fix:" in message and "load_rigid_press" in message.split("Fix:")[1]


def test_load_session_rejects_an_unknown_kind(tmp_path):
    path = write(tmp_path, {**SESSION, "kind": "squeeze"})
    with pytest.raises(InvalidInputError, match=r"field 'kind': unknown session kind 'squeeze'.*'rigid_press'"):
        load_session(path)


@pytest.mark.parametrize("kind", [None, "indentation"])
def test_load_rigid_press_on_an_indentation_session_is_refused(tmp_path, kind):
    doc = SESSION if kind is None else {**SESSION, "kind": kind}
    path = write(tmp_path, doc)
    assert load_session(path).object_name == "ball"  # a valid session, explicit kind or not
    with pytest.raises(
        InvalidInputError, match=r"field 'kind'.*an indentation session of an object, not a rigid"
    ) as info:
        load_rigid_press(path)
    assert str(path) in str(info.value) and "load_session" in str(info.value).split("Fix:")[1]


def test_session_kind_of_both_kinds(tmp_path):
    assert session_kind(write(tmp_path, PRESS, "press.toml")) == "rigid_press"
    assert session_kind(write(tmp_path, SESSION, "session.toml")) == "indentation"
    assert session_kind(write(tmp_path, {**SESSION, "kind": "indentation"}, "explicit.toml")) == "indentation"
    written = write_session(
        tmp_path / "w.toml",
        object_name="ball",
        radius=0.13,
        radius_std=0.0,
        thickness=9e-4,
        thickness_std=5e-5,
        trial=[1, 1, 1],
        force=[5.0, 10.0, 15.0],
        depth=[0.01, 0.02, 0.03],
    )
    assert session_kind(written.source) == "indentation"


@pytest.mark.parametrize(
    "make, pattern",
    [
        (lambda d: None, r"session file does not exist"),
        (lambda d: (d / "p.toml").write_text("kind = \n"), r"not valid TOML"),
        (lambda d: (d / "p.toml").write_bytes(b"\xff\xfe kind"), r"not a UTF-8 text file"),
        (lambda d: (d / "p.toml").write_text('kind = "press"\n'), r"field 'kind': unknown session kind 'press'"),
    ],
)
def test_session_kind_of_an_unreadable_file_is_named(tmp_path, make, pattern):
    make(tmp_path)
    with pytest.raises(InvalidInputError, match=pattern) as info:
        session_kind(tmp_path / "p.toml")
    assert str(tmp_path / "p.toml") in str(info.value) and "Fix:" in str(info.value)
