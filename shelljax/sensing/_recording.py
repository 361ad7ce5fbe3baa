"""The paper's indentation protocol as a resumable recording that ends in a session file.

For each trial (one sweep through the force levels, default 5–20 N in 2.5 N steps, 3 trials):

1. tare: the finger is lifted; a steady unloaded window re-measures the film's zero (the film
   drifts and its preload changes with the fit on the finger); the shift since calibration is
   reported in newtons;
2. each level: the user presses until the reading holds within ``tolerance`` of the target for
   ``hold`` seconds; the level's force is the mean of that window (the measured force is stored,
   not the target); the depth comes from channel 2 or is typed in; the wrinkle count visible at
   that level may be typed in (optional);
3. end of the sweep: the trial's wrinkle count is required (default: the count typed at the last
   level where one was given). One count per trial is what the session format stores; the
   per-level counts stay in the event log.

Files, for ``--out NAME.toml``:

* ``NAME.samples.csv``: every received sample, appended and fsync-ed per batch (see
  :mod:`._capture`), with the force and flags computed at the time;
* ``NAME.events.jsonl``: append-only event log (start, tare, level, skip, trial, resume, done),
  fsync-ed per event; the state a ``--resume`` continues from (see :mod:`._events`);
* ``NAME_trials.csv`` and ``NAME.toml``: the session (format of :mod:`shelljax.session`),
  rewritten atomically and fsync-ed (``_files.atomic_write_text``) after every completed trial, so
  they always hold the completed trials.
"""

from __future__ import annotations

import dataclasses
import datetime
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import tomli_w

from .._errors import InvalidInputError
from .._files import atomic_write_text, check_output_file
from ..paper import PAPER_FORCES
from ..session import LENGTH_UNITS
from ._calibration import ADC_SATURATED, SensorCalibration
from ._capture import HumanOperator, Operator, Pump, Reading, SampleLog, accept_force
from ._console import Console
from ._driver import SerialSensor
from ._events import EVENTS_VERSION, EventLog, RecordingState


class RecordingAborted(Exception):
    """The user quit; everything received is on disk and ``--resume`` continues."""


@dataclasses.dataclass(frozen=True)
class AcquisitionPlan:
    """What to record. Forces [N], times [s], ``depth_scale`` [m/count] for channel 2."""

    forces: tuple[float, ...] = PAPER_FORCES
    trials: int = 3
    hold: float = 0.5
    tolerance: float = 0.5
    level_timeout: float = 60.0
    tare_time: float = 1.0
    tare_timeout: float = 30.0
    depth_source: str = "prompt"  # or "channel"
    depth_unit: str = "mm"
    depth_scale: float | None = None
    ask_level_wrinkles: bool = True

    def check(self, calibration: SensorCalibration) -> None:
        """Raise :class:`InvalidInputError` if the plan cannot be recorded with ``calibration``."""
        if len(self.forces) < 3 or any(not f > 0 for f in self.forces):
            raise InvalidInputError(
                f"--forces {self.forces}: fewer than 3 positive force levels. Fix: give at least 3 "
                "levels in N, e.g. 5:20:2.5"
            )
        if self.trials < 1:
            raise InvalidInputError(f"--trials {self.trials}: no trial. Fix: give at least one, e.g. --trials 3")
        if self.depth_unit not in LENGTH_UNITS:
            raise InvalidInputError(
                f"--depth-unit {self.depth_unit!r}: unknown unit. Fix: use one of {', '.join(LENGTH_UNITS)}"
            )
        if self.depth_source not in ("prompt", "channel"):
            raise InvalidInputError(f"depth source {self.depth_source!r}: unknown. Fix: use 'prompt' or 'channel'")
        if self.depth_source == "channel" and not (self.depth_scale and self.depth_scale > 0):
            raise InvalidInputError(
                "--depth-from-channel without --depth-scale. Fix: add --depth-scale, the depth sensor's metres per count (> 0)"
            )
        if self.hold <= 0 or self.tolerance <= 0 or self.level_timeout <= self.hold:
            raise InvalidInputError(
                f"--level-timeout {self.level_timeout:g} s is not longer than --hold {self.hold:g} s. "
                "Fix: give --hold and --tolerance > 0 and a --level-timeout longer than --hold"
            )
        low = min(self.forces) - self.tolerance
        high = max(self.forces) + self.tolerance
        if low < calibration.force_min or high > calibration.force_max:
            raise InvalidInputError(
                f"force levels {min(self.forces):g}–{max(self.forces):g} N (± tolerance {self.tolerance:g} N) "
                f"leave the calibrated range {calibration.force_min:.3g}–{calibration.force_max:.3g} N "
                f"of the calibration{' ' + repr(calibration.sensor) if calibration.sensor else ''}. "
                "Readings there would be extrapolated. Fix: re-calibrate with known weights spanning "
                f"the levels (e.g. up to {math.ceil(high / calibration.gravity * 1.1 * 10) / 10:g} kg) "
                "or change --forces"
            )


@dataclasses.dataclass(frozen=True)
class RecordingPaths:
    """The files of one recording, all beside the session TOML."""

    session: Path
    trials_csv: Path
    samples: Path
    events: Path

    @classmethod
    def for_session(cls, out: str | Path) -> "RecordingPaths":
        out = Path(out)
        if out.suffix != ".toml":
            raise InvalidInputError(
                f"--out {out}: the session file must end in .toml. Fix: e.g. --out {out.with_suffix('.toml')}"
            )
        stem = out.with_suffix("")
        return cls(
            out,
            stem.parent / f"{stem.name}_trials.csv",
            stem.parent / f"{stem.name}.samples.csv",
            stem.parent / f"{stem.name}.events.jsonl",
        )

    def existing(self) -> list[Path]:
        return [p for p in (self.session, self.trials_csv, self.samples, self.events) if p.exists()]

    def check_new(self) -> None:
        """Refuse a new recording that would overwrite these files or could not write them."""
        check_output_file(self.session, "--out", example="session.toml")
        clash = self.existing()
        if clash:
            raise InvalidInputError(
                f"--out {self.session}: {', '.join(str(p) for p in clash)} already exist(s). Fix: add "
                "--resume to continue that recording, or choose another --out"
            )


@dataclasses.dataclass(frozen=True)
class AcquisitionResult:
    """Where the recording went and what it holds."""

    paths: RecordingPaths
    completed_trials: int
    levels: int
    samples: int
    malformed: int
    reconnects: int


def _plan_to_dict(plan: AcquisitionPlan) -> dict:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(plan).items()}


def _plan_from_dict(data: dict) -> AcquisitionPlan:
    data = dict(data)
    data["forces"] = tuple(data["forces"])
    return AcquisitionPlan(**data)


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def _resumed(paths: RecordingPaths):
    """(state, calibration, plan, meta) of an interrupted recording, from its event log."""
    if not paths.events.exists():
        raise InvalidInputError(f"--resume: {paths.events} not found. Fix: pass the --out of the interrupted recording")
    state = RecordingState.from_events(EventLog.read(paths.events), paths.events)
    start = state.start
    calibration = SensorCalibration.from_dict(start["calibration"], source=str(paths.events))
    return state, calibration, _plan_from_dict(start["plan"]), start["meta"]


def _started(
    paths: RecordingPaths, calibration: SensorCalibration | None, plan: AcquisitionPlan | None, meta: dict | None
) -> RecordingState:
    """The state of a new recording, after checking that nothing would be overwritten."""
    if calibration is None or plan is None or meta is None:
        raise ValueError("a new recording needs calibration, plan and meta")
    paths.check_new()
    plan.check(calibration)
    for key in ("object", "geometry", "wall"):
        if key not in meta:
            raise InvalidInputError(f"session field '{key}' missing. Fix: pass it on the command line")
    start = {
        "event": "start",
        "version": EVENTS_VERSION,
        "time": _now(),
        "session": paths.session.name,
        "calibration": calibration.to_dict(),
        "plan": _plan_to_dict(plan),
        "meta": meta,
    }
    return RecordingState(start)


def acquire(
    driver: SerialSensor,
    out: str | Path,
    console: Console,
    *,
    calibration: SensorCalibration | None = None,
    plan: AcquisitionPlan | None = None,
    meta: dict | None = None,
    operator: Operator | None = None,
    resume: bool = False,
    on_batch: Callable[[Pump, list[Reading]], None] | None = None,
    durable: bool = True,
) -> AcquisitionResult:
    """Walk the user through the indentation protocol and write the session.

    Args:
        driver: an open or openable :class:`SerialSensor`.
        out: the session TOML to write; the other files go beside it (see module docstring).
        console: prompts and live display (:class:`TerminalConsole` or a scripted one).
        calibration, plan, meta: required for a new recording; on ``resume`` they come from the
            event log (so the continuation uses the same calibration and protocol). ``meta`` holds
            the session's non-indentation fields: ``object``, ``geometry``, ``wall``, and
            optionally ``notes``, ``poisson_ratio``, ``mass``..., as in the session format.
        operator: the simulated finger for the emulator; a person otherwise.
        on_batch: called after every batch has been logged (tests check durability with it).

    Raises :class:`RecordingAborted` when the user quits, :class:`~shelljax.DeviceError` when the
    sensor is gone for good; in both cases everything received is on disk and ``resume=True``
    continues.
    """
    paths = RecordingPaths.for_session(out)
    operator = operator or HumanOperator()
    if resume:
        state, calibration, plan, meta = _resumed(paths)
    else:
        state = _started(paths, calibration, plan, meta)
    start = state.start
    paths.session.parent.mkdir(parents=True, exist_ok=True)
    events = EventLog(paths.events)
    log = SampleLog(paths.samples, durable=durable)
    try:
        if resume:
            trial = state.next_trial()
            events.append({"event": "resume", "time": _now(), "trial": trial, "log_row": log.n_rows})
            console.say(
                f"Resuming {paths.session.name}: {len(state.wrinkles)} trial(s) complete, "
                f"continuing with trial {trial}."
            )
        else:
            events.append(start)
        pump = Pump(driver, calibration, log, console, on_batch=on_batch)
        if not driver.is_open:
            driver.open()
        walk = _Walk(pump, plan, meta, console, operator, events, state, paths, calibration)
        for trial in range(state.next_trial(), plan.trials + 1):
            walk.trial(trial)
        events.append(
            {
                "event": "done",
                "time": _now(),
                "samples": log.n_rows,
                "malformed": driver.stats.n_malformed,
                "reconnects": driver.stats.n_reconnects,
            }
        )
        console.say(f"Done: {paths.session} ({len(state.wrinkles)} trials); raw samples in {paths.samples.name}.")
        return AcquisitionResult(
            paths,
            len(state.wrinkles),
            sum(len(v) for v in state.levels.values()),
            log.n_rows,
            driver.stats.n_malformed,
            driver.stats.n_reconnects,
        )
    finally:
        operator.release()
        log.close()
        events.close()


class _Walk:
    """One recording's interactive steps (state lives in the event log)."""

    def __init__(
        self,
        pump: Pump,
        plan: AcquisitionPlan,
        meta: dict,
        console: Console,
        operator: Operator,
        events: EventLog,
        state: RecordingState,
        paths: RecordingPaths,
        calibration: SensorCalibration,
    ):
        self.pump, self.plan, self.meta, self.console = pump, plan, meta, console
        self.operator, self.events, self.state, self.paths = operator, events, state, paths
        self.calibration = calibration
        self.zero_raw1 = 0.0
        self.last_shift: float | None = None

    # -- a trial ------------------------------------------------------------------------------
    def trial(self, trial: int) -> None:
        plan, pump = self.plan, self.pump
        pump.trial = trial
        self.tare(trial)
        done = self.state.done_targets(trial)
        level_counts: list[int] = [
            e["wrinkles"] for e in self.state.levels.get(trial, []) if e.get("wrinkles") is not None
        ]
        for j, target in enumerate(plan.forces, start=1):
            if target in done:
                continue
            count = self.level(trial, j, target)
            if count is not None:
                level_counts.append(count)
        if not self.state.levels.get(trial):
            raise RecordingAborted(f"trial {trial}: every level was skipped; nothing to save")
        # Asked while the top force is still held: the paper counts the stabilised wrinkles there.
        default = level_counts[-1] if level_counts else self.operator.suggest_wrinkles()
        wrinkles = self.ask_int(f"Trial {trial}: number of radial wrinkles at the top force", default)
        self.operator.release()
        event = {"event": "trial", "time": _now(), "trial": trial, "wrinkles": wrinkles}
        self.events.append(event)
        self.state.wrinkles[trial] = wrinkles
        self.write_session()
        self.console.say(f"Trial {trial} saved: {len(self.state.levels[trial])} levels, {wrinkles} wrinkles.")

    def tare(self, trial: int) -> None:
        pump, plan, cal = self.pump, self.plan, self.calibration
        self.operator.release()
        pump.phase = "tare"
        pump.headline = f"trial {trial}/{plan.trials}: lift the finger (tare)"
        self.console.say(f"Trial {trial}/{plan.trials}: lift the finger off the object; taring the sensor.")
        limit = max(0.25 * min(plan.forces), 3 * plan.tolerance)

        def unloaded(r: Reading) -> bool:
            # Against the calibration's zero: a film that drifted further than this needs a
            # new calibration, not a bigger tare.
            force = cal.force_from_conductance(r.c).force[0]
            return not r.flags & ADC_SATURATED and force < limit

        while True:
            window = pump.wait_stable(unloaded, plan.tare_time, plan.tare_timeout)
            if window is not None:
                break
            self.retry_or_quit(f"No steady unloaded reading (< {limit:.2g} N) within {plan.tare_timeout:g} s")
        c = np.array([r.c for r in window])
        zero = float(c.mean())
        pump.zero = zero
        if plan.depth_source == "channel":
            self.zero_raw1 = float(np.mean([r.raw[1] for r in window if len(r.raw) > 1] or [np.nan]))
            if not math.isfinite(self.zero_raw1):
                raise InvalidInputError(
                    "--depth-from-channel: the sensor sends one channel only. Fix: wire the depth "
                    "sensor to the firmware's second channel, or drop --depth-from-channel"
                )
        shift = cal.zero_shift_force(zero, min(plan.forces))
        event = {
            "event": "tare",
            "time": _now(),
            "trial": trial,
            "zero": zero,
            "zero_std": float(c.std(ddof=1) / math.sqrt(len(c))),
            "zero_raw1": self.zero_raw1,
            "shift_N_at_min_force": shift,
        }
        self.events.append(event)
        at_min = cal.force_from_conductance(cal.conductance_at(min(plan.forces)))
        message = f"Tare: zero moved by the equivalent of {shift:+.2f} N at {min(plan.forces):g} N since calibration"
        if self.last_shift is not None:
            message += f" ({shift - self.last_shift:+.2f} N since the last tare)"
        if abs(shift) > 2 * float(at_min.std[0]):
            message += ". That is more than twice the calibration uncertainty: the film drifts; consider re-calibrating"
        self.console.say(message + ".")
        self.last_shift = shift

    def level(self, trial: int, j: int, target: float) -> int | None:
        pump, plan = self.pump, self.plan
        pump.phase = "level"
        pump.headline = f"trial {trial}/{plan.trials} level {j}/{len(plan.forces)}: press to {target:g} N"
        self.console.say(f"Press to {target:g} N and hold steady ({plan.hold:g} s within ±{plan.tolerance:g} N).")
        self.operator.press(target)
        while True:
            window = pump.wait_stable(
                accept_force(target, plan.tolerance),
                plan.hold,
                plan.level_timeout,
                watch=lambda r: self.operator.see(r.force),
            )
            if window is not None:
                break
            if self.retry_or_quit(f"No steady {target:g} N within {plan.level_timeout:g} s", allow_skip=True):
                self.events.append({"event": "skip", "time": _now(), "trial": trial, "target": target})
                self.state.skipped.setdefault(trial, set()).add(target)
                return None
        self.operator.hold()
        force = np.array([r.force for r in window])
        unit = LENGTH_UNITS[plan.depth_unit]
        if plan.depth_source == "channel":
            raw1 = np.mean([r.raw[1] for r in window])
            depth_m = (raw1 - self.zero_raw1) * plan.depth_scale
            depth = depth_m / unit
            self.console.say(f"Captured {force.mean():.2f} N, depth {depth:.3g} {plan.depth_unit} (channel 2).")
        else:
            self.console.say(f"Captured {force.mean():.2f} N: keep still and read the depth.")
            suggestion = self.operator.suggest_depth()
            depth = self.ask_float(
                f"Indentation depth at {force.mean():.2f} N [{plan.depth_unit}]",
                None if suggestion is None else suggestion / unit,
            )
        count = None
        if plan.ask_level_wrinkles:
            count = self.ask_int(
                f"Wrinkles visible at {target:g} N (Enter to skip)", self.operator.suggest_wrinkles(), required=False
            )
        event = {
            "event": "level",
            "time": _now(),
            "trial": trial,
            "target": target,
            "force": float(force.mean()),
            "force_std": float(force.std(ddof=1)),
            "depth": float(depth),
            "depth_unit": plan.depth_unit,
            "depth_source": plan.depth_source,
            "wrinkles": count,
            "t_device": [window[0].device_time, window[-1].device_time],
            "n_samples": len(window),
            "log_rows_to": pump.log.n_rows,
        }
        self.events.append(event)
        self.state.levels.setdefault(trial, []).append(event)
        return count

    # -- prompts ------------------------------------------------------------------------------
    def retry_or_quit(self, problem: str, allow_skip: bool = False) -> bool:
        """Ask what to do; True means skip. Quitting raises :class:`RecordingAborted`."""
        options = "[r]etry, [s]kip this level, [q]uit" if allow_skip else "[r]etry, [q]uit"
        while True:
            answer = self.console.ask(f"{problem}. {options}? ").strip().lower()
            if answer in ("", "r", "retry"):
                return False
            if allow_skip and answer in ("s", "skip"):
                return True
            if answer in ("q", "quit"):
                raise RecordingAborted(problem)

    def ask_float(self, question: str, default: float | None) -> float:
        hint = f" [{default:.3g}]" if default is not None else ""
        while True:
            answer = self.console.ask(f"{question}{hint}: ").strip()
            if not answer and default is not None:
                return float(default)
            if not answer and not getattr(self.console, "interactive", True):
                raise InvalidInputError(
                    f"{question}: no answer and no default in non-interactive mode (--yes). Fix: run "
                    "interactively, or use --depth-from-channel with a depth sensor"
                )
            try:
                value = float(answer)
            except ValueError:
                self.console.say(f"  {answer!r} is not a number; type e.g. 4.5")
                continue
            if math.isfinite(value) and value >= 0:
                return value
            self.console.say("  the depth must be a non-negative number")

    def ask_int(self, question: str, default: int | None, required: bool = True) -> int | None:
        hint = f" [{default}]" if default is not None else ""
        while True:
            answer = self.console.ask(f"{question}{hint}: ").strip()
            if not answer:
                if default is not None:
                    return int(default)
                if not required:
                    return None
                if not getattr(self.console, "interactive", True):
                    raise InvalidInputError(f"{question}: no answer and no default in non-interactive mode")
                self.console.say("  an answer is required")
                continue
            if answer.isdigit():
                return int(answer)
            self.console.say(f"  {answer!r} is not a non-negative whole number")

    # -- output -------------------------------------------------------------------------------
    def write_session(self) -> None:
        write_session_files(
            self.paths, self.meta, self.plan, self.state.levels, self.state.wrinkles, notes_extra=self._notes()
        )

    def _notes(self) -> str:
        hello = self.pump.driver.hello
        stats = self.pump.driver.stats
        device = f"{hello.firmware} {hello.version} at {hello.rate_hz:g} Hz" if hello else "unknown firmware"
        cal = self.calibration
        return (
            f"Recorded with `shelljax acquire` ({device}); calibration {cal.sensor or '(unnamed)'} "
            f"{cal.model} β={cal.exponent:.3f}, range {cal.force_min:.3g}–{cal.force_max:.3g} N; "
            f"raw samples in {self.paths.samples.name} ({self.pump.log.n_rows} rows, "
            f"{stats.n_malformed} malformed lines skipped, {stats.n_reconnects} reconnects)."
        )


def write_session_files(
    paths: RecordingPaths,
    meta: dict,
    plan: AcquisitionPlan,
    levels: dict[int, list[dict]],
    wrinkles: dict[int, int],
    notes_extra: str = "",
) -> None:
    """Write the trials CSV and session TOML for the completed trials (atomically)."""
    completed = sorted(wrinkles)
    lines = ["trial,force,depth"]
    for trial in completed:
        for event in sorted(levels.get(trial, []), key=lambda e: e["target"]):
            lines.append(f"{trial},{event['force']!r},{event['depth']!r}")
    atomic_write_text(paths.trials_csv, "\n".join(lines) + "\n", durable=True)
    session = {"schema_version": 1}
    session.update({k: v for k, v in meta.items() if k not in ("geometry", "wall", "notes")})
    notes = "\n".join(n for n in (meta.get("notes", ""), notes_extra) if n)
    if notes:
        session["notes"] = notes
    session["geometry"] = meta["geometry"]
    session["wall"] = meta["wall"]
    session["indentation"] = {"force_unit": "N", "depth_unit": plan.depth_unit, "trials_csv": paths.trials_csv.name}
    session["wrinkles"] = {"counts": [int(wrinkles[t]) for t in completed]}
    header = "# Written by `shelljax acquire`; format: shelljax.session (docs/session-format.md).\n"
    atomic_write_text(paths.session, header + tomli_w.dumps(session), durable=True)
