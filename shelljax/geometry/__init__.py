"""Geometry data layer: mesh input (metres), enclosed volume, local radius of curvature, and the
sphere meshes every engine builds on (:func:`sphere_mesh`).

numpy + trimesh only; nothing here imports JAX.
"""

from ._curvature import DEFAULT_FIT_RADIUS_FRACTION, LocalCurvature, fit_local_sphere
from ._mesh import (
    LENGTH_UNITS,
    SUPPORTED_MESH_SUFFIXES,
    GeometryWarning,
    bundled_mesh_path,
    enclosed_volume,
    load_mesh,
    mesh_volume,
    signed_volume,
)
from ._primitives import (
    HAMMER_HANDLE_LENGTH,
    HAMMER_HANDLE_RADIUS,
    HAMMER_HEAD_LENGTH,
    HAMMER_HEAD_RADIUS,
    HAMMER_POKE_POINT,
    make_ball_mesh,
    make_hammer_mesh,
    sphere_mesh,
)
