"""Run an experiment config: ``python experiments/run.py configs/paper.toml [--out DIR]``.

The same as ``shelljax run``; kept as a script so experiments can be launched without the console
entry point.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout's shelljax, not an installed one

from shelljax.cli import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main(["run", *sys.argv[1:]]))
