"""Modules of experiments/ that these tools share with the studies there.

A tool and a study draw from one generator (the rig's reality, protocol and noise) or run under
the same process tools (the long 3D runs), so that what the package ships is what the studies
measure. The scripts folders are not packages and nothing patches the module path: a tool loads
the experiments' module from its file, under its own name, so that a module it loads in turn as a
sibling is found.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments"


def load_experiment(name: str) -> ModuleType:
    """``experiments/<name>.py`` as the module ``name`` (loaded once per process)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, EXPERIMENTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
