"""The window around a transducer: absorbing layer, margin, far-field contour, gap, source.

Fit transfers, design problems and accuracy cases all lay out a grid the same way along each
axis, from the low end to the high end:

    [layer_lo][pad_lo] contour_lo [gap][back] source [fwd][gap] contour_hi [pad_hi][layer_hi]

`layer` is the absorbing layer (PML or sponge) in cells, `pad` the cells strictly between the
layer and the contour's line (the contour's stencil cells plus a margin; a window symmetric about
its source has pad_lo = pad_hi), `gap` the index steps from the contour's line to the source's
extent (`back` cells behind its anchor cell, `fwd` in front). A
*closed* low end (the axis of an r-z lattice, or a rigid baffle in the source's plane) has no
layer, pad or gap: the contour starts on it and the source's anchor is cell 0. A `reach` makes
the interior at least that many cells long (a scan line or a far-field range beyond the
contour). `Window` holds one `Span` per axis and gives the grid shape, the source's anchor
cell, the contour's box and the slices of the interior (inside the layers).

The arithmetic was written once per caller before (six copies, each with its own pads); the
callers keep their numbers by passing their pads (see docs/architecture.md).
"""

from __future__ import annotations

from dataclasses import dataclass

from .kinds import LatticeKind


@dataclass(frozen=True)
class Span:
    """One axis of a window, in cells (see the module docstring for the order)."""

    layer_lo: int
    pad_lo: int
    gap: int
    back: int
    fwd: int
    pad_hi: int
    layer_hi: int
    closed_lo: bool = False
    reach: int = 0
    """Minimum interior length (cells from index 0 to the high layer)."""

    def __post_init__(self) -> None:
        for name in ("layer_lo", "pad_lo", "gap", "back", "fwd", "pad_hi", "layer_hi", "reach"):
            if getattr(self, name) < 0:
                raise ValueError(f"Span.{name} = {getattr(self, name)} must be >= 0 cells")
        if self.closed_lo and (self.layer_lo or self.pad_lo or self.back):
            raise ValueError("a closed low end (axis or baffle) has no layer, pad or cells behind the source")

    @classmethod
    def open(cls, *, gap: int, layer: int, pad: int, back: int = 0, fwd: int = 0, pad_hi: int | None = None) -> Span:
        """Open at both ends: the same layer each side, `pad` (and `pad_hi`, default `pad`)."""
        return cls(layer, pad, gap, back, fwd, pad if pad_hi is None else pad_hi, layer)

    @classmethod
    def closed(cls, *, gap: int, layer: int, pad: int, fwd: int = 0) -> Span:
        """Closed at the low end (r-z axis, rigid baffle): the source's anchor on cell 0."""
        return cls(0, 0, gap, 0, fwd, pad, layer, closed_lo=True)

    def with_reach(self, reach: int) -> Span:
        """This span with an interior at least `reach` cells long."""
        return Span(
            self.layer_lo,
            self.pad_lo,
            self.gap,
            self.back,
            self.fwd,
            self.pad_hi,
            self.layer_hi,
            self.closed_lo,
            max(self.reach, int(reach)),
        )

    @property
    def contour_lo(self) -> int:
        """Index of the contour's low line (0 on a closed end)."""
        return 0 if self.closed_lo else self.layer_lo + self.pad_lo

    @property
    def source(self) -> int:
        """Index of the source's anchor cell."""
        return 0 if self.closed_lo else self.contour_lo + self.gap + self.back

    @property
    def contour_hi(self) -> int:
        """Index of the contour's high line."""
        return self.source + self.fwd + self.gap

    @property
    def n(self) -> int:
        """Cells along the axis."""
        return max(self.contour_hi + 1 + self.pad_hi, self.reach) + self.layer_hi

    @property
    def interior(self) -> slice:
        """The cells inside the absorbing layers."""
        return slice(self.layer_lo, self.n - self.layer_hi)


@dataclass(frozen=True)
class Window:
    """A grid window: one `Span` per array axis (axis order of the lattice kind)."""

    spans: tuple[Span, ...]

    @classmethod
    def around(
        cls,
        kind: LatticeKind,
        *,
        gap: int,
        layer: int,
        pad: int,
        extent: tuple[tuple[int, int], ...],
        pad_hi: int | None = None,
    ) -> Window:
        """The window of a source `extent` ((back, fwd) cells per axis) with a contour `gap`
        cells around it, `pad` cells (low side; `pad_hi` high side, default `pad`) between the
        contour and an absorbing layer `layer` cells thick. On a ring-metric kind the last
        (radial) axis is closed at the axis: its `back` is the mirror image of `fwd` (0 or
        `fwd`: a source centred on the axis)."""
        if len(extent) != kind.ndim:
            raise ValueError(f"extent has {len(extent)} axes, a {kind.label} lattice {kind.ndim}")
        spans = []
        for i, (back, fwd) in enumerate(extent):
            if kind.ring_metric and i == kind.ndim - 1:
                if back not in (0, fwd):
                    raise ValueError(
                        f"a radial extent is symmetric about the axis: back = {back} must be 0 or fwd = {fwd}"
                    )
                spans.append(Span.closed(gap=gap, layer=layer, pad=pad if pad_hi is None else pad_hi, fwd=fwd))
            else:
                spans.append(Span.open(gap=gap, layer=layer, pad=pad, back=back, fwd=fwd, pad_hi=pad_hi))
        return cls(tuple(spans))

    @property
    def shape(self) -> tuple[int, ...]:
        """Grid shape, cells."""
        return tuple(s.n for s in self.spans)

    @property
    def source(self) -> tuple[int, ...]:
        """The source's anchor cell."""
        return tuple(s.source for s in self.spans)

    @property
    def box(self) -> tuple[tuple[int, int], ...]:
        """The contour's (low, high) line on each axis."""
        return tuple((s.contour_lo, s.contour_hi) for s in self.spans)

    @property
    def interior(self) -> tuple[slice, ...]:
        """Slices of the cells inside the absorbing layers."""
        return tuple(s.interior for s in self.spans)

    def replace(self, axis: int, span: Span) -> Window:
        """This window with `span` on `axis`."""
        spans = list(self.spans)
        spans[axis] = span
        return Window(tuple(spans))
