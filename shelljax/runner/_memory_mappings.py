"""Keeping a long process within the memory mappings Linux allows it."""

from __future__ import annotations

import jax


def memory_mappings() -> tuple[int, int] | None:
    """(memory mappings of this process, the kernel's limit per process), or None where
    ``/proc`` does not tell (not Linux)."""
    try:
        with open("/proc/self/maps") as maps, open("/proc/sys/vm/max_map_count") as limit:
            return sum(1 for _ in maps), int(limit.read())
    except (OSError, ValueError):
        return None


def release_compiled_programs_if_crowded() -> None:
    """Clear JAX's compiled programs once they hold half the memory mappings Linux allows.

    XLA:CPU maps each compiled kernel into three mappings (code, constants, data), and a process
    that reaches ``vm.max_map_count`` (65 530 by default) dies inside XLA (SIGSEGV or SIGABRT while
    compiling). Every session of an experiment compiles the engine for its own object, a few
    thousand mappings each (``configs/paper.toml``: 40 300 at its peak over 8 sessions),
    so a config with a few dozen sessions would get there. The runner calls this after each
    session; programs needed again come back from the persistent compilation cache (``import
    shelljax``) or are compiled again.
    """
    mappings = memory_mappings()
    if mappings is not None and mappings[0] > mappings[1] // 2:
        jax.clear_caches()
