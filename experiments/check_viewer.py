"""Screenshot of the live viewer (`shelljax play`) in headless Chromium, for the docs.

Starts the viewer on the bundled Pezzi session (P_g and E by the closed form, configs/interaction.toml's
scene) with the hand pressed 3 cm into the ball's top, opens the page in Debian's headless Chromium (WebGL through its software
renderer, SwiftShader: `--disable-gpu` is enough), saves docs/gallery/viewer.png and writes a small
JSON result (what ran, the readouts at the screenshot, whether the ball's colour is on the picture).

    python3 experiments/check_viewer.py [--out docs/gallery/viewer.png] [--json docs/bench/viewer-check.json]

Needs viser (`pip install "shelljax[viewer]"`) and /usr/bin/chromium (`apt-get install -y chromium`).
"""

from __future__ import annotations

import argparse
import json
import shutil
import socket
import subprocess
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from shelljax import viewer

CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _ball_pixels(png: Path, rgb=(90, 160, 230), tolerance=60) -> int:
    """Pixels of the picture near the shell's colour (shaded: a wide tolerance); 0 means no ball drawn."""
    from PIL import Image

    image = np.asarray(Image.open(png).convert("RGB"), dtype=float)
    blue = (image[..., 2] > image[..., 0] + 40) & (np.abs(image - np.asarray(rgb)).sum(axis=-1) < 3 * tolerance)
    return int(blue.sum())


def _press_on_top(app, scene, stop: threading.Event, depth: float = 0.03) -> None:
    """Keep the pointer ``depth`` [m] into the top of the ball, above its centre of mass (a ball
    pressed from above rolls out from under a fixed finger)."""
    height = float(np.ptp(scene.rest_positions[:, 2]))
    while not stop.is_set():
        com, _ = scene.ball.com()
        app.move_pointer([com[0], com[1], height + scene.script.hand.radius - depth])
        stop.wait(0.1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--source", default="bundled:sessions/pezzi.toml")
    parser.add_argument("--script", default="configs/interaction.toml")
    parser.add_argument("--out", default="docs/gallery/viewer.png")
    parser.add_argument("--json", default="docs/gallery/viewer-check.json")
    parser.add_argument("--chromium", default=shutil.which("chromium") or "/usr/bin/chromium")
    parser.add_argument("--wait-ms", type=int, default=8000, help="Chromium's virtual time before the screenshot [ms]")
    args = parser.parse_args()

    start = time.perf_counter()
    scene = viewer.play_scene(args.source, args.script)
    loaded = time.perf_counter() - start
    app = viewer.serve(scene, port=_free_port())
    stop = threading.Event()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        app.command("reset")
        pressing = threading.Thread(target=_press_on_top, args=(app, scene, stop), daemon=True)
        pressing.start()
        with tempfile.TemporaryDirectory() as profile:
            command = [
                args.chromium,
                *CHROMIUM_FLAGS,
                f"--user-data-dir={profile}",
                "--window-size=1200,800",
                f"--virtual-time-budget={args.wait_ms}",
                f"--screenshot={out.resolve()}",
                f"http://127.0.0.1:{app.port}",
            ]
            shot = time.perf_counter()
            run = subprocess.run(command, check=False, capture_output=True, text=True, timeout=120)
            shot = time.perf_counter() - shot
        state = app.state()
    finally:
        stop.set()
        app.stop()
    version = subprocess.run([args.chromium, "--version"], check=True, capture_output=True, text=True).stdout.strip()
    pixels = _ball_pixels(out) if out.is_file() else 0
    result = {
        "source": args.source,
        "script": args.script,
        "scene": scene.label,
        "scene_load_s": round(loaded, 2),
        "chromium": version,
        "flags": CHROMIUM_FLAGS + ["--window-size=1200,800", f"--virtual-time-budget={args.wait_ms}"],
        "webgl": "software (SwiftShader, Chromium's fallback under --disable-gpu)",
        "chromium_exit_code": run.returncode,
        "screenshot": str(out),
        "screenshot_bytes": out.stat().st_size if out.is_file() else 0,
        "screenshot_wall_s": round(shot, 1),
        "ball_pixels": pixels,
        "ball_visible": pixels > 500,
        "readouts_when_chromium_exited": {
            k: (round(v, 3) if isinstance(v, float) else v) for k, v in state.items() if k != "plane_forces_N"
        }
        | {"plane_forces_N": [round(f, 3) for f in state["plane_forces_N"]]},
    }
    Path(args.json).write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
