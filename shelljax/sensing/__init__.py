"""Wearable force-sensor acquisition: serial protocol, driver, calibration, emulator, recording.

Data layer: numpy and pyserial only. Protocol and file formats: docs/sensing.md.
"""

from ._calibrate import DEFAULT_MASSES, calibrate_sensor, emulated_calibration
from ._calibration import (
    ABOVE_RANGE,
    ADC_SATURATED,
    BELOW_RANGE,
    OK,
    ForceReading,
    LoadPoint,
    SensorCalibration,
    fit_calibration,
    load_point,
)
from ._capture import LOG_COLUMNS, HumanOperator, Operator, Pump, Reading, SampleLog, read_sample_log
from ._console import AutoConsole, Console, ScriptedConsole, TerminalConsole
from ._driver import DEFAULT_BAUD, DriverStats, Sample, SerialSensor
from ._emulator import (
    DepthGauge,
    EmulatedDevice,
    EmulatedOperator,
    EmulatedPort,
    FilmSensor,
    Faults,
    PokedBall,
    PtyLink,
)
from ._protocol import (
    MAX_LINE_BYTES,
    PROTOCOL_VERSION,
    Hello,
    MalformedLine,
    RawSample,
    StreamParser,
    checksum,
    format_hello,
    format_sample,
    parse_line,
)
from ._recording import (
    AcquisitionPlan,
    AcquisitionResult,
    RecordingAborted,
    RecordingPaths,
    acquire,
    write_session_files,
)
