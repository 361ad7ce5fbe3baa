"""The README's two quickstart commands stay true: the first two commands, the second one run by CI."""

from __future__ import annotations

import re
from pathlib import Path

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
