"""The README stays true: its two quickstart commands (the second one run by CI), and every example
command it shows, run on the bundled data or parsed by the real parser, with the numbers it quotes
checked against what the commands print."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def quickstart_commands() -> list[str]:
    text = (REPO / "README.md").read_text()
    block = re.search(r"```(?:bash|sh)\n(.*?)```", text, re.S)
    assert block, "README must open with a bash code block"
    return [line for line in block.group(1).splitlines() if line.strip() and not line.startswith("#")]


def test_readme_starts_with_exactly_two_commands():
    commands = quickstart_commands()
    assert len(commands) == 2, commands
    assert "shelljax run" in commands[0] and "pytest" in commands[1]


def test_ci_runs_the_readme_test_command_verbatim():
    ci_lines = (REPO / ".ci" / "run").read_text().splitlines()
    assert quickstart_commands()[1] in ci_lines


def test_config_named_in_readme_exists():
    config = re.search(r"shelljax run (\S+)", quickstart_commands()[0]).group(1)
    assert (REPO / config).is_file()


# ---------------------------------------------------------------------------------- the examples
# The README's example commands (console blocks: "$ shelljax ..."; bash blocks: "shelljax ..."),
# each either run here on the bundled data (RUN) or only parsed by the real parser, every
# subcommand, option and value checked (PARSED_ONLY, with why it is not run: each takes a minute or
# more on 2 cores, or needs hardware or files the reader makes).
SHARED_PROGRAMS = "bundled-session fits"  # the fit below is the main job's program (conftest.py)
PEZZI = "shelljax/data/sessions/pezzi.toml"
RUN = {
    f"shelljax estimate {PEZZI}",  # its output block is compared line by line
    f"shelljax estimate {PEZZI} --method closed-form --json",
    f"shelljax estimate {PEZZI} --method fit",  # slow: the prose quotes its P_g
    f"shelljax replica {PEZZI} --out replica/",  # slow: a fit, then the mesh
    "shelljax acquire --emulate-fast --emulate-faults --yes --out demo/demo.toml",
    "shelljax estimate demo/demo.toml",
}
PARSED_ONLY = {
    f"shelljax estimate {PEZZI} --method bayes": "MCMC, minutes",
    "shelljax diagnose shelljax/data/sessions/calib_pezzi_*.toml --out diag/": "joint fits of every effect, minutes",
    "shelljax diagnose --study ball_a/ --study ball_b/*.toml --out diag/ --workers 2": "placeholder studies",
    "shelljax rig calibrate shelljax/data/sessions/rig/calib_ball_*.toml --out rig.toml": "the rig's calibration, "
    "over a minute (docs/rig.md holds the study behind the README's rig numbers)",
    "shelljax estimate shelljax/data/sessions/rig/toy_3500Pa.toml --method fit --rig rig.toml": "needs the rig above",
    "shelljax estimate shelljax/data/sessions/rig/toy_*.toml --method fit --rig rig.toml": "needs the rig above",
    "shelljax diagnose shelljax/data/sessions/rig/calib_ball_*.toml --rig rig.toml": "needs the rig above",
    f"shelljax replica {PEZZI} --out replica/ --rig rig.toml": "needs the rig above",
    "shelljax validate my_session.toml": "the reader's own file",
    "shelljax run configs/paper.toml --out runs/": "the main job, about 2 minutes",
    "shelljax run configs/paper.toml --workers 2": "the main job on Dask workers",
    "shelljax run configs/paper.toml --device cpu": "the main job, every stage on the CPU",
    "shelljax simulate configs/drop.toml --out runs/drop": "about 2.5 minutes",
    "shelljax simulate configs/bounce.toml --out runs/bounce": "about 2 minutes",
    "shelljax simulate configs/hammer.toml --out runs/hammer": "about 40 s",
    "shelljax run configs/paper.toml": "the quickstart's main job",
    "shelljax sensor-calibrate --port /dev/ttyACM0 --out finger.toml": "hardware",
    "shelljax acquire --port /dev/ttyACM0 --calibration finger.toml --out ball.toml --object ball --radius 0.13 "
    "--thickness 0.9 --thickness-std 0.05": "hardware",
    "shelljax estimate ball.toml": "the hardware recording's file",
}


def _text() -> str:
    return (REPO / "README.md").read_text()


def readme_commands() -> list[str]:
    """Every shelljax command of the README's code blocks, comments and prompts stripped, continued
    lines joined and ``&&`` chains split, in order."""
    import shlex

    commands = []
    for kind, body in re.findall(r"```(console|bash)\n(.*?)```", _text(), re.S):
        lines = [
            line.removeprefix("$ ")
            for line in body.replace("\\\n", " ").splitlines()
            if kind == "bash" or line.startswith("$ ")
        ]
        for line in lines:
            for part in line.split("&&"):
                words = shlex.split(part, comments=True)
                if words and words[0] == "shelljax":
                    commands.append(" ".join(words))
    return commands


def test_every_readme_command_is_run_or_parsed_and_says_why():
    commands = set(readme_commands())
    assert commands == RUN | set(PARSED_ONLY), (
        sorted(commands - RUN - set(PARSED_ONLY)),
        sorted((RUN | set(PARSED_ONLY)) - commands),
    )


def test_every_readme_command_parses_with_the_real_parser():
    from shelljax.cli import build_parser

    parser = build_parser()
    for command in readme_commands():
        parser.parse_args(command.split()[1:])  # a usage error raises, naming the option


def _output_block(command: str) -> list[str]:
    """The lines the README shows under ``$ command`` in its console block."""
    body = re.search(r"```console\n(.*?)```", _text(), re.S).group(1)
    after = body.split(f"$ {command}\n", 1)[1]
    return after.split("\n$ ", 1)[0].rstrip("\n").splitlines()


def _estimate(argv: list[str], capsys, monkeypatch) -> str:
    from shelljax.cli import main

    monkeypatch.chdir(REPO)  # the README's paths are relative to the repository root
    assert main([*argv, "--quiet"]) == 0
    return capsys.readouterr().out


def test_the_readme_estimate_prints_exactly_what_the_readme_shows(capsys, monkeypatch):
    printed = _estimate(["estimate", PEZZI], capsys, monkeypatch).rstrip("\n").splitlines()
    assert printed == _output_block(f"shelljax estimate {PEZZI}")


def test_the_readme_numbers_in_prose_are_what_the_commands_print(capsys, monkeypatch):
    import json

    from shelljax.session import load_session

    shown = json.loads(_estimate(["estimate", PEZZI, "--method", "closed-form", "--json"], capsys, monkeypatch))
    pressure = shown["estimates"]["gauge_pressure"]["value"]
    assert f"gauge_pressure = {pressure:.5g} " in "\n".join(_output_block(f"shelljax estimate {PEZZI}"))
    assert f"the closed form with the paper's k_s reads\n{pressure:.4g} Pa" in _text()
    k_s = re.search(r"noise-free k_s = ([0-9.]+)", load_session(REPO / PEZZI).notes).group(1)
    assert f"gives this sealed ball k_s = {k_s}," in _text()


@pytest.mark.slow  # a fit through the engine, then a replica's mesh: the main job's compiled program
def test_the_readme_fit_and_replica_run_and_print_what_the_readme_says(capsys, monkeypatch, tmp_path):
    import json

    from shelljax.cli import main

    fit = json.loads(_estimate(["estimate", PEZZI, "--method", "fit", "--json"], capsys, monkeypatch))
    pressure = fit["estimates"]["gauge_pressure"]
    assert f"fit through that engine reads {pressure['value']:.4g} ± {pressure['std']:.2g} Pa" in _text()
    assert pressure["ci95"][0] <= 1300.0 <= pressure["ci95"][1]  # the truth in the session's notes
    assert main(["replica", PEZZI, "--out", str(tmp_path / "replica")]) == 0
    assert {p.name for p in (tmp_path / "replica").iterdir()} == {"replica.glb", "replica.json"}


def test_the_readme_sensor_demo_runs(capsys, monkeypatch, tmp_path):
    from shelljax.cli import main

    monkeypatch.chdir(tmp_path)
    demo = [c.split()[1:] for c in readme_commands() if "demo/demo.toml" in c]
    assert [argv[0] for argv in demo] == ["acquire", "estimate"]
    for argv in demo:
        assert main(argv) == 0
    assert "gauge_pressure" in capsys.readouterr().out
