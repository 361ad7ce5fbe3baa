"""``python -m shelljax.cli``: the ``shelljax`` console script."""

import sys

from . import main

sys.exit(main())
