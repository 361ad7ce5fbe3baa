"""The command line's shared argparse pieces: a parser whose every error is one line with a fix,
a help formatter that shows each option's default, and value types that refuse a number no
option can take (a negative count, a probability above 1) while the command line is parsed,
before any work. Ranges that depend on a unit option (a radius in --length-unit) are checked by
the command itself (``shelljax.session`` holds them). Imports only argparse and the error types,
so every layer's command line may use it."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

from ._errors import InvalidInputError


class DefaultsHelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """``--help`` shows every option's default, but for an on/off flag or a default of None (whose
    help says what happens without it)."""

    def _get_help_string(self, action):
        if action.default is None or action.default is False or action.nargs == 0:
            return action.help
        return super()._get_help_string(action)


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser (and, through ``add_subparsers``, every subcommand's) that shows defaults
    in ``--help`` and turns a usage error into :class:`InvalidInputError`: one line naming the
    option and a fix, exit status 2 through the command's own error handling."""

    def __init__(self, *args, formatter_class=DefaultsHelpFormatter, **kwargs):
        super().__init__(*args, formatter_class=formatter_class, **kwargs)

    def error(self, message):
        fix = "" if "Fix:" in message else f". Fix: see `{self.prog} --help`"
        raise InvalidInputError(f"{message}{fix}")


def shown(value: float) -> str:
    """``value`` as short as it reads back exactly (``%g``, or all its digits where ``%g`` rounds
    it: 10.000000000000002 is not 10)."""
    text = f"{value:g}"
    return text if not math.isfinite(value) or float(text) == value else repr(value)


def _bounds(low, high, low_open: bool = False, high_open: bool = False) -> str:
    parts = []
    if low is not None:
        parts.append(f"{'>' if low_open else '>='} {low:g}")
    if high is not None:
        parts.append(f"{'<' if high_open else '<='} {high:g}")
    return " and ".join(parts)


def whole(low: int = 0, high: int | None = None, *, hint: str = "") -> Callable[[str], int]:
    """An argparse ``type``: a whole number in [``low``, ``high``]; ``hint`` ends the fix."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not a whole number. Fix: write one {_bounds(low, high)}{hint}"
            ) from None
        if value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(
                f"{value} is out of range. Fix: give a whole number {_bounds(low, high)}{hint}"
            )
        return value

    parse.__name__ = "whole number"
    return parse


def real(
    low: float | None = None,
    high: float | None = None,
    *,
    low_open: bool = False,
    high_open: bool = False,
    unit: str = "",
    hint: str = "",
) -> Callable[[str], float]:
    """An argparse ``type``: a finite number from ``low`` to ``high`` (either bound left out with
    ``low_open`` / ``high_open``), in ``unit`` (named in the message); ``hint`` ends the fix."""
    suffix = f" {unit}" if unit else ""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not a number. Fix: write a plain decimal number{hint}"
            ) from None
        below = low is not None and (value <= low if low_open else value < low)
        above = high is not None and (value >= high if high_open else value > high)
        if not math.isfinite(value) or below or above:
            raise argparse.ArgumentTypeError(
                f"{shown(value)}{suffix} is out of range. Fix: give a number "
                f"{_bounds(low, high, low_open, high_open)}{suffix}{hint}"
            )
        return value

    parse.__name__ = "number"
    return parse
