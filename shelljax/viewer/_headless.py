"""The headless replay of an interaction script: the frames of a :class:`Scene` driven by its
script, recorded per frame (SI units), without a browser. A blow-up of the runtime is never
swallowed: :func:`replay` raises :class:`shelljax.realtime.BlowUpError`, naming the action under
way, with the frames recorded up to it attached (``error.replay``)."""

from __future__ import annotations

import dataclasses
import json
import time as _time
from pathlib import Path

import numpy as np

from .._files import atomic_write_text
from ..realtime import BlowUpError, Planes
from ._driver import ScriptDriver
from ._hand import HandControl
from ._scene import Scene


@dataclasses.dataclass
class Replay:
    """Per-frame records of a replay (N frames; P planes; K kept shapes).

    ``time_s`` (N,) [s] at each frame's end; ``gauge_pressure_Pa`` (N,); ``collider_force_N``
    (N, 3) the hand's force on the shell; ``plane_forces_N`` (N, P, 3); ``com_m`` (N, 3) and
    ``com_velocity_m_per_s`` (N, 3); ``real_time_factor`` (N,) [-] simulated / wall time of the
    frame; ``hand_m`` (N, 3) the hand's centre (NaN where it is off); ``holding`` (N,) bool;
    ``action`` (N,) what was under way; ``shapes_m`` (K, V, 3) the positions at frames
    ``shape_frames`` (K,) (for the GIF); ``faces`` (F, 3); ``plane_names``; ``planes`` (``realtime.Planes``: point [m], unit normal, μ,
    v_ε [m/s], c [N·s/m], barrier ĝ [m], κ [J/m²] per plane); ``blow_up``: the
    error's message, or None."""

    time_s: np.ndarray
    gauge_pressure_Pa: np.ndarray
    collider_force_N: np.ndarray
    plane_forces_N: np.ndarray
    com_m: np.ndarray
    com_velocity_m_per_s: np.ndarray
    real_time_factor: np.ndarray
    hand_m: np.ndarray
    holding: np.ndarray
    action: list
    shapes_m: np.ndarray
    shape_frames: np.ndarray
    faces: np.ndarray
    plane_names: tuple
    planes: Planes
    blow_up: str | None = None

    def summary(self) -> dict:
        """Peaks and medians of the replay (units in the keys)."""
        return {
            "frames": int(self.time_s.size),
            "simulated_s": float(self.time_s[-1]) if self.time_s.size else 0.0,
            "peak_gauge_pressure_Pa": float(self.gauge_pressure_Pa.max(initial=0.0)),
            "peak_collider_force_N": float(np.linalg.norm(self.collider_force_N, axis=-1).max(initial=0.0)),
            "peak_plane_force_N": {
                n: float(np.linalg.norm(self.plane_forces_N[:, i], axis=-1).max(initial=0.0))
                for i, n in enumerate(self.plane_names)
            },
            "real_time_factor_median": float(np.median(self.real_time_factor)) if self.time_s.size else 0.0,
            "real_time_factor_p01": float(np.percentile(self.real_time_factor, 1)) if self.time_s.size else 0.0,
            "blow_up": self.blow_up,
        }

    def write_json(self, path: str | Path) -> Path:
        """The per-frame records (not the shapes) and the summary as JSON, units in the keys."""
        body = {"summary": self.summary(), "plane_names": list(self.plane_names), "action": self.action}
        for name in (
            "time_s",
            "gauge_pressure_Pa",
            "collider_force_N",
            "plane_forces_N",
            "com_m",
            "com_velocity_m_per_s",
            "real_time_factor",
            "hand_m",
            "holding",
        ):
            body[name] = np.where(np.isnan(a := np.asarray(getattr(self, name), dtype=float)), None, a).tolist()
        return atomic_write_text(path, json.dumps(body, indent=1))


def replay(scene: Scene, *, shape_every: int | None = None, on_frame=None) -> Replay:
    """Replay ``scene.script`` from rest at t = 0; keep the shape every ``shape_every`` frames
    (default: at the script's ``gif_fps``); ``on_frame(index, frame)`` after each frame.
    Raises BlowUpError (with ``.replay``: the frames so far) if the runtime blows up."""
    script, ball = scene.script, scene.ball
    scene.reset()
    hand = HandControl(ball, script.hand)
    driver = ScriptDriver(scene, hand)
    dt = 1.0 / script.fps
    every = shape_every or max(1, round(script.fps / script.gif_fps))
    rows, shapes, shape_frames = [], [], []
    blow_up = None
    for k in range(script.n_frames):
        driver.before_frame(k * dt, dt)
        start = _time.perf_counter()
        try:
            frame = ball.frame(dt)
        except BlowUpError as err:
            blow_up = err
            break
        wall = _time.perf_counter() - start
        hand_at = hand.position if (hand.active or hand.holding) else np.full(3, np.nan)
        rows.append(
            (
                frame.time_s,
                frame.gauge_pressure_Pa,
                frame.collider_force_N,
                frame.plane_forces_N,
                frame.com_m,
                frame.com_velocity_m_per_s,
                dt / max(wall, 1e-9),
                hand_at,
                hand.holding,
                driver.label,
            )
        )
        if k % every == 0:
            shapes.append(ball.x.copy())
            shape_frames.append(k)
        if on_frame is not None:
            on_frame(k, frame)
    if blow_up is not None:  # the failing state, for the last picture
        shapes.append(ball.x.copy())
        shape_frames.append(len(rows))
    record = _collect(rows, shapes, shape_frames, ball, blow_up)
    if blow_up is not None:
        during = driver.label or (f"free motion after the {driver.last}" if driver.last else "free motion")
        message = f"{blow_up} (during the script's {during}; {script.source or script.name})"
        error = BlowUpError(message, reason=blow_up.reason, time_s=blow_up.time_s, dt_s=blow_up.dt_s)
        error.replay = record
        raise error from blow_up
    return record


def _collect(rows, shapes, shape_frames, ball, blow_up) -> Replay:
    n_planes = ball.contact.planes.count
    columns = list(zip(*rows)) if rows else [()] * 10
    as_array = lambda i, shape: np.array(columns[i], dtype=float).reshape(shape)
    n = len(rows)
    return Replay(
        time_s=as_array(0, (n,)),
        gauge_pressure_Pa=as_array(1, (n,)),
        collider_force_N=as_array(2, (n, 3)),
        plane_forces_N=as_array(3, (n, n_planes, 3)),
        com_m=as_array(4, (n, 3)),
        com_velocity_m_per_s=as_array(5, (n, 3)),
        real_time_factor=as_array(6, (n,)),
        hand_m=as_array(7, (n, 3)),
        holding=np.array(columns[8], dtype=bool),
        action=list(columns[9]),
        shapes_m=np.array(shapes).reshape(len(shapes), -1, 3),
        shape_frames=np.array(shape_frames, dtype=int),
        faces=ball.geometry.faces.copy(),
        plane_names=tuple(ball.plane_names),
        planes=ball.contact.planes,
        blow_up=None if blow_up is None else str(blow_up),
    )
