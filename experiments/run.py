"""Run an experiment config: ``python experiments/run.py configs/paper.toml [--out DIR]``.

The same as ``shelljax run``; kept as a script so experiments can be launched without the console
entry point. Run it under an editable install (``pip install -e .``) or with ``PYTHONPATH`` set to
the checkout.
"""

import sys

from shelljax.cli import main

if __name__ == "__main__":
    sys.exit(main(["run", *sys.argv[1:]]))
