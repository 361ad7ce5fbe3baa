"""Real-time runtime: explicit symplectic stepping of the 3D shell's physics with compiled
(Numba) per-element kernels, contact against planes (the reference's barrier, continued by a
spring) and a moving collider, an automatic stable Δt and a blow-up guard (SI units). See
docs/realtime.md.

Quick start::

    from shelljax import realtime as rt
    from shelljax.physics import Plane, ShellProperties
    props = ShellProperties(gauge_pressure=1300.0, young_modulus=2.34e6, thickness=0.9e-3,
                            poisson_ratio=0.4, radius=0.13)
    ball = rt.RealtimeShell.ball(props, mass=0.8, n_faces=2000, planes=[Plane([0, 0, 0], [0, 0, 1])])
    ball.drop(0.5)
    frame = ball.frame(1 / 60)      # substeps at the stable Δt; raises rt.BlowUpError if unstable
    scan = ball.embed(fine_vertices)  # a finer display mesh carried by the simulated one
    shown = scan.positions(ball.x)    # (N, 3) [m], each frame
"""

from ._embedding import DisplayEmbedding
from ._errors import BlowUpError
from ._model import RealtimeShell
from ._parts import Body, Buffers, Contact, Geometry, Material, Planes
from ._records import SAFETY, Collider, Frame, RealtimeOptions, RestShape
from ._stable import StableStep

__all__ = [
    "SAFETY",
    "BlowUpError",
    "Body",
    "Buffers",
    "Collider",
    "Contact",
    "DisplayEmbedding",
    "Frame",
    "Geometry",
    "Material",
    "Planes",
    "RealtimeOptions",
    "RealtimeShell",
    "RestShape",
    "StableStep",
]
