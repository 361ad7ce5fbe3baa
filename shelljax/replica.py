"""Digital replicas: a session's estimated shell as a mesh (glTF) plus ``replica.json`` that a game
engine, a VR scene or another simulator can load, and that :func:`load_replica` turns back into a
:class:`shelljax.dynamics.ShellDynamicSystem`.

``replica.json`` holds the gauge pressure P_g [Pa], Young's modulus E [Pa], Poisson's ratio ν [-],
the wall thickness h [m], the mass [kg], the gas model, the COR [-] (null when unmeasured), each
with its standard deviation (null when unknown), the mesh file and the units.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ._errors import InvalidInputError
from ._files import atomic_write, atomic_write_text, check_output_dir, read_json

REPLICA_VERSION = 1
_QUANTITIES = ("gauge_pressure_Pa", "youngs_modulus_Pa", "poisson_ratio", "thickness_m", "mass_kg", "cor")
#: What to do about a replica file that cannot be read.
REEXPORT = "export the replica again with `shelljax replica SESSION --out DIR`"
#: Triangles of a sphere replica: the sphere builder needs 20; beyond a million, no simulator loads it.
MESH_FACES = (20, 1_000_000)


def _quantity(value, std=None) -> dict:
    return {"value": None if value is None else float(value), "std": None if std is None else float(std)}


def write_replica(out_dir: str | Path, shell, quantities: dict, *, gas: str, source: dict | None = None) -> list[Path]:
    """Write ``replica.glb`` (the inflated mesh [m]) and ``replica.json`` to ``out_dir``.

    ``quantities`` maps each of ``gauge_pressure_Pa``, ``youngs_modulus_Pa``, ``poisson_ratio``,
    ``thickness_m``, ``mass_kg`` and ``cor`` to a value or a (value, std) pair (None: unknown).
    """
    import trimesh

    out = check_output_dir(out_dir, "--out")
    out.mkdir(parents=True, exist_ok=True)
    mesh_path = out / "replica.glb"
    atomic_write(mesh_path, trimesh.Trimesh(shell.mesh.vertices, shell.mesh.faces, process=False).export)
    body = {
        "replica_version": REPLICA_VERSION,
        "mesh": mesh_path.name,
        "length_unit": "m",
        "gas": gas,
        "source": source or {},
    }
    for name in _QUANTITIES:
        q = quantities.get(name)
        body[name] = _quantity(*q) if isinstance(q, tuple) else _quantity(q)
    atomic_write_text(out / "replica.json", json.dumps(body, indent=1))
    return [mesh_path, out / "replica.json"]


def export_replica(
    session_path: str | Path,
    out_dir: str | Path,
    *,
    method: str = "fit",
    gas: str = "adiabatic",
    cor: float | None = None,
    mesh_faces: int = 2000,
    wrinkle_law: str | None = None,
    rig: str | Path | None = None,
) -> list[Path]:
    """The replica of a session: P_g and E ± std from its ``method`` estimate, ν, h ± std, mass and
    the mesh (the session's, or a sphere of its radius with ``mesh_faces`` triangles).

    fit and bayes read the session through the axisym engine with ``wrinkle_law`` (default
    "scaling"), and with a sealed isothermal gas unless the replica's ``gas`` is "prescribed" (a poke
    is slow: no heat is kept in); with a ``rig`` file, through that rig and its forward model."""
    from . import shell3d as s3
    from .estimate import DEFAULT_OPTIONS
    from .object_estimate import estimated_parameters
    from .physics import gas_law
    from .session import load_session

    session = load_session(session_path)
    if session.mass is None:
        raise InvalidInputError(f"{session.source}: field 'mass' is missing. Fix: add `mass = <kg>` to the session")
    if cor is not None and not 0.0 < cor <= 1.0:
        raise InvalidInputError(f"--cor {cor}: a COR is in (0, 1]. Fix: measure it as √(bounce height / drop height)")
    if getattr(session, "mesh_path", None) is None and not MESH_FACES[0] <= mesh_faces <= MESH_FACES[1]:
        raise InvalidInputError(
            f"--mesh-faces {mesh_faces}: a sphere replica has {MESH_FACES[0]}-{MESH_FACES[1]} "
            "triangles. Fix: e.g. --mesh-faces 2000"
        )
    check_output_dir(out_dir, "--out")  # before the estimate: a refused path costs no fit
    estimator_gas = DEFAULT_OPTIONS.gas if gas_law(gas).sealed else "prescribed"
    if rig is not None:
        from .rig import load_rig

        estimator_gas, wrinkle_law = load_rig(rig).gas, wrinkle_law or load_rig(rig).wrinkle_law
    wrinkle_law = wrinkle_law or DEFAULT_OPTIONS.wrinkle_law
    p_g, e, stats = estimated_parameters(session, method, {"gas": estimator_gas, "wrinkle_law": wrinkle_law}, rig)
    mesh_path = getattr(session, "mesh_path", None)
    shell = (
        s3.load(mesh_path, session.thickness)
        if mesh_path
        else s3.ball(session.radius, session.thickness, n_triangles=mesh_faces)
    )
    quantities = {
        "gauge_pressure_Pa": (p_g, stats["gauge_pressure_Pa"]["std"]),
        "youngs_modulus_Pa": (e, stats["youngs_modulus_Pa"]["std"]),
        "poisson_ratio": (session.poisson_ratio, None),
        "thickness_m": (session.thickness, session.thickness_std),
        "mass_kg": (session.mass, None),
        "cor": (cor, None),
    }
    return write_replica(
        out_dir,
        shell,
        quantities,
        gas=gas,
        source={
            "session": str(session.source),
            "estimator": method,
            "estimator_gas": estimator_gas,
            "wrinkle_law": wrinkle_law,
            "rig": None if rig is None else str(rig),
        },
    )


def load_replica(directory: str | Path, *, planes=(), gravity=None):
    """A :class:`shelljax.dynamics.ShellDynamicSystem` from a replica directory, with ``planes``;
    also returns the replica's dictionary: ``(system, replica)``."""
    from . import dynamics as d
    from . import shell3d as s3
    from .physics import STANDARD_GRAVITY, ShellProperties, gas_law

    directory = Path(directory)
    path = directory / "replica.json"
    if not path.is_file():
        raise InvalidInputError(f"{directory}: no replica.json. Fix: give a directory written by `shelljax replica`")
    replica = read_json(path, "replica file", fix=REEXPORT)
    if not isinstance(replica, dict):
        raise InvalidInputError(f"{path}: not a replica file (a JSON {type(replica).__name__}). Fix: {REEXPORT}")
    for name in _QUANTITIES[:-1]:
        if replica.get(name, {}).get("value") is None:
            raise InvalidInputError(f"{path}: field '{name}.value' is missing. Fix: re-export the replica")
    value = lambda k: float(replica[k]["value"])  # noqa: E731
    shell = s3.load(directory / replica["mesh"], value("thickness_m"))
    properties = ShellProperties(
        gauge_pressure=value("gauge_pressure_Pa"),
        young_modulus=value("youngs_modulus_Pa"),
        thickness=shell.thickness,
        poisson_ratio=value("poisson_ratio"),
    )
    system = d.shell_system(
        shell,
        properties,
        gas=gas_law(replica["gas"]),
        mass=value("mass_kg"),
        planes=planes,
        gravity=STANDARD_GRAVITY if gravity is None else gravity,
    )
    return system, replica


def replica_volume(directory: str | Path) -> float:
    """Volume [m³] enclosed by a replica's mesh."""
    import trimesh

    mesh = trimesh.load(str(Path(directory) / "replica.glb"), force="mesh")
    return float(np.abs(mesh.volume))
