"""The tree is formatted by the house formatter, ``ruff format`` (configured in pyproject.toml)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_tree_is_formatted_by_ruff():
    checked = subprocess.run(
        [sys.executable, "-m", "ruff", "format", "--check", "--diff", str(ROOT)], capture_output=True, text=True
    )
    assert checked.returncode == 0, (
        f"these files are not formatted (run `ruff format` from the repository root):\n{checked.stdout[-4000:]}"
    )


def test_no_hand_formatting_markers_remain():
    marked = [
        f"{path.relative_to(ROOT)}:{number}"
        for folder in ("shelljax", "tests", "experiments", "tools")
        for path in sorted((ROOT / folder).rglob("*.py"))
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if "fmt: " + "skip" in line or "fmt: " + "off" in line
    ]
    assert not marked, f"the formatter owns the layout; drop these markers: {marked}"
