"""What ``shelljax play`` does: the scene from a replica or session and an optional script, then
either the headless replay (records, GIF) or the live viewer until Ctrl+C (SI units)."""

from __future__ import annotations

import dataclasses
import time as _time
from pathlib import Path

from .._errors import InvalidInputError
from .._files import check_output_file
from ..physics import AbstractGasLaw, AdiabaticGas
from ..realtime import BlowUpError
from ._gif import write_gif
from ._headless import Replay, replay
from ._scene import Scene, load_scene
from ._script import InteractionScript, load_script

#: The live viewer's script when none is given: the ground only, no actions, 10 s for "play script".
DEFAULT_SCRIPT = InteractionScript(duration=10.0)


def play_scene(
    source, script_path=None, *, mesh_faces: int | None = None, gas: AbstractGasLaw = AdiabaticGas()
) -> Scene:
    """The :class:`Scene` of ``source`` (a replica directory or session) with the script at
    ``script_path`` (None: :data:`DEFAULT_SCRIPT`), meshed with ``mesh_faces`` where given."""
    script = DEFAULT_SCRIPT if script_path is None else load_script(script_path)
    if mesh_faces is not None:
        if mesh_faces < 20:
            raise InvalidInputError(
                f"--mesh-faces {mesh_faces}: need at least 20 triangles. Fix: e.g. --mesh-faces 500"
            )
        script = dataclasses.replace(script, mesh_faces=int(mesh_faces))
    return load_scene(source, script, gas=gas)


def check_replay_outputs(record: str | Path | None, records_json: str | Path | None) -> None:
    """Refuse, before a replay is simulated, a GIF path (``--record``) or records path
    (``--records``) that cannot be written; creates nothing."""
    if record is not None:
        check_output_file(record, "--record", example="play.gif")
        if Path(record).suffix.lower() != ".gif":
            raise InvalidInputError(
                f"--record {record}: the replay is written as a GIF. Fix: name a .gif file, e.g. "
                f"--record {Path(record).with_suffix('.gif')}"
            )
    if records_json is not None:
        check_output_file(records_json, "--records", example="records.json")


def play_headless(
    scene: Scene, *, record: str | Path | None = None, records_json: str | Path | None = None, dpi: int = 72
) -> Replay:
    """Replay the scene's script; write the GIF to ``record`` and the per-frame records to
    ``records_json`` where given (both checked before the replay, their folders created after it).
    A blow-up still writes both (up to the failing frame, the GIF's last frame marked) and is then
    raised."""
    check_replay_outputs(record, records_json)
    script = scene.script
    if not script.actions:
        raise InvalidInputError(
            f"{script.source or 'the script'}: field 'actions': none to replay. Fix: add [[actions]] "
            "tables (drop, poke, throw, wait; docs/realtime.md#viewer)"
        )
    try:
        result = replay(scene)
    except BlowUpError as err:
        _write(err.replay, scene, record, records_json, dpi)
        raise
    _write(result, scene, record, records_json, dpi)
    return result


def _write(result: Replay, scene: Scene, record, records_json, dpi: int) -> None:
    for path in (record, records_json):
        if path is not None:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
    if record is not None and len(result.shape_frames):
        write_gif(result, record, hand_radius=scene.script.hand.radius, gif_fps=scene.script.gif_fps, dpi=dpi)
    if records_json is not None:
        result.write_json(records_json)


def play_live(scene: Scene, *, host: str = "127.0.0.1", port: int = 8080, announce=print) -> int:
    """Serve the live viewer until Ctrl+C; returns 0."""
    from ._server import ViewerApp, require_viser

    require_viser()
    app = ViewerApp(scene, host=host, port=port)
    announce(f"shelljax play: {scene.label}; open http://{host}:{app.port} in a browser (Ctrl+C stops)")
    try:
        while True:
            _time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        app.stop()
    return 0
