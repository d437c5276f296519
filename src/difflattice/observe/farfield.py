"""Near-to-far-field transform: the 2-D Kirchhoff-Helmholtz integral over a box around the sources.

The simulator records phasors at the drive frequency on two nested rectangles of cells, one cell
apart; their mean and difference give p and dp/dn on the rectangle through the faces between them.
The field outside is then

    p(x) = sum over the contour [ p(x') dG/dn'(x, x') - G(x, x') dp/dn'(x') ] dl'

with G = (i/4) H0^(1)(k |x - x'|) (time convention exp(-i omega t), n' the outward normal). The
Hankel functions use their large-argument expansion to four terms (relative error < 2e-7 for
k |x - x'| > 30). With ``dispersion="lattice"`` the wavenumber of each observation direction
follows the lattice dispersion relation, so the transform continues the lattice's own field;
``"continuum"`` uses k = omega / c.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import ClassVar, Literal

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from ..lattice.grid import Grid
from ..lattice.kinds import PLANE, LatticeKind
from .analytic import lattice_wavenumber
from .farfield_base import FarFieldSurface, no_plane, split_pairs


class BoxContour(FarFieldSurface):
    """A rectangle of cells [ix0, ix1] x [iy0, iy1] (inner ring) and its outer ring: the plane
    lattice's far-field surface.

    `cells` lists the inner then the outer cells of each contour sample (2M cells); `points`
    are the sample positions (cells), `normals` the outward unit normals.
    """

    kind: ClassVar[LatticeKind] = PLANE

    ix0: int = eqx.field(static=True)
    ix1: int = eqx.field(static=True)
    iy0: int = eqx.field(static=True)
    iy1: int = eqx.field(static=True)

    def __check_init__(self):
        if not (self.ix1 > self.ix0 and self.iy1 > self.iy0):
            raise ValueError(f"empty contour box [{self.ix0}, {self.ix1}] x [{self.iy0}, {self.iy1}]")

    @classmethod
    def from_box(cls, lo, hi, baffle: str | None = None) -> BoxContour:
        if baffle is not None:
            raise ValueError(
                f"baffle = {baffle!r}: a plane contour is closed (no baffle image on the plane lattice); "
                "leave baffle out"
            )
        return cls(int(lo[0]), int(hi[0]), int(lo[1]), int(hi[1]))

    @property
    def box(self) -> tuple[tuple[int, ...], tuple[int, ...]]:
        return (self.ix0, self.iy0), (self.ix1, self.iy1)

    @property
    def open_sides(self) -> tuple[tuple[int, int], ...]:
        return ()

    def samples(self):
        """(inner (M,2), outer (M,2), points (M,2), normals (M,2)) in cell units."""
        xs = np.arange(self.ix0, self.ix1 + 1)
        ys = np.arange(self.iy0, self.iy1 + 1)
        inner, outer, normal = [], [], []
        for y in ys:  # left and right sides
            inner += [(self.ix0, y), (self.ix1, y)]
            outer += [(self.ix0 - 1, y), (self.ix1 + 1, y)]
            normal += [(-1, 0), (1, 0)]
        for x in xs:  # bottom and top sides
            inner += [(x, self.iy0), (x, self.iy1)]
            outer += [(x, self.iy0 - 1), (x, self.iy1 + 1)]
            normal += [(0, -1), (0, 1)]
        inner, outer, normal = (np.asarray(a, dtype=np.int64) for a in (inner, outer, normal))
        points = 0.5 * (inner + outer)
        return inner, outer, points, normal.astype(float)

    def _outside_message(self, shape, margin: int) -> str:
        return (
            f"far-field contour [{self.ix0}, {self.ix1}] x [{self.iy0}, {self.iy1}] (plus its outer "
            f"ring) must lie inside the grid and outside the {margin}-cell absorbing layer"
        )

    def field_at(self, phasors, grid, points_cells, **kwargs):
        return field_at(phasors, self, grid, points_cells, **kwargs)

    def far_field(self, phasors, grid, angles_deg, *, range_m=None, centre_cells=None, plane=None, **kwargs):
        no_plane(plane, "plane")
        if range_m is None:
            return far_field_pattern(phasors, self, grid, angles_deg, centre_cells=centre_cells, **kwargs)
        if centre_cells is None:
            centre_cells = tuple(self.samples()[2].mean(0))
        return far_field(phasors, self, grid, angles_deg, range_m, centre_cells, **kwargs)


def box_around(cells: np.ndarray, gap: int, grid: Grid | None = None) -> BoxContour:
    """The contour box `gap` cells around a set of cells (e.g. a transducer's)."""
    return BoxContour.around(cells, gap)


def _hankel(nu: int, z):
    """H_nu^(1)(z) by its asymptotic expansion (4 terms), complex for real z > 0 (NumPy).
    sqrt(2 / (pi z)) exp(i (z - nu pi/2 - pi/4)) (1 + a1 i/z + a2 (i/z)^2 + a3 (i/z)^3), the
    series split into its real part 1 - a2/z^2 and imaginary part a1/z - a3/z^3: real
    arithmetic on the (observation x contour) arrays, no complex powers."""
    mu = 4.0 * nu * nu
    a1 = (mu - 1) / 8
    a2 = a1 * (mu - 9) / (2 * 8)
    a3 = a2 * (mu - 25) / (3 * 8)
    u = 1.0 / np.asarray(z, dtype=float)
    u2 = u * u
    s_re = 1.0 - a2 * u2
    s_im = u * (a1 - a3 * u2)
    amp = np.sqrt((2 / math.pi) * u)
    phase = z - (nu * math.pi / 2 + math.pi / 4)
    c, s = amp * np.cos(phase), amp * np.sin(phase)
    out = np.empty(np.shape(u), dtype=complex)
    out.real = c * s_re - s * s_im
    out.imag = c * s_im + s * s_re
    return out


def far_field(
    phasors: Complex[Array, " two_m"],
    contour: BoxContour,
    grid: Grid,
    angles_deg: Sequence[float] | Float[np.ndarray, " a"],
    range_m: float,
    centre_cells: tuple[float, float],
    **kwargs,
) -> Complex[Array, " a"]:
    """Complex pressure at `range_m` from `centre_cells` at `angles_deg` (0 = +x, towards +y), from
    contour phasors ordered as `contour.cells` (inner ring then outer ring). The angles are host
    values (a tuple or NumPy array, never traced: they set the propagation kernel). Keyword
    arguments go to `field_at`."""
    theta = np.radians(np.asarray(angles_deg, dtype=float))
    r = grid.m_to_cells(range_m)
    obs = np.stack([centre_cells[0] + r * np.cos(theta), centre_cells[1] + r * np.sin(theta)], 1)
    return field_at(phasors, contour, grid, obs, **kwargs)


def field_at(
    phasors: Complex[Array, " two_m"] | Complex[np.ndarray, " two_m"],
    contour: BoxContour,
    grid: Grid,
    points_cells: Float[np.ndarray, "a 2"],
    *,
    c_lattice: float | None = None,
    dispersion: Literal["lattice", "continuum"] = "lattice",
    frequency_hz: float | None = None,
) -> Complex[Array, " a"]:
    """Complex pressure at points outside the contour (positions in cells); NumPy phasors give a
    NumPy result (no XLA program), JAX ones a JAX array (differentiable)."""
    inner, outer, pts, normals = contour.samples()
    p, dpdn = split_pairs(phasors, len(inner), "contour phasors (inner then outer ring)")
    omega = grid.hz_to_lattice_omega(frequency_hz or grid.frequency_hz)
    c = grid.courant if c_lattice is None else c_lattice
    obs = np.asarray(points_cells, dtype=float).reshape(-1, 2)
    d = obs[:, None, :] - pts[None, :, :]  # (A, M, 2)
    R = np.sqrt((d**2).sum(-1))
    centre = pts.mean(0)
    theta = np.arctan2(obs[:, 1] - centre[1], obs[:, 0] - centre[0])
    k = _wavenumbers(grid, omega, c, theta, dispersion)
    kR = k[:, None] * R
    if kR.min() < 30:
        raise ValueError("far-field point too close to the contour (k R < 30): use a larger range")
    dR_dn = -(d * normals[None]).sum(-1) / R  # derivative of R with respect to x' along n'
    G = 0.25j * _hankel(0, kR)
    dG_dR = -0.25j * k[:, None] * _hankel(1, kR)
    # host kernels (NumPy): NumPy phasors give a NumPy field with no XLA program at all
    kernel_p = dG_dR * dR_dn
    kernel_dp = -G
    return p @ kernel_p.T + dpdn @ kernel_dp.T


def _wavenumbers(grid, omega: float, c: float, theta, dispersion: str) -> np.ndarray:
    if dispersion == "lattice":
        return lattice_wavenumber(omega, c, theta, stencil=grid.stencil)
    if dispersion == "continuum":
        return np.full_like(theta, omega / c)
    raise ValueError(f"dispersion = {dispersion!r}; allowed: 'lattice', 'continuum'")


def far_field_pattern(
    phasors: Complex[Array, " two_m"] | Complex[np.ndarray, " two_m"],
    contour: BoxContour,
    grid: Grid,
    angles_deg: Sequence[float] | Float[np.ndarray, " a"],
    *,
    centre_cells: tuple[float, float] | None = None,
    c_lattice: float | None = None,
    dispersion: Literal["lattice", "continuum"] = "lattice",
    frequency_hz: float | None = None,
) -> Complex[Array, " a"]:
    """The plane far-field pattern F(theta) (Pa x cells^(1/2)): p(r, theta) ~ F exp(i k r) / sqrt(r),
    r in cells from `centre_cells` (default: the contour's centre), at `angles_deg` (0 = +x,
    towards +y). The Hankel function's leading term, (i/4) H0(k R) ~ C exp(i k R) / sqrt(R) with
    C = (i/4) sqrt(2 / (pi k)) exp(-i pi/4), and R ~ r - x_hat . x' give

        F = C sum [ -i k (x_hat . n') p - dp/dn' ] exp(-i k x_hat . x') dl'.
    """
    inner, _, pts, normals = contour.samples()
    p, dpdn = split_pairs(phasors, len(inner), "contour phasors (inner then outer ring)")
    omega = grid.hz_to_lattice_omega(frequency_hz or grid.frequency_hz)
    c = grid.courant if c_lattice is None else c_lattice
    theta = np.radians(np.asarray(angles_deg, dtype=float)).reshape(-1)
    k = _wavenumbers(grid, omega, c, theta, dispersion)[:, None]
    u = np.stack([np.cos(theta), np.sin(theta)], 1)
    centre = pts.mean(0) if centre_cells is None else np.asarray(centre_cells, float)
    C = 0.25j * np.sqrt(2 / (math.pi * k)) * np.exp(-0.25j * math.pi)
    ph = C * np.exp(-1j * k * (u @ (pts - centre).T))
    kernel_p = -1j * k * (u @ normals.T) * ph
    kernel_dp = -ph
    return p @ kernel_p.T + dpdn @ kernel_dp.T


def level_db(p, floor_db: float = -80.0, reference=None):
    """20 log10 |p| relative to `reference` (default: max |p|), floored at `floor_db`."""
    a = jnp.abs(p)
    ref = jnp.max(a) if reference is None else reference
    return jnp.maximum(20 * jnp.log10(jnp.maximum(a / ref, 1e-30)), floor_db)
