"""The live viewer (viser): the shell's mesh updated every frame in the browser, the planes, and
the hand as an orange sphere that follows a transform gizmo. In "poke" mode the hand is a collider
that pushes the shell; in "grab" mode, dragging the gizmo near the shell holds it (the centre of
mass follows the pointer) and letting go throws it with the velocity it has. The GUI shows the
real-time factor, time [s], gauge pressure [Pa] and contact forces [N], with buttons to drop,
reset, pause and play the script. The simulation runs in a thread at real time in frames of
1/fps [s] (``RealtimeShell.frame``); a blow-up (``realtime.BlowUpError``) pauses it and is shown
with its message, never passed on as a state."""

from __future__ import annotations

import threading
import time as _time

import numpy as np

from .._errors import InvalidInputError
from ..realtime import BlowUpError
from ._driver import ScriptDriver
from ._hand import HandControl
from ._scene import Scene

SHELL_RGB = (90, 160, 230)
BLOWN_RGB = (220, 40, 40)
HAND_RGB = (255, 140, 25)


def require_viser():
    """The viser module; a one-line ``InvalidInputError`` naming the fix where it is not installed."""
    try:
        import viser
    except ImportError:
        raise InvalidInputError(
            'the live viewer needs viser, which is not installed. Fix: pip install "shelljax[viewer]" '
            "(or run with --headless)"
        ) from None
    return viser


def _plane_quad(point, normal, half: float) -> tuple[np.ndarray, np.ndarray]:
    """A square (4, 3) [m] of half-width ``half`` [m] on the plane, and its two triangles."""
    normal = np.asarray(normal, dtype=float)
    helper = np.eye(3)[np.argmin(np.abs(normal))]
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    corners = np.array([np.asarray(point) + half * (a * u + b * v) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    return corners.astype(np.float32), np.array([[0, 1, 2], [0, 2, 3]], dtype=np.uint32)


class ViewerApp:
    """A viser server showing ``scene`` on ``host``:``port`` with the simulation thread running
    (``start_paused``: wait for the Pause/Resume button). ``fps`` [1/s]: frame rate (default the
    script's). ``state()`` gives the latest readouts; :meth:`command` runs a button's action;
    :meth:`move_pointer` moves the gizmo as a drag does; ``mode`` (the hand dropdown, "poke" or
    "grab"), ``height`` (the drop-height slider [m]) and ``status`` (the status line) are the GUI
    handles; :meth:`stop` ends the thread and the server."""

    def __init__(
        self,
        scene: Scene,
        *,
        host: str = "127.0.0.1",
        port: int = 8080,
        fps: float | None = None,
        start_paused: bool = False,
    ):
        viser = require_viser()
        self.scene, self.ball = scene, scene.ball
        self.frame_dt = 1.0 / (fps or scene.script.fps)
        self.hand = HandControl(self.ball, scene.script.hand)
        self.driver: ScriptDriver | None = None
        self.paused, self.error = start_paused, None
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self._grab_offset = None
        self._dragging = False
        self._pointer = np.array(scene.script.hand.start, dtype=float)
        self._pointer_before = self._pointer.copy()
        self._pointer_velocity = np.zeros(3)
        self.readouts = {
            "time_s": 0.0,
            "real_time_factor": 0.0,
            "gauge_pressure_Pa": self.ball.properties.gauge_pressure,
            "hand_force_N": 0.0,
            "plane_forces_N": [0.0] * len(scene.script.planes),
            "frames": 0,
        }
        self.server = viser.ViserServer(host=host, port=port, label="shelljax play", verbose=False)
        self._build_scene()
        self._build_gui()
        self._thread = threading.Thread(target=self._loop, name="shelljax-play", daemon=True)
        self._thread.start()

    @property
    def port(self) -> int:
        """The port the server listens on."""
        return self.server.get_port()

    # ------------------------------------------------------------------ scene and GUI
    def _build_scene(self) -> None:
        s = self.server.scene
        s.set_up_direction("+z")
        com, _ = self.ball.com()
        size = float(np.ptp(self.ball.x, axis=0).max())
        for i, plane in enumerate(self.scene.script.planes):
            foot = com - ((com - np.asarray(plane.point)) @ np.asarray(plane.normal)) * np.asarray(
                plane.normal
            )  # under the shell
            corners, tris = _plane_quad(foot, plane.normal, 4.0 * size + 0.5)
            s.add_mesh_simple(
                f"/planes/{plane.name or i}",
                corners,
                tris,
                color=(170, 170, 170),
                opacity=0.45,
                side="double",
                cast_shadow=False,
            )
        self.mesh = s.add_mesh_simple(
            "/shell",
            self.ball.x.astype(np.float32),
            self.ball.geometry.faces.astype(np.uint32),
            color=SHELL_RGB,
            flat_shading=False,
        )
        self.gizmo = s.add_transform_controls(
            "/pointer", scale=0.25, disable_rotations=True, position=tuple(self._pointer)
        )
        self.hand_sphere = s.add_icosphere(
            "/hand", radius=self.scene.script.hand.radius, color=HAND_RGB, subdivisions=2, position=tuple(self._pointer)
        )
        self.gizmo.on_update(self._on_pointer)
        self.server.initial_camera.position = tuple(com + np.array([1.2, -1.6, 0.9]) * max(size, 0.2) * 1.8)
        self.server.initial_camera.look_at = tuple(com)

    def _build_gui(self) -> None:
        g = self.server.gui
        g.add_markdown(f"**{self.scene.label}**")
        self.status = g.add_markdown("running")
        self.time_s = g.add_number("time [s]", 0.0, step=0.001, disabled=True)
        self.rt_factor = g.add_number(
            "real-time factor [-]",
            0.0,
            step=0.01,
            disabled=True,
            hint="simulated time / compute time of the last frame (≥ 1: keeps up with real time)",
        )
        self.pressure = g.add_number(
            "gauge pressure [Pa]", float(self.ball.properties.gauge_pressure), step=0.1, disabled=True
        )
        self.hand_force = g.add_number("hand force [N]", 0.0, step=0.01, disabled=True)
        self.plane_forces = [
            g.add_number(f"{p.name} force [N]", 0.0, step=0.01, disabled=True) for p in self.scene.script.planes
        ]
        self.mode = g.add_dropdown(
            "hand",
            ("poke", "grab"),
            initial_value="poke",
            hint="poke: the sphere pushes the shell; grab: drag the gizmo onto the shell to hold it, move, let go to throw",
        )
        self.height = g.add_slider("drop height [m]", min=0.0, max=1.5, step=0.05, initial_value=0.3)
        g.add_button("Drop").on_click(lambda _: self.command("drop"))
        g.add_button("Reset").on_click(lambda _: self.command("reset"))
        self.pause_button = g.add_button("Pause / resume")
        self.pause_button.on_click(lambda _: self.command("pause"))
        g.add_button("Play script").on_click(lambda _: self.command("script"))

    # ------------------------------------------------------------------ input
    def _on_pointer(self, event) -> None:
        """The gizmo moved (phase "start", "update" or "end" of a drag): the pointer [m]; a grab ends with the drag."""
        with self.lock:
            self._pointer = np.asarray(event.target.position, dtype=float)
            phase = getattr(event, "phase", "update")
            self._dragging = phase != "end"
            if phase == "end" and self._grab_offset is not None:
                self._grab_offset = None
                self.hand.release()

    def _maybe_grab(self) -> None:
        """In grab mode, a drag that brings the hand within reach of the shell takes hold of it."""
        if self.mode.value != "grab" or not self._dragging or self._grab_offset is not None:
            return
        com, _ = self.ball.com()
        reach = 0.5 * float(np.ptp(self.ball.x, axis=0).max()) + self.scene.script.hand.radius
        if np.linalg.norm(self._pointer - com) <= reach:
            self._grab_offset = self._pointer - com
            self._pointer_velocity = np.zeros(3)  # the reach itself is not a throw

    def move_pointer(self, position) -> None:
        """Move the pointer (the gizmo) to ``position`` (3,) [m], as a drag in the browser does."""
        with self.lock:
            self._pointer = np.array(position, dtype=float).reshape(3)
        self.gizmo.position = tuple(float(c) for c in self._pointer)

    def command(self, name: str) -> None:
        """Run a GUI command: "drop", "reset", "pause" (toggle) or "script" (replay the script from t = 0)."""
        with self.lock:
            if name == "pause":
                self.paused = not self.paused if self.error is None else True
                if self.error is None:
                    self.status.content = "paused" if self.paused else "running"
                return
            self.error = None
            self.mesh.color = SHELL_RGB
            self.driver = None
            self._grab_offset = None
            self.hand.park()
            if name == "drop":
                self.scene.drop(float(self.height.value))
            elif name == "reset":
                self.scene.reset()
            elif name == "script":
                self.scene.reset()
                self.driver = ScriptDriver(self.scene, self.hand)
            else:
                raise InvalidInputError(f"command {name!r}: unknown. Fix: use drop, reset, pause or script")
            self.paused = False

    # ------------------------------------------------------------------ simulation
    def _steer_hand(self) -> None:
        """The hand for the next frame: the script's, or the user's pointer (poke or hold)."""
        dt = self.frame_dt
        if self.driver is not None:
            self.driver.before_frame(self.ball.time, dt)
            if self.ball.time >= self.scene.script.duration:
                self.driver = None
                self.hand.place(self._pointer)  # back to the pointer at once, not through the shell
            return
        # the browser's pointer updates come unevenly: smooth the velocity a hold gives the shell
        self._pointer_velocity = 0.6 * self._pointer_velocity + 0.4 * (self._pointer - self._pointer_before) / dt
        self._pointer_before = self._pointer.copy()
        velocity = self._pointer_velocity
        self._maybe_grab()
        if self._grab_offset is not None:
            self.hand.hold(self._pointer - self._grab_offset, velocity, dt)
        elif self.mode.value == "grab":  # reaching for the shell: the hand passes through, pushing nothing
            self.hand.place(self._pointer)
        else:
            self.hand.move_toward(self._pointer, dt)

    def step(self) -> None:
        """One frame: steer the hand, advance the shell, publish the mesh and the readouts. A
        blow-up pauses the simulation and is shown (red shell, its message in the status)."""
        with self.lock:
            if self.paused:
                return
            self._steer_hand()
            try:
                frame = self.ball.frame(self.frame_dt)
            except BlowUpError as err:
                self.error, self.paused = str(err), True
                self.status.content = f"**Blow-up ({err.reason}) — paused.** {err} Press Reset or Drop."
                self.mesh.color = BLOWN_RGB
                return
            x = self.ball.x.astype(np.float32)
            self.readouts = {
                "time_s": frame.time_s,
                "real_time_factor": self.frame_dt / max(frame.wall_s, 1e-9),
                "gauge_pressure_Pa": frame.gauge_pressure_Pa,
                "hand_force_N": float(np.linalg.norm(frame.collider_force_N)),
                "plane_forces_N": [float(np.linalg.norm(f)) for f in frame.plane_forces_N],
                "frames": self.readouts["frames"] + 1,
            }
            hand_at = self.hand.position.copy()
        self._publish(x, hand_at)

    def _publish(self, x: np.ndarray, hand_at: np.ndarray) -> None:
        r = self.readouts
        with self.server.atomic():
            self.mesh.vertices = x
            self.hand_sphere.position = tuple(float(c) for c in hand_at)
            self.time_s.value = round(r["time_s"], 3)
            self.rt_factor.value = round(r["real_time_factor"], 2)
            self.pressure.value = round(r["gauge_pressure_Pa"], 1)
            self.hand_force.value = round(r["hand_force_N"], 2)
            for handle, force in zip(self.plane_forces, r["plane_forces_N"]):
                handle.value = round(force, 2)
            what = "script" if self.driver is not None else ("holding" if self.hand.holding else self.mode.value)
            if self.status.content != f"running ({what})":
                self.status.content = f"running ({what})"

    def _loop(self) -> None:
        """Frames at real time: sleep to each frame's wall-clock slot; a late frame is not caught up."""
        next_at = _time.perf_counter()
        while not self._stop.is_set():
            if self.paused:
                _time.sleep(0.05)
                next_at = _time.perf_counter()
                continue
            self.step()
            next_at += self.frame_dt
            wait = next_at - _time.perf_counter()
            if wait > 0:
                self._stop.wait(wait)
            else:
                next_at = _time.perf_counter()

    def state(self) -> dict:
        """The latest readouts (time [s], real-time factor [-], gauge pressure [Pa], forces [N]) and the status."""
        return {**self.readouts, "paused": self.paused, "error": self.error}

    def stop(self) -> None:
        """End the simulation thread and the server."""
        self._stop.set()
        self._thread.join(timeout=5.0)
        self.server.stop()
