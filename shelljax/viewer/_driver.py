"""The script's actions over time: before each frame, what the hand does (poke: move the collider
along its path; throw: hold the centre of mass on its wind-up path, then release) and when a drop
resets the shell. The headless replay and the live viewer's "play script" use the same driver."""

from __future__ import annotations

import numpy as np

from ._hand import HandControl
from ._scene import Scene
from ._script import Action


class ScriptDriver:
    """Runs ``scene.script``'s actions on ``scene.ball`` through ``hand``; call :meth:`before_frame`
    with the time [s] of each frame's start and the frame length [s]. ``label`` names what is under
    way ("drop 0.3 m", "poke", "throw", "wait", "" between actions); ``last`` the latest action begun
    and when ("drop 0.3 m at 0 s"; "" before the first)."""

    def __init__(self, scene: Scene, hand: HandControl):
        self.scene, self.hand = scene, hand
        self.done: set[int] = set()
        self.label = ""
        self.last = ""
        self._start: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def before_frame(self, time: float, frame_dt: float) -> None:
        """Set up the frame from ``time`` to ``time + frame_dt`` [s]."""
        eps = 1e-9
        self.label = ""
        was_busy = self.hand.active or self.hand.holding
        busy = False
        for i, action in enumerate(self.scene.script.actions):
            if action.kind == "drop":
                if i not in self.done and action.at <= time + eps:
                    self.done.add(i)
                    self.hand.park()
                    self.scene.drop(action.height, action.velocity, action.centre_xy)
                    self.label = f"drop {action.height:g} m"
                    self.last = f"{self.label} at {action.at:g} s"
                continue
            if action.at <= time + eps < action.end:
                self.label = action.kind
                self.last = f"{action.kind} at {action.at:g} s"
                busy = True
                self._act(i, action, time, frame_dt)
        if was_busy and not busy:
            self.hand.release() if self.hand.holding else self.hand.park()

    def _act(self, i: int, action: Action, time: float, frame_dt: float) -> None:
        ball = self.scene.ball
        if i not in self._start:  # the path is fixed where the action starts: at the centre of mass then
            com, _ = ball.com()
            direction = np.asarray(action.direction)
            surface = float(((ball.x - com) @ -direction).max())
            self._start[i] = (com, com - direction * (surface + self.hand.hand.radius))
            if action.kind == "poke":
                self.hand.place(self._start[i][1])
        com0, touch = self._start[i]
        tau = min(time + frame_dt - action.at, action.duration)  # where the hand is at the frame's end
        if action.kind == "poke":
            travel = action.depth * (1.0 - abs(2.0 * tau / action.duration - 1.0))  # in, then out, at constant speed
            self.hand.move_toward(touch + travel * np.asarray(action.direction), frame_dt)
        elif action.kind == "throw":
            velocity = np.asarray(action.velocity)
            target = com0 + 0.5 * velocity * tau**2 / action.duration  # uniform acceleration to the release velocity
            self.hand.hold(target, velocity * tau / action.duration, frame_dt)
