"""The user's hand in the real-time runtime: a sphere collider that follows a target point at a
bounded speed (it pokes and pushes), or a hold that carries the shell's centre of mass along a
target path and releases it with the velocity it has (grab and throw). SI units."""

from __future__ import annotations

import numpy as np

from ..realtime import Collider, RealtimeShell
from ._script import Hand

#: Natural frequency ω [rad/s] of the critically damped hold: the centre of mass follows the hand
#: within ≈ 1/ω = 40 ms, and ω × frame (1/60 s) = 0.42 keeps the explicit update stable.
HOLD_OMEGA = 25.0
#: Largest acceleration [m/s²] a hold gives the centre of mass (≈ 6 g: a hard throw by hand); a
#: jump of the pointer would otherwise fling the shell into the ground faster than contact holds.
HOLD_MAX_ACCEL = 60.0


class HandControl:
    """Moves the hand between frames of ``ball`` (a :class:`RealtimeShell`).

    :meth:`move_toward` places the collider (a sphere of ``hand.radius`` [m]) where it is and gives
    it the velocity that reaches the target [m] in one frame, capped at ``hand.max_speed`` [m/s];
    :meth:`hold` removes the collider and pulls the centre of mass towards a target by a critically
    damped spring that also carries the weight (a velocity change spread uniformly over the
    vertices, like gravity: it moves the shell without denting it); :meth:`release` ends the hold,
    the shell keeping its velocity. ``position`` (3,) [m]: the hand's centre now."""

    def __init__(self, ball: RealtimeShell, hand: Hand):
        self.ball, self.hand = ball, hand
        self.position = np.array(hand.start, dtype=float)
        self.active = False
        self.holding = False

    def _touching_inside(self, position) -> bool:
        """True where the hand's centre is inside the shell (it slipped through or was placed there)."""
        com, _ = self.ball.com()
        reach = np.linalg.norm(self.ball.x - com, axis=1).min()
        return bool(np.linalg.norm(position - com) < reach)

    def move_toward(self, target, frame_dt: float) -> None:
        """The collider for the next frame of ``frame_dt`` [s]: at ``position``, moving towards ``target`` (3,) [m]."""
        target = np.asarray(target, dtype=float)
        self.holding = False
        step = target - self.position
        distance = float(np.linalg.norm(step))
        speed = min(distance / frame_dt, self.hand.max_speed)
        velocity = step / distance * speed if distance > 0.0 else np.zeros(3)
        if self._touching_inside(self.position):  # never switch a collider on inside the shell: it would blow it apart
            self.ball.set_collider(None)
            self.active = False
        else:
            self.ball.set_collider(
                Collider(
                    a=tuple(self.position),
                    radius=self.hand.radius,
                    velocity=tuple(velocity),
                    friction=self.hand.friction,
                )
            )
            self.active = True
        self.position = self.position + velocity * frame_dt

    def place(self, position) -> None:
        """Put the hand at ``position`` (3,) [m] at rest (the collider follows at the next :meth:`move_toward`)."""
        self.position = np.array(position, dtype=float)
        self.ball.set_collider(None)
        self.active = False

    def park(self) -> None:
        """Take the hand away from the shell: no collider, no hold."""
        self.ball.set_collider(None)
        self.active = self.holding = False

    def hold(self, target, target_velocity, frame_dt: float) -> None:
        """Pull the centre of mass towards ``target`` (3,) [m] moving at ``target_velocity`` (3,)
            [m/s] (at most ``hand.max_speed``) over the next frame of ``frame_dt`` [s], with at most
        ``HOLD_MAX_ACCEL`` [m/s²] and the weight carried; the hand is drawn there."""
        self.ball.set_collider(None)
        self.active, self.holding = False, True
        com, vcom = self.ball.com()
        target_velocity = np.asarray(target_velocity, dtype=float)
        speed = float(np.linalg.norm(target_velocity))
        if speed > self.hand.max_speed:
            target_velocity = target_velocity * (self.hand.max_speed / speed)
        accel = HOLD_OMEGA**2 * (np.asarray(target) - com) + 2.0 * HOLD_OMEGA * (target_velocity - vcom)
        size = float(np.linalg.norm(accel))
        if size > HOLD_MAX_ACCEL:
            accel *= HOLD_MAX_ACCEL / size
        dv = (accel - self.ball.body.gravity) * frame_dt
        self.ball.set_state(self.ball.x, self.ball.v + dv, time=self.ball.time)
        self.position = np.asarray(target, dtype=float) + np.asarray(target_velocity) * frame_dt

    def release(self) -> None:
        """End the hold: the shell flies on with its velocity; the hand stays where it is, off."""
        self.holding = False
        self.ball.set_collider(None)
        self.active = False
