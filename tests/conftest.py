import ast
import functools
import os
from pathlib import Path


def _default_xla_flag(flag: str) -> None:
    """Append ``--name=value`` to XLA_FLAGS unless the environment already sets that name."""
    name = flag.removeprefix("--").partition("=")[0]
    if name not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + flag).strip()


# The suite is mostly XLA compilation of programs it then runs briefly, and LLVM's optimization
# passes are most of that: at optimization level 0 the suite compiles far faster, and its results
# agree with the optimized build to round-off with the same Newton iterations, so the tests check
# the same arithmetic (measurements: docs/fit-and-bayes.md, *The suite*). The flag is part of the
# persistent cache's key: programs compiled here are not reused by shelljax outside the tests. An
# XLA_FLAGS that sets its own level overrides this.
_default_xla_flag("--xla_backend_optimization_level=0")
# For the same reason XLA:CPU uses its legacy elemental emitters here, as shelljax's own fit does:
# they compile the engines' programs faster (docs/fit-and-bayes.md#compilation), with the same
# arithmetic up to the rounding of fused expressions.
_default_xla_flag("--xla_cpu_use_fusion_emitters=false")

# And without the two passes that hoist loop-invariant code and constants out of while loops: the
# engines' programs are Newton and line-search loops inside load-step scans, where those passes are
# about a quarter of the compile time (docs/fit-and-bayes.md, *The suite*). The loops then redo that
# work each iteration; results agree to round-off, with the same Newton iterations.
_default_xla_flag("--xla_disable_hlo_passes=while-loop-invariant-code-motion,while-loop-constant-sinking")

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")

import shelljax  # noqa: E402,F401  (x64 for every test, whatever it imports first)


# Test files that run the same compiled programs go to one xdist worker, in file order, so that
# the later ones find those programs in the persistent caches instead of compiling them again at
# the same time on the other worker. A file says so itself, with a module-level
# ``SHARED_PROGRAMS = "<group>"``, so that the group moves with the file when it is renamed: the
# sim_to_real notebook's diagnosis is test_diagnose's joint fit (4 sessions), and
# test_estimate_forward_model, test_readme and test_runner_cli all fit with the main job's program.
# A group runs on one worker, so it must stay well under half the suite: the heaviest files that
# share the main job's programs (test_rig, test_runner_cluster) are left out and take them from
# the persistent cache. The scheduler runs where no test module is imported, so it reads the name
# from the file's source.
GROUP_ATTRIBUTE = "SHARED_PROGRAMS"


@functools.cache
def programs_group(path: Path) -> str | None:
    """The group a test file declares with a module-level ``SHARED_PROGRAMS = "<group>"``, or None."""
    try:
        tree = ast.parse(path.read_text())
    except (OSError, SyntaxError, UnicodeDecodeError):  # pytest reports the file's own error
        return None
    for node in tree.body:
        if (
            isinstance(node, ast.Assign)
            and any(isinstance(t, ast.Name) and t.id == GROUP_ATTRIBUTE for t in node.targets)
            and isinstance(node.value, ast.Constant)
            and isinstance(node.value.value, str)
        ):
            return node.value.value
    return None


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    from xdist.scheduler import LoadFileScheduling

    class SharedProgramsTogether(LoadFileScheduling):
        def _split_scope(self, nodeid):
            path = super()._split_scope(nodeid)
            group = programs_group(config.rootpath / path)
            return f"{GROUP_ATTRIBUTE}={group}" if group else path

    return SharedProgramsTogether(config, log)


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop JAX's compiled programs after each test file.

    XLA:CPU maps every compiled kernel into its own three memory mappings (code, constants, data),
    and Linux allows a process 65 530 (vm.max_map_count). An xdist worker running half the suite
    with an empty compilation cache reached that limit and died inside XLA (SIGSEGV or SIGABRT
    while compiling). Cleared after each file, a worker peaked at 17 200 mappings; what a later
    file needs again comes back from the persistent compilation cache.
    """
    yield
    jax.clear_caches()
