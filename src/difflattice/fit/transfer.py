"""Transfer matrices: the complex response at the measured points to a unit drive of each source
cell, at the drive frequency.

The field is linear in the source terms, so a model with cell amplitudes a_k = w_k exp(i omega
tau_k) predicts p = sum_k T_k a_k. In free field the lattice is translation invariant, so one
simulation of a single cell gives every T_k:

- lobe: the Kirchhoff-Helmholtz transform of the single cell's contour phasors, evaluated at the
  measurement points shifted by each cell's offset (exact at any range, no far-field
  approximation);
- wavefront: the single cell's phasors on a block of 4 columns x many rows around the scan line,
  interpolated (4-point Lagrange in both directions) at the shifted positions.

Phasors are divided by the discrete spectrum of the drive at the same frequency, so T does not
depend on the burst used to compute it. `superposition_transfer` computes the same matrices with
one simulation per cell (any scene, also with objects) and is the reference for the fast path.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Literal

import jax
import numpy as np

from ..lattice.coefficients import Edges
from ..lattice.grid import Grid, make_grid
from ..lattice.medium import Medium, air_density_kg_m3
from ..lattice.window import Span, Window
from ..observe.farfield import BoxContour, field_at
from ..solver.loop import simulate
from ..solver.sensors import Sensors
from ..solver.sources import PointSources, ToneBurst


@dataclass
class Transfer:
    """Complex transfer matrices (measured point x source cell) and their provenance."""

    grid: Grid
    n_cells: int
    cell_offset_m: np.ndarray  # (N,) positions of the cells across the face, m (0 = centre)
    lobe: np.ndarray | None  # (A, N)
    wave: np.ndarray | None  # (J, N)
    info: dict = field(default_factory=dict)

    @property
    def omega_rad_s(self) -> float:
        return 2 * math.pi * self.grid.frequency_hz


def _lagrange4(t):
    """Weights of 4-point Lagrange interpolation at fraction t in [0, 1) for nodes -1, 0, 1, 2."""
    t = np.asarray(t, float)
    return np.stack(
        [
            -t * (t - 1) * (t - 2) / 6,
            (t + 1) * (t - 1) * (t - 2) / 2,
            -(t + 1) * t * (t - 2) / 2,
            (t + 1) * t * (t - 1) / 6,
        ],
        axis=-1,
    )


def _source_spectrum(sig, grid: Grid, n_steps: int) -> complex:
    n = np.arange(1, n_steps + 1)
    s = np.asarray(jax.jit(sig)(jax.device_put(n * grid.dt_s)))  # one program, not one per operation
    return complex(np.sum(s * np.exp(1j * grid.omega * n)))


def free_field_transfer(
    *,
    frequency_hz: float,
    c_m_s: float,
    n_cells: int,
    cells_per_wavelength: float = 20.0,
    lobe_angle_deg=None,
    lobe_range_m: float | None = None,
    wave_x_m=None,
    wave_z_m: float | None = None,
    dtype: Literal["float32", "float64"] = "float64",
    pml_cells: int = 20,
    contour_gap: int = 3,
    dispersion: Literal["lattice", "continuum"] = "continuum",
) -> Transfer:
    """Transfer matrices of a line of `n_cells` cells (spacing one cell) in free air.
    `contour_gap`: cells between the source cell and the Kirchhoff-Helmholtz contour.
    `dispersion`: wavenumber of the far-field propagation. "continuum" (default) propagates from a
    contour 3 cells from each cell with the physical k, so the path differences between cells
    across the aperture, which set the lobe's null angles, carry no lattice dispersion (at 20
    cells per wavelength the lattice's 0.4 % slower waves move the first null of a 38 mm piston
    by ~0.05 deg, several sigma of a good lobe measurement); "lattice" reproduces the lattice's
    own far field (what a direct simulation to that range would give)."""
    if wave_x_m is not None and wave_z_m is None:
        raise ValueError("wave_x_m needs wave_z_m, the wavefront line's distance from the face in m")
    if lobe_angle_deg is not None and lobe_range_m is None:
        raise ValueError("lobe_angle_deg needs lobe_range_m, the lobe's measurement range in m")
    grid0 = make_grid(
        frequency_hz=frequency_hz, cells_per_wavelength=cells_per_wavelength, c_max_m_s=c_m_s, shape=(3, 3), dtype=dtype
    )
    dx = grid0.dx_m
    L = pml_cells
    offsets = np.arange(n_cells) - (n_cells - 1) / 2.0  # cells
    gap = contour_gap
    # x: layer, 4 cells, the contour `gap` cells round the source cell, 3 cells, layer (with a
    # wavefront line, the interior reaches 7 cells past its row); y: symmetric about the source
    span_x = Span.open(gap=gap, layer=L, pad=4, pad_hi=3)
    if wave_x_m is not None:
        assert wave_z_m is not None  # checked above
        zc = wave_z_m / dx
        if zc < gap + 3:
            raise ValueError(f"wavefront distance z = {wave_z_m} m is too close to the face for this grid")
        iz = int(math.floor(zc))
        half = int(math.ceil(np.max(np.abs(wave_x_m)) / dx + np.max(np.abs(offsets)) + 4))
        span_x = span_x.with_reach(span_x.source + iz + 7)
    else:
        half = gap + 4
    win = Window((span_x, Span.open(gap=gap, layer=L, pad=half + 2 - gap)))
    (nx, ny), (xs, yc) = win.shape, win.source
    grid = make_grid(
        frequency_hz=frequency_hz,
        cells_per_wavelength=cells_per_wavelength,
        c_max_m_s=c_m_s,
        shape=(nx, ny),
        dtype=dtype,
    )
    (x0, x1), (y0, y1) = win.box
    contour = BoxContour(x0, x1, y0, y1)
    parts = [contour.cells]
    if wave_x_m is not None:
        cols = xs + iz + np.arange(-1, 3)
        rows = yc + np.arange(-half, half + 1)
        block = np.stack(np.meshgrid(cols, rows, indexing="ij"), -1).reshape(-1, 2)
        parts.append(block)
    cells = np.concatenate(parts)
    sig = ToneBurst(frequency_hz, 4.0)
    src = PointSources(
        cells=np.array([(xs, yc)]),
        signal=sig,
        weights=jax.device_put(np.ones(1, grid.dtype)),
        lags_s=jax.device_put(np.zeros(1, grid.dtype)),
    )
    reach = math.hypot(nx - xs, half) / grid.courant
    n_steps = int(reach + 10 * grid.steps_per_period)
    t0 = time.perf_counter()
    res = simulate(
        grid,
        Medium(c_m_s, air_density_kg_m3(20.0)),
        src,
        Sensors(phasor_cells=cells),
        n_steps=n_steps,
        edges=Edges(thickness_cells=L),
    )
    ph = np.asarray(res.phasors) / _source_spectrum(sig, grid, n_steps)
    sim_s = time.perf_counter() - t0
    m2 = len(contour.cells)
    lobe = wave = None
    if lobe_angle_deg is not None:
        assert lobe_range_m is not None  # checked above
        th = np.radians(np.asarray(lobe_angle_deg, float))
        r = lobe_range_m / dx
        # observation points seen from each cell: shift by -offset along y
        obs = np.stack([xs + r * np.cos(th), yc + r * np.sin(th)], -1)  # (A, 2)
        pts = obs[:, None, :] - np.stack([np.zeros(n_cells), offsets], -1)[None, :, :]  # (A, N, 2)
        lobe = np.asarray(field_at(ph[:m2], contour, grid, pts.reshape(-1, 2), dispersion=dispersion)).reshape(
            len(th), n_cells
        )
    if wave_x_m is not None:
        blk = ph[m2:].reshape(4, 2 * half + 1)
        tz = zc - iz
        wz = _lagrange4(tz)  # (4,)
        col = wz @ blk  # (2 half + 1,) field on the line at distance z
        u = (np.asarray(wave_x_m, float)[:, None] / dx - offsets[None, :]) + half  # row coordinate
        i = np.floor(u).astype(int)
        wy = _lagrange4(u - i)  # (J, N, 4)
        idx = i[..., None] + np.arange(-1, 3)
        if idx.min() < 0 or idx.max() > 2 * half:
            raise ValueError("wavefront positions outside the computed block (internal error)")
        wave = np.sum(col[idx] * wy, axis=-1)
    info = {
        "grid_shape": [nx, ny],
        "n_steps": n_steps,
        "simulation_s": sim_s,
        "method": "free-field translation",
        "farfield_dispersion": dispersion,
        "cells_per_wavelength": cells_per_wavelength,
        "dx_m": dx,
        "dt_s": grid.dt_s,
    }
    return Transfer(grid=grid, n_cells=n_cells, cell_offset_m=offsets * dx, lobe=lobe, wave=wave, info=info)
