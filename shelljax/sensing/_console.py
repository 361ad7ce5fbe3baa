"""Who answers the prompts and watches the live display: a terminal, a script, or nobody.

The recording and calibration walk-throughs only talk to a :class:`Console`, so tests drive them
with :class:`ScriptedConsole` and ``--yes`` runs with :class:`AutoConsole`.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterable
from typing import Protocol, TextIO


class Console(Protocol):
    """The three things a walk-through needs from its user."""

    def ask(self, prompt: str) -> str:
        """Ask a question; the answer without its newline ('' means: take the default)."""
        ...

    def say(self, message: str) -> None:
        """An instruction or a result, on its own line."""
        ...

    def status(self, line: str) -> None:
        """The live display: one line, overwritten by the next call."""
        ...


class TerminalConsole:
    """Prompts on stdin/stderr; the live display is a carriage-return line, redrawn ≤ 10×/s
    (only when ``stream`` is a terminal)."""

    def __init__(self, stream: TextIO = sys.stderr, read: Callable[[str], str] = input, min_interval: float = 0.1):
        self._stream, self._read = stream, read
        self._min_interval = min_interval
        self._last = 0.0
        self._width = 0
        self._live = hasattr(stream, "isatty") and stream.isatty()

    def _clear(self) -> None:
        if self._width:
            self._stream.write("\r" + " " * self._width + "\r")
            self._width = 0

    def ask(self, prompt: str) -> str:
        self._clear()
        self._stream.flush()
        return self._read(prompt).strip()

    def say(self, message: str) -> None:
        self._clear()
        print(message, file=self._stream, flush=True)

    def status(self, line: str) -> None:
        if not self._live:
            return  # a redrawn line only makes sense on a terminal, not in a log file
        now = time.monotonic()
        if now - self._last < self._min_interval:
            return
        self._last = now
        padded = line.ljust(self._width)
        self._width = len(line)
        self._stream.write("\r" + padded)
        self._stream.flush()


class ScriptedConsole:
    """Answers from a script, for tests. Each answer is a string or a callable of the prompt.

    ``transcript`` records ``("ask"|"say", text)``; ``statuses`` counts live-display updates.
    Running out of answers raises :class:`EOFError`, as ``input()`` does at end of input.
    """

    def __init__(self, answers: Iterable[str | Callable[[str], str]] = ()):
        self._answers = iter(answers)
        self.transcript: list[tuple[str, str]] = []
        self.statuses = 0
        self.last_status = ""

    def ask(self, prompt: str) -> str:
        self.transcript.append(("ask", prompt))
        try:
            answer = next(self._answers)
        except StopIteration:
            raise EOFError(f"script ran out of answers at prompt {prompt!r}") from None
        return answer(prompt) if callable(answer) else answer

    def say(self, message: str) -> None:
        self.transcript.append(("say", message))

    def status(self, line: str) -> None:
        self.statuses += 1
        self.last_status = line


class AutoConsole(ScriptedConsole):
    """Takes the default of every prompt (``--yes``); messages go to ``stream`` if given."""

    interactive = False

    def __init__(self, stream: TextIO | None = None):
        super().__init__()
        self._stream = stream

    def ask(self, prompt: str) -> str:
        self.transcript.append(("ask", prompt))
        if self._stream is not None:
            print(prompt + "(default)", file=self._stream, flush=True)
        return ""

    def say(self, message: str) -> None:
        super().say(message)
        if self._stream is not None:
            print(message, file=self._stream, flush=True)
