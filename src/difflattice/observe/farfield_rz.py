"""Axisymmetric near-to-far-field transform: the 3-D Kirchhoff-Helmholtz integral over a closed
cylinder of ring cells around the source, and sampling an rz field at points (the scan line).

The simulator records phasors at the drive frequency on pairs of cells across the faces of a
cylinder (two caps and the side); their mean and difference give p and dp/dn on the faces. The
field outside is then

    p(x) = sum over the surface [ p(x') dG/dn'(x, x') - G(x, x') dp/dn'(x') ] dS'

with G = exp(i k R) / (4 pi R) (time convention exp(-i omega t), n' the outward normal). Each face
is a ring: dS' = r' dphi' x (its width), and the azimuth integral is done per observation point,
by the trapezoidal rule (spectrally accurate for a periodic, analytic integrand: the nodes are
chosen so that k r' < n_phi / 2 - 8 for every ring) at a finite range, and in closed form (Bessel
functions J0, J1) in the far-field limit.

A rigidly baffled source (the rz grid's z_lo face closed, z = 0) needs no lower cap: the Green's
function that satisfies the baffle's boundary condition is G(x, x') + G(x, M x') (M mirrors z), and
on the baffle both it and dp/dn vanish, so the integral over the top cap and the side (down to the
baffle) is the whole field. This replaces a Rayleigh integral over a plane in front of the face
(which would need the plane out to infinity: truncating it at the window costs side-lobe
accuracy).

The kernels are NumPy constants: the transform is linear in the phasors and differentiable in
JAX through them.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from ..lattice.grid import Grid
from ..lattice.kinds import AXISYMMETRIC, LatticeKind
from .analytic import lattice_wavenumber
from .farfield_base import FarFieldSurface, no_plane, split_pairs


class CylinderSurface(FarFieldSurface):
    """A closed cylinder of ring cells on an rz grid: rows `iz0` .. `iz1`, rings 0 .. `jr`: the rz
    lattice's far-field surface.

    The surface runs along the cell faces just outside those cells: the caps at z = iz0 (lower,
    normal -z) and z = iz1 + 1 (upper, +z) in cells, the side at r = jr + 1 (+r). Each sample is
    the pair (inner cell, outer cell) across its face. With `baffled` the lower cap is left out and
    the side runs down to the rigid baffle z = 0 (`iz0` must be 0).
    """

    kind: ClassVar[LatticeKind] = AXISYMMETRIC

    iz0: int = eqx.field(static=True)
    iz1: int = eqx.field(static=True)
    jr: int = eqx.field(static=True)
    baffled: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        if not (self.iz1 >= self.iz0 >= 0 and self.jr >= 0):
            raise ValueError(f"empty cylinder rows [{self.iz0}, {self.iz1}], rings [0, {self.jr}]")
        if self.baffled and self.iz0 != 0:
            raise ValueError(f"a baffled cylinder starts at the baffle (iz0 = 0), got iz0 = {self.iz0}")
        if not self.baffled and self.iz0 < 1:
            raise ValueError("an unbaffled cylinder needs iz0 >= 1 (its lower cap's outer cells are row iz0 - 1)")

    @classmethod
    def from_box(cls, lo, hi, baffle: str | None = None) -> CylinderSurface:
        """The cylinder of rows lo[0] .. hi[0] and rings 0 .. hi[1] (a surface of revolution spans
        the axis: lo[1] plays no part); `baffle` can only be "z_lo", the rigid window face z = 0."""
        if baffle is not None and cls.side(baffle) != (0, -1):
            raise ValueError(f"baffle = {baffle!r}: an rz cylinder's baffle is the z_lo window face (or none)")
        return cls(int(lo[0]), int(hi[0]), int(hi[1]), baffle is not None)

    @property
    def box(self) -> tuple[tuple[int, ...], tuple[int, ...]]:
        return (self.iz0, 0), (self.iz1, self.jr)

    @property
    def open_sides(self) -> tuple[tuple[int, int], ...]:
        return ((1, -1), (0, -1)) if self.baffled else ((1, -1),)

    @property
    def span_cells(self) -> tuple[float, ...]:
        """(rows, diameter) in cells: the cylinder's diameter plays the box's height."""
        return float(self.iz1 - self.iz0), float(2 * self.jr)

    def samples(self):
        """(inner (M, 2), outer (M, 2), points (M, 2) as (z, r) in cells, normals (M, 2) as
        (n_z, n_r), widths (M,) in cells): the face samples of the surface."""
        rings = np.arange(self.jr + 1)
        rows = np.arange(self.iz0, self.iz1 + 1)
        inner, outer, pts, nrm = [], [], [], []
        caps = [(self.iz1, self.iz1 + 1, self.iz1 + 1.0, 1.0)]
        if not self.baffled:
            caps.append((self.iz0, self.iz0 - 1, float(self.iz0), -1.0))
        for i_in, i_out, z, nz in caps:
            inner += [(i_in, j) for j in rings]
            outer += [(i_out, j) for j in rings]
            pts += [(z, j + 0.5) for j in rings]
            nrm += [(nz, 0.0)] * len(rings)
        inner += [(i, self.jr) for i in rows]
        outer += [(i, self.jr + 1) for i in rows]
        pts += [(i + 0.5, self.jr + 1.0) for i in rows]
        nrm += [(0.0, 1.0)] * len(rows)
        inner, outer = (np.asarray(a, dtype=np.int64) for a in (inner, outer))
        return inner, outer, np.asarray(pts, float), np.asarray(nrm, float), np.ones(len(pts))

    def _outside_message(self, shape, margin: int) -> str:
        nz, nr = shape
        return (
            f"cylinder rows [{self.iz0}, {self.iz1}], rings [0, {self.jr}] (plus its outer cells) must "
            f"lie inside the {nz} x {nr} grid and outside the {margin}-cell absorbing layer"
        )

    def field_at(self, phasors, grid, points_cells, **kwargs):
        return field_at_rz(phasors, self, grid, points_cells, **kwargs)

    def far_field(self, phasors, grid, angles_deg, *, range_m=None, centre_cells=None, plane=None, **kwargs):
        """The lobe at polar angles `angles_deg` from +z: the pattern (`far_field_rz`, referred to
        z = 0 on the axis) or, at `range_m`, the pressure at that range from `centre_cells`
        (z, 0) on the axis (default z: the surface's middle or the baffle) by `field_at_rz`,
        exact at any range. The field is even in the angle: each |angle| is evaluated once."""
        no_plane(plane, "rz")
        if range_m is None:
            if centre_cells is not None:
                raise ValueError("the rz far-field pattern is referred to z = 0 on the axis: leave centre_cells out")
            return far_field_rz(phasors, self, grid, angles_deg, **kwargs)
        zc = self._axis_point(centre_cells)
        ang = np.asarray(angles_deg, float).reshape(-1)
        th_u, inv = np.unique(np.abs(ang), return_inverse=True)
        th = np.radians(th_u)
        r_cells = range_m / grid.dx_m
        pts = np.stack([zc + r_cells * np.cos(th), r_cells * np.sin(th)], axis=1)
        return field_at_rz(phasors, self, grid, pts, **kwargs)[inv]

    def _axis_point(self, centre_cells) -> float:
        if centre_cells is None:
            return 0.0 if self.baffled else 0.5 * (self.iz0 + self.iz1 + 1)
        z, rho = (float(v) for v in centre_cells)
        if rho != 0:
            raise ValueError(f"centre_cells = {tuple(centre_cells)}: an rz lobe is measured from the axis, give (z, 0)")
        return z

    def lobe_centre_cells(self, source_cells, centre_m, dx_m: float) -> tuple[float, ...]:
        """The transducer's face centre on the axis, (z_m / dx, 0): a disc's cells are rings."""
        return float(centre_m[0]) / dx_m, 0.0


def cylinder_around(cells: np.ndarray, gap: int, *, baffled: bool) -> CylinderSurface:
    """The cylinder `gap` cells around a set of (z, r) cells (e.g. a disc transducer's)."""
    return CylinderSurface.around(cells, gap, "z_lo" if baffled else None)


def _wavenumbers(grid: Grid, theta, dispersion, frequency_hz, c_lattice):
    omega = grid.hz_to_lattice_omega(frequency_hz or grid.frequency_hz)
    c = grid.courant if c_lattice is None else c_lattice
    theta = np.asarray(theta, float)
    if dispersion == "lattice":
        return lattice_wavenumber(omega, c, theta, stencil=grid.stencil)
    if dispersion == "continuum":
        return np.full_like(theta, omega / c)
    raise ValueError(f"dispersion = {dispersion!r}; allowed: 'lattice', 'continuum'")


def _split(phasors, m: int):
    return split_pairs(phasors, m)


def far_field_rz(
    phasors: Complex[Array, " two_m"] | Complex[np.ndarray, " two_m"],
    surface: CylinderSurface,
    grid: Grid,
    angles_deg: Float[np.ndarray, " a"],
    *,
    dispersion: Literal["lattice", "continuum"] = "continuum",
    frequency_hz: float | None = None,
    c_lattice: float | None = None,
) -> Complex[Array, " a"]:
    """Far-field pattern F(theta) at `angles_deg` from the +z axis (the limit of R p(R, theta)
    exp(-i k R) as R -> infinity, in Pa x cells), from surface phasors ordered as
    `surface.cells` (NumPy phasors give a NumPy result, no XLA program; JAX ones a JAX array).
    "continuum" (default) continues the surface field with k = omega / c: the
    surface lies within a few cells of the source, where the lattice's phase error is small, so
    this is the physical far field (baffled 38.4 mm piston at 50 kHz, 20 cells per wavelength:
    first null within 0.0001 deg of 2 J1(x)/x, side lobe within 0.003 dB). "lattice" uses the
    lattice dispersion relation per direction: the pattern an unbounded lattice would give (null
    0.024 deg closer to the axis there)."""
    from scipy.special import j0, j1

    inner, _, pts, nrm, width = surface.samples()
    p, dpdn = _split(phasors, len(inner))
    th = np.radians(np.asarray(angles_deg, float)).reshape(-1)
    k = _wavenumbers(grid, th, dispersion, frequency_hz, c_lattice)
    st, ct = np.sin(th)[:, None], np.cos(th)[:, None]
    kk = k[:, None]
    z, r = pts[None, :, 0], pts[None, :, 1]
    nz, nr = nrm[None, :, 0], nrm[None, :, 1]
    u = kk * r * st  # argument of the Bessel functions
    ds = r * width[None, :]  # ring surface per radian

    def term(zs, nzs):
        # integral over phi' of exp(-i k xhat.x') and of (-i k xhat.n') exp(-i k xhat.x')
        ph = np.exp(-1j * kk * zs * ct)
        g = 2 * math.pi * j0(u) * ph
        dg = (-1j * kk) * (nzs * ct * g + nr * st * (-2j * math.pi * j1(u)) * ph)
        return g, dg

    g, dg = term(z, nz)
    if surface.baffled:  # the image source of the rigid baffle z = 0
        gi, dgi = term(-z, -nz)
        g, dg = g + gi, dg + dgi
    # host kernels: NumPy phasors give a NumPy field (no XLA program), JAX ones a JAX array
    kernel_p = dg * ds / (4 * math.pi)
    kernel_dp = -g * ds / (4 * math.pi)
    return p @ kernel_p.T + dpdn @ kernel_dp.T


def field_at_rz(
    phasors: Complex[Array, " two_m"] | Complex[np.ndarray, " two_m"],
    surface: CylinderSurface,
    grid: Grid,
    points_cells: Float[np.ndarray, "a 2"],
    *,
    dispersion: Literal["lattice", "continuum"] = "continuum",
    frequency_hz: float | None = None,
    c_lattice: float | None = None,
    n_phi: int | None = None,
) -> Complex[Array, " a"]:
    """Complex pressure at points (z, rho) in cells (rho >= 0, the distance from the axis) outside
    the surface, at any range, from surface phasors ordered as `surface.cells` (NumPy phasors: a
    NumPy result, no XLA program). The azimuth
    integral uses `n_phi` trapezoidal nodes (default: enough for k r' + 16 < n_phi / 2)."""
    inner, _, pts, nrm, width = surface.samples()
    p, dpdn = _split(phasors, len(inner))
    obs = np.asarray(points_cells, float).reshape(-1, 2)
    if (obs[:, 1] < 0).any():
        raise ValueError("points_cells are (z, rho) with rho >= 0 (the distance from the axis)")
    # direction of each point as seen from the surface's centre, for the lattice wavenumber
    zc = 0.0 if surface.baffled else 0.5 * (surface.iz0 + surface.iz1 + 1)
    k = _wavenumbers(grid, np.arctan2(obs[:, 1], obs[:, 0] - zc), dispersion, frequency_hz, c_lattice)
    if n_phi is None:
        n_phi = 2 * int(math.ceil(float(k.max()) * (pts[:, 1].max() + obs[:, 1].max()) / 2 + 16))
    phi = (np.arange(n_phi) + 0.5) * (2 * math.pi / n_phi)
    cphi, sphi = np.cos(phi), np.sin(phi)
    kp, kd = [], []
    images = (1.0, -1.0) if surface.baffled else (1.0,)
    for i in range(len(obs)):  # one point at a time: (M, n_phi) arrays
        zo, ro = obs[i]
        kk = k[i]
        gp = np.zeros(len(pts), complex)
        gd = np.zeros(len(pts), complex)
        for mz in images:
            zs, nz = mz * pts[:, 0:1], mz * nrm[:, 0:1]
            xs, ys = pts[:, 1:2] * cphi, pts[:, 1:2] * sphi
            dx, dy, dz = xs - ro, ys, zs - zo  # source minus observation
            R = np.sqrt(dx * dx + dy * dy + dz * dz)
            G = np.exp(1j * kk * R) / (4 * math.pi * R)
            dGdR = (1j * kk - 1 / R) * G
            dn = (nrm[:, 1:2] * (cphi * dx + sphi * dy) + nz * dz) / R  # dR/dn'
            gp += (dGdR * dn).mean(1) * 2 * math.pi
            gd += G.mean(1) * 2 * math.pi
        ds = pts[:, 1] * width
        kp.append(gp * ds)
        kd.append(-gd * ds)
    return p @ np.array(kp).T + dpdn @ np.array(kd).T  # NumPy phasors: a NumPy field


# ------------------------------------------------------------------------------------------
# sampling an rz field at points (the rig's scan line, the axis)


class FieldSampler(eqx.Module):
    """Samples an rz field at points (z, x): p(x, z) = p(|x|, z), by cubic (4-point Lagrange)
    interpolation in z and r of recorded phasors. The field is even in r, so rings -1, -2 are
    rings 0, 1 mirrored (on the axis: (9 p_0 - p_1) / 8 at a row centre).

    `cells` (m, 2): the phasor cells to record (`Sensors(phasor_cells=...)`); `weights`
    (n_points, m): the interpolation matrix. `__call__` is linear in the phasors (differentiable).
    """

    cells: np.ndarray
    weights: np.ndarray

    def __call__(self, phasors: Complex[Array, " m"]) -> Complex[Array, " n"]:
        return phasors @ jnp.asarray(self.weights).T.astype(phasors.dtype)


def _lagrange4(u: float):
    """First node and the 4 cubic Lagrange weights at fractional index u (nodes i0 .. i0 + 3)."""
    i0 = int(math.floor(u)) - 1
    t = u - (i0 + 1)  # in [0, 1): nodes at -1, 0, 1, 2
    w = np.array(
        [
            -t * (t - 1) * (t - 2) / 6,
            (t + 1) * (t - 1) * (t - 2) / 2,
            -(t + 1) * t * (t - 2) / 2,
            (t + 1) * t * (t - 1) / 6,
        ]
    )
    return i0, w


def field_sampler(grid: Grid, points_m) -> FieldSampler:
    """The `FieldSampler` of points (z_m, x_m) in metres on an rz grid (z = 0 is the z_lo window
    face, x the signed distance from the axis)."""
    if not grid.kind.ring_metric:
        raise ValueError(f"field_sampler needs an rz grid, got kind = {grid.kind.name!r}")
    nz, nr = grid.shape
    pts = np.asarray(points_m, float).reshape(-1, 2)
    index: dict[tuple[int, int], int] = {}
    rows = []
    for z, x in pts:
        iz, wz = _lagrange4(z / grid.dx_m - 0.5)  # row centres at (i + 1/2) dx
        jr, wr = _lagrange4(abs(x) / grid.dx_m - 0.5)
        if iz < 0 or iz + 3 >= nz:
            raise ValueError(
                f"point z = {z} m needs rows {iz} .. {iz + 3}: outside the grid (0 .. {nz - 1}); "
                "move it at least 1.5 cells from the z edges"
            )
        if jr + 3 >= nr:
            raise ValueError(f"point x = {x} m needs ring {jr + 3}: outside the grid (0 .. {nr - 1})")
        row: dict[tuple[int, int], float] = {}
        for a in range(4):
            j = jr + a
            j = -1 - j if j < 0 else j  # even in r
            for b in range(4):
                key = (iz + b, j)
                row[key] = row.get(key, 0.0) + wz[b] * wr[a]
        rows.append(row)
        for key in row:
            index.setdefault(key, len(index))
    cells = np.array(list(index), dtype=np.int64).reshape(-1, 2)
    W = np.zeros((len(pts), len(cells)))
    for k, row in enumerate(rows):
        for key, w in row.items():
            W[k, index[key]] += w
    return FieldSampler(cells=cells, weights=W)


def scan_line(grid: Grid, x_m, z_m: float) -> FieldSampler:
    """The sampler of the rig's scan line: points x_m (metres, either side of the axis) at distance
    z_m (metres from z = 0) on an rz grid."""
    x = np.asarray(x_m, float).reshape(-1)
    return field_sampler(grid, np.stack([np.full_like(x, z_m), x], 1))


def axis_line(grid: Grid, z_m) -> FieldSampler:
    """The sampler of the axis (x = 0) at distances z_m (metres) on an rz grid."""
    z = np.asarray(z_m, float).reshape(-1)
    return field_sampler(grid, np.stack([z, np.zeros_like(z)], 1))
