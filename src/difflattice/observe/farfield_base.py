"""The far-field surface protocol: what every Kirchhoff-Helmholtz surface offers its callers.

A far-field surface is a closed surface of cell faces around the sources (and every object) of a
lattice of one kind. The simulator records phasors at the drive frequency on the cell pair
across each face (`cells`: the inner cells, then the outer ones); the surface turns them into
the pressure outside (`field_at`), on a lobe at a range or in the far-field limit (`far_field`).
`observe.surfaces` gives each lattice kind its surface (`surface_for`, `surface_around`).

Conventions shared by every surface:
- positions in cells are metres / dx (the kind's coordinates: on the plane and in the volume
  the centre of cell 0 is the origin, on the rz lattice the axis and the z = 0 window face);
- a lobe lies in the plane of array axes 0 and 1, its angles (degrees) counted from axis 0
  towards axis 1 (plane: from +x towards +y; rz: from the +z axis; volume: from +x towards +y
  unless another plane is given);
- `far_field(..., range_m=None)` is the far-field pattern F with p(r) ~ F exp(i k r) / r^((d-1)/2)
  (d = 2 on the plane, 3 on the rz lattice and in the volume; r in cells from the centre);
- `dispersion=None` keeps each surface's own default ("lattice" on the plane and in the volume,
  "continuum" on the rz lattice, as their transforms always had).

A new surface (for a new lattice kind) subclasses `FarFieldSurface`, sets `kind`, implements the
abstract methods and is added to `observe.surfaces.SURFACES` (docs/architecture.md).
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from typing import TYPE_CHECKING, ClassVar, Self

import equinox as eqx
import numpy as np

if TYPE_CHECKING:
    from ..lattice.kinds import LatticeKind


class FarFieldSurface(eqx.Module):
    """A closed Kirchhoff-Helmholtz surface of cell faces (abstract).

    Subclasses are frozen equinox modules whose fields are static ints (the surface's box) and set
    `kind`, the lattice kind the surface is written for.
    """

    kind: ClassVar[LatticeKind]
    """The lattice kind whose grids this surface lies on."""

    # --- geometry -------------------------------------------------------------------------------
    @classmethod
    @abc.abstractmethod
    def from_box(cls, lo: Sequence[int], hi: Sequence[int], baffle: str | None = None) -> Self:
        """The surface whose inner cells bound the box [lo, hi] (inclusive, one entry per array
        axis); `baffle` names a window side ("<axis name>_lo") that carries no surface."""

    @property
    @abc.abstractmethod
    def box(self) -> tuple[tuple[int, ...], tuple[int, ...]]:
        """(lo, hi): the box of the inner cells per array axis, inclusive."""

    @property
    @abc.abstractmethod
    def open_sides(self) -> tuple[tuple[int, int], ...]:
        """(axis, -1 or +1) of the sides that carry no surface (a baffle, the rz axis): what lies
        beyond them is the surface's image, not outside it."""

    @abc.abstractmethod
    def samples(self) -> tuple[np.ndarray, ...]:
        """(inner (M, ndim), outer (M, ndim), points (M, ndim), normals (M, ndim), ...): the face
        samples (cells, positions in cells, outward unit normals)."""

    @property
    def cells(self) -> np.ndarray:
        """(2M, ndim) phasor cells to record: every sample's inner cell, then its outer cell."""
        inner, outer, *_ = self.samples()
        return np.concatenate([inner, outer], axis=0)

    @property
    def n_samples(self) -> int:
        """M, the number of face samples (half the phasor cells)."""
        return len(self.samples()[0])

    @property
    def span_cells(self) -> tuple[float, ...]:
        """The surface's physical extent per array axis in cells (a run must cross it)."""
        lo, hi = self.box
        return tuple(float(b - a) for a, b in zip(lo, hi))

    @classmethod
    def around(cls, cells, gap: int, baffle: str | None = None) -> Self:
        """The surface `gap` cells around a set of cells (n, ndim), e.g. a transducer's and every
        object's; with `baffle` the box starts at that (low) window side."""
        ndim = cls.kind.ndim
        c = np.asarray(cells).reshape(-1, ndim)
        lo = [int(v) for v in c.min(0) - gap]
        hi = [int(v) for v in c.max(0) + gap]
        if baffle is not None:
            axis, side = cls.side(baffle)
            if side > 0:
                raise ValueError(
                    f"baffle = {baffle!r} on a high window side: give the surface explicitly "
                    f"({cls.__name__}.from_box(lo, hi, baffle=...), hi at the last cell)"
                )
            lo[axis] = 0
        return cls.from_box(lo, hi, baffle)

    @classmethod
    def side(cls, name: str) -> tuple[int, int]:
        """(axis, -1 or +1) of a window side named "<axis name>_lo" / "_hi" on this kind."""
        names = cls.kind.axis_names
        allowed = [f"{a}_{s}" for a in names for s in ("lo", "hi")]
        if name not in allowed:
            raise ValueError(f"side = {name!r}; allowed on a {cls.kind.label} grid: {', '.join(allowed)}")
        return names.index(name[:-3]), (-1 if name.endswith("lo") else 1)

    # --- checks ---------------------------------------------------------------------------------
    def check_inside(self, grid, margin: int = 0) -> None:
        """Refuse a surface whose outer cells leave the grid (or its shape) or enter a
        `margin`-cell absorbing layer; an open side may lie on the window face. A grid of another
        kind is refused too."""
        kind = getattr(grid, "kind", None)
        if kind is not None and kind != self.kind:
            raise ValueError(
                f"{type(self).__name__} is the far-field surface of {self.kind.label} grids, got kind = {kind.name!r}: "
                "use observe.surfaces.surface_for(grid.kind)"
            )
        shape = tuple(grid.shape) if hasattr(grid, "shape") else tuple(grid)
        lo, hi = self.box
        open_ = set(self.open_sides)
        for a in range(len(shape)):
            lo_ok = lo[a] - 1 >= margin or (a, -1) in open_
            hi_ok = hi[a] + 1 < shape[a] - margin or (a, 1) in open_
            if not (lo_ok and hi_ok):
                raise ValueError(self._outside_message(shape, margin))

    def _outside_message(self, shape, margin: int) -> str:
        lo, hi = self.box
        return (
            f"far-field surface lo = {tuple(lo)}, hi = {tuple(hi)} (plus its outer cells) must lie inside "
            f"the {tuple(shape)} grid and outside the {margin}-cell absorbing layer: shrink the gap or "
            "enlarge the grid"
        )

    def crossing(self, cells) -> np.ndarray:
        """The cells (n, ndim) that are not strictly inside the surface: on its recorded cells or
        beyond them (an open side bounds nothing)."""
        c = np.asarray(cells).reshape(-1, self.kind.ndim)
        lo, hi = self.box
        ok = np.ones(len(c), bool)
        open_ = set(self.open_sides)
        for a in range(c.shape[1]):
            if (a, -1) not in open_:
                ok &= c[:, a] > lo[a]
            if (a, 1) not in open_:
                ok &= c[:, a] < hi[a]
        return c[~ok]

    def check_encloses(self, cells, what: str = "object") -> None:
        """Refuse a surface that does not enclose `cells` (e.g. an object's): the integral over a
        surface through an object is not a free-space field, so its lobe would be wrong."""
        bad = self.crossing(cells)
        if len(bad):
            lo, hi = self.box
            raise ValueError(
                f"the far-field surface lo = {tuple(lo)}, hi = {tuple(hi)} crosses the {what}: "
                f"{len(bad)} of its cells (e.g. {tuple(int(v) for v in bad[0])}) lie on or outside it; "
                "enclose it (a larger gap or surface) or leave it out"
            )

    # --- transforms -----------------------------------------------------------------------------
    @abc.abstractmethod
    def field_at(self, phasors, grid, points_cells, **kwargs):
        """Complex pressure at points outside the surface (positions in cells), from phasors
        ordered as `cells` (keyword arguments: `dispersion`, `frequency_hz`, `c_lattice`)."""

    @abc.abstractmethod
    def far_field(
        self,
        phasors,
        grid,
        angles_deg,
        *,
        range_m: float | None = None,
        centre_cells=None,
        plane=None,
        **kwargs,
    ):
        """The lobe at `angles_deg` (from axis 0 towards axis 1): the complex pressure at
        `range_m` metres from `centre_cells` (default: the surface's centre; on the rz lattice a
        point of the axis), or with `range_m=None` the far-field pattern (module docstring). `plane` = (axis, in_plane) direction vectors picks another lobe plane
        where the kind has one (the volume). Keyword arguments: `dispersion`, `frequency_hz`,
        `c_lattice`."""

    def lobe_centre_cells(self, source_cells, centre_m, dx_m: float) -> tuple[float, ...]:
        """The point a scene's lobe is measured from: the mean of the source's cells (its place
        on the lattice); the rz surface takes the transducer's face centre on the axis."""
        return tuple(float(v) for v in np.asarray(source_cells, float).reshape(-1, self.kind.ndim).mean(0))


def split_pairs(phasors, m: int, what: str = "surface phasors (inner then outer cells)"):
    """(p, dp/dn) on the faces from the 2M pair phasors: their mean and their difference."""
    if phasors.shape[-1] != 2 * m:
        raise ValueError(f"expected {2 * m} {what}, got {phasors.shape[-1]}")
    p_in, p_out = phasors[..., :m], phasors[..., m:]
    return 0.5 * (p_in + p_out), p_out - p_in


def no_plane(plane, label: str) -> None:
    """Refuse a lobe plane where the kind has only one."""
    if plane is not None:
        raise ValueError(f"plane = {plane!r}: a {label} lobe lies in the grid's own plane; leave plane out")
