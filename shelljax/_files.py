"""Result files: their paths checked before any work, each written whole or not at all, and read
back with a one-line error when one is not whole.

A command checks every output path it was given (:func:`check_output_file`,
:func:`check_output_dir`) before it computes anything and creates nothing while checking, so a
refused path costs no fit and leaves nothing behind; every result file is written whole through
:func:`atomic_write_text`, :func:`atomic_write_bytes` or, for a library that writes to a path
itself (matplotlib's ``savefig``, trimesh's ``export``), :func:`atomic_write`.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ._errors import InvalidInputError


def _nearest_existing(path: Path) -> Path:
    """``path`` itself or its nearest ancestor that exists (the working directory for a relative one)."""
    for candidate in (path, *path.parents):
        if candidate.exists():
            return candidate
    return Path.cwd()


def _check_creatable(path: Path, option: str) -> None:
    """Refuse ``path`` when the directories above it cannot be created or written to."""
    existing = _nearest_existing(path.parent)
    if not existing.is_dir():
        raise InvalidInputError(
            f"{option} {path}: {existing} is a file, so nothing can be created under it. Fix: "
            "choose a path whose parent is a directory"
        )
    if not os.access(existing, os.W_OK | os.X_OK):
        raise InvalidInputError(
            f"{option} {path}: the directory {existing} is not writable. Fix: choose a path in a "
            "directory you can write to"
        )


def check_output_file(path: str | Path, option: str, *, example: str = "result") -> Path:
    """``path`` as a Path once it is known to be writable as a file (``option``: the command-line
    option or field that named it, for the message; ``example``: a file name the fix suggests):
    not a directory, its parent a directory that is, or can be made, writable. Creates nothing.

    Raises:
        InvalidInputError: naming ``option``, the path and a fix.
    """
    named_a_directory = str(path).endswith(("/", os.sep))
    path = Path(path)
    if named_a_directory or path.is_dir():
        raise InvalidInputError(
            f"{option} {path}: is a directory, not a file. Fix: name a file, e.g. {option} {path / example}"
        )
    if path.exists() and not os.access(path, os.W_OK):
        raise InvalidInputError(
            f"{option} {path}: the file is not writable. Fix: choose another path, or make it writable"
        )
    _check_creatable(path, option)
    return path


def check_output_dir(path: str | Path, option: str) -> Path:
    """``path`` as a Path once it is known to be usable as an output directory (``option``: the
    command-line option or field that named it): an existing writable directory, or one that can be
    created. Creates nothing.

    Raises:
        InvalidInputError: naming ``option``, the path and a fix.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InvalidInputError(
            f"{option} {path}: exists and is not a directory. Fix: name a new or existing directory, "
            f"e.g. {option} {path.with_suffix('')}-out/"
        )
    if path.is_dir() and not os.access(path, os.W_OK | os.X_OK):
        raise InvalidInputError(
            f"{option} {path}: the directory is not writable. Fix: choose a directory you can write to"
        )
    _check_creatable(path, option)
    return path


def read_json(path: str | Path, what: str, *, fix: str) -> Any:
    """The JSON document ``what`` (e.g. "replica file") at ``path``.

    Raises:
        InvalidInputError: a missing, unreadable or truncated file, naming it and ``fix``.
    """
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InvalidInputError(f"{path}: {what} does not exist. Fix: {fix}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise InvalidInputError(f"{path}: not a whole {what} ({type(err).__name__}: {err}). Fix: {fix}") from None


def _replace_whole(path: Path, write: Callable[[Path], object], suffix: str, check) -> Path:
    """``write(temporary)``, then ``check(temporary)``, then the temporary file renamed to ``path``."""
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=suffix)
    os.close(handle)
    try:
        write(Path(temporary))
        os.chmod(temporary, 0o644)
        if check is not None:
            check(Path(temporary))
        os.replace(temporary, path)
    finally:
        Path(temporary).unlink(missing_ok=True)
    return path


def atomic_write_text(
    path: str | Path, text: str, *, check: Callable[[Path], object] | None = None, durable: bool = False
) -> Path:
    """Write ``text`` to ``path`` through a temporary file renamed into place (readable by all), so
    a reader or a killed run never sees half a file; ``check(temporary_path)`` may refuse the
    content by raising before the rename, leaving ``path`` as it was; ``durable``: the content is
    fsync-ed to the disk before the rename, so the file also survives a power cut (a recording)."""

    def write(temporary: Path) -> None:
        with open(temporary, "w") as out:
            out.write(text)
            if durable:
                out.flush()
                os.fsync(out.fileno())

    return _replace_whole(Path(path), write, ".tmp", check)


def atomic_write_bytes(path: str | Path, data: bytes, *, check: Callable[[Path], object] | None = None) -> Path:
    """:func:`atomic_write_text` for ``data`` given as bytes."""
    return _replace_whole(Path(path), lambda temporary: temporary.write_bytes(data), ".tmp", check)


def atomic_write(path: str | Path, write: Callable[[Path], object]) -> Path:
    """``write(temporary_path)`` writes the whole file, which is then renamed to ``path``: for a
    library that writes to a path itself. The temporary path ends in ``path``'s suffix, from which
    matplotlib's ``savefig`` and trimesh's ``export`` take the format."""
    path = Path(path)
    return _replace_whole(path, write, path.suffix, None)
