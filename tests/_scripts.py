"""Scripts of experiments/ and tools/ loaded as modules (the folders are not packages)."""

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def load_script(folder: str, name: str):
    """``<folder>/<name>.py`` as the module ``name``, registered so that a script loaded after it
    finds it by a sibling import, as ``python <folder>/x.py`` would (loaded once per process)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, ROOT / folder / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
