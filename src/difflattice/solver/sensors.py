"""Sensors: what is recorded inside the time loop (never the whole field history).

- `probes`: cells whose pressure is recorded every step (time series).
- `phasor_cells`: cells whose running DFT at one frequency is accumulated on the fly
  (complex amplitude, sum over steps of p(n) exp(+i omega n)); arcs, lines and the far-field
  contour are phasor cells.
- `p_max`, `p_rms`, `arrival_threshold_pa`: whole-field statistics (peak |p|, RMS, first step at
  which |p| exceeds a threshold), each compiled in only when asked.
- `snapshot_every`: the field every k steps, for images and animations; on a 3-D grid only
  planes of it (`snapshot_slices`, default the three mid-planes) unless the whole volume is asked
  for (`snapshot_slices="volume"`).
- `received_signal`: what a transducer receives from the pressures recorded at its cells
  (pulse-echo by reciprocity).
"""

from __future__ import annotations

import equinox as eqx
import jax
import numpy as np

from ..lattice.grid import Grid
from .sources import Cells, as_cells


class Sensors(eqx.Module):
    """What to record. The number of cells fixes output shapes; their positions are data (moving a
    sensor does not recompile).

    **Arguments:**
    - `probes`: (n, 2) cell indices recorded every step ((n, 3) on a 3-D grid).
    - `phasor_cells`: (m, 2) (or (m, 3)) cell indices whose DFT at `phasor_frequency_hz` is accumulated.
    - `phasor_frequency_hz`: None means the grid's drive frequency.
    - `phasor_from_step`: accumulate the phasors over steps n > this only (0: all steps). For a
      continuous wave, start once the field is steady and run a whole number of periods after it
      (with a whole number of steps per period the DFT has no leakage): the phasor is then
      (n_steps - phasor_from_step) / 2 times the complex amplitude (p = Re(A exp(-i omega t))).
    - `p_max`, `p_rms`: record the whole-field peak |p| and RMS (Pa).
    - `arrival_threshold_pa`: if set, record the first step at which |p| exceeds it (-1: never).
    - `snapshot_every`: if set, return the field every that many steps.
    - `snapshot_slices` (3-D grids): the planes kept as snapshots, ((axis, index), ...) with axis
      0 = x, 1 = y, 2 = z (default None: the three mid-planes), or "volume" for the whole field
      (nx ny nz values per snapshot).
    """

    probes: Cells = eqx.field(default=(), converter=as_cells)
    phasor_cells: Cells = eqx.field(default=(), converter=as_cells)
    phasor_frequency_hz: float | None = eqx.field(static=True, default=None)
    phasor_from_step: int = eqx.field(static=True, default=0)
    p_max: bool = eqx.field(static=True, default=False)
    p_rms: bool = eqx.field(static=True, default=False)
    arrival_threshold_pa: float | None = eqx.field(static=True, default=None)
    snapshot_every: int | None = eqx.field(static=True, default=None)
    snapshot_slices: tuple[tuple[int, int], ...] | str | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        sl = self.snapshot_slices
        if sl is not None and sl != "volume":
            if not (
                isinstance(sl, tuple)
                and sl
                and all(
                    isinstance(t, tuple) and len(t) == 2 and t[0] in (0, 1, 2) and isinstance(t[1], int) for t in sl
                )
            ):
                raise ValueError(
                    f"snapshot_slices = {sl!r}: give ((axis, index), ...) with axis 0, 1 or 2, or 'volume'"
                )
        if self.snapshot_every is not None and self.snapshot_every < 1:
            raise ValueError(f"snapshot_every = {self.snapshot_every} must be >= 1 step")
        if not (isinstance(self.phasor_from_step, (int, np.integer)) and self.phasor_from_step >= 0):
            raise ValueError(f"phasor_from_step = {self.phasor_from_step!r} must be an integer >= 0 (steps)")
        if self.arrival_threshold_pa is not None and not self.arrival_threshold_pa > 0:
            raise ValueError(f"arrival_threshold_pa = {self.arrival_threshold_pa} must be > 0")

    @property
    def n_probes(self) -> int:
        return int(self.probes.shape[0])

    @property
    def n_phasors(self) -> int:
        return int(self.phasor_cells.shape[0])

    def snapshot_planes(self, shape) -> tuple[tuple[int, int], ...] | None:
        """The (axis, index) planes a 3-D snapshot keeps (None: the whole field)."""
        if len(shape) != 3 or self.snapshot_slices == "volume":
            return None
        if self.snapshot_slices is None or isinstance(self.snapshot_slices, str):
            return tuple((a, n // 2) for a, n in enumerate(shape))
        return self.snapshot_slices

    def snapshot_of(self, p):
        """What a snapshot keeps of the field `p`: all of it in 2-D (and for "volume"), otherwise a
        tuple of planes (one (n_i, n_j) array per (axis, index) of `snapshot_planes`)."""
        planes = self.snapshot_planes(p.shape)
        if planes is None:
            return p
        return tuple(jax.lax.index_in_dim(p, i, axis=a, keepdims=False) for a, i in planes)

    def check_inside(self, grid: Grid) -> None:
        shape = tuple(grid.shape)
        dims = " x ".join(map(str, shape))
        if self.snapshot_slices is not None and len(shape) != 3:
            raise ValueError("snapshot_slices applies to 3-D grids only (a 2-D snapshot is the whole field)")
        for a, i in self.snapshot_planes(shape) or ():
            if not 0 <= i < shape[a]:
                raise ValueError(
                    f"snapshot slice (axis {a}, index {i}) lies outside the grid's {shape[a]} cells along that axis"
                )
        for name, cells in (("probes", self.probes), ("phasor_cells", self.phasor_cells)):
            if not isinstance(cells, np.ndarray) or len(cells) == 0:
                continue  # traced positions: not checkable here
            if cells.shape[1] != len(shape):
                raise ValueError(
                    f"sensor {name} cells have {cells.shape[1]} indices each; the {dims} grid needs {len(shape)}"
                )
            out = (cells < 0) | (cells >= np.asarray(shape))
            if out.any():
                bad = tuple(int(v) for v in cells[np.argmax(out.any(axis=1))])
                raise ValueError(f"sensor {name} cell {bad} lies outside the {dims} grid")


def probe_cells(grid: Grid, points_m) -> np.ndarray:
    """Cells containing points given in metres ((x, y), (x, y, z) on a 3-D grid, or (z, r) on an
    rz grid), shape (n, 2) or (n, 3)."""
    return grid.cells_of(points_m)


def arc_cells(grid: Grid, centre_m, radius_m: float, angles_deg) -> np.ndarray:
    """Cells nearest to points on an arc (angle 0 = +x, counter-clockwise towards +y)."""
    a = np.radians(np.asarray(angles_deg, dtype=float))
    pts = np.stack([centre_m[0] + radius_m * np.cos(a), centre_m[1] + radius_m * np.sin(a)], 1)
    return probe_cells(grid, pts)


def received_signal(probe_series, weights, lags_s=None, dt_s: float | None = None):
    """What a transducer receives (reciprocity): ``e(n) = sum_i w_i p_i(n - lag_i / dt)`` from the
    pressures `probe_series` (n_steps, n_cells) recorded at its source cells (the probes of
    `Sensors(probes=source.cells)`), its `weights` (n_cells,) and `lags_s` (n_cells,) (a lag that
    delays cell i on transmit delays its signal on receive; fractional delays by linear
    interpolation, `dt_s` the time step). Pulse-echo: the A-scan of the scene. Differentiable."""
    import jax.numpy as jnp

    p = jnp.asarray(probe_series)
    w = jnp.asarray(weights, p.dtype)
    if p.ndim != 2 or p.shape[1] != w.shape[0]:
        raise ValueError(f"probe_series {p.shape} must be (n_steps, {w.shape[0]}): one column per transducer cell")
    if lags_s is None:
        return p @ w
    if dt_s is None:
        raise ValueError("give dt_s (the grid's time step) to apply the lags")
    d = jnp.asarray(lags_s, p.dtype) / dt_s  # delay in steps, per cell
    n = jnp.arange(p.shape[0], dtype=p.dtype)[:, None] - d[None, :]
    i0 = jnp.floor(n)
    f = n - i0
    i0 = i0.astype(jnp.int32)
    cols = jnp.arange(p.shape[1])[None, :]

    def at(i):
        ok = (i >= 0) & (i < p.shape[0])
        return jnp.where(ok, p[jnp.clip(i, 0, p.shape[0] - 1), cols], 0.0)

    return ((1 - f) * at(i0) + f * at(i0 + 1)) @ w
