"""The perfectly matched layer's coefficients: the split-field update factors per axis
(`PML`), the rz r_hi layer's cylindrical correction (`RadialPML`) and the layer's cells as
disjoint boxes (`layer_boxes`), the only cells whose step carries split fields."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, Float

from .grid import Grid

if TYPE_CHECKING:
    from .coefficients import Edges


class RadialPML(eqx.Module):
    """The cylindrical correction of the r_hi PML of an rz grid, on its outer `width` rings.

    The split-field PML stretches d/dr -> d/dr / s_r (s_r = 1 + i sigma / omega) but a ring's
    metric (1/r) d/dr (r .) also needs the stretched radius r~ = r s_bar, s_bar = 1 + i sigma_bar /
    omega, sigma_bar(r) = (1/r) int_0^r sigma: the radial operator is
    ``(1 / (s_r s_bar)) (1/r) d/dr (r (s_bar / s_r) dP/dr)``
    ``= (1 / s_r) [(1/r) d/dr (r W) + C]``, with W = dP/dr / s_r the split form's radial flux and
    ``C = (s_bar' / s_bar) W = (sigma - sigma_bar) / (r (-i omega + sigma_bar)) W``: in time,
    ``dC/dt + sigma_bar C = (sigma - sigma_bar) W / r`` (W averaged to the ring centre), one
    auxiliary field on the layer's rings, added to the ring's flux divergence. Without it the layer
    reflects obliquely incident waves (-24 dB at 45 deg with 20 cells; with it -100 dB, the 2-D
    layer: -115 dB).
    `decay`, `drive`: C's update factors (1 - sigma_bar/2) / (1 + sigma_bar/2) and
    (sigma - sigma_bar) / (4 r (1 + sigma_bar/2)) (the flux averaged over the ring's two faces and
    two half steps).
    """

    decay: Float[Array, "1 w"]
    drive: Float[Array, "1 w"]
    width: int = eqx.field(static=True)


Box = tuple[tuple[int, int], ...]  # cell ranges [lo, hi) per axis


class PML(eqx.Module):
    """Split-field PML update factors (decay a, gain b) per axis, for cells and faces; `radial`:
    the cylindrical correction of an rz grid's r_hi layer (None otherwise). On a 3-D grid the z
    factors exist too and every array has rank 3 (broadcast along the other axes).

    `boxes`: the layer's cells as disjoint boxes (`layer_boxes`), the only cells that carry split
    fields; every other cell has a = b = 1 on itself and its faces and steps the leapfrog."""

    ax_cell: Float[Array, "nx 1"]
    bx_cell: Float[Array, "nx 1"]
    ax_face: Float[Array, "nx1 1"]
    bx_face: Float[Array, "nx1 1"]
    ay_cell: Float[Array, "1 ny"]
    by_cell: Float[Array, "1 ny"]
    ay_face: Float[Array, "1 ny1"]
    by_face: Float[Array, "1 ny1"]
    radial: RadialPML | None = None
    az_cell: Float[Array, "1 1 nz"] | None = None
    bz_cell: Float[Array, "1 1 nz"] | None = None
    az_face: Float[Array, "1 1 nz1"] | None = None
    bz_face: Float[Array, "1 1 nz1"] | None = None
    boxes: tuple[Box, ...] = eqx.field(static=True, default=())

    def factors(self, axis: int, where: str):
        """(a, b) of `axis` (0, 1, 2) at "cell" or "face"."""
        key = "xyz"[axis]
        return getattr(self, f"a{key}_{where}"), getattr(self, f"b{key}_{where}")


def pml_factors(grid: Grid, edges: Edges, dtype) -> PML:
    """The `PML` of `edges` on `grid`: sigma(d) = sigma_max (d/L)^order per axis, cells and faces."""
    L = edges.thickness_cells
    m = edges.pml_order
    smax = (m + 1) * grid.courant * math.log(1 / edges.pml_r0) / (2 * L)
    out: dict[str, Array] = {}
    ndim = len(grid.shape)
    ny = grid.shape[1]
    for axis, n in enumerate(grid.shape):
        key = "xyz"[axis]
        for where, faces in (("cell", False), ("face", True)):
            d = edges.layer_depth(n, f"{key}_lo", f"{key}_hi", faces=faces)
            sigma = smax * (d / L) ** m
            av = (1 - sigma / 2) / (1 + sigma / 2)
            bv = 1 / (1 + sigma / 2)
            shape = _axis_shape(axis, ndim)
            # converted on the host and copied (jnp.asarray of a NumPy array is an XLA program per shape)
            out[f"a{key}_{where}"] = jax.device_put(np.asarray(av.reshape(shape), dtype=np.dtype(dtype)))
            out[f"b{key}_{where}"] = jax.device_put(np.asarray(bv.reshape(shape), dtype=np.dtype(dtype)))
    radial = _radial_pml(ny, L, m, smax, dtype) if grid.kind.ring_metric and edges.y_hi == "pml" else None
    return PML(**out, radial=radial, boxes=layer_boxes(tuple(grid.shape), edges))


def layer_boxes(shape: tuple[int, ...], edges: Edges) -> tuple[Box, ...]:
    """The PML layer's cells as disjoint boxes: per axis in turn, the lo and hi slabs of that
    axis's layer, spanning the middle of the axes before it (whose slabs hold their own corners)
    and all of the axes after it (2-D: x slabs of full width, then y slabs between them). A cell
    outside every box has sigma = 0 on itself and on its faces (`Edges.layer_depth`: the layer
    is the `thickness_cells` outermost cells, its inner face undamped)."""
    L = edges.thickness_cells
    ndim = len(shape)
    lo = [min(L, n) if getattr(edges, f"{'xyz'[a]}_lo") == "pml" else 0 for a, n in enumerate(shape)]
    hi = [min(L, n - lo[a]) if getattr(edges, f"{'xyz'[a]}_hi") == "pml" else 0 for a, n in enumerate(shape)]
    boxes = []
    for axis in range(ndim):
        for r in ((0, lo[axis]), (shape[axis] - hi[axis], shape[axis])):
            box = tuple(
                r if a == axis else ((lo[a], shape[a] - hi[a]) if a < axis else (0, shape[a])) for a in range(ndim)
            )
            if all(h > l for l, h in box):
                boxes.append(box)
    return tuple(boxes)


def _radial_pml(ny: int, L: int, m: float, smax: float, dtype) -> RadialPML:
    """The `RadialPML` of an rz grid's r_hi layer. The layer starts at r0 = ny - L; sigma(r) =
    smax ((r - r0) / L)^m, sigma_bar(r) = (1/r) int sigma = smax L ((r - r0) / L)^(m+1) / ((m+1) r)."""
    r0 = ny - L
    rc = np.arange(ny - L, ny) + 0.5  # the layer's ring centres
    d = np.clip(rc - r0, 0, L) / L
    sig = smax * d**m
    sbar = smax * L * d ** (m + 1) / ((m + 1) * rc)
    row = lambda a: jax.device_put(np.asarray(a, float).reshape(1, -1).astype(np.dtype(dtype)))
    return RadialPML(
        decay=row((1 - sbar / 2) / (1 + sbar / 2)), drive=row((sig - sbar) / (4 * rc * (1 + sbar / 2))), width=L
    )


def _axis_shape(axis: int, ndim: int) -> tuple[int, ...]:
    """Broadcast shape of a 1-D profile along `axis` of a rank-`ndim` field."""
    return tuple(-1 if a == axis else 1 for a in range(ndim))
