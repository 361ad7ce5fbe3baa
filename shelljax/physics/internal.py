"""What the physics layer lends the packages above it beyond its laws: the checks of a law's
parameters, one-line ``InvalidInputError`` naming the field and a fix, so every law refuses bad
input in the same words. Not for users; the public names are in ``shelljax.physics``.
"""

from ._contact import check_nonnegative, check_positive

__all__ = ["check_nonnegative", "check_positive"]
