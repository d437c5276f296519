"""The transducer window (lattice/window.py): layer, pad, contour, gap and source along each axis,
counted cell by cell, and the callers' layouts it replaced (their numbers, kept)."""

from __future__ import annotations

import pytest

from difflattice.lattice.kinds import AXISYMMETRIC, PLANE
from difflattice.lattice.window import Span, Window


def _cells(span: Span) -> str:
    """The axis drawn cell by cell: L layer, p pad, C contour line, g gap/extent, S source."""
    row = ["g"] * span.n
    for i in range(span.layer_lo):
        row[i] = "L"
    for i in range(span.n - span.layer_hi, span.n):
        row[i] = "L"
    for i in range(span.layer_lo, span.contour_lo):
        row[i] = "p"
    for i in range(span.contour_hi + 1, span.n - span.layer_hi):
        row[i] = "p"
    row[span.contour_lo] = row[span.contour_hi] = "C"
    row[span.source] = "S"
    return "".join(row)


def test_open_span_counts_every_cell():
    """Layer 2, pad 1, the contour line, the source's extent (1 cell behind its anchor, 2 in
    front) `gap` = 2 index steps from the contour on each side, pad 1, layer 2."""
    s = Span.open(gap=2, layer=2, pad=1, back=1, fwd=2)
    assert _cells(s) == "LLpCggSgggCpLL"
    assert (s.contour_lo, s.source, s.contour_hi, s.n) == (3, 6, 10, 14)
    assert s.interior == slice(2, 12)


def test_symmetric_window_is_centred_on_its_source():
    """pad_lo = pad_hi gives 2 (layer + pad + gap) + 1 cells with the source in the middle."""
    s = Span.open(gap=3, layer=5, pad=2)
    assert s.n == 2 * (5 + 2 + 3) + 1
    assert s.source == s.n // 2


def test_closed_axis_starts_on_the_contour_and_source():
    """A closed low end (rz axis, baffle): no layer, pad or gap below; cell 0 is the source."""
    s = Span.closed(gap=2, layer=3, pad=1, fwd=4)
    assert _cells(s) == "SgggggCpLLL"
    assert (s.contour_lo, s.source, s.contour_hi) == (0, 0, 6)


def test_reach_lengthens_only_the_interior():
    s = Span.open(gap=1, layer=4, pad=0)
    assert s.with_reach(2).n == s.n  # shorter than the window: no change
    longer = s.with_reach(20)
    assert longer.n == 20 + 4
    assert (longer.contour_lo, longer.source, longer.contour_hi) == (s.contour_lo, s.source, s.contour_hi)


def test_window_around_a_source_by_kind():
    """Plane: both axes open; rz: the radial axis closed at the axis (the design problem's layout:
    pad 3 below the contour, 2 above)."""
    plane = Window.around(PLANE, gap=4, layer=12, pad=3, pad_hi=2, extent=((2, 5), (3, 3)))
    assert plane.shape == (12 + 3 + 4 + 2 + 5 + 4 + 1 + 2 + 12, 12 + 3 + 4 + 3 + 3 + 4 + 1 + 2 + 12)
    assert plane.source == (12 + 3 + 4 + 2, 12 + 3 + 4 + 3)
    assert plane.box == ((15, 30), (15, 29))
    rz = Window.around(AXISYMMETRIC, gap=4, layer=12, pad=3, pad_hi=2, extent=((2, 5), (3, 3)))
    assert rz.shape == (plane.shape[0], 3 + 4 + 1 + 2 + 12)
    assert rz.source == (plane.source[0], 0)
    assert rz.box[1] == (0, 7)
    assert rz.interior == (slice(12, plane.shape[0] - 12), slice(0, 3 + 4 + 1 + 2))


def test_bad_windows_are_refused_with_the_reason():
    with pytest.raises(ValueError, match="pad_lo = -1"):
        Span.open(gap=1, layer=2, pad=-1)
    with pytest.raises(ValueError, match="closed low end"):
        Span(1, 0, 1, 0, 0, 0, 1, closed_lo=True)
    with pytest.raises(ValueError, match="3 axes"):
        Window.around(PLANE, gap=1, layer=1, pad=1, extent=((0, 0),) * 3)
    with pytest.raises(ValueError, match="symmetric about the axis"):
        Window.around(AXISYMMETRIC, gap=1, layer=1, pad=1, extent=((0, 0), (1, 2)))
