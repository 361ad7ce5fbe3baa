"""The interaction script (TOML) of ``shelljax play``: a scene (planes, the hand, frame rates,
mesh size) and a list of timed actions (drop, poke, throw, wait), validated into plain frozen
dataclasses (SI units). Every check fails with one line naming the file, the field and the fix
(:class:`shelljax._toml.TomlReader`). The format is documented in docs/realtime.md ("Viewer")."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from .._toml import TomlReader, read_toml

_DOC = "docs/realtime.md#viewer"
_TOP_KEYS = {"name", "description", "duration_s", "fps", "gif_fps", "mesh_faces", "hand", "planes", "actions"}
_HAND_KEYS = {"radius_m", "friction", "start_m", "max_speed_m_per_s"}
_PLANE_KEYS = {"name", "point_m", "normal", "friction", "damping_N_s_per_m"}
_ACTION_KEYS = {
    "drop": {"at_s", "kind", "height_m", "velocity_m_per_s", "centre_xy_m"},
    "poke": {"at_s", "kind", "direction", "depth_m", "duration_s"},
    "throw": {"at_s", "kind", "velocity_m_per_s", "hold_s"},
    "wait": {"at_s", "kind", "duration_s"},
}
ACTION_KINDS = tuple(_ACTION_KEYS)


@dataclasses.dataclass(frozen=True)
class ScriptPlane:
    """A rigid plane through ``point`` (3,) [m] with unit ``normal`` (3,) to the free side, Coulomb
    friction μ ``friction`` [-] and the centre-of-mass dashpot ``damping`` c [N·s/m] (as the
    realtime runtime reads ``physics.Plane``)."""

    name: str
    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    friction: float
    damping: float


@dataclasses.dataclass(frozen=True)
class Hand:
    """The user's hand: a sphere collider of ``radius`` [m] with friction μ ``friction`` [-],
    parked at ``start`` (3,) [m], moving at most ``max_speed`` [m/s] (a faster pointer is followed
    at that speed: the contact springs stay within the stable Δt)."""

    radius: float = 0.03
    friction: float = 0.5
    start: tuple[float, float, float] = (0.4, 0.0, 0.4)
    max_speed: float = 3.0


@dataclasses.dataclass(frozen=True)
class Action:
    """One timed action starting at ``at`` [s].

    ``kind``: ``"drop"`` (the relaxed shell placed with its lowest point ``height`` [m] above the
    first plane, moving at ``velocity`` (3,) [m/s], centred at ``centre_xy`` (2,) [m] or where it
    is); ``"poke"`` (the hand pressed along the unit ``direction`` (3,) at the centre of mass,
    from touching the surface to ``depth`` [m] inside it and back out, over ``duration`` [s]);
    ``"throw"`` (the hand grabs the centre of mass, accelerates it uniformly to ``velocity`` (3,)
    [m/s] over ``duration`` [s], the hold, and releases it); ``"wait"`` (nothing for ``duration``).
    """

    kind: str
    at: float
    duration: float = 0.0
    height: float = 0.0
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    centre_xy: tuple[float, float] | None = None
    direction: tuple[float, float, float] = (0.0, 0.0, -1.0)
    depth: float = 0.0

    @property
    def end(self) -> float:
        """When it ends [s]."""
        return self.at + self.duration


@dataclasses.dataclass(frozen=True)
class InteractionScript:
    """A validated interaction script: ``duration`` [s] of simulation in frames of 1/``fps`` [s]
    (``RealtimeShell.frame``), a GIF at ``gif_fps`` [1/s], the shell meshed with ``mesh_faces``
    triangles (sessions; a replica keeps its mesh), the ``planes`` (the first is the ground that
    drops fall onto), the ``hand`` and the ``actions`` in time order. ``source``: the file."""

    duration: float
    fps: float = 60.0
    gif_fps: float = 15.0
    mesh_faces: int = 500
    planes: tuple[ScriptPlane, ...] = (ScriptPlane("ground", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 0.5, 5.0),)
    hand: Hand = Hand()
    actions: tuple[Action, ...] = ()
    name: str = "interaction"
    source: Path | None = None

    @property
    def n_frames(self) -> int:
        """Frames of the replay: round(duration × fps)."""
        return max(1, round(self.duration * self.fps))

    def active(self, time: float) -> Action | None:
        """The action under way at ``time`` [s] (a drop is instantaneous: never under way)."""
        for action in self.actions:
            if action.kind != "drop" and action.at <= time < action.end:
                return action
        return None


def _plane(r: TomlReader, i: int, table) -> ScriptPlane:
    prefix = r.entry(table, "planes", i, _PLANE_KEYS)
    normal = r.direction(table, "normal", prefix, fix="give the normal pointing to the free side, e.g. [0, 0, 1]")
    name = table.get("name", f"plane{i}")
    if not isinstance(name, str):
        raise r.fail(prefix + "name", "expected a string", 'write e.g. name = "ground"', value=name)
    return ScriptPlane(
        name=name,
        point=r.vector(table, "point_m", prefix, 3),
        normal=tuple(np.asarray(normal) / np.linalg.norm(normal)),
        friction=r.number(table, "friction", prefix, default=0.5, nonnegative=True),
        damping=r.number(table, "damping_N_s_per_m", prefix, default=5.0, nonnegative=True),
    )


def _hand(r: TomlReader, data: dict) -> Hand:
    table = r.table(data, "hand", _HAND_KEYS)
    if table is None:
        return Hand()
    p = "hand."
    default = Hand()
    return Hand(
        radius=r.number(
            table,
            "radius_m",
            p,
            default=default.radius,
            positive=True,
            fix="write the finger's or hand's radius in m, e.g. radius_m = 0.03",
        ),
        friction=r.number(table, "friction", p, default=default.friction, nonnegative=True),
        start=r.vector(table, "start_m", p, 3, default=list(default.start)),
        max_speed=r.number(table, "max_speed_m_per_s", p, default=default.max_speed, positive=True),
    )


def _unit(r: TomlReader, table: dict, key: str, prefix: str) -> tuple[float, float, float]:
    value = np.asarray(
        r.direction(
            table, key, prefix, fix="give the direction the hand moves in, e.g. [0, 0, -1]", default=[0.0, 0.0, -1.0]
        )
    )
    return tuple(float(c) for c in value / np.linalg.norm(value))


def _action(r: TomlReader, i: int, table) -> Action:
    prefix = f"actions[{i}]."
    if not isinstance(table, dict):
        raise r.fail(f"actions[{i}]", "expected a table", "write it as [[actions]]", value=table)
    kind = r.choice(table, "kind", prefix, ACTION_KINDS, what="action kind")
    r.no_unknown_keys(table, _ACTION_KEYS[kind], prefix)
    at = r.number(table, "at_s", prefix, nonnegative=True, fix="write the start time in s, e.g. at_s = 0.5")
    if kind == "drop":
        xy = table.get("centre_xy_m")
        return Action(
            kind,
            at,
            height=r.number(table, "height_m", prefix, nonnegative=True, fix="write e.g. height_m = 0.3"),
            velocity=r.vector(table, "velocity_m_per_s", prefix, 3, default=[0.0, 0.0, 0.0]),
            centre_xy=None if xy is None else r.vector(table, "centre_xy_m", prefix, 2),
        )
    if kind == "poke":
        return Action(
            kind,
            at,
            duration=r.number(table, "duration_s", prefix, positive=True, fix="write e.g. duration_s = 0.6"),
            direction=_unit(r, table, "direction", prefix),
            depth=r.number(table, "depth_m", prefix, positive=True, fix="write how far in, e.g. depth_m = 0.03"),
        )
    if kind == "throw":
        return Action(
            kind,
            at,
            duration=r.number(table, "hold_s", prefix, positive=True, fix="write the wind-up in s, e.g. hold_s = 0.3"),
            velocity=r.vector(table, "velocity_m_per_s", prefix, 3),
        )
    return Action(
        kind, at, duration=r.number(table, "duration_s", prefix, positive=True, fix="write e.g. duration_s = 0.5")
    )


def _check_timeline(r: TomlReader, actions: list[Action], duration: float) -> None:
    """Actions in time order, each starting after the previous one ends and before the end."""
    for i, action in enumerate(actions):
        if action.at >= duration:
            raise r.fail(
                f"actions[{i}].at_s",
                f"starts at or after the end of the script ({duration:g} s)",
                f"start it before {duration:g} s or raise duration_s",
                value=action.at,
            )
        if i and action.at < actions[i - 1].end - 1e-12:
            raise r.fail(
                f"actions[{i}].at_s",
                f"starts before actions[{i - 1}] ({actions[i - 1].kind}) ends at {actions[i - 1].end:g} s",
                f"set at_s >= {actions[i - 1].end:g} (actions run one after another, in time order)",
                value=action.at,
            )


def load_script(path: str | Path) -> InteractionScript:
    """The validated :class:`InteractionScript` of the TOML file at ``path``; raises
    ``InvalidInputError`` with one line naming the file, the field and the fix."""
    data = read_toml(
        path, "interaction script", fix_missing="give the path of an interaction TOML, e.g. configs/interaction.toml"
    )
    r = TomlReader(path, doc=_DOC)
    r.no_unknown_keys(data, _TOP_KEYS)
    duration = r.number(data, "duration_s", positive=True, fix="write the replay's length in s, e.g. duration_s = 4.0")
    fps = r.number(data, "fps", default=60.0, positive=True)
    if not 10.0 <= fps <= 1000.0:
        raise r.fail("fps", "frames per second must be within 10 … 1000", "write e.g. fps = 60", value=fps)
    gif_fps = r.number(data, "gif_fps", default=15.0, positive=True)
    if gif_fps > fps:
        raise r.fail(
            "gif_fps",
            f"the GIF cannot have more frames per second than the simulation (fps = {fps:g})",
            f"write gif_fps <= {fps:g}",
            value=gif_fps,
        )
    planes = data.get("planes", [{"name": "ground", "point_m": [0.0, 0.0, 0.0], "normal": [0.0, 0.0, 1.0]}])
    if not isinstance(planes, list) or not planes:
        raise r.fail(
            "planes", "no plane (the first is the ground that drops fall onto)", "add a [[planes]] table", value=planes
        )
    actions = data.get("actions", [])
    if not isinstance(actions, list):
        raise r.fail("actions", "expected an array of tables", "write each action as [[actions]]", value=actions)
    parsed = [_action(r, i, a) for i, a in enumerate(actions)]
    _check_timeline(r, parsed, duration)
    name = data.get("name", Path(path).stem)
    return InteractionScript(
        duration=duration,
        fps=fps,
        gif_fps=gif_fps,
        mesh_faces=r.integer(data, "mesh_faces", default=500, minimum=20),
        planes=tuple(_plane(r, i, p) for i, p in enumerate(planes)),
        hand=_hand(r, data),
        actions=tuple(parsed),
        name=str(name),
        source=Path(path),
    )
