"""shelljax._toml: the one TOML reader; every refusal names the file, the field, the value and the fix."""

from __future__ import annotations

import math

import pytest

from shelljax import InvalidInputError
from shelljax._toml import REQUIRED, TomlReader, read_toml


@pytest.mark.parametrize(
    "write, pattern",
    [
        (lambda p: None, r"x.toml: config file does not exist. Fix: check the path"),
        (lambda p: p.write_bytes(b"\xff\xfe a = 1"), r"x.toml: not a UTF-8 text file. Fix: save it as UTF-8 TOML"),
        (lambda p: p.write_text("a = = 1\n"), r"x.toml: not valid TOML \(.*\). Fix: correct the syntax"),
    ],
)
def test_read_toml_names_the_file_and_the_fix(tmp_path, write, pattern):
    path = tmp_path / "x.toml"
    write(path)
    with pytest.raises(InvalidInputError, match=pattern):
        read_toml(path, "config file", fix_missing="check the path")


def test_read_toml_reads_a_document(tmp_path):
    (tmp_path / "x.toml").write_text("a = 1\n[b]\nc = [1.0, 2.0]\n")
    assert read_toml(tmp_path / "x.toml", "config file", fix_missing="-") == {"a": 1, "b": {"c": [1.0, 2.0]}}


@pytest.mark.parametrize(
    "call, pattern",
    [
        (
            lambda r: r.no_unknown_keys({"a": 1, "colour": 2}, {"a"}, "t."),
            r"c.toml: field 't.colour': unknown key \(unknown keys: t.colour\). Fix: remove it .*allowed keys here: a",
        ),
        (
            lambda r: r.table({}, "wall", {"x"}, required=True),
            r"field 'wall': missing table. Fix: add a \[wall\] table \(see doc.md\)",
        ),
        (
            lambda r: r.table({"wall": 3}, "wall", {"x"}),
            r"field 'wall': expected a table, got 3. Fix: write it as \[wall\]",
        ),
        (lambda r: r.number({}, "h", "wall."), r"field 'wall.h': missing. Fix: add 'h = <value>'"),
        (lambda r: r.number({"h": "x"}, "h"), r"field 'h': expected a number, got 'x'"),
        (lambda r: r.number({"h": True}, "h"), r"field 'h': expected a number, got True"),
        (lambda r: r.number({"h": math.nan}, "h"), r"field 'h': value nan is not finite"),
        (lambda r: r.number({"h": 0}, "h", positive=True), r"field 'h': value 0 must be positive"),
        (
            lambda r: r.number({"h": -1.0}, "h", nonnegative=True, fix="give h"),
            r"field 'h': value -1.0 must be non-negative. Fix: give h",
        ),
        (lambda r: r.integer({"n": 2}, "n", minimum=8), r"field 'n': 2 is not an integer >= 8"),
        (lambda r: r.integer({"n": -1}, "n", default=0), r"field 'n': -1 is not a non-negative integer"),
        (lambda r: r.flag({"f": 1}, "f", default=True), r"field 'f': 1 is not true/false. Fix: write true or false"),
        (
            lambda r: r.choice({"g": "plasma"}, "g", "", ("a", "b"), "a", what="gas"),
            r"field 'g': unknown gas 'plasma'. Fix: use one of a, b",
        ),
        (lambda r: r.choice({}, "g", "", ("a", "b"), REQUIRED), r"field 'g': missing. Fix: use one of a, b"),
        (lambda r: r.vector({"v": [1.0, 2.0]}, "v", "", 3), r"field 'v' = \[1.0, 2.0\]: expected a list of 3 numbers"),
        (
            lambda r: r.direction({"n": [0, 0, 0]}, "n", "p.", fix="point it up"),
            r"field 'p.n' = \[0.0, 0.0, 0.0\]: must be nonzero. Fix: point it up",
        ),
        (
            lambda r: r.entry(3, "planes", 1, {"n"}),
            r"field 'planes\[1\]' = 3: expected a table. Fix: write it as \[\[planes\]\]",
        ),
        (lambda r: r.entry({"m": 1}, "planes", 0, {"n"}), r"field 'planes\[0\].m': unknown key"),
        (lambda r: r.array({"a": [1.0, "x"]}, "a"), r"field 'a\[1\]': expected a number, got 'x'"),
        (lambda r: r.array({"a": []}, "a"), r"field 'a': expected a non-empty array"),
        (lambda r: r.typed({"s": 3}, "s", str, "t."), r"field 't.s': 3 is not a str"),
        (lambda r: r.typed({"x": math.inf}, "x", float), r"field 'x': inf is not a finite number"),
    ],
)
def test_each_check_names_the_file_field_value_and_fix(call, pattern):
    with pytest.raises(InvalidInputError, match=pattern) as info:
        call(TomlReader("c.toml", doc="doc.md"))
    assert str(info.value).startswith("c.toml: field '") and "Fix: " in str(info.value)


def test_a_readers_own_fix_replaces_the_checks_defaults():
    reader = TomlReader("rig.toml", fix="re-create it")
    with pytest.raises(InvalidInputError, match=r"field 'x': missing. Fix: re-create it$"):
        reader.typed({}, "x", float)
    with pytest.raises(InvalidInputError, match=r"Fix: re-calibrate$"):
        raise reader.fail("x", "wrong", "re-calibrate")


def test_values_come_back_typed_with_defaults():
    reader = TomlReader("c.toml")
    table = {"n": 3, "x": 2, "v": [1, 2, 3], "f": False, "g": "b"}
    assert reader.number(table, "x") == 2.0 and isinstance(reader.number(table, "x"), float)
    assert reader.number(table, "absent", default=None) is None and reader.number(table, "absent", default=1.5) == 1.5
    assert reader.integer(table, "n") == 3 and reader.integer(table, "absent", default=7) == 7
    assert reader.vector(table, "v") == (1.0, 2.0, 3.0)
    assert reader.flag(table, "f", default=True) is False
    assert (
        reader.choice(table, "g", "", ("a", "b"), "a") == "b"
        and reader.choice(table, "absent", "", ("a", "b"), "a") == "a"
    )
    assert reader.typed(table, "n", float) == 3.0
    assert reader.table({}, "t", {"a"}) is None and reader.table({"t": {"a": 1}}, "t", {"a"}) == {"a": 1}
