"""The far-field surfaces of every lattice kind through their one protocol (`FarFieldSurface`,
`observe.surfaces`), against exact fields (no simulation).

Each case samples the exact field of a point source (a line source on the plane: (i/4) H0(k R);
a monopole on the rz axis and in the volume: exp(i k R) / (4 pi R); with its mirror image when the
surface stands on a rigid baffle) at the surface's recorded cells, and asks the surface for the
field at points outside it (`field_at`) and for the far-field pattern (`far_field`, range None:
p ~ F exp(i k r) / r^((d-1)/2), so F = amp(k) sum_s exp(-i k u . (s - c)), amp = 1 / (4 pi) in 3-D
and (i/4) sqrt(2 / (pi k)) exp(-i pi / 4) on the plane, the leading term of the Hankel function).

Where the tolerances come from: the transform's own error is the two-cell sampling of each face,
the same on every kind: the mean of the pair is off by (k h)^2 / 8 and the difference by
(k h)^2 / 24 along the normal, and the faces are summed by the midpoint rule, so the plane and
volume cases are held to (k h)^2 / 6 (1.6 % at 20, 0.41 % at 40 cells per wavelength) and must
converge at second order (each error falls more than 3x from 20 to 40); the rz cases keep the
bound their test always had (2 % at 20 cells per wavelength, the larger error at least 4x smaller
at 40: the ring quadrature adds a (k dx)^2 / 8 term of its own). The plane adds the Hankel
expansion's 2e-7 (`test_farfield_lobe.test_hankel_expansion_against_scipy`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.special as sp

from difflattice.lattice.grid import make_grid
from difflattice.lattice.kinds import AXISYMMETRIC, PLANE, VOLUME, Axisymmetric, LatticeKind, Plane
from difflattice.observe.farfield import BoxContour
from difflattice.observe.farfield3d import BoxSurface, directions_in_plane
from difflattice.observe.farfield_base import FarFieldSurface
from difflattice.observe.farfield_rz import CylinderSurface
from difflattice.observe.surfaces import SURFACES, surface_around, surface_for


def _grid(k):
    # the transforms need omega (rad/step), the courant number and metres -> cells (1 cell = 1 m)
    return SimpleNamespace(
        hz_to_lattice_omega=lambda f: 0.5 * k, frequency_hz=1.0, courant=0.5, m_to_cells=lambda r: r, dx_m=1.0
    )


def _unit(angles_deg, plane):
    """Unit directions (a, ndim) of a lobe: in the plane of axes 0 and 1, or a 3-D `plane`."""
    if plane is not None:
        return directions_in_plane(*plane, angles_deg)
    t = np.radians(np.asarray(angles_deg, float))
    return np.stack([np.cos(t), np.sin(t)], 1)


@dataclass(frozen=True)
class Case:
    """A point source (and its baffle image) inside one kind's surface."""

    kind: LatticeKind
    surface: Callable[[int], FarFieldSurface]  # cells per wavelength -> surface
    sources: Callable[[int], list]  # cells per wavelength -> source positions (cells), image included
    near: Callable[[int, list], np.ndarray]  # (cells per wavelength, sources) -> field points (cells)
    lobes: tuple  # (angles_deg, plane) of the pattern's lobes
    centre: Callable[[int], object] = lambda ppw: None  # the pattern's centre (None: the surface's own)
    tol: Callable[[float], float] = lambda k: k**2 / 6  # bound on both errors, per wavenumber (rad/cell)
    tol_at_40: bool = True  # the bound also holds at 40 cells per wavelength
    ratio_each: float | None = 3.0  # each error falls by more than this from 20 to 40
    ratio_max: float | None = None  # the larger error falls by more than this

    def green(self, k, R):
        if self.kind.ndim == 2 and not self.kind.ring_metric:
            return 0.25j * sp.hankel1(0, k * R)
        return np.exp(1j * k * R) / (4 * math.pi * R)

    def amplitude(self, k):
        if self.kind.ndim == 2 and not self.kind.ring_metric:
            return 0.25j * math.sqrt(2 / (math.pi * k)) * np.exp(-0.25j * math.pi)
        return 1 / (4 * math.pi)

    def field(self, k, x, sources):
        return sum(self.green(k, np.linalg.norm(np.asarray(x, float) - s, axis=-1)) for s in sources)


def _on_axis(z):
    return [np.array([z, 0.0])]


CASES = {
    # a line source off the contour's centre (new: the plane's transform against the exact field)
    "plane": Case(
        PLANE,
        lambda ppw: BoxContour(0, 30, 0, 24),
        lambda ppw: [np.array([12.3, 10.2])],
        lambda ppw, s: s[0] + 400.0 * _unit(np.linspace(-180, 180, 25), None),
        ((np.linspace(-180, 180, 25), None),),
        centre=lambda ppw: (12.3, 10.2),
    ),
    # was test_axisym_observe.test_kirchhoff_transform_of_a_monopole[free]
    "rz": Case(
        AXISYMMETRIC,
        lambda ppw: CylinderSurface(ppw, 3 * ppw, int(1.25 * ppw)),
        lambda ppw: _on_axis(1.87 * ppw),
        lambda ppw, s: np.array([[10.0 * ppw, 0.0], [7.5 * ppw, 4.0 * ppw], [15.0 * ppw, 15.0 * ppw]]),
        ((np.arange(0.0, 91.0, 5.0), None),),
        tol=lambda k: 0.02,
        tol_at_40=False,
        ratio_each=None,
        ratio_max=4.0,
    ),
    # was test_axisym_observe.test_kirchhoff_transform_of_a_monopole[baffled]
    "rz-baffled": Case(
        AXISYMMETRIC,
        lambda ppw: CylinderSurface(0, int(1.5 * ppw), int(1.25 * ppw), baffled=True),
        lambda ppw: _on_axis(0.31 * ppw) + _on_axis(-0.31 * ppw),
        lambda ppw, s: np.array([[10.0 * ppw, 0.0], [7.5 * ppw, 4.0 * ppw], [15.0 * ppw, 15.0 * ppw]]),
        ((np.arange(0.0, 91.0, 5.0), None),),
        tol=lambda k: 0.02,
        tol_at_40=False,
        ratio_each=None,
        ratio_max=4.0,
    ),
    # was test_3d_farfield.test_point_source_range_and_pattern
    "volume": Case(
        VOLUME,
        lambda ppw: BoxSurface((0, 0, 0), (30, 24, 20)),
        lambda ppw: [np.array([12.3, 10.2, 9.7])],
        lambda ppw, s: (
            s[0]
            + 400.0
            * np.concatenate(
                [
                    directions_in_plane([1, 0, 0], [0, 1, 0], np.linspace(-180, 180, 25)),
                    directions_in_plane([0, 0, 1], [1, 1, 0], np.linspace(-90, 90, 13)),
                ]
            )
        ),
        (
            (np.linspace(-180, 180, 25), ([1, 0, 0], [0, 1, 0])),
            (np.linspace(-90, 90, 13), ([0, 0, 1], [1, 1, 0])),
        ),
        centre=lambda ppw: np.array([12.3, 10.2, 9.7]),
    ),
    # was test_3d_farfield.test_baffled_box_uses_the_image (there at 40 cells per wavelength only)
    "volume-baffled": Case(
        VOLUME,
        lambda ppw: BoxSurface((0, 0, 0), (20, 24, 22), baffle="x_lo"),
        lambda ppw: [np.array([1.3, 11.6, 10.2]), np.array([-2.3, 11.6, 10.2])],
        lambda ppw, s: (
            np.array([-0.5, 11.6, 10.2]) + 500.0 * directions_in_plane([1, 0, 0], [0, 1, 1], np.linspace(-85, 85, 18))
        ),
        ((np.linspace(-85, 85, 18), ([1, 0, 0], [0, 1, 1])),),
        centre=lambda ppw: np.array([-0.5, 11.6, 10.2]),
    ),
}


def _errors(case: Case, ppw: int):
    """(error of the field at the near points, error of the pattern), each relative."""
    k = 2 * math.pi / ppw
    g = _grid(k)
    surf = case.surface(ppw)
    assert surf.kind == case.kind and isinstance(surf, surface_for(case.kind))
    srcs = case.sources(ppw)
    # recorded cells -> positions in cells (metres / dx): the kind's cell-centre offset
    ph = jnp.asarray(case.field(k, surf.cells + case.kind.origin_cells, srcs))
    pts = case.near(ppw, srcs)
    exact = case.field(k, pts, srcs)
    near = np.asarray(surf.field_at(ph, g, pts, dispersion="continuum"))
    e_near = float(np.max(np.abs(near / exact - 1)))
    c = case.centre(ppw)
    F, F_exact = [], []
    for angles, plane in case.lobes:
        kw = {} if plane is None else {"plane": plane}
        F.append(np.asarray(surf.far_field(ph, g, angles, centre_cells=c, dispersion="continuum", **kw)))
        u = _unit(angles, plane)
        origin = np.zeros(case.kind.ndim) if c is None else np.asarray(c, float)
        F_exact.append(case.amplitude(k) * sum(np.exp(-1j * k * (u @ (s - origin))) for s in srcs))
    F, F_exact = np.concatenate(F), np.concatenate(F_exact)
    e_far = float(np.max(np.abs(F - F_exact)) / np.max(np.abs(F_exact)))
    return e_near, e_far


@pytest.mark.parametrize("name", list(CASES))
def test_point_source_field_and_pattern(name):
    """The field outside the surface and the far-field pattern of a point source (and its baffle
    image), against the exact ones, within the sampling bound and converging at second order."""
    case = CASES[name]
    e20, e40 = _errors(case, 20), _errors(case, 40)
    tol20, tol40 = case.tol(2 * math.pi / 20), case.tol(2 * math.pi / 40)
    assert max(e20) < tol20, (e20, tol20)
    if case.tol_at_40:
        assert max(e40) < tol40, (e40, tol40)
    if case.ratio_each is not None:
        assert all(a / b > case.ratio_each for a, b in zip(e20, e40)), (e20, e40)
    if case.ratio_max is not None:
        assert max(e40) < max(e20) / case.ratio_max, (e20, e40)


KIND_SURFACES = {"plane": (PLANE, BoxContour), "rz": (AXISYMMETRIC, CylinderSurface), "volume": (VOLUME, BoxSurface)}


def _real_grid(kind, shape):
    return make_grid(frequency_hz=50e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=shape, kind=kind)


@pytest.mark.parametrize("name", list(KIND_SURFACES))
def test_each_kind_chooses_its_surface(name):
    """`surface_for` gives each kind its surface (by the kind or its name; a subclass of a kind
    gets its parent's) and refuses a kind with none, naming the fix."""
    kind, cls = KIND_SURFACES[name]
    assert surface_for(kind) is cls and surface_for(kind.name) is cls and cls.kind == kind
    assert all(type(load().kind) is k for k, load in SURFACES.items())

    class Sub(type(kind)):  # type: ignore[misc]
        pass

    assert surface_for(Sub()) is cls

    class Tube(LatticeKind):
        name, label, noun, ndim, axis_names = "tube", "1-D", "tube", 1, ("x",)

    with pytest.raises(ValueError, match="no far-field surface for the 1-D lattice.*SURFACES"):
        surface_for(Tube())


@pytest.mark.parametrize("name", list(KIND_SURFACES))
def test_surface_encloses_objects_or_refuses(name):
    """`surface_around` encloses the transducer and every object `gap` cells out (the rz cylinder
    from the axis); a surface through an object, or one that leaves the grid or enters the
    absorbing layer, is refused with the reason."""
    kind, cls = KIND_SURFACES[name]
    n = kind.ndim
    g = _real_grid(kind, (60,) * n)
    src = np.full((1, n), 30)
    obj = np.full((1, n), 30)
    obj[0, 0] = 36  # an object 6 cells along axis 0 (the beam)
    s = surface_around(g, src, 3, objects=[obj], margin=8)
    assert isinstance(s, cls) and len(s.crossing(np.concatenate([src, obj]))) == 0
    lo, hi = s.box
    assert hi[0] == 39 and lo[0] == 27
    assert lo[1] == (0 if kind.has_axis_edge else 27)  # the cylinder spans the axis
    # an explicit surface between the transducer and the object crosses it: refused
    cut = cls.from_box(lo, tuple(h if a else 35 for a, h in enumerate(hi)))
    with pytest.raises(ValueError, match="crosses the object"):
        cut.check_encloses(obj)
    cut.check_encloses(src)
    # the object on the recorded cells themselves is not enclosed either
    assert len(cls.from_box(lo, tuple(h if a else 36 for a, h in enumerate(hi))).crossing(obj)) == 1
    with pytest.raises(ValueError, match="absorbing layer"):
        surface_around(g, src, 3, objects=[obj], margin=21)
    assert 2 * s.n_samples == len(s.cells) == 2 * len(s.samples()[0])
    other = next(k for k, _ in KIND_SURFACES.values() if k != kind)
    with pytest.raises(ValueError, match=f"surface of {kind.label} grids"):
        s.check_inside(_real_grid(other, (60,) * other.ndim))


@pytest.mark.parametrize("name", list(KIND_SURFACES))
def test_lobe_at_range_is_the_field_on_the_arc(name):
    """The lobe convention shared by every kind: `far_field(..., range_m=R, centre_cells=c)` is
    the field at c + R (cos t, sin t) in the plane of axes 0 and 1 (rz: |sin t|, the field being
    even in the angle; centred on the axis), and a wrong phasor count is refused."""
    kind, cls = KIND_SURFACES[name]
    k = 2 * math.pi / 20
    g = _grid(k)
    s = cls.from_box((4,) * kind.ndim, (16,) * kind.ndim)
    rng = np.random.default_rng(0)
    ph = rng.normal(size=len(s.cells)) + 1j * rng.normal(size=len(s.cells))
    ang = np.array([-40.0, 0.0, 25.0, 90.0])
    c = np.array([10.0, 0.0] if kind.has_axis_edge else [10.0] * kind.ndim)
    lobe = np.asarray(s.far_field(ph, g, ang, range_m=300.0, centre_cells=c, dispersion="continuum"))
    u = _unit(ang, None)
    if kind.has_axis_edge:
        u = np.abs(u)
    u = np.concatenate([u, np.zeros((len(u), kind.ndim - 2))], 1)
    direct = np.asarray(s.field_at(ph, g, c + 300.0 * u, dispersion="continuum"))
    np.testing.assert_allclose(lobe, direct, rtol=1e-12)
    with pytest.raises(ValueError, match=f"expected {len(s.cells)}"):
        s.field_at(ph[:-1], g, c + 300.0 * u)
    if kind.ndim == 2:
        with pytest.raises(ValueError, match="leave plane out"):
            s.far_field(ph, g, ang, plane=([1, 0, 0], [0, 1, 0]))


def test_named_baffles():
    """A baffle is named by its window side in the kind's axis names; the plane's contour has
    none, the cylinder's is z_lo, and a high side must be given explicitly."""
    with pytest.raises(ValueError, match="no baffle image"):
        BoxContour.around(np.array([[5, 5]]), 2, "x_lo")
    assert CylinderSurface.around(np.array([[0, 3]]), 2, "z_lo") == CylinderSurface(0, 2, 5, baffled=True)
    with pytest.raises(ValueError, match="allowed on a rz grid: z_lo"):
        CylinderSurface.around(np.array([[4, 3]]), 2, "x_lo")
    with pytest.raises(ValueError, match="high window side"):
        BoxSurface.around(np.array([[5, 5, 5]]), 2, "y_hi")
    assert isinstance(Plane(), Plane) and isinstance(Axisymmetric(), Axisymmetric)
