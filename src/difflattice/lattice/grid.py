"""Grid and units: the one place where physical (SI) and lattice units meet.

Inside the simulator everything is in lattice units: one cell is the length unit and one time step
the time unit, so speeds are in cells/step. The paper's scales (McKerrow, Zhu & New 2001, eqs.
11-12) fix the cell size from the drive frequency and the number of cells per wavelength in the
fastest medium, and the time step from a Courant number (the fastest medium's speed in
cells/step).

    model scale  S = m f / c_max             cells per metre   (m = cells per wavelength)
    sim rate     R = c_max S / courant        steps per second

Two kinds of lattice (`Grid.kind`, static):

- ``"2d"``: a plane of square cells; axis 0 is x, axis 1 is y; the origin is the centre of cell
  (0, 0).
- ``"rz"``: an axisymmetric (r-z) lattice of ring cells, the meridian plane of a body of
  revolution. Axis 0 is z (the propagation direction: sources facing +x in 2-D face +z here),
  axis 1 is r. The axis r = 0 is the low face of ring 0 (cell centres at r = (j + 1/2) dx), and
  the origin (z = 0, r = 0) is the low corner of cell (0, 0), so the z_lo window face is z = 0
  (where a rigid baffle lies). The y_lo window side is the axis (`Edges(y_lo="axis")`).
- ``"3d"``: a volume of cubic cells, shape (nx, ny, nz); axes 0, 1, 2 are x, y, z; the origin is
  the centre of cell (0, 0, 0).

The plane and r-z leapfrogs are stable for speeds up to `stability_limit(kind)` = 1/sqrt(2)
cells/step, the 3-D seven-point leapfrog up to 1/sqrt(3); a faster one is refused (see
`stability_limit` for the derivations).
"""

from __future__ import annotations

import math
from typing import Literal

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .kinds import (
    DEFAULT_COURANT_3D,
    KINDS,
    MAX_COURANT,
    MAX_COURANT_3D,
    MAX_COURANT_ISOTROPIC,
    PAPER_COURANT,
    STENCILS,
    LatticeKind,
    StencilKind,
    as_kind,
)

__all__ = [
    "DEFAULT_COURANT_3D",
    "GRID_KINDS",
    "MAX_COURANT",
    "MAX_COURANT_3D",
    "MAX_COURANT_ISOTROPIC",
    "PAPER_COURANT",
    "STENCILS",
    "Grid",
    "GridKind",
    "LatticeKind",
    "StencilKind",
    "check_courant",
    "make_grid",
    "stability_limit",
]

GridKind = Literal["2d", "rz", "3d"]
GRID_KINDS = tuple(KINDS)


def stability_limit(kind: LatticeKind | GridKind = "2d", stencil: StencilKind = "standard") -> float:
    """Largest stable lattice speed (cells/step) of the leapfrog on a grid of `kind` with the
    spatial `stencil`.

    The leapfrog ``P(t+1) = 2 P - P(t-1) + c^2 L P`` is stable iff c^2 rho(-L) <= 4, rho the
    spectral radius of the spatial operator (cells^-2).

    - "2d": -L is the five-point Laplacian, rho < 8 on any finite grid, so c <= 1/sqrt(2).
    - "rz": the finite-volume operator on ring cells (axis on the low face of ring 0, ring
      volume V_j = j + 1/2, radial face areas A_f = f, axial faces (j + 1/2), per radian) is
      ``(L P)_ij = P_(i+1)j + P_(i-1)j - 2 P_ij + [A_(j+1) (P_i(j+1) - P_ij) - A_j (P_ij - P_i(j-1))] / V_j``
      (no 1/r: the axis face has zero area, so ring 0 is exact). L is similar to a symmetric
      matrix (V^(1/2) L V^(-1/2)), so its eigenvalues are real, and by Gershgorin's theorem each row
      bounds them: axial 2 + 2, radial |A_(j+1) + A_j| / V_j + (A_(j+1) + A_j) / V_j = 2 + 2, in all
      rho <= 8, the 2-D bound, for every ring including the axis one. Measured (dense and Lanczos
      eigenvalues of the actual operator, n x n rings): rho = 7.800, 7.985, 7.9991, 7.99994 for
      n = 8, 32, 128, 512, tending to 8 (the checkerboard far from the axis): the limit 1/sqrt(2) is
      sharp. (With a node on the axis instead, a disc cell of radius 1/2, rho tends to 8.8418 and
      the limit drops to 0.6726: that is why the axis lies on a face here.)
    - "3d": -L is the seven-point Laplacian, rho < 12 (the checkerboard (pi, pi, pi) tends to 12),
      so c <= 1/sqrt(3).
    - stencil "isotropic" (plane, rz): -L = D^T M D with the flux filter M = 1 + d_t^2 / 12 per
      axis (d_t the second difference across the face; 2/3 <= M <= 1); its symbol is
      4 [sx (1 - sy / 3) + sy (1 - sx / 3)] with sx = sin^2(kx/2), sy = sin^2(ky/2), largest at the
      checkerboard: rho < 16/3, so c <= sqrt(3)/2. On the rz grid the filter of the axial fluxes
      across rings is the area-weighted one (the same ring metric), which keeps L similar to a
      symmetric matrix; measured spectral radius of the actual rz operator
      (`tests/core/test_isotropic_stencil.py`): below 16/3 for every size tried.
    - stencil "wide" (3-D): ``L = L7 + a sum T_i T_j - (e/4) sum D_i W D_i`` (a = 0.08, e = 1/4),
      symbol ``-4 B``, ``B = sum s_i + e sum s_i^2 - 4a sum s_i s_j``; B is convex along each s_i,
      so its maximum over [0, 1]^3 is at a vertex: 3 + 3e - 12a = 2.79 at (pi, pi, pi), and
      c <= 1/sqrt(2.79) = 0.5987 (`kinds.MAX_COURANT_WIDE`).
    """
    return as_kind(kind).stability_limit(stencil)


class Grid(eqx.Module):
    """A square-cell lattice of `shape` = (nx, ny) cells, axis 0 is x and axis 1 is y (for
    `kind` = "rz": axis 0 is z and axis 1 is r; for `kind` = "3d": (nx, ny, nz) cubic cells; see
    the module docstring).

    All fields are static (they decide array shapes and compiled structure).

    **Arguments:**
    - `shape`: number of cells along x and y (and z for "3d").
    - `frequency_hz`: drive frequency the scales are built for.
    - `cells_per_wavelength`: cells per wavelength in the fastest medium at `frequency_hz`.
    - `c_max_m_s`: speed of sound of the fastest medium in the scene, m/s.
    - `courant`: that medium's speed in cells/step (<= 1/sqrt(2); <= 1/sqrt(3) for "3d").
    - `dtype`: "float32" or "float64".
    - `kind`: "2d" (plane), "rz" (axisymmetric ring cells; the y_lo side is the axis) or "3d".
    - `stencil`: "standard" (the paper's 5-point flux stencil) or "isotropic" (plane and rz: the
      9-point Mehrstellen form, direction-independent phase speed, limit sqrt(3)/2; `STENCILS`) or,
      3-D only, "wide" (25 points, 0.24 % worst phase-speed error at 6 cells/wavelength).
    """

    shape: tuple[int, ...] = eqx.field(static=True)
    frequency_hz: float = eqx.field(static=True)
    cells_per_wavelength: float = eqx.field(static=True)
    c_max_m_s: float = eqx.field(static=True)
    courant: float = eqx.field(static=True, default=PAPER_COURANT)
    dtype: Literal["float32", "float64"] = eqx.field(static=True, default="float32")
    kind: LatticeKind = eqx.field(static=True, default="2d", converter=as_kind)
    stencil: StencilKind = eqx.field(static=True, default="standard")

    def __check_init__(self):
        self.kind.check_shape(self.shape)
        if not (self.frequency_hz > 0 and self.cells_per_wavelength > 0 and self.c_max_m_s > 0):
            raise ValueError(
                "frequency_hz, cells_per_wavelength and c_max_m_s must be positive, got "
                f"{self.frequency_hz}, {self.cells_per_wavelength}, {self.c_max_m_s}"
            )
        self.kind.check_stencil(self.stencil)
        check_courant(
            self.courant, what="grid courant (the fastest medium's speed)", kind=self.kind, stencil=self.stencil
        )
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"dtype must be 'float32' or 'float64', got {self.dtype!r}")

    def describe(self) -> dict:
        """The grid's scales as plain values (SI and lattice units), for a run's summary."""
        return {
            "shape": list(self.shape),
            "dx_m": self.dx_m,
            "dt_s": self.dt_s,
            "kind": self.kind.name,
            "stencil": self.stencil,
            "size_m": list(self.size_m),
            "frequency_hz": self.frequency_hz,
            "cells_per_wavelength": self.cells_per_wavelength,
            "courant": self.courant,
            "steps_per_period": self.steps_per_period,
            "dtype": self.dtype,
        }

    @property
    def ndim(self) -> int:
        """Number of grid axes (2 for "2d" and "rz", 3 for "3d")."""
        return len(self.shape)

    @property
    def max_courant(self) -> float:
        """The stability limit of this kind of lattice and stencil, cells/step (`stability_limit`)."""
        return self.kind.stability_limit(self.stencil)

    # --- scales -------------------------------------------------------------------------
    @property
    def dx_m(self) -> float:
        """Cell size in metres (1 / model scale S)."""
        return self.c_max_m_s / (self.frequency_hz * self.cells_per_wavelength)

    @property
    def dt_s(self) -> float:
        """Time step in seconds (1 / sim rate R)."""
        return self.courant * self.dx_m / self.c_max_m_s

    @property
    def cells_per_m(self) -> float:
        return 1.0 / self.dx_m

    @property
    def steps_per_period(self) -> float:
        """Time steps per period of the drive frequency."""
        return 1.0 / (self.frequency_hz * self.dt_s)

    @property
    def omega(self) -> float:
        """Drive angular frequency in radians per step."""
        return 2.0 * math.pi * self.frequency_hz * self.dt_s

    @property
    def size_m(self) -> tuple[float, ...]:
        return tuple(n * self.dx_m for n in self.shape)

    @property
    def jnp_dtype(self):
        return jnp.float64 if self.dtype == "float64" else jnp.float32

    # --- conversions ----------------------------------------------------------------------
    def speed_to_lattice(self, c_m_s):
        """Speed in m/s -> cells/step (array or float)."""
        return c_m_s * (self.dt_s / self.dx_m)

    def m_to_cells(self, length_m):
        return length_m / self.dx_m

    def cells_to_m(self, cells):
        return cells * self.dx_m

    def s_to_steps(self, time_s):
        return time_s / self.dt_s

    def steps_to_s(self, steps):
        return steps * self.dt_s

    def hz_to_lattice_omega(self, frequency_hz):
        """Frequency in Hz -> angular frequency in radians/step."""
        return 2.0 * math.pi * frequency_hz * self.dt_s

    @property
    def origin_cells(self) -> float:
        """Offset of cell centres from the origin, in cells (`LatticeKind.origin_cells`: 0 for a
        plane or volume, whose origin is the centre of cell 0; 1/2 for rz, whose origin is the
        axis and z = 0)."""
        return self.kind.origin_cells

    def cell_of(self, position_m) -> tuple[int, ...]:
        """Index of the cell containing a point (x_m, y_m[, z_m]), or (z_m, r_m) for "rz"."""
        if len(position_m) != self.ndim:
            raise ValueError(
                f"position {tuple(position_m)} has {len(position_m)} coordinates; this grid has {self.ndim}"
            )
        return tuple(int(i) for i in self.kind.cells_of(np.asarray([position_m], dtype=float), self.dx_m)[0])

    def cells_of(self, points_m) -> np.ndarray:
        """Indices (n, ndim) of the cells containing points given in metres (`cell_of` for many)."""
        pts = np.asarray(points_m, dtype=float).reshape(-1, self.ndim)
        return self.kind.cells_of(pts, self.dx_m)

    def coordinates_m(self) -> tuple[np.ndarray, ...]:
        """Cell-centre coordinates per axis (x_m of shape (nx,), y_m of shape (ny,)[, z_m]); for
        "rz" (z_m, r_m) with r_m = (j + 1/2) dx."""
        return self.kind.coordinates_m(self.shape, self.dx_m)


def check_courant(
    c_lattice: float, what: str = "speed", kind: LatticeKind | GridKind = "2d", stencil: StencilKind = "standard"
) -> None:
    """Refuse a lattice speed above `stability_limit(kind, stencil)` cells/step (unstable, not
    merely inaccurate)."""
    if not (c_lattice >= 0):
        raise ValueError(f"{what} = {c_lattice} cells/step: must be >= 0")
    k = as_kind(kind)
    limit = k.stability_limit(stencil)
    if c_lattice > limit * (1 + 1e-12):
        raise ValueError(
            f"{what} = {c_lattice:.6f} cells/step exceeds the {k.limit_name(stencil)} stability limit "
            f"{k.limit_formula(stencil)} = {limit:.6f}: the leapfrog would grow without bound. Lower `courant` "
            f"({k.usual_courant}) or set c_max_m_s to the fastest medium's speed."
        )


def make_grid(
    *,
    frequency_hz: float,
    cells_per_wavelength: float,
    c_max_m_s: float,
    shape: tuple[int, ...] | None = None,
    size_m: tuple[float, ...] | None = None,
    courant: float | None = None,
    dtype: Literal["float32", "float64"] = "float32",
    kind: LatticeKind | GridKind = "2d",
    stencil: StencilKind = "standard",
) -> Grid:
    """Build a `Grid` from the paper's scale parameters and either `shape` (cells) or `size_m`
    (for `kind` = "rz": (length along z, radius) in metres; for "3d": three sizes). `courant`
    defaults to the paper's 0.707, and to 0.577 for "3d"."""
    k = as_kind(kind)
    if (shape is None) == (size_m is None):
        raise ValueError("give exactly one of shape=(nx, ny[, nz]) cells or size_m=(width_m, height_m[, depth_m])")
    if courant is None:
        courant = k.default_courant
    if shape is None:
        assert size_m is not None
        shape = k.shape_for_size(tuple(size_m), c_max_m_s / (frequency_hz * cells_per_wavelength))
    return Grid(
        shape=tuple(int(n) for n in shape),
        frequency_hz=float(frequency_hz),
        cells_per_wavelength=float(cells_per_wavelength),
        c_max_m_s=float(c_max_m_s),
        courant=float(courant),
        dtype=dtype,
        kind=k,
        stencil=stencil,
    )
