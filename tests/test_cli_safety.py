"""Safe by default (issue #58): every subcommand refuses a bad output path or a bad value before any
work, with exit status 2, one line on stderr naming the option or field and a fix, and no new file
in the working directory; the refusals and messages the issue lists; --help shows every default and
unit. The property-based sweeps drive ``shelljax.cli.main`` in-process (a refusal costs
milliseconds, so each sweep runs in seconds)."""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shelljax.cli import build_parser, main
from shelljax.config import bundled_data_dir

REPO = Path(__file__).resolve().parents[1]
SESSIONS = bundled_data_dir() / "sessions"
SESSION = str(SESSIONS / "pezzi.toml")
CALIBRATION = [str(SESSIONS / "calib_pezzi_0900Pa.toml"), str(SESSIONS / "calib_pezzi_1200Pa.toml")]
CONFIG, DROP, SCRIPT = (str(REPO / "configs" / name) for name in ("paper.toml", "drop.toml", "interaction.toml"))
SWEEP = settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
_names = itertools.count()


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _tree(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


def assert_refused(argv: list[str], capsys, root: Path, *names: str) -> str:
    """``main(argv)`` exits 2 with one line on stderr naming one of ``names`` and a fix, and
    creates nothing under ``root``; returns the line."""
    before = _tree(root)
    code = main(argv)
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert code == 2, (argv, captured.err)
    assert len(lines) == 1 and lines[0].startswith("shelljax: error: "), captured.err
    assert "Fix:" in lines[0] and any(n in lines[0] for n in names), lines[0]
    assert _tree(root) == before, (argv, sorted(_tree(root) - before))
    return lines[0]


# ------------------------------------------------------------------------------ output paths
# (how the command is given the path, the option that names it); files: a suffix the path gets
FILE_OUTPUTS = {
    "estimate --chain": (
        lambda p: ["estimate", SESSION, "--method", "bayes", "--chain", p, "--quiet"],
        "--chain",
        ".h5",
    ),
    "rig calibrate --out": (lambda p: ["rig", "calibrate", *CALIBRATION, "--out", p, "--quiet"], "--out", ".toml"),
    "play --record": (lambda p: ["play", SESSION, "--headless", "--script", SCRIPT, "--record", p], "--record", ".gif"),
    "play --records": (
        lambda p: ["play", SESSION, "--headless", "--script", SCRIPT, "--records", p],
        "--records",
        ".json",
    ),
    "acquire --out": (lambda p: ["acquire", "--emulate-fast", "--yes", "--out", p], "--out", ".toml"),
    "sensor-calibrate --out": (lambda p: ["sensor-calibrate", "--emulate-fast", "--yes", "--out", p], "--out", ".toml"),
}
DIR_OUTPUTS = {
    "run --out": (lambda p: ["run", CONFIG, "--out", p, "--quiet"], "--out"),
    "diagnose --out": (lambda p: ["diagnose", *CALIBRATION, "--out", p, "--quiet"], "--out"),
    "diagnose --study --out": (
        lambda p: ["diagnose", "--study", "bundled:sessions/calib_pezzi_*.toml", "--out", p, "--quiet"],
        "--out",
    ),
    "simulate --out": (lambda p: ["simulate", DROP, "--out", p, "--quiet"], "--out"),
    "replica --out": (lambda p: ["replica", SESSION, "--out", p], "--out"),
}


def _bad_path(root: Path, kind: str, suffix: str) -> str:
    """A path of the ``kind`` no output can take, made under ``root``: an existing directory (for
    a file), an existing file (for a directory), or a path under a file."""
    name = f"p{next(_names)}"
    if kind == "directory":
        (root / f"{name}{suffix}").mkdir()
        return f"{name}{suffix}"
    (root / name).write_text("a file\n")
    return name if kind == "file" else f"{name}/inside/out{suffix}"


@SWEEP
@given(case=st.sampled_from(sorted(FILE_OUTPUTS)), kind=st.sampled_from(["directory", "under a file"]))
def test_every_output_file_is_checked_before_any_work(workdir, capsys, case, kind):
    argv, option, suffix = FILE_OUTPUTS[case]
    assert_refused(argv(_bad_path(workdir, kind, suffix)), capsys, workdir, option)


@SWEEP
@given(case=st.sampled_from(sorted(DIR_OUTPUTS)), kind=st.sampled_from(["file", "under a file"]))
def test_every_output_directory_is_checked_before_any_work(workdir, capsys, case, kind):
    argv, option = DIR_OUTPUTS[case]
    assert_refused(argv(_bad_path(workdir, kind, "")), capsys, workdir, option)


# ------------------------------------------------------------------------------ values
def _outside(low=None, high=None, *, integer=False, low_open=False):
    """Values a range [low, high] ((low, high] with ``low_open``) refuses: below, above, and for
    numbers nan and inf."""
    if integer:
        out = [st.integers(max_value=low - 1)] + ([st.integers(min_value=high + 1)] if high is not None else [])
        return st.one_of(out).map(str)
    out = [st.sampled_from(["nan", "inf", "-inf"])]
    if low is not None:
        out.append(st.floats(max_value=low, exclude_max=not low_open, allow_nan=False, allow_infinity=False))
    if high is not None:
        out.append(st.floats(min_value=high, exclude_min=True, allow_nan=False, allow_infinity=False))
    return st.one_of(out).map(lambda v: v if isinstance(v, str) else repr(float(v)))


ACQUIRE = ["acquire", "--emulate-fast", "--yes", "--out", "ball.toml"]
# (the command with the value, the option to name, the values it refuses); lengths and pressures in
# the unit their unit option names (here its default): m, mm for the wall, kg, Pa
BAD_VALUES = [
    (lambda v: ["estimate", SESSION, "--bootstrap", v], "--bootstrap", _outside(0, integer=True)),
    (lambda v: ["estimate", SESSION, "--seed", v], "--seed", _outside(0, integer=True)),
    (lambda v: ["estimate", SESSION, "--method", "bayes", "--walkers", v], "--walkers", _outside(8, integer=True)),
    (
        lambda v: ["estimate", SESSION, "--method", "bayes", "--max-steps", v],
        "--max-steps",
        _outside(100, integer=True),
    ),
    (lambda v: ["estimate", SESSION, "--k-s", v], "--k-s", _outside(0.0, 10.0, low_open=True)),
    (lambda v: ["estimate", SESSION, "--k-s-std", v], "--k-s-std", _outside(0.0)),
    (
        lambda v: ["replica", SESSION, "--out", "r", "--mesh-faces", v],
        "--mesh-faces",
        _outside(20, 10**6, integer=True),
    ),
    (lambda v: ["replica", SESSION, "--out", "r", "--cor", v], "--cor", _outside(0.0, 1.0, low_open=True)),
    (lambda v: ["play", SESSION, "--mesh-faces", v], "--mesh-faces", _outside(20, 10**6, integer=True)),
    (lambda v: ["play", SESSION, "--port", v], "--port", _outside(1, 65535, integer=True)),
    (
        lambda v: ["rig", "calibrate", *CALIBRATION, "--out", "rig.toml", "--manometer-std", v],
        "--manometer-std",
        _outside(0.0, 1.0, low_open=True),
    ),
    (lambda v: ["run", CONFIG, "--workers", v], "--workers", _outside(1, integer=True)),
    (lambda v: ["simulate", DROP, "--workers", v], "--workers", _outside(1, integer=True)),
    (
        lambda v: ["diagnose", "--study", "bundled:sessions/calib_pezzi_*.toml", "--out", "d", "--workers", v],
        "--workers",
        _outside(1, integer=True),
    ),
    (
        lambda v: [*ACQUIRE, "--radius", v, "--thickness", "0.9", "--thickness-std", "0.05"],
        "--radius",
        _outside(0.01, 2.0),
    ),
    (
        lambda v: [*ACQUIRE, "--radius", "0.13", "--thickness", v, "--thickness-std", "1e-6"],
        "--thickness",
        _outside(0.05, 10.0),
    ),
    (lambda v: [*ACQUIRE, "--mass", v], "--mass", _outside(1e-4, 100.0)),
    (lambda v: [*ACQUIRE, "--manometer-pressure", v], "--manometer-pressure", _outside(10.0, 1e5)),
    (lambda v: [*ACQUIRE, "--poisson-ratio", v], "--poisson-ratio", _outside(-1.0, 0.5)),
    (lambda v: [*ACQUIRE, "--trials", v], "--trials", _outside(1, integer=True)),
    (lambda v: [*ACQUIRE, "--tolerance", v], "--tolerance", _outside(0.0, 10.0, low_open=True)),
    (lambda v: [*ACQUIRE, "--forces", f"5,10,{v}"], "--forces", _outside(0.01, 200.0)),
    (
        lambda v: ["sensor-calibrate", "--emulate-fast", "--yes", "--out", "c.toml", "--cycles", v],
        "--cycles",
        _outside(1, integer=True),
    ),
    (
        lambda v: ["sensor-calibrate", "--emulate-fast", "--yes", "--out", "c.toml", "--gravity", v],
        "--gravity",
        _outside(9.7, 9.9),
    ),
    (
        lambda v: ["sensor-calibrate", "--emulate-fast", "--yes", "--out", "c.toml", "--masses", f"0,1,{v}"],
        "--masses",
        _outside(0.0, 20.0),
    ),
    (lambda v: ["sensor-emulator", "--duration", v], "--duration", _outside(0.0, low_open=True)),
]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_every_subcommand_refuses_a_bad_value_before_any_work(workdir, capsys, data):
    argv, option, values = data.draw(st.sampled_from(BAD_VALUES))
    value = data.draw(values)
    assert_refused(argv(value), capsys, workdir, option)


def _command(argv: list[str]) -> str:
    return " ".join(argv[:2]) if argv[0] == "rig" else argv[0]


def test_the_sweeps_cover_every_subcommand():
    covered = {_command(argv("x")) for argv, *_ in [*FILE_OUTPUTS.values(), *DIR_OUTPUTS.values(), *BAD_VALUES]}
    commands = set(_subparsers(build_parser()))
    assert commands - covered == {"validate"}  # it writes nothing and takes no number: its files are checked below


def test_validate_names_a_missing_or_wrong_file_in_one_line(workdir, capsys):
    (workdir / "folder.toml").mkdir()
    assert "folder.toml" in assert_refused(["validate", "folder.toml"], capsys, workdir, "folder.toml")
    assert_refused(["validate", "absent.toml"], capsys, workdir, "absent.toml")


# ------------------------------------------------------------------------------ the defects
def test_acquire_refuses_a_wall_1000x_too_thin_before_recording(workdir, capsys):
    line = assert_refused(
        [
            "acquire",
            "--emulate-fast",
            "--yes",
            "--out",
            "demo/ball.toml",
            "--radius",
            "0.13",
            "--thickness",
            "0.0009",
            "--thickness-std",
            "0.00005",
        ],
        capsys,
        workdir,
        "--thickness",
    )
    assert "0.0009 mm" in line and "--thickness-unit m" in line and "--thickness 0.9" in line


def test_acquire_refuses_a_radius_in_millimetres_before_recording(workdir, capsys):
    line = assert_refused([*ACQUIRE, "--radius", "130"], capsys, workdir, "--radius")
    assert "130 m" in line and "--length-unit mm" in line and "--radius 0.13" in line


def test_rig_calibrate_onto_a_directory_is_refused_before_the_fit(workdir, capsys):
    (workdir / "rigs").mkdir()
    line = assert_refused(["rig", "calibrate", *CALIBRATION, "--out", "rigs", "--quiet"], capsys, workdir, "--out")
    assert "is a directory" in line and "rigs/rig.toml" in line


def test_replica_onto_a_file_is_refused_before_the_estimate(workdir, capsys):
    (workdir / "replica").write_text("not a directory\n")
    assert "not a directory" in assert_refused(["replica", SESSION, "--out", "replica"], capsys, workdir, "--out")


def test_play_on_a_truncated_replica_names_the_file(workdir, capsys):
    (workdir / "replica").mkdir()
    (workdir / "replica" / "replica.json").write_text('{"replica_version": 1, "gauge_pressure_Pa": {"val')
    line = assert_refused(["play", "replica", "--headless", "--script", SCRIPT], capsys, workdir, "replica.json")
    assert "not a whole replica file" in line and "shelljax replica" in line


def test_a_refused_run_on_an_unreachable_cluster_leaves_no_run_directory(workdir, capsys):
    line = assert_refused(["run", CONFIG, "--cluster", "tcp://127.0.0.1:1", "--quiet"], capsys, workdir, "--cluster")
    assert not (workdir / "runs").exists() and "scheduler" in line


def test_a_refused_diagnosis_on_an_unreachable_cluster_leaves_no_inputs(workdir, capsys):
    assert_refused(
        [
            "diagnose",
            "--study",
            "bundled:sessions/calib_pezzi_*.toml",
            "--out",
            "diag",
            "--cluster",
            "tcp://127.0.0.1:1",
            "--quiet",
        ],
        capsys,
        workdir,
        "--cluster",
    )
    assert not (workdir / "diag").exists()


def test_a_session_given_as_rig_is_named_a_session(workdir, capsys):
    line = assert_refused(["estimate", SESSION, "--method", "fit", "--rig", SESSION], capsys, workdir, "format")
    assert "measurement session, not a rig file" in line and "shelljax rig calibrate" in line and "None" not in line


def _ideal_rig(path: Path) -> Path:
    from shelljax.rig import write_rig
    from shelljax.rig._calibrate import Rig, RigModel

    model = RigModel(
        terms=(),
        parameters=(),
        mean=np.zeros(0),
        covariance=np.zeros((0, 0)),
        fixes={},
        elpd=0.0,
        elpd_se=0.0,
        delta=0.0,
        delta_se=0.0,
        weight=1.0,
    )
    rig = Rig(
        models=(model,),
        excluded=(),
        inclusion={},
        not_identified=(),
        gas="isothermal",
        wrinkle_law="scaling",
        force_ref=10.0,
        indenter_radius=0.008,
        noise=(1e-4, (1e-7, 0.01)),
        calibration=(),
        objects=(),
    )
    return write_rig(rig, path)


def test_two_objects_through_a_rig_are_refused_as_an_estimate(workdir, capsys):
    rig = _ideal_rig(workdir / "rig.toml")
    line = assert_refused(
        ["estimate", SESSION, str(SESSIONS / "yoga.toml"), "--method", "fit", "--rig", str(rig)],
        capsys,
        workdir,
        "different objects",
    )
    assert "Fix: estimate --rig one object at a time" in line and "diagnose" not in line


def test_replica_mesh_faces_zero_names_the_option_and_its_range(workdir, capsys):
    line = assert_refused(["replica", SESSION, "--out", "r", "--mesh-faces", "0"], capsys, workdir, "--mesh-faces")
    assert ">= 20" in line and "pole_refinement" not in line


def test_negative_bootstrap_is_refused(workdir, capsys):
    assert ">= 0" in assert_refused(["estimate", SESSION, "--bootstrap", "-5"], capsys, workdir, "--bootstrap")


# ------------------------------------------------------------------------------ help and names
def _subparsers(parser: argparse.ArgumentParser) -> dict:
    """Every (sub)command's parser by its command line ("rig calibrate" for a nested one)."""
    found = {}
    for action in parser._actions:
        if action.nargs == argparse.PARSER:
            for name, sub in action.choices.items():
                nested = _subparsers(sub)
                found.update({f"{name} {k}": v for k, v in nested.items()} if nested else {name: sub})
    return found


def test_help_shows_every_default_and_every_unit():
    for command, parser in _subparsers(build_parser()).items():
        text = " ".join(parser.format_help().split())
        for action in parser._actions:
            if not action.option_strings or action.default in (None, False) or action.nargs == 0:
                continue
            assert f"(default: {action.default})" in text, f"{command} {action.option_strings[0]}"
            if getattr(action.type, "__name__", "") == "number":
                assert "[" in action.help or " in --" in action.help, f"{command} {action.option_strings[0]}: no unit"
    acquire = " ".join(_subparsers(build_parser())["acquire"].format_help().split())
    for unit in ("--mass-unit", "--pressure-unit", "--length-unit", "--thickness-unit", "--depth-unit"):
        assert unit in acquire
    assert acquire.count("(default: mm)") >= 2 and "(default: m)" in acquire and "(default: kg)" in acquire


def test_multi_session_estimates_through_a_rig_name_their_sessions(monkeypatch, capsys):
    import shelljax.rig as rig
    from shelljax.estimate import Estimate

    paths = [str(SESSIONS / "rig" / "toy_2200Pa.toml"), str(SESSIONS / "rig" / "toy_3500Pa.toml")]
    estimate = Estimate(1.0, 0.1, (0.8, 1.2), "Pa", "test")

    class Result:
        estimates = {"gauge_pressure[0]": estimate, "gauge_pressure[1]": estimate, "young_modulus": estimate}
        sources, models, not_identified = tuple(paths), (), ()

        def to_dict(self):
            return {"estimates": {k: v.to_dict() for k, v in self.estimates.items()}}

    monkeypatch.setattr(rig, "load_rig", lambda path: None)
    monkeypatch.setattr(rig, "estimate_with_rig", lambda *a, **k: Result())
    assert main(["estimate", *paths, "--method", "fit", "--rig", "rig.toml", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "gauge_pressure[toy_2200Pa]" in out and "gauge_pressure[toy_3500Pa]" in out and "[0]" not in out
    assert main(["estimate", *paths, "--method", "fit", "--rig", "rig.toml", "--json", "--quiet"]) == 0
    assert json.loads(capsys.readouterr().out)["session"] == paths  # JSON: indices in the order of this list
