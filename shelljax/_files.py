"""Files written whole or not at all: every writer of a result a reader may open meanwhile."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path


def atomic_write_text(path: str | Path, text: str, *, check: Callable[[Path], object] | None = None) -> Path:
    """Write ``text`` to ``path`` through a temporary file renamed into place (readable by all), so
    a reader or a killed run never sees half a file; ``check(temporary_path)`` may refuse the
    content by raising before the rename, leaving ``path`` as it was."""
    path = Path(path)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(handle, "w") as out:
            out.write(text)
        os.chmod(temporary, 0o644)
        if check is not None:
            check(Path(temporary))
        os.replace(temporary, path)
    finally:
        Path(temporary).unlink(missing_ok=True)
    return path
