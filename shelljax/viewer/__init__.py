"""The viewer of the real-time runtime (``shelljax play``): interaction scripts, their headless
replay with per-frame records and a GIF, and the live 3D view in the browser (viser, optional:
``pip install "shelljax[viewer]"``). SI units. See docs/realtime.md ("Viewer").

Headless::

    from shelljax import viewer
    script = viewer.load_script("configs/interaction.toml")
    scene = viewer.load_scene("bundled:sessions/pezzi.toml", script)
    replay = viewer.replay(scene)            # raises realtime.BlowUpError if the runtime blows up
    viewer.write_gif(replay, "play.gif", hand_radius=script.hand.radius, gif_fps=script.gif_fps)
"""

from ._gif import write_gif
from ._hand import HandControl
from ._headless import Replay, replay
from ._play import DEFAULT_SCRIPT, check_replay_outputs, play_headless, play_live, play_scene
from ._scene import Scene, load_scene, resolve_source
from ._script import ACTION_KINDS, Action, Hand, InteractionScript, ScriptPlane, load_script

__all__ = [
    "ACTION_KINDS",
    "DEFAULT_SCRIPT",
    "Action",
    "check_replay_outputs",
    "Hand",
    "HandControl",
    "InteractionScript",
    "Replay",
    "Scene",
    "ScriptPlane",
    "load_scene",
    "load_script",
    "play_headless",
    "play_live",
    "play_scene",
    "replay",
    "require_viser",
    "resolve_source",
    "serve",
    "write_gif",
]


def require_viser():
    """The viser module, or a one-line error naming ``pip install "shelljax[viewer]"``."""
    from ._server import require_viser as check

    return check()


def serve(scene, *, host: str = "127.0.0.1", port: int = 8080, **options):
    """Start the live viewer of ``scene`` (a :class:`Scene`); returns the running ``ViewerApp``
    (needs viser: ``pip install "shelljax[viewer]"``)."""
    from ._server import ViewerApp

    return ViewerApp(scene, host=host, port=port, **options)
