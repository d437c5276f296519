"""The discretised space: units and grid, media, geometry, lattice coefficients, the operator.

Nothing here knows about time loops, sources or sensors (`difflattice.solver` builds on it).
"""

from .coefficients import PML, AxisymMetric, Edges, Lattice, RadialPML, build_lattice
from .grid import MAX_COURANT, MAX_COURANT_3D, PAPER_COURANT, Grid, check_courant, make_grid, stability_limit
from .kinds import AXISYMMETRIC, KINDS, PLANE, VOLUME, Axisymmetric, LatticeKind, Plane, Volume, as_kind
from .medium import MATERIALS, Material, Medium, air, homogeneous, material

__all__ = [
    "AXISYMMETRIC",
    "KINDS",
    "PLANE",
    "VOLUME",
    "Axisymmetric",
    "LatticeKind",
    "Plane",
    "Volume",
    "as_kind",
    "MATERIALS",
    "MAX_COURANT",
    "MAX_COURANT_3D",
    "PAPER_COURANT",
    "PML",
    "AxisymMetric",
    "Edges",
    "Grid",
    "Lattice",
    "Material",
    "Medium",
    "RadialPML",
    "air",
    "build_lattice",
    "check_courant",
    "homogeneous",
    "make_grid",
    "material",
    "stability_limit",
]
