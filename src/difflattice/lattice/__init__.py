"""The discretised space: units and grid, media, geometry, lattice coefficients, the operator.

Nothing here knows about time loops, sources or sensors (`difflattice.solver` builds on it).
"""

from .coefficients import PML, Edges, Lattice, build_lattice
from .grid import MAX_COURANT, PAPER_COURANT, Grid, check_courant, make_grid
from .medium import MATERIALS, Material, Medium, air, homogeneous, material

__all__ = [
    "MATERIALS", "MAX_COURANT", "PAPER_COURANT", "PML", "Edges", "Grid", "Lattice", "Material",
    "Medium", "air", "build_lattice", "check_courant", "homogeneous", "make_grid", "material",
]
