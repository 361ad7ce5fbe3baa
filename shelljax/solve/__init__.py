"""Sparse Newton, host sparse direct solves, continuation and implicit differentiation."""

from ._continuation import continuation
from ._implicit import implicit_equilibrium
from ._newton import NewtonResult, newton
from ._sparse import SparseSolver, SparsityPattern, assemble_values, element_positions, release_factorizations
