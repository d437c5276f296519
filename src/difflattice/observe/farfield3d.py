"""Near-to-far-field transform in 3-D: the Kirchhoff-Helmholtz integral over a closed box.

The simulator records phasors at the drive frequency on two nested box shells of cells, one cell
apart (`BoxSurface.cells`: inner shell, then outer shell); their mean and difference give p and
dp/dn on the surface through the faces between them (unit-area samples, midpoint rule, as
`farfield.py` does in 2-D). The field outside is

    p(x) = sum over the surface [ p(x') dG/dn'(x, x') - G(x, x') dp/dn'(x') ] dS'

with G = exp(i k R) / (4 pi R), R = |x - x'| (time convention exp(-i omega t), n' the outward
normal). At infinity p ~ exp(i k r) / r F(x_hat) with the far-field pattern

    F(x_hat) = (1 / 4 pi) sum [ -i k (x_hat . n') p - dp/dn' ] exp(-i k x_hat . x') dS'

(`far_field_pattern`, x' measured from `centre_cells`). A source on a rigid baffle that is a
closed window face (`BoxSurface(..., baffle="x_lo")`: the plane half a cell below the box's first
cell) needs no surface on the baffle: with the Green's function G(x, x') + G(x, M x') (M mirrors
in the baffle) both that and dp/dn vanish there, so the other five faces and their mirror
images carry the whole field (as `farfield_rz` does for a baffled disc). With ``dispersion="lattice"`` the
wavenumber of each direction follows the 3-D lattice dispersion relation (the transform continues
the lattice's own field); ``"continuum"`` uses k = omega / c.

Errors of the transform itself (a smooth field, continuum reference): the mean of the two shells
is off by O((k h)^2 / 8) and their difference by O((k h)^2 / 24) (1.2 % and 0.4 % at 20 cells per
wavelength along the normal), the same order as in 2-D.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from ..lattice.kinds import VOLUME, LatticeKind
from .analytic3d import lattice_wavenumber_3d
from .farfield_base import FarFieldSurface, split_pairs

MAX_KERNEL_ENTRIES = 4_000_000
"""Observation points x surface samples evaluated at once (memory bound of the dense kernel)."""


class BoxSurface(FarFieldSurface):
    """The box of cells [lo, hi] (inclusive, per axis; inner shell) and its outer shell: the
    volume lattice's far-field surface.

    Sample s lies on the face between inner cell `inner[s]` and outer cell `outer[s]` (one cell
    outward along the face normal); edge and corner cells of the inner shell appear once per
    face they touch, so the samples tile the closed surface of the box [lo - 1/2, hi + 1/2].
    """

    kind: ClassVar[LatticeKind] = VOLUME

    lo: tuple[int, int, int] = eqx.field(static=True)
    hi: tuple[int, int, int] = eqx.field(static=True)
    baffle: str | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        if len(self.lo) != 3 or len(self.hi) != 3 or any(b <= a for a, b in zip(self.lo, self.hi)):
            raise ValueError(f"empty far-field box lo = {self.lo}, hi = {self.hi}: need hi > lo on every axis")
        if self.baffle is not None:
            if self.baffle not in BAFFLE_SIDES:
                raise ValueError(f"baffle = {self.baffle!r}; allowed: None or one of {', '.join(BAFFLE_SIDES)}")
            axis, side = self.baffle_axis_side
            if side < 0 and self.lo[axis] != 0:
                raise ValueError(
                    f"a box on the {self.baffle} baffle starts at cell 0 along that axis, got lo = {self.lo}"
                )

    @classmethod
    def from_box(cls, lo, hi, baffle: str | None = None) -> BoxSurface:
        return cls((int(lo[0]), int(lo[1]), int(lo[2])), (int(hi[0]), int(hi[1]), int(hi[2])), baffle)

    @property
    def box(self) -> tuple[tuple[int, ...], tuple[int, ...]]:
        return self.lo, self.hi

    @property
    def open_sides(self) -> tuple[tuple[int, int], ...]:
        return () if self.baffle is None else (self.baffle_axis_side,)

    @property
    def baffle_axis_side(self) -> tuple[int, int]:
        """(axis, -1 or +1) of the baffle's window side."""
        if self.baffle is None:
            raise ValueError("this far-field box has no baffle")
        return "xyz".index(self.baffle[0]), (-1 if self.baffle.endswith("lo") else 1)

    def mirror(self, points, normals):
        """Points and normals mirrored in the baffle plane (cell units)."""
        axis, side = self.baffle_axis_side
        plane = -0.5 if side < 0 else self.hi[axis] + 0.5
        p = np.array(points, dtype=float)
        n = np.array(normals, dtype=float)
        p[:, axis] = 2 * plane - p[:, axis]
        n[:, axis] = -n[:, axis]
        return p, n

    def samples(self):
        """(inner (M,3), outer (M,3), points (M,3), normals (M,3)) in cell units."""
        inner, normal = [], []
        for axis in range(3):
            o1, o2 = [a for a in range(3) if a != axis]
            u = np.arange(self.lo[o1], self.hi[o1] + 1)
            v = np.arange(self.lo[o2], self.hi[o2] + 1)
            U, V = np.meshgrid(u, v, indexing="ij")
            for side, at in ((-1, self.lo[axis]), (1, self.hi[axis])):
                if self.baffle is not None and (axis, side) == self.baffle_axis_side:
                    continue  # no surface on the baffle (the image carries it)
                c = np.zeros((U.size, 3), np.int64)
                c[:, axis] = at
                c[:, o1] = U.ravel()
                c[:, o2] = V.ravel()
                n = np.zeros((U.size, 3))
                n[:, axis] = side
                inner.append(c)
                normal.append(n)
        inner = np.concatenate(inner)
        normal = np.concatenate(normal)
        outer = inner + normal.astype(np.int64)
        points = 0.5 * (inner + outer)
        return inner, outer, points, normal

    @property
    def n_samples(self) -> int:
        d = [b - a + 1 for a, b in zip(self.lo, self.hi)]
        full = 2 * (d[0] * d[1] + d[1] * d[2] + d[0] * d[2])
        if self.baffle is None:
            return full
        a = self.baffle_axis_side[0]
        return full - math.prod(d) // d[a]

    @property
    def centre_cells(self) -> np.ndarray:
        return 0.5 * (np.asarray(self.lo, float) + np.asarray(self.hi, float))

    def check_inside(self, shape, margin: int = 0) -> None:
        """Refuse a box whose outer shell leaves the grid (or a grid's `shape`) or enters a
        `margin`-cell absorbing layer (a baffled side lies on the window face instead)."""
        super().check_inside(shape, margin)

    def _outside_message(self, shape, margin: int) -> str:
        return (
            f"far-field box lo = {self.lo}, hi = {self.hi} (plus its outer shell) must lie inside "
            f"the {tuple(shape)} grid and outside the {margin}-cell absorbing layer: shrink the "
            "gap or enlarge the grid"
        )

    def field_at(self, phasors, grid, points_cells, **kwargs):
        return field_at(phasors, self, grid, points_cells, **kwargs)

    def far_field(self, phasors, grid, angles_deg, *, range_m=None, centre_cells=None, plane=None, **kwargs):
        """The lobe at `angles_deg` in `plane` = (axis, in_plane) (default ((1, 0, 0), (0, 1, 0)):
        from +x towards +y, as on the plane lattice); see `far_field`."""
        axis, in_plane = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)) if plane is None else plane
        dirs = directions_in_plane(axis, in_plane, np.asarray(angles_deg, float).reshape(-1))
        return far_field(phasors, self, grid, dirs, range_m, centre_cells, **kwargs)


BAFFLE_SIDES = ("x_lo", "x_hi", "y_lo", "y_hi", "z_lo", "z_hi")


def box_around_3d(cells, gap: int, baffle: str | None = None) -> BoxSurface:
    """The far-field box `gap` cells around a set of (n, 3) cells (e.g. a transducer's); with
    `baffle` (e.g. "x_lo": a rigid window face behind a transducer in the first cell layer) the box
    starts at the baffle on that side."""
    if baffle is not None and baffle not in BAFFLE_SIDES:
        raise ValueError(f"baffle = {baffle!r}; allowed: None or one of {', '.join(BAFFLE_SIDES)}")
    return BoxSurface.around(cells, gap, baffle)


def _with_images(surface: BoxSurface, p, dpdn, pts, normals):
    """Append the baffle's mirror images of the samples (same p and dp/dn)."""
    if surface.baffle is None:
        return p, dpdn, pts, normals
    mp, mn = surface.mirror(pts, normals)
    return (
        jnp.concatenate([p, p], axis=-1),
        jnp.concatenate([dpdn, dpdn], axis=-1),
        np.concatenate([pts, mp]),
        np.concatenate([normals, mn]),
    )


def directions_in_plane(axis, in_plane, angles_deg) -> np.ndarray:
    """Unit vectors (a, 3) at `angles_deg` from `axis` towards `in_plane` (a lobe cut: the plane
    spanned by the transducer axis and one direction across it)."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    b = np.asarray(in_plane, float)
    b = b - (b @ a) * a
    if np.linalg.norm(b) == 0:
        raise ValueError("in_plane is parallel to axis: give a direction across the axis")
    b = b / np.linalg.norm(b)
    t = np.radians(np.asarray(angles_deg, float))
    return np.cos(t)[:, None] * a + np.sin(t)[:, None] * b


def _wavenumbers(omega: float, c: float, directions: np.ndarray, dispersion: str) -> np.ndarray:
    if dispersion == "lattice":
        return lattice_wavenumber_3d(omega, c, directions)
    if dispersion == "continuum":
        return np.full(directions.shape[:-1], omega / c)
    raise ValueError(f"dispersion = {dispersion!r}; allowed: 'lattice', 'continuum'")


def _split(phasors, m: int):
    return split_pairs(phasors, m, "surface phasors (inner shell then outer shell)")


def _omega_c(grid, c_lattice, frequency_hz):
    omega = grid.hz_to_lattice_omega(frequency_hz or grid.frequency_hz)
    c = grid.courant if c_lattice is None else c_lattice
    return omega, c


def field_at(
    phasors: Complex[Array, " two_m"],
    surface: BoxSurface,
    grid,
    points_cells: Float[np.ndarray, "a 3"],
    *,
    c_lattice: float | None = None,
    dispersion: Literal["lattice", "continuum"] = "lattice",
    frequency_hz: float | None = None,
) -> Complex[Array, " a"]:
    """Complex pressure at points outside the box (positions in cells, finite range), from the
    surface phasors ordered as `surface.cells`. With "lattice" dispersion the wavenumber of each
    (point, sample) pair follows the direction from the box centre to the point."""
    inner, outer, pts, normals = surface.samples()
    p, dpdn = _split(phasors, len(inner))
    p, dpdn, pts, normals = _with_images(surface, p, dpdn, pts, normals)
    omega, c = _omega_c(grid, c_lattice, frequency_hz)
    obs = np.asarray(points_cells, dtype=float).reshape(-1, 3)
    centre = surface.centre_cells
    k_all = _wavenumbers(omega, c, obs - centre, dispersion)
    chunk = max(1, MAX_KERNEL_ENTRIES // len(pts))
    out = []
    for s in range(0, len(obs), chunk):
        o, k = obs[s : s + chunk], k_all[s : s + chunk, None]
        d = o[:, None, :] - pts[None, :, :]  # (A, M, 3)
        R = np.sqrt((d**2).sum(-1))
        if (k * R).min() < 1.0:
            raise ValueError("field point on or inside the far-field box (k R < 1): evaluate outside it")
        G = np.exp(1j * k * R) / (4 * math.pi * R)
        dG_dR = (1j * k - 1 / R) * G
        dR_dn = -(d * normals[None]).sum(-1) / R  # derivative of R in x' along n'
        kp = jnp.asarray(dG_dR * dR_dn)
        kd = jnp.asarray(-G)
        out.append(p @ kp.T + dpdn @ kd.T)
    return jnp.concatenate(out, axis=-1)


def far_field_pattern(
    phasors: Complex[Array, " two_m"],
    surface: BoxSurface,
    grid,
    directions: Float[np.ndarray, "a 3"],
    *,
    centre_cells=None,
    c_lattice: float | None = None,
    dispersion: Literal["lattice", "continuum"] = "lattice",
    frequency_hz: float | None = None,
) -> Complex[Array, " a"]:
    """The far-field pattern F(x_hat) (cells x Pa): p(r x_hat) ~ exp(i k r) / r F, r in cells from
    `centre_cells` (default: the box centre), for unit `directions` (a, 3)."""
    inner, outer, pts, normals = surface.samples()
    p, dpdn = _split(phasors, len(inner))
    p, dpdn, pts, normals = _with_images(surface, p, dpdn, pts, normals)
    omega, c = _omega_c(grid, c_lattice, frequency_hz)
    u = np.asarray(directions, float).reshape(-1, 3)
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    centre = surface.centre_cells if centre_cells is None else np.asarray(centre_cells, float)
    x = pts - centre
    k_all = _wavenumbers(omega, c, u, dispersion)
    chunk = max(1, MAX_KERNEL_ENTRIES // len(pts))
    out = []
    for s in range(0, len(u), chunk):
        uu, k = u[s : s + chunk], k_all[s : s + chunk, None]
        ph = np.exp(-1j * k * (uu @ x.T)) / (4 * math.pi)
        kp = jnp.asarray(-1j * k * (uu @ normals.T) * ph)
        kd = jnp.asarray(-ph)
        out.append(p @ kp.T + dpdn @ kd.T)
    return jnp.concatenate(out, axis=-1)


def far_field(
    phasors: Complex[Array, " two_m"],
    surface: BoxSurface,
    grid,
    directions: Float[np.ndarray, "a 3"],
    range_m: float | None = None,
    centre_cells=None,
    **kwargs,
) -> Complex[Array, " a"]:
    """Complex pressure at `range_m` from `centre_cells` (default: the box centre) along unit
    `directions` (a, 3) (`directions_in_plane` gives a lobe cut). `range_m=None` gives the
    far-field pattern (`far_field_pattern`). Keyword arguments go to `field_at`."""
    if range_m is None:
        return far_field_pattern(phasors, surface, grid, directions, centre_cells=centre_cells, **kwargs)
    u = np.asarray(directions, float).reshape(-1, 3)
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    centre = surface.centre_cells if centre_cells is None else np.asarray(centre_cells, float)
    r = grid.m_to_cells(range_m)
    return field_at(phasors, surface, grid, centre + r * u, **kwargs)
