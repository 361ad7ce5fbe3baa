"""What :mod:`shelljax.dynamics` offers other shelljax packages but not its users (not public API;
it may change without notice): the scenario previews' renderer (the scenario figures and the
viewer's GIF draw with it) and a trajectory's plane levels."""

from ._output import plane_levels
from ._render import contact_faces, draw_shell, face_strain, strain_colourbar, strain_limit, strain_rgba

__all__ = [
    "contact_faces",
    "draw_shell",
    "face_strain",
    "plane_levels",
    "strain_colourbar",
    "strain_limit",
    "strain_rgba",
]
