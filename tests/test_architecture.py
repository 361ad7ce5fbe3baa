"""The house rules of docs/architecture.md, checked on the source tree (no JAX needed).

* a module imports only from its own layer or the layers below it;
* the data layer does not import JAX;
* no package file is over 600 lines, no function over 80;
* scripts (experiments/, tools/) and notebooks import public names only and patch no ``sys.path``;
* the paper's laws and constants are defined once.
"""

from __future__ import annotations

import ast
import collections
import functools
import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "shelljax"
LAYERS = {  # rank: a module may import ranks ≤ its own
    "paper": 0,
    "_errors": 0,
    "_toml": 0,
    "_files": 0,
    "_arguments": 0,
    "_options": 0,
    "physics": 1,
    "_solution": 1,
    "session": 1,
    "geometry": 1,
    "sensing": 1,
    "executor": 1,
    "_placement": 1,
    "axisym": 2,
    "shell3d": 2,
    "_parallel": 2,
    "_programs": 2,
    "estimate": 3,
    "diagnose": 3,
    "rig": 3,
    "virtual": 3,
    "dynamics": 3,
    "realtime": 3,
    "cli": 4,
    "runner": 4,
    "config": 4,
    "plots": 4,
    "report": 4,
    "scenario": 4,
    "replica": 4,
    "object_estimate": 4,
    "viewer": 4,
}
DATA_LAYER = ("session", "geometry", "sensing")
MAX_FILE_LINES = 600
MAX_FUNCTION_LINES = 80


def _package_files():
    return sorted(p for p in PACKAGE.rglob("*.py") if "data" not in p.relative_to(PACKAGE).parts[:1])


def _top(path: Path) -> str:
    part = path.relative_to(PACKAGE).parts[0]
    return part.removesuffix(".py")


def _imported_tops(path: Path) -> set[str]:
    """The shelljax top-level modules ``path`` imports (relative or absolute)."""
    tree = ast.parse(path.read_text())
    depth_of_file = len(path.relative_to(PACKAGE).parts) - 1  # 0: shelljax/x.py, 1: shelljax/pkg/x.py
    tops = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level == 0 and node.module and node.module.startswith("shelljax."):
                tops.add(node.module.split(".")[1])
            elif node.level > 0:
                up = node.level - 1  # levels above the file's own package
                if up > depth_of_file:
                    continue
                if up == depth_of_file:  # relative to shelljax/ itself
                    names = [node.module.split(".")[0]] if node.module else [a.name for a in node.names]
                    tops.update(names)
                else:
                    tops.add(_top(path))
        elif isinstance(node, ast.Import):
            tops.update(a.name.split(".")[1] for a in node.names if a.name.startswith("shelljax."))
    return tops


def _imported_modules(path: Path):
    """(line, module parts under shelljax, imported names) of each shelljax import in ``path``."""
    rel = path.relative_to(PACKAGE).parts
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("shelljax."):
                    yield node.lineno, a.name.split(".")[1:], []
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                if node.module and node.module.startswith("shelljax."):
                    yield node.lineno, node.module.split(".")[1:], [a.name for a in node.names]
            elif node.level <= len(rel):
                base = list(rel[: len(rel) - node.level])
                yield node.lineno, base + (node.module.split(".") if node.module else []), [a.name for a in node.names]


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def test_no_module_imports_another_packages_private_module():
    # a package's private modules and names are its own; what it lends other packages is in its
    # __init__ or its `internal` module; shelljax's top-level private modules (_files, _errors,
    # _toml, _options, ...) are shared by every package (docs/architecture.md, "Public names")
    reached = []
    for path in _package_files():
        own = _top(path)
        for line, parts, names in _imported_modules(path):
            if not parts or parts[0].removesuffix(".py") == own:
                continue  # `from .. import pkg` names top-level modules, shared alike
            private = [p for p in parts[1:] if _private(p)] + [n for n in names if _private(n)]
            if private:
                reached.append(f"{path.relative_to(ROOT)}:{line} imports {'.'.join(parts)}: {', '.join(private)}")
    assert not reached, "import what a package lends from its __init__ or its internal module:\n" + "\n".join(reached)


def test_every_package_module_has_a_layer():
    missing = {_top(p) for p in _package_files() if _top(p) != "__init__"} - set(LAYERS)
    assert not missing, f"add these to LAYERS here and to docs/architecture.md: {sorted(missing)}"


def test_modules_import_only_their_layer_and_below():
    upward = []
    for path in _package_files():
        own = _top(path)
        if own == "__init__":
            continue
        for top in _imported_tops(path) - {"__init__", "__version__"}:
            if top in LAYERS and LAYERS[top] > LAYERS[own]:
                upward.append(
                    f"{path.relative_to(ROOT)} ({own}, layer {LAYERS[own]}) imports {top} (layer {LAYERS[top]})"
                )
    assert not upward, "\n".join(upward)


JAX_IMPORT = re.compile(r"^\s*(import|from) (jax|equinox|optimistix|lineax)\b", re.M)


@functools.cache
def _tops_reaching_jax() -> frozenset[str]:
    """The top-level modules that import JAX themselves or through any shelljax module they import."""
    imports, reaching = collections.defaultdict(set), set()
    for path in _package_files():
        imports[_top(path)] |= _imported_tops(path) - {_top(path)}
        if JAX_IMPORT.search(path.read_text()):
            reaching.add(_top(path))
    while grown := {top for top, used in imports.items() if top not in reaching and used & reaching}:
        reaching |= grown
    return frozenset(reaching)


def test_data_layer_does_not_import_jax():
    offenders = [
        str(p.relative_to(ROOT)) for p in _package_files() if _top(p) in DATA_LAYER and JAX_IMPORT.search(p.read_text())
    ]
    assert not offenders, offenders


def test_data_layer_does_not_import_jax_through_other_modules():
    through = {
        str(p.relative_to(ROOT)): sorted(_imported_tops(p) & _tops_reaching_jax())
        for p in _package_files()
        if _top(p) in DATA_LAYER
    }
    offenders = {path: tops for path, tops in through.items() if tops}
    assert not offenders, f"these data-layer modules reach JAX through: {offenders}"


def test_the_indirect_jax_check_sees_the_engines():
    # the check above is vacuous if it finds no module reaching JAX: the engines and physics must
    assert {"physics", "axisym", "shell3d", "estimate"} <= _tops_reaching_jax()


def test_no_package_file_is_over_600_lines():
    long = {
        str(p.relative_to(ROOT)): n for p in _package_files() if (n := len(p.read_text().splitlines())) > MAX_FILE_LINES
    }
    assert not long, long


def test_no_package_function_is_over_80_lines():
    long = [
        f"{p.relative_to(ROOT)}:{n.lineno} {n.name} ({n.end_lineno - n.lineno + 1} lines)"
        for p in _package_files()
        for n in ast.walk(ast.parse(p.read_text()))
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.end_lineno - n.lineno + 1 > MAX_FUNCTION_LINES
    ]
    assert not long, "split these into named steps:\n" + "\n".join(long)


# The writers of files that must stream, or that move a set of files into place together, each
# with its reason; every other file is written whole through shelljax/_files.py.
STREAMING_WRITERS = {
    ("shelljax/estimate/_bayes.py", "open('a')"): "emcee's HDF5 chain, appended by h5py block by block as it samples",
    ("shelljax/sensing/_capture.py", "open('ab')"): "the live sample log, appended row by row, fsync-ed",
    ("shelljax/sensing/_events.py", "open('ab')"): "the recording's event log, appended event by event, fsync-ed",
    ("shelljax/session/_write.py", "write_text"): "a session's TOML and CSVs, written and read back in a scratch "
    "folder, then renamed into place together",
}


def _file_writes(path: Path):
    """(line, what) of each ``.write_text(``, ``.write_bytes(`` and ``open(`` for writing in ``path``."""
    for node in ast.walk(ast.parse(path.read_text())):
        if not isinstance(node, ast.Call):
            continue
        name = getattr(node.func, "attr", getattr(node.func, "id", None))
        if name in ("write_text", "write_bytes"):
            yield node.lineno, name
        elif name in ("open", "fdopen"):
            given = [*node.args, *(k.value for k in node.keywords if k.arg == "mode")]
            for mode in (a.value for a in given if isinstance(a, ast.Constant) and isinstance(a.value, str)):
                if set(mode) <= set("rwaxbt+") and set(mode) & set("wax+"):
                    yield node.lineno, f"open({mode!r})"


def test_result_files_are_written_only_through_files_module():
    found = {
        (str(p.relative_to(ROOT)), what): line
        for p in _package_files()
        if p.name != "_files.py" or p.parent != PACKAGE
        for line, what in _file_writes(p)
    }
    unchecked = [
        f"{path}:{line} {what}" for (path, what), line in found.items() if (path, what) not in STREAMING_WRITERS
    ]
    assert not unchecked, "write result files through shelljax._files (atomic_write_text, ...):\n" + "\n".join(
        unchecked
    )
    stale = sorted(set(STREAMING_WRITERS) - set(found))
    assert not stale, f"these exempt writers no longer write: remove them from STREAMING_WRITERS: {stale}"


def test_the_file_write_check_sees_writes():
    # the check above is vacuous if it finds nothing: the exempt writers must be found
    assert {what for p in [PACKAGE / "_files.py"] for _, what in _file_writes(p)} >= {"open('w')", "write_bytes"}


def _script_sources():
    for path in sorted([*(ROOT / "experiments").glob("*.py"), *(ROOT / "tools").glob("*.py")]):
        yield path, path.read_text()
    for path in sorted((ROOT / "notebooks").glob("*.ipynb")):
        cells = json.loads(path.read_text())["cells"]
        yield path, "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")


@pytest.mark.parametrize("path, source", list(_script_sources()), ids=lambda v: v.name if isinstance(v, Path) else "")
def test_scripts_and_notebooks_use_public_names_only(path, source):
    private_module = re.findall(r"shelljax(?:\.\w+)*\._(?!_)\w+", source)
    # os._exit is the standard library's documented way out of a process from a thread
    private_attribute = re.findall(r"\b(?!self\b|os\._exit\b)[a-z]\w*\._[a-z]\w*", source)
    assert "sys.path" not in source, f"{path.name} patches sys.path; use an editable install"
    assert not private_module, f"{path.name} imports private modules: {sorted(set(private_module))}"
    assert not private_attribute, f"{path.name} reaches private attributes: {sorted(set(private_attribute))}"


TEXT_SUFFIXES = {".py", ".md", ".ipynb", ".toml", ".txt", ".cfg", ".ini", ".yaml", ".yml", ".ino", ".sh", ".rst"}
OUTSIDE_FILES = ("DESIGN" + ".md", ".." + "/shared")  # written split, so this file does not name them


BUILD_OUTPUTS = ("build", "dist", "runs")  # what pip and the commands leave in a checkout, not its sources


def _text_files():
    for path in sorted(ROOT.rglob("*")):
        parts = path.relative_to(ROOT).parts
        generated = parts[0] in BUILD_OUTPUTS or any(p.startswith(".") or p.endswith(".egg-info") for p in parts)
        if path.is_file() and path.suffix in TEXT_SUFFIXES and not generated:
            yield path


def test_no_text_refers_to_files_outside_the_repository():
    cited = [
        f"{p.relative_to(ROOT)}:{n}: {name}"
        for p in _text_files()
        for n, line in enumerate(p.read_text(errors="replace").splitlines(), 1)
        for name in OUTSIDE_FILES
        if name in line
    ]
    assert not cited, "say it here, or cite the paper by its title and authors:\n" + "\n".join(cited)


def _layout_block() -> str:
    readme = (ROOT / "README.md").read_text()
    return readme.split("## Layout", 1)[1].split("\n## ", 1)[0]


def test_readme_layout_names_every_package_and_module():
    layout = set(re.findall(r"[\w.]+/?", _layout_block()))
    modules = [f"{p.name}/" for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()]
    modules += [p.name for p in PACKAGE.glob("*.py") if p.name != "__init__.py"]
    missing = sorted(set(modules) - layout)
    assert not missing, f"the README's layout leaves out {missing}"


def test_experiments_readme_lists_every_script():
    listed = set(re.findall(r"`(\w+\.py)`", (ROOT / "experiments" / "README.md").read_text()))
    missing = sorted(p.name for p in (ROOT / "experiments").glob("*.py") if p.name not in listed)
    assert not missing, f"experiments/README.md does not list {missing}"


def test_no_test_patches_sys_path():
    offenders = [
        p.name for p in (ROOT / "tests").glob("*.py") if p.name != Path(__file__).name and "sys.path" in p.read_text()
    ]
    assert not offenders, offenders


def _numbers(path: Path) -> set[float]:
    return {
        n.value for n in ast.walk(ast.parse(path.read_text())) if isinstance(n, ast.Constant) and type(n.value) is float
    }


@pytest.mark.parametrize(
    "value, home",
    [
        (1.33, "paper.py"),  # the wrinkle law's prefactor
        (2.52, "physics/_shell_theory.py"),  # the wrinkling onset
        (0.64, "paper.py"),  # the paper's k_s
    ],
)
def test_each_constant_of_the_paper_is_defined_once(value, home):
    where = [str(p.relative_to(PACKAGE)) for p in _package_files() if value in _numbers(p)]
    assert where == [home], f"{value} is written in {where}; its one home is {home}"


def test_the_finger_radius_default_is_the_papers():
    written = []
    for path in _package_files():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                args = node.args.args[len(node.args.args) - len(node.args.defaults) :] + node.args.kwonlyargs
                defaults = node.args.defaults + node.args.kw_defaults
                written += [
                    f"{path.relative_to(PACKAGE)}:{node.lineno}"
                    for a, d in zip(args, defaults)
                    if a.arg == "indenter_radius" and isinstance(d, ast.Constant) and isinstance(d.value, float)
                ]
            elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                if (
                    node.target.id == "indenter_radius"
                    and isinstance(node.value, ast.Constant)
                    and isinstance(node.value.value, float)
                ):
                    written.append(f"{path.relative_to(PACKAGE)}:{node.lineno}")
    assert not written, (
        f"indenter_radius defaults written as numbers (use shelljax.paper.PAPER_INDENTER_RADIUS): {written}"
    )


@pytest.mark.parametrize(
    "pattern, home",
    [
        (r"arctanh", "physics/_shell_theory.py"),  # Vella's point-load stiffness
        (r"(?m)^def tau\(", "paper.py"),
        (r"(?m)^def \w*signed_volume\(", "geometry/_mesh.py"),
        (r"arange\(5", None),  # the force levels are listed once, in paper.py
        (r"(?m)^class AbstractGasLaw\b", "physics/_gas.py"),  # the gas laws, objects every engine takes
        (r"(?m)^def gas_law\(", "physics/_gas.py"),  # the one map from a gas's name to its law
        (r"(?m)^class AbstractContactLaw\b", "physics/_contact_laws.py"),  # the laws a Plane carries
        (r"(?m)^\s*WRINKLE_LAWS = ", "_options.py"),  # the wrinkle laws' names, in one order
        (r"(?m)^class ShellProperties\b", "physics/_properties.py"),  # P_g, E, h, ν, R: one object
        # docs/architecture.md's other "one X": the TOML reader, the sphere builder, the plane, the defaults
        (r"(?m)^\s*(import|from) tomllib\b", "_toml.py"),
        (r"trimesh\.creation\.(icosphere|uv_sphere)\(", "geometry/_primitives.py"),
        (r"(?m)^class Plane\b", "physics/_contact.py"),
        (r"(?m)^DEFAULT_OPTIONS = ", "_options.py"),
        (r"\*\*\s?3 / \(12\.0 \* \(1\.0 - ", "paper.py"),  # B = E h³/(12(1 − ν²)): τ's, physics re-exports it
        (r"(?m)^def \w*mesh_volume\(", "geometry/_mesh.py"),  # a mesh's enclosed volume, for NumPy and JAX
    ],
)
def test_each_law_is_defined_once(pattern, home):
    where = [str(p.relative_to(PACKAGE)) for p in _package_files() if re.search(pattern, p.read_text())]
    assert where == ([home] if home else []), f"{pattern!r} appears in {where}; its one home is {home or 'paper.py'}"


def test_each_group_of_test_files_sharing_programs_has_several_files():
    from conftest import programs_group  # tests/conftest.py: the xdist scheduler's groups

    groups = collections.Counter(g for p in (ROOT / "tests").glob("test_*.py") if (g := programs_group(p)))
    lone = sorted(g for g, n in groups.items() if n < 2)
    assert groups and not lone, f"SHARED_PROGRAMS groups of a single file (a misspelt name?): {lone}"


# the modules past the edge (TOML, session and rig files, CLI options): they take gas laws as objects
GAS_OBJECT_PACKAGES = ("axisym", "shell3d", "dynamics", "estimate", "diagnose", "realtime", "physics")
GAS_NAME = r'"(?:prescribed|isothermal|adiabatic|polytropic)"'
GAS_NAME_COMPARISON = re.compile(rf"[=!]=\s*{GAS_NAME}|{GAS_NAME}\s*[=!]=|\bin\s*[(\[{{][^)\]}}]*{GAS_NAME}")


def test_gas_names_are_compared_only_at_the_edge():
    compared = [
        f"{path.relative_to(PACKAGE)}:{source[: match.start()].count(chr(10)) + 1}"
        for path in _package_files()
        if _top(path) in GAS_OBJECT_PACKAGES
        for source in [path.read_text()]
        for match in GAS_NAME_COMPARISON.finditer(source)
    ]
    assert not compared, (
        f"gas laws compared by name past the edge (take a physics.AbstractGasLaw, ask it .sealed or "
        f"isinstance; physics.gas_law maps a name at the edge): {compared}"
    )


#: The most parameters a function in shelljax/ takes (``self``/``cls`` not counted; ``*args`` and
#: ``**kwargs`` count one each): more are packed into a named structure (realtime's kernels take
#: geometry, body, material, contact and buffers).
MAX_PARAMETERS = 10
#: Functions over the limit, each for a reason: public entry points whose options are keyword-only
#: (named at every call, documented one by one: sample_posterior, sphere_mesh, calibrate_sensor,
#: write_session and its document, Indentation, shell3d's newton), and two private functions whose arguments are the
#: leaves of a traced call (axisym's _params, the dynamics' host-callback solve). module:function -> count.
PARAMETER_EXEMPTIONS = {
    "axisym/_model.py:_params": 11,
    "dynamics/_sparse.py:_host_solve": 11,
    "estimate/_bayes.py:sample_posterior": 12,
    "geometry/_primitives.py:sphere_mesh": 13,
    "sensing/_calibrate.py:calibrate_sensor": 12,
    "session/_write.py:write_session": 16,
    "session/_write.py:_session_document": 14,
    "shell3d/_indent.py:__init__": 17,
    "shell3d/_newton.py:newton": 11,
}


def _parameter_counts():
    for path in _package_files():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                a = node.args
                names = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs]
                if names and names[0] in ("self", "cls"):
                    names = names[1:]
                yield (
                    f"{path.relative_to(PACKAGE)}:{node.name}",
                    len(names) + (a.vararg is not None) + (a.kwarg is not None),
                )


def test_no_function_takes_more_than_ten_parameters():
    over = {name: n for name, n in _parameter_counts() if n > MAX_PARAMETERS}
    unexpected = {name: n for name, n in over.items() if PARAMETER_EXEMPTIONS.get(name) != n}
    stale = sorted(set(PARAMETER_EXEMPTIONS) - set(over))
    assert not unexpected, (
        f"functions over {MAX_PARAMETERS} parameters (pack them into a named structure): {unexpected}"
    )
    assert not stale, f"exempted functions now within {MAX_PARAMETERS} parameters (drop their exemption): {stale}"


@pytest.mark.parametrize(
    "path", sorted([*(ROOT / "experiments").glob("*.py"), *(ROOT / "tools").glob("*.py")]), ids=lambda p: p.name
)
def test_every_runnable_script_parses_its_arguments(path):
    # `python tools/x.py --help` must print help, not run the script: several overwrite bundled data
    source = path.read_text()
    if "__main__" in source:
        assert "ArgumentParser(" in source, f"{path.name}: parse the command line with argparse (at least --help)"
