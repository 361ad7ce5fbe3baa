"""The sessions shipped inside the package (``shelljax/data/sessions``)."""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def bundled_sessions(pattern: str = "*.toml") -> list[Path]:
    """Sorted paths of the bundled session files matching the glob ``pattern`` (e.g. ``"calib_pezzi_*.toml"``)."""
    return sorted(Path(str(resources.files("shelljax") / "data" / "sessions")).glob(pattern))
