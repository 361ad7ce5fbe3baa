"""What :mod:`shelljax.shell3d` offers other shelljax packages but not its users (not public API; it
may change without notice): ``membrane_strain``, the small-strain membrane strain of an inflated
scan that the realtime runtime shrinks it by."""

from ._rest import membrane_strain

__all__ = ["membrane_strain"]
