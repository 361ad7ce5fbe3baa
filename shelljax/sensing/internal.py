"""What the sensing package lends the ``shelljax`` command line: :func:`register` adds the
``acquire``, ``sensor-calibrate`` and ``sensor-emulator`` subcommands to its parser. Not for users;
the public names are in ``shelljax.sensing``.
"""

from ._cli import register

__all__ = ["register"]
