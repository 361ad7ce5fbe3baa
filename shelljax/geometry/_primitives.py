"""Synthetic meshes of test objects (metres): a ball and an inflatable hammer toy."""

from __future__ import annotations

import numpy as np
import trimesh

from .._errors import InvalidInputError

__all__ = [
    "HAMMER_HEAD_LENGTH",
    "HAMMER_HEAD_RADIUS",
    "HAMMER_HANDLE_LENGTH",
    "HAMMER_HANDLE_RADIUS",
    "HAMMER_POKE_POINT",
    "make_ball_mesh",
    "make_hammer_mesh",
]

#: Default hammer dimensions [m]: head is a capsule along x, centred at the origin.
HAMMER_HEAD_LENGTH = 0.32
HAMMER_HEAD_RADIUS = 0.08
#: Handle: capsule along −z from the head's axis; `HAMMER_HANDLE_LENGTH` is the part that sticks
#: out below the head (from z = −head_radius to the tip at z = −head_radius − handle_length).
HAMMER_HANDLE_LENGTH = 0.35
HAMMER_HANDLE_RADIUS = 0.03
#: Poke point [m] on the default hammer: apex of the head's striking face (the hemispherical end
#: cap at +x). The surface there is a sphere of radius `HAMMER_HEAD_RADIUS` = 0.08 m out to 90°
#: from the apex, so the local radius is 0.08 m for any fit_radius up to ~0.11 m.
HAMMER_POKE_POINT = (HAMMER_HEAD_LENGTH / 2.0, 0.0, 0.0)


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not (np.isfinite(value) and value > 0.0):
        raise InvalidInputError(f"{name} = {value!r} m must be a positive length")
    return value


def make_ball_mesh(radius: float, subdivisions: int = 4) -> trimesh.Trimesh:
    """Icosphere of the given radius [m], centred at the origin.

    All vertices lie exactly on the sphere; the flat faces lie inside it, so the enclosed volume
    is slightly below 4/3 π R³. `subdivisions` = 4 gives 2562 vertices (edge ≈ 0.06 R).
    """
    radius = _positive("radius", radius)
    if int(subdivisions) != subdivisions or not 0 <= subdivisions <= 7:
        raise InvalidInputError(f"subdivisions = {subdivisions!r} must be an integer in 0..7")
    return trimesh.creation.icosphere(subdivisions=int(subdivisions), radius=radius)


def make_hammer_mesh(
    head_length: float = HAMMER_HEAD_LENGTH,
    head_radius: float = HAMMER_HEAD_RADIUS,
    handle_length: float = HAMMER_HANDLE_LENGTH,
    handle_radius: float = HAMMER_HANDLE_RADIUS,
    *,
    sections: int = 48,
) -> trimesh.Trimesh:
    """Inflatable hammer toy [m]: capsule head along x on a capsule handle along −z.

    The head (total length `head_length`, radius `head_radius`) is centred at the origin; the
    handle (radius `handle_radius`) starts on the head's axis and sticks out `handle_length` below
    the head. The two capsules are merged by a boolean union (manifold3d), which yields a single
    closed, manifold surface. `sections` sets the latitude/longitude resolution of the head
    (the handle uses half). See `HAMMER_POKE_POINT` for a poke point with local radius
    `head_radius`.
    """
    head_length = _positive("head_length", head_length)
    head_radius = _positive("head_radius", head_radius)
    handle_length = _positive("handle_length", handle_length)
    handle_radius = _positive("handle_radius", handle_radius)
    if head_length <= 2.0 * head_radius:
        raise InvalidInputError(
            f"head_length = {head_length} m must exceed the head diameter {2 * head_radius} m"
        )
    if handle_radius >= head_radius:
        raise InvalidInputError(
            f"handle_radius = {handle_radius} m must be smaller than head_radius = {head_radius} m"
        )
    try:
        import manifold3d  # noqa: F401  (trimesh's boolean engine)
    except ImportError:
        raise InvalidInputError(
            "make_hammer_mesh needs the boolean engine manifold3d: pip install manifold3d "
            "(or load the bundled mesh: shelljax.geometry.bundled_mesh_path('hammer.stl'))"
        ) from None

    head = trimesh.creation.capsule(
        height=head_length - 2.0 * head_radius, radius=head_radius, count=[sections, sections]
    )
    head.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2.0, [0.0, 1.0, 0.0]))
    handle_total = head_radius + handle_length  # from the head's axis to the handle tip
    handle = trimesh.creation.capsule(
        height=handle_total - 2.0 * handle_radius,
        radius=handle_radius,
        count=[max(sections // 2, 8), max(sections // 2, 8)],
    )
    handle.apply_translation([0.0, 0.0, -handle_total / 2.0])
    hammer = trimesh.boolean.union([head, handle], engine="manifold")
    # manifold3d works in float32; return float64 coordinates with merged duplicates.
    hammer = trimesh.Trimesh(
        vertices=np.asarray(hammer.vertices, dtype=np.float64),
        faces=np.asarray(hammer.faces, dtype=np.int64),
        process=True,
    )
    if not (hammer.is_watertight and hammer.is_winding_consistent and hammer.volume > 0):
        raise RuntimeError("boolean union of the hammer parts is not a closed manifold")
    return hammer
