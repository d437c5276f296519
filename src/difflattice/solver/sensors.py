"""Sensors: what is recorded inside the time loop (never the whole field history).

- `probes`: cells whose pressure is recorded every step (time series).
- `phasor_cells`: cells whose running DFT at one frequency is accumulated on the fly
  (complex amplitude, sum over steps of p(n) exp(+i omega n)); arcs, lines and the far-field
  contour are phasor cells.
- `p_max`, `p_rms`, `arrival_threshold_pa`: whole-field statistics (peak |p|, RMS, first step at
  which |p| exceeds a threshold), each compiled in only when asked.
- `snapshot_every`: the field every k steps, for images and animations.
"""

from __future__ import annotations


import equinox as eqx
import numpy as np

from ..lattice.grid import Grid
from jaxtyping import Array, Int

from .sources import as_cells


class Sensors(eqx.Module):
    """What to record. The number of cells fixes output shapes; their positions are data (moving a
    sensor does not recompile).

    **Arguments:**
    - `probes`: (n, 2) cell indices recorded every step.
    - `phasor_cells`: (m, 2) cell indices whose DFT at `phasor_frequency_hz` is accumulated.
    - `phasor_frequency_hz`: None means the grid's drive frequency.
    - `phasor_from_step`: accumulate the phasors over steps n > this only (0: all steps). For a
      continuous wave, start once the field is steady and run a whole number of periods after it
      (with a whole number of steps per period the DFT has no leakage): the phasor is then
      (n_steps - phasor_from_step) / 2 times the complex amplitude (p = Re(A exp(-i omega t))).
    - `p_max`, `p_rms`: record the whole-field peak |p| and RMS (Pa).
    - `arrival_threshold_pa`: if set, record the first step at which |p| exceeds it (-1: never).
    - `snapshot_every`: if set, return the field every that many steps.
    """

    probes: Int[Array, "n 2"] = eqx.field(default=(), converter=as_cells)
    phasor_cells: Int[Array, "m 2"] = eqx.field(default=(), converter=as_cells)
    phasor_frequency_hz: float | None = eqx.field(static=True, default=None)
    phasor_from_step: int = eqx.field(static=True, default=0)
    p_max: bool = eqx.field(static=True, default=False)
    p_rms: bool = eqx.field(static=True, default=False)
    arrival_threshold_pa: float | None = eqx.field(static=True, default=None)
    snapshot_every: int | None = eqx.field(static=True, default=None)

    def __check_init__(self):
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

    def check_inside(self, grid: Grid) -> None:
        nx, ny = grid.shape
        for name, cells in (("probes", self.probes), ("phasor_cells", self.phasor_cells)):
            if not isinstance(cells, np.ndarray):
                continue  # traced positions: not checkable here
            for ix, iy in cells:
                if not (0 <= ix < nx and 0 <= iy < ny):
                    raise ValueError(
                        f"sensor {name} cell ({ix}, {iy}) lies outside the {nx} x {ny} grid"
                    )


def probe_cells(grid: Grid, points_m) -> np.ndarray:
    """Cells containing points given in metres ((x, y), or (z, r) on an rz grid), shape (n, 2)."""
    pts = np.asarray(points_m, dtype=float).reshape(-1, 2)
    if grid.kind == "rz":
        return np.floor(pts / grid.dx_m).astype(np.int64)
    return np.rint(pts / grid.dx_m).astype(np.int64)


def arc_cells(grid: Grid, centre_m, radius_m: float, angles_deg) -> np.ndarray:
    """Cells nearest to points on an arc (angle 0 = +x, counter-clockwise towards +y)."""
    a = np.radians(np.asarray(angles_deg, dtype=float))
    pts = np.stack([centre_m[0] + radius_m * np.cos(a), centre_m[1] + radius_m * np.sin(a)], 1)
    return probe_cells(grid, pts)
