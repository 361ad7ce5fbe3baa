"""Building a :class:`shelljax.realtime.RealtimeShell`: from a dynamics system, a shell3d shell
(the engine's rest-shape solve, or its small-strain shrink with no solve to compile), a sphere, a
session or a replica directory (SI units). Each is a classmethod of the shell (``cls`` the class);
``**options`` are :class:`RealtimeOptions`' fields."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import jax.numpy as jnp
import numpy as np

from .._errors import InvalidInputError
from ..geometry import signed_volume
from ..physics import GAS_LAWS, STANDARD_GRAVITY, AdiabaticGas, ShellProperties, gas_law
from ..shell3d import rest_geometry
from ..shell3d.internal import membrane_strain
from ._checks import _check
from ._records import RealtimeOptions, RestShape

if TYPE_CHECKING:
    from ._model import RealtimeShell


def from_system(cls, system, **options) -> RealtimeShell:
    """The realtime twin of a :class:`shelljax.dynamics.ShellDynamicSystem` (its rest geometry,
    E, ν, h, gas and reference volume, vertex masses, gravity, planes and ``inflated`` start)."""
    params, geometry = system.params, system.geometry
    rest = RestShape(
        stencil=np.asarray(geometry.stencil),
        rest_metric=np.asarray(geometry.rest_metric),
        rest_curvature=np.asarray(geometry.rest_curvature),
        rest_area=np.asarray(geometry.rest_area),
        vertex_area=np.asarray(geometry.vertex_area),
    )
    properties = ShellProperties(
        gauge_pressure=float(params.gauge_pressure),
        young_modulus=float(params.young_modulus),
        thickness=float(params.thickness),
        poisson_ratio=float(params.poisson_ratio),
    )
    planes = options.pop("planes", tuple(system.planes))
    options.setdefault("gravity", np.asarray(system.gravity))
    return cls(
        rest,
        properties,
        positions=np.asarray(system.inflated).reshape(-1, 3),
        masses=np.asarray(system.node_masses),
        gas=system.config.gas,
        reference_volume=None if params.reference_volume is None else float(params.reference_volume),
        atmospheric_pressure=float(params.outside_pressure),
        planes=planes,
        options=RealtimeOptions.of(options),
    )


def from_shell(
    cls,
    shell,
    properties: ShellProperties,
    *,
    mass=None,
    wall_density=None,
    gas=AdiabaticGas(),
    planes=(),
    gravity=STANDARD_GRAVITY,
    rest_shape="solve",
    **options,
) -> RealtimeShell:
    """From a :class:`shelljax.shell3d.Shell` (its mesh the inflated shape [m]) and a
    ``physics.ShellProperties`` (P_g [Pa], E [Pa], h [m], ν [-]), the mass [kg] (or the wall
    density [kg/m³]). ``rest_shape="solve"``: the rest shape, inflated state and masses exactly
    as :func:`shelljax.dynamics.shell_system` (its JAX rest-shape solve: tens of seconds to
    compile); ``"small-strain"``: the scan shrunk about its centroid by 1 + P R (1 − ν)/(2 E h)
    (R = 3V/A: thin-sphere membrane strain), the scan itself the start (not exactly in equilibrium: call
    :meth:`relax`), no JAX."""
    from .. import dynamics as d

    if not isinstance(properties, ShellProperties):
        raise InvalidInputError(f"properties: expected a physics.ShellProperties; got {type(properties).__name__}.")
    for name in ("gauge_pressure", "young_modulus", "thickness", "poisson_ratio"):
        _check(
            f"properties.{name}", getattr(properties, name), positive=name not in ("gauge_pressure", "poisson_ratio")
        )
    if rest_shape not in ("solve", "small-strain"):
        raise InvalidInputError(f"rest_shape: expected 'solve' or 'small-strain'; got {rest_shape!r}.")
    if rest_shape == "small-strain":
        return _small_strain(
            cls,
            shell,
            properties,
            mass=mass,
            wall_density=wall_density,
            gas=gas,
            planes=planes,
            gravity=gravity,
            **options,
        )
    system = d.shell_system(
        shell, properties, gas=gas, mass=mass, wall_density=wall_density, planes=(), gravity=gravity
    )
    return cls.from_system(system, planes=tuple(planes), **options)


def _small_strain(cls, shell, properties, *, mass, wall_density, gas, planes, gravity, **options):
    scan = np.asarray(shell.mesh.vertices, dtype=float)
    faces = np.asarray(shell.mesh.faces)
    p, e, h, nu = (
        float(properties.gauge_pressure),
        float(properties.young_modulus),
        float(properties.thickness),
        float(properties.poisson_ratio),
    )
    volume = signed_volume(scan, faces)
    strain, _ = membrane_strain(scan, faces, properties)
    centroid = scan.mean(axis=0)
    rest = centroid + (scan - centroid) / (1.0 + strain)
    metric, curvature, rest_area = (np.asarray(v) for v in rest_geometry(jnp.asarray(rest[shell.mesh.stencil])))
    vertex_area = np.zeros(len(scan))
    np.add.at(vertex_area, faces, rest_area[:, None] / 3.0)
    if (mass is None) == (wall_density is None):
        raise InvalidInputError("mass: give either `mass` [kg] or `wall_density` [kg/m³] (exactly one).")
    masses = (
        _check("mass [kg]", mass) * vertex_area / vertex_area.sum()
        if mass is not None
        else _check("wall_density [kg/m³]", wall_density) * h * vertex_area
    )
    return cls(
        RestShape(shell.mesh.stencil, metric, curvature, rest_area, vertex_area),
        ShellProperties(gauge_pressure=p, young_modulus=e, thickness=h, poisson_ratio=nu),
        positions=scan,
        masses=masses,
        gas=gas,
        reference_volume=volume,
        planes=planes,
        options=RealtimeOptions.of({"gravity": gravity, **options}),
    )


def ball(
    cls,
    properties: ShellProperties,
    *,
    mass,
    n_faces=2000,
    gas=AdiabaticGas(),
    planes=(),
    gravity=STANDARD_GRAVITY,
    pole_refinement=1.0,
    **options,
) -> RealtimeShell:
    """A sphere of ``properties.radius`` R [m] remeshed with about ``n_faces`` faces (the rings
    layout of :func:`shelljax.geometry.sphere_mesh`, uniform unless ``pole_refinement`` > 1)."""
    from ..shell3d import Shell, ShellMesh

    if not isinstance(properties, ShellProperties):
        raise InvalidInputError(f"properties: expected a physics.ShellProperties; got {type(properties).__name__}.")
    radius = _check("properties.radius [m]", properties.radius)
    thickness = _check("properties.thickness [m]", properties.thickness)
    _check("mass [kg]", mass)
    n = int(_check("n_faces", n_faces))
    if n < 20:
        raise InvalidInputError(f"n_faces: need at least 20 faces; got {n_faces}.")
    shell = Shell(mesh=ShellMesh.sphere(radius, n, pole_refinement=pole_refinement), thickness=thickness)
    return cls.from_shell(shell, properties, mass=mass, gas=gas, planes=planes, gravity=gravity, **options)


def from_session(
    cls, session, properties: ShellProperties, *, n_faces=2000, gas=AdiabaticGas(), planes=(), mesh=None, **options
) -> RealtimeShell:
    """From a session (a path or a loaded ``Session``: its mass [kg], h [m], ν [-], radius R
    [m] or mesh) and the estimates ``properties`` (P_g [Pa], E [Pa]; its h, ν, R where given
    override the session's). ``mesh``: a mesh file to use instead of the session's (refined to
    ``n_faces`` when it has fewer, as :func:`shelljax.dynamics.remeshed`)."""
    from .. import dynamics as d
    from .. import shell3d as s3
    from ..session import load_session

    s = load_session(session) if isinstance(session, (str, Path)) else session
    if s.mass is None:
        raise InvalidInputError(f"{s.source}: field 'mass' is missing. Fix: add `mass = <kg>` to the session.")
    thickness = float(properties.thickness if properties.thickness is not None else s.thickness)
    nu = float(properties.poisson_ratio if properties.poisson_ratio is not None else s.poisson_ratio)
    full = ShellProperties(
        gauge_pressure=properties.gauge_pressure,
        young_modulus=properties.young_modulus,
        thickness=thickness,
        poisson_ratio=nu,
        radius=properties.radius if properties.radius is not None else s.radius,
    )
    mesh_path = mesh or getattr(s, "mesh_path", None)
    if mesh_path is None:
        return cls.ball(full, mass=s.mass, n_faces=n_faces, gas=gas, planes=planes, **options)
    shell = s3.load(mesh_path, thickness)
    if n_faces is not None and n_faces > shell.mesh.n_faces:
        shell = d.remeshed(shell, n_faces)
    return cls.from_shell(shell, full, mass=s.mass, gas=gas, planes=planes, **options)


def from_replica(
    cls, directory, *, planes=(), gravity=STANDARD_GRAVITY, rest_shape="solve", **options
) -> RealtimeShell:
    """From a ``shelljax replica`` output directory (``replica.json``: P_g [Pa], E [Pa], ν [-],
    h [m], mass [kg], gas law; ``replica.glb``: the inflated mesh [m]), as
    :func:`shelljax.replica.load_replica` reads it, with ``rest_shape`` as :meth:`from_shell`."""
    from .. import shell3d as s3
    from .._files import read_json

    directory = Path(directory)
    path = directory / "replica.json"
    if not path.is_file():
        raise InvalidInputError(f"{directory}: no replica.json. Fix: give a directory written by `shelljax replica`.")
    replica = read_json(path, "replica file", fix="export the replica again with `shelljax replica SESSION --out DIR`")
    if not isinstance(replica, dict):
        raise InvalidInputError(
            f"{path}: not a replica file (a JSON {type(replica).__name__}). Fix: export the "
            "replica again with `shelljax replica SESSION --out DIR`"
        )
    values = {}
    for name in ("gauge_pressure_Pa", "youngs_modulus_Pa", "poisson_ratio", "thickness_m", "mass_kg"):
        entry = replica.get(name)
        if not isinstance(entry, dict) or entry.get("value") is None:
            raise InvalidInputError(f"{path}: field '{name}.value' is missing. Fix: re-export the replica.")
        values[name] = float(entry["value"])
    if replica.get("gas") not in GAS_LAWS:
        raise InvalidInputError(f"{path}: field 'gas' must be one of {GAS_LAWS}; got {replica.get('gas')!r}.")
    shell = s3.load(directory / str(replica.get("mesh", "replica.glb")), values["thickness_m"])
    properties = ShellProperties(
        gauge_pressure=values["gauge_pressure_Pa"],
        young_modulus=values["youngs_modulus_Pa"],
        thickness=shell.thickness,
        poisson_ratio=values["poisson_ratio"],
    )
    return cls.from_shell(
        shell,
        properties,
        mass=values["mass_kg"],
        gas=gas_law(replica["gas"]),
        planes=planes,
        gravity=gravity,
        rest_shape=rest_shape,
        **options,
    )
