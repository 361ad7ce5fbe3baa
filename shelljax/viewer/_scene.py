"""The object ``shelljax play`` moves: a :class:`shelljax.realtime.RealtimeShell` built from a
replica directory or a session, with the script's planes, settled at rest on the ground (SI
units). The rest shape is the small-strain shrink of the scan, then relaxed (no JAX rest-shape
solve to compile: the viewer starts in seconds)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from .._errors import InvalidInputError
from ..physics import AbstractGasLaw, AdiabaticGas
from ..realtime import RealtimeShell
from ._script import InteractionScript

#: Simulated time [s] of the damped settling on the ground before the first frame.
RELAX_S = 0.3


@dataclasses.dataclass
class Scene:
    """A shell ready to play: ``ball`` (at rest on the first plane), its ``rest_positions`` (V, 3)
    [m] (what a drop starts from), the ``script`` (planes, hand, actions) and a ``label`` of where
    it came from (with its P_g [Pa] and E [Pa])."""

    ball: RealtimeShell
    rest_positions: np.ndarray
    script: InteractionScript
    label: str

    @classmethod
    def settle(cls, ball: RealtimeShell, script: InteractionScript, label: str = "shell") -> Scene:
        """Give ``ball`` the script's planes, put it on the first one and relax it there (``RELAX_S``)."""
        ball.set_planes(script.planes)
        ball.set_collider(None)
        ball.drop(0.0)
        ball.relax(RELAX_S)
        return cls(ball, ball.x.copy(), script, label)

    def reset(self) -> None:
        """Back to rest on the ground at t = 0, no collider."""
        self.ball.set_collider(None)
        self.ball.set_state(self.rest_positions, time=0.0)

    def drop(self, height: float, velocity=(0.0, 0.0, 0.0), centre_xy=None) -> None:
        """The rest shape with its lowest point ``height`` [m] above the ground, moving at ``velocity`` [m/s]."""
        time = self.ball.time
        self.ball.set_state(self.rest_positions, time=time)
        self.ball.drop(height, velocity=velocity, centre_xy=centre_xy)
        self.ball.time = time


def _session_properties(session):
    """P_g [Pa] and E [Pa] of a session by the paper's closed form (Procedures 2-3; seconds), as
    ``shelljax replica`` obtains estimates (``object_estimate.estimated_parameters``)."""
    from ..object_estimate import estimated_parameters
    from ..physics import ShellProperties

    p_g, e, _ = estimated_parameters(session, "closed-form", {})
    return ShellProperties(
        gauge_pressure=p_g, young_modulus=e, thickness=session.thickness, poisson_ratio=session.poisson_ratio
    )


def resolve_source(source: str | Path) -> Path:
    """The path of a replica directory or a session file (``bundled:sessions/pezzi.toml`` for a bundled one)."""
    from ..config import bundled_data_dir

    text = str(source)
    path = bundled_data_dir() / text.removeprefix("bundled:") if text.startswith("bundled:") else Path(text)
    if path.is_dir() and (path / "replica.json").is_file():
        return path
    if path.is_file() and path.suffix == ".toml":
        return path
    raise InvalidInputError(
        f"{source}: neither a replica directory (with replica.json) nor a session TOML file. "
        "Fix: give a directory written by `shelljax replica`, a session such as "
        "bundled:sessions/pezzi.toml, or its path"
    )


def load_scene(source: str | Path, script: InteractionScript, *, gas: AbstractGasLaw = AdiabaticGas()) -> Scene:
    """The :class:`Scene` of a replica directory (its P_g, E, ν, h, mass, gas and mesh as saved)
    or a session file (its mass, h, ν and radius or mesh, meshed with ``script.mesh_faces``
    triangles; P_g and E estimated by the closed form; ``gas`` the sealed gas law)."""
    from ..session import load_session

    path = resolve_source(source)
    if path.is_dir():
        ball = RealtimeShell.from_replica(path, rest_shape="small-strain")
        label = f"replica {path.name}"
    else:
        session = load_session(path)
        properties = _session_properties(session)
        ball = RealtimeShell.from_session(
            session, properties, n_faces=script.mesh_faces, gas=gas, rest_shape="small-strain"
        )
        label = f"{session.object_name} (closed-form estimate)"
    p = ball.properties
    label += f": P_g {p.gauge_pressure:.0f} Pa, E {p.young_modulus / 1e6:.3g} MPa, {ball.geometry.faces.shape[0]} faces"
    return Scene.settle(ball, script, label)
