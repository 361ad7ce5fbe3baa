"""Writing results to disk: the diagnosis's JSON and figure."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np

from ._errors import InvalidInputError


def jsonable(value):
    """``value`` with numpy scalars and arrays as Python ones and non-finite floats as None."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def write_diagnosis(diagnosis, out_dir: str | Path) -> list[Path]:
    """Write ``diagnosis.json`` and ``diagnosis.png`` into ``out_dir`` (created).

    Both files are written to temporary names and renamed once complete, so an interrupted run
    leaves no half-written file.
    """
    from .plots import plot_diagnosis

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InvalidInputError(f"--out {out}: exists and is not a directory. Fix: name a directory")
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, write in (("diagnosis.json", lambda p: p.write_text(json.dumps(jsonable(diagnosis.report), indent=2))),
                        ("diagnosis.png", lambda p: plot_diagnosis(diagnosis, p))):  # fmt: skip
        fd, tmp = tempfile.mkstemp(dir=out, prefix=f".{name}.", suffix=Path(name).suffix)
        os.close(fd)
        try:
            write(Path(tmp))
            os.replace(tmp, out / name)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        written.append(out / name)
    return written
