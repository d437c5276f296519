"""Each lattice kind's far-field surface, chosen by the kind (one call, no branches on kinds).

`surface_for(kind)` gives the `FarFieldSurface` class written for a lattice kind (plane:
`farfield.BoxContour`, rz: `farfield_rz.CylinderSurface`, volume: `farfield3d.BoxSurface`);
`surface_around(grid, cells, gap, ...)` builds one around a transducer's and every object's cells
and refuses it, with the reason, where it would leave the grid or enter the absorbing layer.
The lattice kinds live in a layer below this one (`lattice/kinds.py` imports nothing from
`observe`), so this module looks the kind up (`SURFACES`, by the kind's class; a subclass of a
kind gets its parent's surface) and each surface names its kind (`FarFieldSurface.kind`). A new
surface: its class, and one entry in `SURFACES`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..lattice.kinds import Axisymmetric, LatticeKind, Plane, Volume, as_kind
from .farfield_base import FarFieldSurface


# each kind's surface is imported when asked for: a plane scene loads no 3-D module
def _box_contour() -> type[FarFieldSurface]:
    from .farfield import BoxContour

    return BoxContour


def _cylinder() -> type[FarFieldSurface]:
    from .farfield_rz import CylinderSurface

    return CylinderSurface


def _box_surface() -> type[FarFieldSurface]:
    from .farfield3d import BoxSurface

    return BoxSurface


SURFACES: dict[type[LatticeKind], Callable[[], type[FarFieldSurface]]] = {
    Plane: _box_contour,
    Axisymmetric: _cylinder,
    Volume: _box_surface,
}
"""The far-field surface of each built-in lattice kind (by the kind's class; loaded when asked for)."""


def surface_for(kind: LatticeKind | str) -> type[FarFieldSurface]:
    """The far-field surface class of a lattice kind (or its name)."""
    k = as_kind(kind)
    for cls in type(k).__mro__:
        if cls in SURFACES:
            return SURFACES[cls]()
    raise ValueError(
        f"no far-field surface for the {k.label} lattice ({type(k).__name__}): write a FarFieldSurface "
        "subclass with kind = that kind and add it to observe.surfaces.SURFACES (docs/architecture.md)"
    )


def surface_around(
    grid,
    cells,
    gap: int,
    *,
    objects: Sequence[np.ndarray] = (),
    baffle: str | None = None,
    margin: int = 0,
) -> FarFieldSurface:
    """The far-field surface of `grid`'s kind `gap` cells around `cells` (n, ndim) and every
    object's cells in `objects` (so that it crosses none), with `baffle` the low window side that
    carries no surface (e.g. "z_lo" for a disc on the rz lattice's rigid baffle); refused where it
    would not lie inside the grid and outside a `margin`-cell absorbing layer."""
    cls = surface_for(grid.kind)
    ndim = cls.kind.ndim
    enclosed = np.concatenate(
        [np.asarray(cells).reshape(-1, ndim), *(np.asarray(o).reshape(-1, ndim) for o in objects)]
    )
    surface = cls.around(enclosed, gap, baffle)
    for o in objects:
        surface.check_encloses(o)
    surface.check_inside(grid, margin)
    return surface
