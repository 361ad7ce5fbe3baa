"""The measurement sessions (SI units): an indentation experiment on one object, and a rigid-surface press."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

# The deformed-shape observables of the paper's evaluation rig (docs/session-format.md), all [m]:
# height H of the ball's highest point above the ground, diameter D_u of the ridge circle around
# the dimple, diameter D_l of the ground contact disc, depth d of the sunken region (ridge height
# minus the poke point's height).
SHAPE_OBSERVABLES = ("height", "upper_diameter", "contact_diameter", "sunken_depth")


@dataclasses.dataclass(frozen=True)
class Session:
    """One measurement session, every quantity in SI units.

    Attributes:
        source: the session TOML file.
        object_name: free name of the object.
        radius: local radius of curvature R at the poke point [m] (given, or fitted on the mesh).
        radius_std: standard deviation of R [m] (0 when given without one).
        thickness: wall thickness h [m]; ``thickness_std`` its standard deviation [m].
        poisson_ratio: ν [-].
        trial: trial id of each indentation sample (one trial = one sweep of force levels).
        force: indenter force F of each sample [N].
        depth: indentation depth |w(0)| of each sample [m] (positive).
        wrinkle_counts: radial wrinkle count per trial, in order of ``trial_ids``; None if absent.
        onset_depth: depths at which wrinkles were first seen [m], None if absent (unreliable).
        manometer_gauge_pressure: manometer reading P_g [Pa] (calibration objects), else None.
        mass: total mass [kg] or None.
        mesh_path, poke_point [m], fit_radius [m]: mesh geometry, when R comes from a mesh.
        fit_rms_residual: rms distance of mesh vertices to the fitted sphere [m] (mesh only).
        enclosed_volume: volume enclosed by the mesh [m³] (watertight meshes only; the sealed gas).
        shape_trial: trial id of each shape point, one of ``trial_ids`` (a shape point is the
            deformed shape measured during one trial at one force); None without a [shape] table.
        shape_force: indenter force F at each shape point [N]; None without a [shape] table.
        shape: the measured deformed-shape observables, by name (those of ``SHAPE_OBSERVABLES``
            that the file gives): height H, upper_diameter D_u, contact_diameter D_l and
            sunken_depth d, each an array [m] with one value per shape point, NaN where it was
            not measured at that point; None without a [shape] table.
        input_files: sha256 of every file the session was read from, by path.
        rig_name: the name of the measuring chain (person, finger, sensor) it was recorded with,
            or None; a rig calibration refuses sessions of several.
    """

    source: Path
    object_name: str
    radius: float
    radius_std: float
    thickness: float
    thickness_std: float
    poisson_ratio: float
    trial: np.ndarray
    force: np.ndarray
    depth: np.ndarray
    wrinkle_counts: np.ndarray | None = None
    onset_depth: np.ndarray | None = None
    manometer_gauge_pressure: float | None = None
    mass: float | None = None
    mesh_path: Path | None = None
    poke_point: np.ndarray | None = None
    fit_radius: float | None = None
    fit_rms_residual: float | None = None
    enclosed_volume: float | None = None
    shape_trial: np.ndarray | None = None
    shape_force: np.ndarray | None = None
    shape: dict[str, np.ndarray] | None = None
    notes: str = ""
    input_files: dict[str, str] = dataclasses.field(default_factory=dict)
    rig_name: str | None = None

    @property
    def trial_ids(self) -> np.ndarray:
        """Distinct trial ids in order of first appearance."""
        _, first = np.unique(self.trial, return_index=True)
        return self.trial[np.sort(first)]

    @property
    def force_levels(self) -> np.ndarray:
        """Distinct force levels [N], ascending."""
        return np.unique(self.force)


@dataclasses.dataclass(frozen=True)
class RigidPress:
    """A rigid-surface press: the instrumented finger pressed on a rigid table, every quantity in SI.

    With no object in the way, the recorded depth is the finger pad's own compression plus the
    depth gauge's zero error, so it may be zero or slightly negative; it measures the rig (pad
    compliance, force sensor response) for ``shelljax rig calibrate``.

    Attributes:
        source: the press TOML file.
        object_name: what was pressed (e.g. "table").
        notes: free text.
        trial: trial id of each sample (int; one trial = one sweep of force levels).
        force: force F read by the sensor at each sample [N] (positive).
        depth: recorded depth of each sample [m]: the pad's compression plus the gauge's zero
            error (finite, any sign).
        sha256: hex sha256 of the TOML file's bytes (a trials CSV is not included).
        rig_name: the name of the measuring chain pressed, or None.
    """

    source: Path
    object_name: str
    notes: str
    trial: np.ndarray
    force: np.ndarray
    depth: np.ndarray
    sha256: str
    rig_name: str | None = None

    @property
    def trial_ids(self) -> np.ndarray:
        """Distinct trial ids in order of first appearance."""
        _, first = np.unique(self.trial, return_index=True)
        return self.trial[np.sort(first)]
