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

from .._arguments import real, shown, whole
from .._errors import DeviceError, InvalidInputError
from .._files import check_output_file
from ..paper import PAPER_FORCES
from ..session import MASS_UNITS, PLAUSIBLE_RANGES, PRESSURE_UNITS, convert_unit, implausible, likely_unit
from ._calibrate import DEFAULT_MASSES, MAX_MASS, calibrate_sensor
from ._calibration import MODELS, SensorCalibration
from ._capture import HumanOperator
from ._console import AutoConsole, Console, TerminalConsole
from ._driver import DEFAULT_BAUD, SerialSensor, logger
from ._emulator import EmulatedDevice, EmulatedOperator, Faults, PtyLink
from ._recording import LENGTH_UNITS, AcquisitionPlan, RecordingAborted, RecordingPaths, acquire

EXIT_INTERRUPTED = 130
EXIT_ABORTED = 3
EMULATED_CALIBRATION = "emulated-film.toml"


def emulated_calibration_path() -> Path:
    """The bundled calibration of the emulator's default film (shelljax/data/calibration/)."""
    return Path(str(resources.files("shelljax") / "data" / "calibration" / EMULATED_CALIBRATION))


def register(subparsers) -> None:
    """Add ``acquire``, ``sensor-calibrate`` and ``sensor-emulator`` to an argparse subparsers object."""
    _register_acquire(subparsers)
    _register_calibrate(subparsers)
    _register_emulator(subparsers)


def _register_acquire(subparsers) -> None:
    """Add ``shelljax acquire``: the source, the output, the session's fields and the protocol."""
    acq = subparsers.add_parser(
        "acquire",
        help="record an indentation session from the force sensor (or the emulator)",
        description="Walk through the paper's protocol (5–20 N in 2.5 N steps, repeated trials) and "
        "write a session file for `shelljax estimate`. See docs/sensing.md.",
    )
    _add_source(acq)
    acq.add_argument(
        "--out", required=True, help="session TOML to write (other files go beside it; checked before the first sample)"
    )
    acq.add_argument("--resume", action="store_true", help="continue the interrupted recording at --out")
    acq.add_argument(
        "--calibration",
        help="sensor calibration TOML (from `shelljax sensor-calibrate`); "
        "default with --emulate: the bundled calibration of the emulated film",
    )
    _add_session_fields(acq)
    proto = acq.add_argument_group("protocol")
    proto.add_argument("--forces", default="5:20:2.5", help="levels [N]: START:STOP:STEP or a comma list")
    proto.add_argument("--trials", type=whole(1), default=3, help="sweeps through the levels [count]")
    proto.add_argument(
        "--hold",
        type=real(0.0, 60.0, low_open=True, unit="s"),
        default=0.5,
        help="[s] a level is captured after holding this long",
    )
    proto.add_argument(
        "--tolerance",
        type=real(0.0, 10.0, low_open=True, unit="N"),
        default=0.5,
        help="[N] allowed deviation from the level while holding",
    )
    proto.add_argument(
        "--level-timeout",
        type=real(0.0, low_open=True, unit="s"),
        default=60.0,
        help="[s] before offering retry/skip/quit",
    )
    proto.add_argument("--depth-unit", default="mm", choices=list(LENGTH_UNITS), help="unit of typed depths")
    proto.add_argument(
        "--depth-from-channel", action="store_true", help="read the depth from the sensor's second channel"
    )
    proto.add_argument(
        "--depth-scale",
        type=real(0.0, low_open=True, unit="m/count"),
        help="[m/count] of the second channel (with --depth-from-channel)",
    )
    proto.add_argument("--no-level-wrinkles", action="store_true", help="ask for the wrinkle count only once per trial")
    acq.set_defaults(func=cmd_acquire)


def _register_calibrate(subparsers) -> None:
    """Add ``shelljax sensor-calibrate``: the source, the output, the known masses and the curve."""
    cal = subparsers.add_parser("sensor-calibrate", help="calibrate the force sensor with known weights")
    _add_source(cal)
    cal.add_argument("--out", required=True, help="calibration TOML to write (checked before the first weight)")
    cal.add_argument(
        "--masses",
        default=",".join(f"{m:g}" for m in DEFAULT_MASSES),
        help="known masses [kg], comma-separated, including 0",
    )
    cal.add_argument("--cycles", type=whole(1), default=2, help="up-and-down cycles through the masses [count]")
    cal.add_argument("--hold", type=real(0.0, 60.0, low_open=True, unit="s"), default=1.0, help="[s] averaged per mass")
    cal.add_argument("--model", choices=MODELS, default="power", help="calibration curve (docs/sensing.md)")
    cal.add_argument("--sensor", default="", help="a name for the sensor (stored in the file)")
    cal.add_argument("--gravity", type=real(9.7, 9.9, unit="m/s^2"), default=9.80665, help="[m/s^2] local gravity")
    cal.set_defaults(func=cmd_calibrate)


def _register_emulator(subparsers) -> None:
    """Add ``shelljax sensor-emulator``: the emulated sensor served on a pseudo-terminal."""
    emu = subparsers.add_parser(
        "sensor-emulator",
        help="serve the emulated sensor on a pseudo-terminal (try the hardware path without hardware)",
    )
    emu.add_argument("--link", default=None, help="path of the port symlink to create (default: a temporary path)")
    emu.add_argument(
        "--faults", action="store_true", help="add garbage bytes, corrupted lines and an unplug every 20 s"
    )
    emu.add_argument("--seed", type=whole(0), default=0, help="emulator random seed")
    emu.add_argument(
        "--duration",
        type=real(0.0, low_open=True, unit="s"),
        default=None,
        help="[s] stop after this long (default: until Ctrl-C)",
    )
    emu.set_defaults(func=cmd_emulator)


def _add_session_fields(acq: argparse.ArgumentParser) -> None:
    """The session's own fields of ``shelljax acquire``: every number in the unit its unit option
    names, checked against the session format's plausible ranges before the first sample."""
    meta = acq.add_argument_group("session fields (see the session format; ignored with --resume)")
    meta.add_argument("--object", help="object name (default with --emulate: emulated-ball)")
    meta.add_argument("--notes", default="", help="free text")
    meta.add_argument(
        "--poisson-ratio",
        type=real(-1.0, 0.5, low_open=True, high_open=True),
        help="Poisson's ratio of the wall [-] (default: the paper's 0.4)",
    )
    meta.add_argument("--mass", type=real(0.0, low_open=True), help="object mass, in --mass-unit")
    meta.add_argument("--mass-unit", choices=list(MASS_UNITS), default="kg", help="unit of --mass")
    meta.add_argument(
        "--manometer-pressure",
        type=real(0.0, low_open=True),
        help="measured gauge pressure (calibration objects), in --pressure-unit",
    )
    meta.add_argument(
        "--pressure-unit", default="Pa", choices=list(PRESSURE_UNITS), help="unit of --manometer-pressure"
    )
    meta.add_argument(
        "--radius", type=real(0.0, low_open=True), help="local radius of curvature at the poke point, in --length-unit"
    )
    meta.add_argument("--radius-std", type=real(0.0), help="standard deviation of --radius, in --length-unit")
    meta.add_argument("--mesh", help="mesh file (instead of --radius); stored relative to the session file")
    meta.add_argument(
        "--poke-point", type=real(), nargs=3, metavar=("X", "Y", "Z"), help="with --mesh, in --length-unit"
    )
    meta.add_argument("--fit-radius", type=real(0.0, low_open=True), help="with --mesh, in --length-unit")
    meta.add_argument(
        "--length-unit",
        default="m",
        choices=list(LENGTH_UNITS),
        help="unit of --radius, --radius-std, --poke-point, --fit-radius and the mesh",
    )
    meta.add_argument("--thickness", type=real(0.0, low_open=True), help="wall thickness, in --thickness-unit")
    meta.add_argument("--thickness-std", type=real(0.0), help="standard deviation of --thickness, in --thickness-unit")
    meta.add_argument(
        "--thickness-unit",
        default="mm",
        choices=list(LENGTH_UNITS),
        help="unit of --thickness and --thickness-std (a calliper reads millimetres)",
    )


# (option, its attribute, its range in shelljax.session.PLAUSIBLE_RANGES, the option naming its unit)
_RANGED_OPTIONS = (
    ("--radius", "radius", "radius", "--length-unit"),
    ("--fit-radius", "fit_radius", "fit_radius", "--length-unit"),
    ("--thickness", "thickness", "thickness", "--thickness-unit"),
    ("--mass", "mass", "mass", "--mass-unit"),
    ("--manometer-pressure", "manometer_pressure", "pressure", "--pressure-unit"),
)


def _check_session_options(args) -> None:
    """Refuse, before the sensor is opened, a session field the session format would refuse: a
    value outside its plausible range in the unit its unit option names (with the unit that would
    make it plausible), or a standard deviation as large as its value."""
    for option, attribute, name, unit_option in _RANGED_OPTIONS:
        value = getattr(args, attribute)
        unit = getattr(args, unit_option.removeprefix("--").replace("-", "_"))
        problem = None if value is None else implausible(name, value, unit)
        if problem is None:
            continue
        likely = likely_unit(name, value)
        fix = f"{option} is in {unit_option} ({unit})"
        if likely is not None and likely != unit:
            meant = convert_unit(value, PLAUSIBLE_RANGES[name].quantity, likely, unit)
            fix += f": if you meant {value:g} {likely}, add {unit_option} {likely} (or write {option} {meant:g})"
        else:
            fix += "; check the value you measured"
        raise InvalidInputError(f"{option} {shown(value)}: {problem}. Fix: {fix}")
    for option, std, value in (
        ("--radius-std", args.radius_std, args.radius),
        ("--thickness-std", args.thickness_std, args.thickness),
    ):
        if std is not None and value is not None and std >= value:
            raise InvalidInputError(
                f"{option} {std:g}: not smaller than {option.removesuffix('-std')} {value:g}. Fix: give "
                "the standard deviation in the same unit, e.g. 5 % of the value"
            )
    for level in _parse_forces(args.forces):
        problem = implausible("force", level, "N")
        if problem is not None:
            raise InvalidInputError(f"--forces {args.forces}: {problem}. Fix: give levels in newtons, e.g. 5:20:2.5")


def _add_source(parser: argparse.ArgumentParser) -> None:
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--port", help="serial port (/dev/ttyACM0, COM3) or pyserial URL (socket://host:port)")
    source.add_argument(
        "--emulate", action="store_true", help="no hardware: an emulated sensor on a pseudo-terminal, in real time"
    )
    source.add_argument(
        "--emulate-fast",
        action="store_true",
        help="no hardware: an in-process emulated sensor on a virtual clock (seconds)",
    )
    parser.add_argument("--baud", type=whole(1), default=DEFAULT_BAUD, help="baud rate [bit/s]")
    parser.add_argument("--yes", action="store_true", help="accept every default (no typing; emulator demo)")
    parser.add_argument(
        "--emulate-faults",
        action="store_true",
        help="emulator: garbage bytes, corrupted lines, split writes and one unplug",
    )
    parser.add_argument("--seed", type=whole(0), default=0, help="emulator random seed")


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
        raise InvalidInputError(
            f"--forces {text!r}: not a list of levels. Fix: write START:STOP:STEP (e.g. 5:20:2.5) or a comma list [N]"
        ) from None


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
        faults = (
            Faults(garbage_rate=0.01, corrupt_rate=0.01, split_rate=0.05, disconnects=(20.0,))
            if args.emulate_faults
            else Faults()
        )
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
        raise InvalidInputError("--object: the object's name is required for a new recording. Fix: add --object NAME")
    meta: dict = {"object": name}
    notes = args.notes
    if ball is not None:
        notes = (notes + "\n" if notes else "") + (
            f"Emulated: R = {ball.radius} m, P_g = {ball.gauge_pressure} Pa, k_s = {ball.k_s}, "
            f"E = {ball.young_modulus} Pa, h = {ball.thickness} m, nu = {ball.poisson_ratio}."
        )
    if notes:
        meta["notes"] = notes
    for key, value in (
        ("poisson_ratio", args.poisson_ratio),
        ("mass", args.mass),
        ("manometer_gauge_pressure", args.manometer_pressure),
    ):
        if value is not None:
            meta[key] = value
    if args.mass is not None:
        meta["mass_unit"] = args.mass_unit
    if args.manometer_pressure is not None:
        meta["pressure_unit"] = args.pressure_unit
    geometry: dict = {"length_unit": args.length_unit}
    if args.mesh and args.radius is not None:
        raise InvalidInputError("--radius and --mesh both given. Fix: give either --radius or --mesh, not both")
    if args.mesh:
        if args.poke_point is None:
            raise InvalidInputError("--mesh without --poke-point. Fix: add --poke-point X Y Z (in --length-unit)")
        mesh = Path(args.mesh).resolve()
        if not mesh.exists():
            raise InvalidInputError(f"--mesh {args.mesh}: file not found. Fix: check the path")
        geometry["mesh"] = os.path.relpath(mesh, out.resolve().parent)
        geometry["poke_point"] = list(args.poke_point)
        if args.fit_radius is not None:
            geometry["fit_radius"] = args.fit_radius
    elif args.radius is not None:
        geometry["radius"] = args.radius
    elif ball is not None:
        geometry = {"radius": ball.radius, "length_unit": "m"}
    else:
        raise InvalidInputError(
            "--radius missing: the local radius of curvature is required. Fix: add --radius R "
            "(in --length-unit), or --mesh with --poke-point"
        )
    if args.radius_std is not None:
        geometry["radius_std"] = args.radius_std
    meta["geometry"] = geometry
    if args.thickness is not None and args.thickness_std is not None:
        meta["wall"] = {
            "thickness": args.thickness,
            "thickness_std": args.thickness_std,
            "thickness_unit": args.thickness_unit,
        }
    elif ball is not None and args.thickness is None:
        meta["wall"] = {"thickness": ball.thickness * 1e3, "thickness_std": 0.05, "thickness_unit": "mm"}
    else:
        raise InvalidInputError(
            "--thickness or --thickness-std missing: the wall is required. Fix: add both (a "
            "calliper reading in --thickness-unit, e.g. --thickness 0.9 --thickness-std 0.05 for mm)"
        )
    return meta


def cmd_acquire(args) -> int:
    """Handler of ``shelljax acquire``; returns the exit code. Every option of a new recording is
    checked before the sensor is opened: a refused one records nothing and writes nothing."""
    out = Path(args.out)
    paths = RecordingPaths.for_session(out)
    if not args.resume:
        paths.check_new()
        _check_session_options(args)
    console = _console(args)
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
                forces=_parse_forces(args.forces),
                trials=args.trials,
                hold=args.hold,
                tolerance=args.tolerance,
                level_timeout=args.level_timeout,
                depth_source="channel" if args.depth_from_channel else "prompt",
                depth_unit=args.depth_unit,
                depth_scale=depth_scale,
                ask_level_wrinkles=not args.no_level_wrinkles,
            )
            kwargs = {"calibration": SensorCalibration.load(cal_path), "plan": plan, "meta": _meta(args, out, device)}
        try:
            result = acquire(driver, out, console, operator=operator, resume=args.resume, **kwargs)
        except (KeyboardInterrupt, EOFError):
            console.say(
                f"\nInterrupted. Everything received is in {out.with_suffix('')}.samples.csv; "
                f"continue with the same command plus --resume."
            )
            return EXIT_INTERRUPTED
        except RecordingAborted as why:
            console.say(f"Stopped ({why}). Continue later with --resume.")
            return EXIT_ABORTED
        except DeviceError as error:
            raise DeviceError(f"{error} (the recording so far is kept; continue with --resume)") from error
        finally:
            driver.close()
    console.say(
        f"{result.completed_trials} trials, {result.levels} levels, {result.samples} samples "
        f"({result.malformed} malformed lines skipped, {result.reconnects} reconnects). "
        f"Next: shelljax estimate {out}"
    )
    return 0


def cmd_calibrate(args) -> int:
    """Handler of ``shelljax sensor-calibrate``."""
    try:
        masses = [float(m) for m in args.masses.split(",")]
    except ValueError:
        raise InvalidInputError(
            f"--masses {args.masses!r}: not a list of numbers. Fix: a comma-separated list of kg, e.g. 0,0.5,1,2"
        ) from None
    if not masses or min(masses) != 0.0 or any(not 0 <= m <= MAX_MASS for m in masses) or len(set(masses)) < 3:
        raise InvalidInputError(
            f"--masses {args.masses}: not a set of calibration weights. Fix: give 0 (unloaded) and "
            f"at least two other masses in kg, up to {MAX_MASS:g} kg, e.g. 0,0.5,1,2.5"
        )
    out = check_output_file(args.out, "--out", example="sensor.toml")
    console = _console(args)
    with _source(args, console) as (driver, operator, _device):
        try:
            calibration = calibrate_sensor(
                driver,
                console,
                masses=masses,
                cycles=args.cycles,
                hold=args.hold,
                model=args.model,
                sensor=args.sensor,
                gravity=args.gravity,
                operator=operator,
                log_path=out.with_suffix(".samples.csv"),
            )
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
    faults = (
        Faults(garbage_rate=0.01, corrupt_rate=0.01, disconnects=tuple(20.0 * k for k in range(1, 1000)))
        if args.faults
        else Faults()
    )
    if args.link is not None:
        link = Path(args.link)
        if link.exists() and not link.is_symlink():
            raise InvalidInputError(
                f"--link {link}: exists and is not a link; the emulator would replace it. Fix: name a "
                "new path, e.g. --link /tmp/ttyEMU0"
            )
        check_output_file(link, "--link", example="ttyEMU0")
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
