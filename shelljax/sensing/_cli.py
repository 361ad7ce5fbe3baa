"""Command-line front end: ``shelljax acquire``, ``shelljax sensor-calibrate``, ``shelljax sensor-emulator``.

:func:`register` adds the subcommands to the main parser; handlers return an exit code.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import os
import sys
import time
from importlib import resources
from pathlib import Path

from .._errors import DeviceError, InvalidInputError
from ..paper import PAPER_FORCES
from ._calibrate import DEFAULT_MASSES, calibrate_sensor
from ._calibration import MODELS, SensorCalibration
from ._capture import HumanOperator
from ._console import AutoConsole, Console, TerminalConsole
from ._driver import DEFAULT_BAUD, SerialSensor, logger
from ._emulator import EmulatedDevice, EmulatedOperator, Faults, PtyLink
from ._recording import LENGTH_UNITS, AcquisitionPlan, RecordingAborted, acquire

EXIT_INTERRUPTED = 130
EXIT_ABORTED = 3
EMULATED_CALIBRATION = "emulated-film.toml"


def emulated_calibration_path() -> Path:
    """The bundled calibration of the emulator's default film (shelljax/data/calibration/)."""
    return Path(str(resources.files("shelljax") / "data" / "calibration" / EMULATED_CALIBRATION))


def register(subparsers) -> None:
    """Add ``acquire``, ``sensor-calibrate`` and ``sensor-emulator`` to an argparse subparsers object."""
    acq = subparsers.add_parser(
        "acquire",
        help="record an indentation session from the force sensor (or the emulator)",
        description="Walk through the paper's protocol (5–20 N in 2.5 N steps, repeated trials) and "
        "write a session file for `shelljax estimate`. See docs/sensing.md.",
    )
    _add_source(acq)
    acq.add_argument("--out", required=True, help="session TOML to write (other files go beside it)")
    acq.add_argument("--resume", action="store_true", help="continue the interrupted recording at --out")
    acq.add_argument("--calibration", help="sensor calibration TOML (from `shelljax sensor-calibrate`); "
                     "default with --emulate: the bundled calibration of the emulated film")  # fmt: skip
    meta = acq.add_argument_group("session fields (see the session format; ignored with --resume)")
    meta.add_argument("--object", help="object name (default with --emulate: emulated-ball)")
    meta.add_argument("--notes", default="", help="free text")
    meta.add_argument("--poisson-ratio", type=float)
    meta.add_argument("--mass", type=float, help="object mass, in --mass-unit")
    meta.add_argument("--mass-unit", choices=["kg", "g"], default="kg")
    meta.add_argument("--manometer-pressure", type=float, help="measured gauge pressure (calibration objects), in --pressure-unit")
    meta.add_argument("--pressure-unit", default="Pa", choices=["Pa", "hPa", "kPa", "mbar", "bar", "psi"])
    meta.add_argument("--radius", type=float, help="local radius of curvature at the poke point, in --length-unit")
    meta.add_argument("--radius-std", type=float)
    meta.add_argument("--mesh", help="mesh file (instead of --radius); stored relative to the session file")
    meta.add_argument("--poke-point", type=float, nargs=3, metavar=("X", "Y", "Z"), help="with --mesh, in --length-unit")
    meta.add_argument("--fit-radius", type=float, help="with --mesh, in --length-unit")
    meta.add_argument("--length-unit", default="m", choices=list(LENGTH_UNITS))
    meta.add_argument("--thickness", type=float, help="wall thickness, in --thickness-unit")
    meta.add_argument("--thickness-std", type=float)
    meta.add_argument("--thickness-unit", default="mm", choices=list(LENGTH_UNITS))
    proto = acq.add_argument_group("protocol")
    proto.add_argument("--forces", default="5:20:2.5", help="levels [N]: START:STOP:STEP or a comma list (default 5:20:2.5)")
    proto.add_argument("--trials", type=int, default=3)
    proto.add_argument("--hold", type=float, default=0.5, help="[s] a level is captured after holding this long")
    proto.add_argument("--tolerance", type=float, default=0.5, help="[N] allowed deviation from the level while holding")
    proto.add_argument("--level-timeout", type=float, default=60.0, help="[s] before offering retry/skip/quit")
    proto.add_argument("--depth-unit", default="mm", choices=list(LENGTH_UNITS), help="unit of typed depths")
    proto.add_argument("--depth-from-channel", action="store_true", help="read the depth from the sensor's second channel")
    proto.add_argument("--depth-scale", type=float, help="[m/count] of the second channel (with --depth-from-channel)")
    proto.add_argument("--no-level-wrinkles", action="store_true", help="ask for the wrinkle count only once per trial")
    acq.set_defaults(func=cmd_acquire)

    cal = subparsers.add_parser("sensor-calibrate", help="calibrate the force sensor with known weights")
    _add_source(cal)
    cal.add_argument("--out", required=True, help="calibration TOML to write")
    cal.add_argument("--masses", default=",".join(f"{m:g}" for m in DEFAULT_MASSES),
                     help="known masses [kg], comma-separated, including 0 (default %(default)s)")  # fmt: skip
    cal.add_argument("--cycles", type=int, default=2, help="up-and-down cycles through the masses")
    cal.add_argument("--hold", type=float, default=1.0, help="[s] averaged per mass")
    cal.add_argument("--model", choices=MODELS, default="power")
    cal.add_argument("--sensor", default="", help="a name for the sensor (stored in the file)")
    cal.add_argument("--gravity", type=float, default=9.80665, help="[m/s^2] local gravity")
    cal.set_defaults(func=cmd_calibrate)

    emu = subparsers.add_parser("sensor-emulator",
                                help="serve the emulated sensor on a pseudo-terminal (try the hardware path without hardware)")  # fmt: skip
    emu.add_argument("--link", default=None, help="path of the port symlink to create (default: a temporary path)")
    emu.add_argument("--faults", action="store_true", help="add garbage bytes, corrupted lines and an unplug every 20 s")
    emu.add_argument("--seed", type=int, default=0)
    emu.add_argument("--duration", type=float, default=None, help="[s] stop after this long (default: until Ctrl-C)")
    emu.set_defaults(func=cmd_emulator)


def _add_source(parser: argparse.ArgumentParser) -> None:
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--port", help="serial port (/dev/ttyACM0, COM3) or pyserial URL (socket://host:port)")
    source.add_argument("--emulate", action="store_true",
                        help="no hardware: an emulated sensor on a pseudo-terminal, in real time")  # fmt: skip
    source.add_argument("--emulate-fast", action="store_true",
                        help="no hardware: an in-process emulated sensor on a virtual clock (seconds)")  # fmt: skip
    parser.add_argument("--baud", type=int, default=DEFAULT_BAUD, help="baud rate (default %(default)s)")
    parser.add_argument("--yes", action="store_true", help="accept every default (no typing; emulator demo)")
    parser.add_argument("--emulate-faults", action="store_true",
                        help="emulator: garbage bytes, corrupted lines, split writes and one unplug")  # fmt: skip
    parser.add_argument("--seed", type=int, default=0, help="emulator random seed")


def _parse_forces(text: str) -> tuple[float, ...]:
    try:
        if ":" in text:
            start, stop, step = (float(x) for x in text.split(":"))
            if step <= 0 or stop < start:
                raise ValueError
            n = int(round((stop - start) / step))
            return tuple(start + i * step for i in range(n + 1))
        return tuple(float(x) for x in text.split(","))
    except ValueError:
        raise InvalidInputError(f"--forces {text!r}: write START:STOP:STEP (e.g. 5:20:2.5) or a comma list") from None


def _console(args) -> Console:
    return AutoConsole(stream=sys.stderr) if args.yes else TerminalConsole()


class _ConsoleLogHandler(logging.Handler):
    """Driver warnings through the console, so they do not tear the live display line."""

    def __init__(self, console: Console):
        super().__init__(logging.WARNING)
        self.console = console

    def emit(self, record: logging.LogRecord) -> None:
        self.console.say(f"warning: {record.getMessage()}")


@contextlib.contextmanager
def _source(args, console: Console):
    """Yields (driver, operator, emulated device or None) for --port / --emulate / --emulate-fast."""
    handler = _ConsoleLogHandler(console)
    logger.addHandler(handler)
    logger.propagate = False
    try:
        if args.port:
            yield SerialSensor(args.port, args.baud), HumanOperator(), None
            return
        faults = Faults(garbage_rate=0.01, corrupt_rate=0.01, split_rate=0.05, disconnects=(20.0,)) \
            if args.emulate_faults else Faults()  # fmt: skip
        use_pty = args.emulate and os.name == "posix"
        device = EmulatedDevice(faults=faults, seed=args.seed, realtime=args.emulate and not use_pty)
        operator = EmulatedOperator(device)
        if args.emulate_fast:
            yield SerialSensor(opener=device.open_port, clock=device.clock, sleep=device.sleep), operator, device
        elif use_pty:
            with PtyLink(device) as link:
                console.say(f"Emulated sensor on {link.port} (a pseudo-terminal; same code path as hardware).")
                yield SerialSensor(link.port, args.baud), operator, device
        else:
            yield SerialSensor(opener=device.open_port), operator, device
    finally:
        logger.removeHandler(handler)
        logger.propagate = True


def _meta(args, out: Path, device: EmulatedDevice | None) -> dict:
    ball = device.ball if device is not None else None
    name = args.object or ("emulated-ball" if ball else None)
    if name is None:
        raise InvalidInputError("--object: the object's name is required for a new recording")
    meta: dict = {"object": name}
    notes = args.notes
    if ball is not None:
        notes = (notes + "\n" if notes else "") + (
            f"Emulated: R = {ball.radius} m, P_g = {ball.gauge_pressure} Pa, k_s = {ball.k_s}, "
            f"E = {ball.youngs_modulus} Pa, h = {ball.thickness} m, nu = {ball.poisson_ratio}."
        )
    if notes:
        meta["notes"] = notes
    for key, value in (("poisson_ratio", args.poisson_ratio), ("mass", args.mass),
                       ("manometer_gauge_pressure", args.manometer_pressure)):  # fmt: skip
        if value is not None:
            meta[key] = value
    if args.mass is not None:
        meta["mass_unit"] = args.mass_unit
    if args.manometer_pressure is not None:
        meta["pressure_unit"] = args.pressure_unit
    geometry: dict = {"length_unit": args.length_unit}
    if args.mesh and args.radius is not None:
        raise InvalidInputError("give either --radius or --mesh, not both")
    if args.mesh:
        if args.poke_point is None:
            raise InvalidInputError("--mesh needs --poke-point X Y Z")
        mesh = Path(args.mesh).resolve()
        if not mesh.exists():
            raise InvalidInputError(f"--mesh {args.mesh}: file not found")
        geometry["mesh"] = os.path.relpath(mesh, out.resolve().parent)
        geometry["poke_point"] = list(args.poke_point)
        if args.fit_radius is not None:
            geometry["fit_radius"] = args.fit_radius
    elif args.radius is not None:
        geometry["radius"] = args.radius
    elif ball is not None:
        geometry = {"radius": ball.radius, "length_unit": "m"}
    else:
        raise InvalidInputError("--radius (or --mesh with --poke-point) is required: the local radius of curvature")
    if args.radius_std is not None:
        geometry["radius_std"] = args.radius_std
    meta["geometry"] = geometry
    if args.thickness is not None and args.thickness_std is not None:
        meta["wall"] = {"thickness": args.thickness, "thickness_std": args.thickness_std,
                        "thickness_unit": args.thickness_unit}  # fmt: skip
    elif ball is not None and args.thickness is None:
        meta["wall"] = {"thickness": ball.thickness * 1e3, "thickness_std": 0.05, "thickness_unit": "mm"}
    else:
        raise InvalidInputError("--thickness and --thickness-std are required (caliper reading, e.g. 0.9 and 0.05 mm)")
    return meta


def cmd_acquire(args) -> int:
    """Handler of ``shelljax acquire``; returns the exit code."""
    console = _console(args)
    out = Path(args.out)
    with _source(args, console) as (driver, operator, device):
        kwargs: dict = {}
        if not args.resume:
            cal_path = args.calibration or (emulated_calibration_path() if device is not None else None)
            if cal_path is None:
                raise InvalidInputError(
                    "--calibration is required with --port. Fix: calibrate the sensor first with "
                    "`shelljax sensor-calibrate --port PORT --out sensor.toml`"
                )
            depth_scale = args.depth_scale
            if args.depth_from_channel and depth_scale is None and device is not None and device.depth_gauge:
                depth_scale = 1.0 / device.depth_gauge.counts_per_m
            plan = AcquisitionPlan(
                forces=_parse_forces(args.forces), trials=args.trials, hold=args.hold,
                tolerance=args.tolerance, level_timeout=args.level_timeout,
                depth_source="channel" if args.depth_from_channel else "prompt", depth_unit=args.depth_unit,
                depth_scale=depth_scale, ask_level_wrinkles=not args.no_level_wrinkles,
            )  # fmt: skip
            kwargs = {"calibration": SensorCalibration.load(cal_path), "plan": plan, "meta": _meta(args, out, device)}
        try:
            result = acquire(driver, out, console, operator=operator, resume=args.resume, **kwargs)
        except (KeyboardInterrupt, EOFError):
            console.say(f"\nInterrupted. Everything received is in {out.with_suffix('')}.samples.csv; "
                        f"continue with the same command plus --resume.")  # fmt: skip
            return EXIT_INTERRUPTED
        except RecordingAborted as why:
            console.say(f"Stopped ({why}). Continue later with --resume.")
            return EXIT_ABORTED
        except DeviceError as error:
            raise DeviceError(f"{error} (the recording so far is kept; continue with --resume)") from error
        finally:
            driver.close()
    console.say(f"{result.completed_trials} trials, {result.levels} levels, {result.samples} samples "
                f"({result.malformed} malformed lines skipped, {result.reconnects} reconnects). "
                f"Next: shelljax estimate {out}")  # fmt: skip
    return 0


def cmd_calibrate(args) -> int:
    """Handler of ``shelljax sensor-calibrate``."""
    console = _console(args)
    try:
        masses = [float(m) for m in args.masses.split(",")]
    except ValueError:
        raise InvalidInputError(f"--masses {args.masses!r}: a comma-separated list of kg, e.g. 0,0.5,1,2") from None
    out = Path(args.out)
    with _source(args, console) as (driver, operator, _device):
        try:
            calibration = calibrate_sensor(
                driver, console, masses=masses, cycles=args.cycles, hold=args.hold, model=args.model,
                sensor=args.sensor, gravity=args.gravity, operator=operator,
                log_path=out.with_suffix(".samples.csv"),
            )  # fmt: skip
        except (KeyboardInterrupt, EOFError):
            console.say("\nInterrupted; no calibration written.")
            return EXIT_INTERRUPTED
        finally:
            driver.close()
    calibration.save(out)
    console.say(f"Calibration written to {out}.")
    return 0


def cmd_emulator(args) -> int:
    """Handler of ``shelljax sensor-emulator``: an autopilot finger pokes 5→20 N, over and over."""
    faults = Faults(garbage_rate=0.01, corrupt_rate=0.01, disconnects=tuple(20.0 * k for k in range(1, 1000))) \
        if args.faults else Faults()  # fmt: skip
    device = EmulatedDevice(faults=faults, seed=args.seed, finger_tau=0.3)
    levels = PAPER_FORCES
    with PtyLink(device, args.link) as link:
        print(f"emulated force sensor on {link.port} (Ctrl-C to stop)", flush=True)
        stop = math.inf if args.duration is None else time.monotonic() + args.duration
        script = [(0.0, 2.0)] + [(level, 3.0) for level in levels]  # (force [N], hold [s])
        try:
            while time.monotonic() < stop:
                for force, hold in script:
                    device.press(force) if force > 0 else device.release()
                    time.sleep(max(0.0, min(hold, stop - time.monotonic())))
        except KeyboardInterrupt:
            pass
    return 0
