"""Sources: drive signals and transducers (lines of source cells with per-cell weights and lags).

Per-cell weights (dimensionless) and phase lags (seconds) are arrays, so they can be fitted. Cell
positions are integer arrays: their number fixes the compiled shapes, their values do not, so a
moved transducer reuses the compiled simulation. The signal shape and the injection mode are static.
"""

from __future__ import annotations

import math
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ..lattice.grid import Grid


class ToneBurst(eqx.Module):
    """`cycles` cycles of a sine at `frequency_hz` (Hz), starting at t = 0, amplitude in Pa.

    `window` is "hann" (smooth, narrow band) or "rect" (the unwindowed burst, broadband).
    """

    frequency_hz: float = eqx.field(static=True)
    cycles: float = eqx.field(static=True, default=5.0)
    window: Literal["hann", "rect"] = eqx.field(static=True, default="hann")
    amplitude_pa: float = eqx.field(static=True, default=1.0)

    def __check_init__(self):
        if not self.frequency_hz > 0:
            raise ValueError(f"ToneBurst.frequency_hz = {self.frequency_hz} must be > 0")
        if not self.cycles > 0:
            raise ValueError(f"ToneBurst.cycles = {self.cycles} must be > 0")
        if self.window not in ("hann", "rect"):
            raise ValueError(f"ToneBurst.window = {self.window!r}; allowed: 'hann', 'rect'")

    def duration_s(self) -> float:
        return self.cycles / self.frequency_hz

    def __call__(self, t_s):
        """Signal at times `t_s` (seconds, any shape)."""
        phase = 2 * math.pi * self.frequency_hz * t_s
        u = t_s / self.duration_s()
        inside = (u >= 0) & (u <= 1)
        env = 0.5 - 0.5 * jnp.cos(2 * math.pi * u) if self.window == "hann" else 1.0
        return jnp.where(inside, self.amplitude_pa * env * jnp.sin(phase), 0.0)


class ContinuousWave(eqx.Module):
    """A continuous sine at `frequency_hz` (Hz), switched on with a raised-cosine ramp of
    `ramp_cycles` cycles; amplitude in Pa."""

    frequency_hz: float = eqx.field(static=True)
    ramp_cycles: float = eqx.field(static=True, default=3.0)
    amplitude_pa: float = eqx.field(static=True, default=1.0)

    def __check_init__(self):
        if not self.frequency_hz > 0:
            raise ValueError(f"ContinuousWave.frequency_hz = {self.frequency_hz} must be > 0")
        if not self.ramp_cycles >= 0:
            raise ValueError(f"ContinuousWave.ramp_cycles = {self.ramp_cycles} must be >= 0")

    def duration_s(self) -> float:
        return math.inf

    def __call__(self, t_s):
        phase = 2 * math.pi * self.frequency_hz * t_s
        if self.ramp_cycles == 0:
            env = jnp.where(t_s >= 0, 1.0, 0.0)
        else:
            u = jnp.clip(t_s * self.frequency_hz / self.ramp_cycles, 0.0, 1.0)
            env = 0.5 - 0.5 * jnp.cos(math.pi * u)
        return self.amplitude_pa * env * jnp.sin(phase)


Signal = ToneBurst | ContinuousWave


class PointSources(eqx.Module):
    """A set of source cells sharing one drive signal.

    **Arguments:**
    - `cells`: (n, 2) integer cell indices (ix, iy).
    - `signal`: the drive signal.
    - `weights`: (n,) amplitude weights (dimensionless, differentiable).
    - `lags_s`: (n,) delays in seconds (differentiable; > 0 emits later).
    - `injection`: "soft" (add to P: transparent to waves) or "hard" (set P: a reflecting source).
    """

    cells: Int[Array, "n 2"] = eqx.field(converter=lambda c: as_cells(c))
    signal: Signal
    weights: Float[Array, " n"]
    lags_s: Float[Array, " n"]
    injection: Literal["soft", "hard"] = eqx.field(static=True, default="soft")

    def __check_init__(self):
        n = self.n_cells
        if jnp.shape(self.weights) != (n,) or jnp.shape(self.lags_s) != (n,):
            raise ValueError(
                f"weights {jnp.shape(self.weights)} and lags_s {jnp.shape(self.lags_s)} must both "
                f"have shape ({n},), one entry per source cell"
            )
        if self.injection not in ("soft", "hard"):
            raise ValueError(f"injection = {self.injection!r}; allowed: 'soft', 'hard'")

    @property
    def n_cells(self) -> int:
        return int(self.cells.shape[0])

    @property
    def cells_array(self) -> Int[np.ndarray, "n 2"]:
        """The cells as a NumPy array (outside jit)."""
        return np.asarray(self.cells, dtype=np.int64).reshape(-1, 2)

    def values(self, t_s):
        """Source values at time t_s (scalar seconds): weights * signal(t - lags)."""
        return self.weights * self.signal(t_s - self.lags_s)



def as_cells(cells) -> Int[Array, "n 2"]:
    """Cell indices as an (n, 2) int32 array: NumPy when given concrete values (traced by
    `eqx.filter_jit` as data, so new positions do not recompile), left alone when traced."""
    if isinstance(cells, jax.Array) and not isinstance(cells, np.ndarray):
        if cells.ndim != 2 or cells.shape[-1] != 2 or not jnp.issubdtype(cells.dtype, jnp.integer):
            raise ValueError(f"cells must be an (n, 2) integer array, got {cells.shape} {cells.dtype}")
        return cells
    arr = np.asarray(cells)
    if arr.size == 0:
        return np.zeros((0, 2), np.int32)
    if not np.issubdtype(arr.dtype, np.integer):
        if not np.all(np.equal(np.mod(arr, 1), 0)):
            raise ValueError("cells must be integer cell indices (ix, iy); convert positions in metres "
                             "with difflattice.sensors.probe_cells or line_cells")
    return arr.astype(np.int32).reshape(-1, 2)


def line_cells(
    grid: Grid, centre_m: tuple[float, float], n_cells: int, direction_deg: float = 0.0
) -> np.ndarray:
    """Cells of a line transducer of `n_cells` cells, centred at `centre_m` (x_m, y_m), whose face
    points along `direction_deg` (0 = +x). The line runs perpendicular to the facing direction,
    rasterised to the nearest cells; cell k = 0 is at the start of the line."""
    if n_cells < 1:
        raise ValueError(f"n_cells = {n_cells} must be >= 1")
    theta = math.radians(direction_deg)
    tx, ty = -math.sin(theta), math.cos(theta)  # along the face
    # snap the centre to the half-cell lattice so round-off never splits the line
    cx, cy = (np.round(2 * c / grid.dx_m) / 2 for c in centre_m)
    s = np.arange(n_cells) - (n_cells - 1) / 2.0
    ix = np.floor(cx + np.round(s * tx, 9) + 0.5).astype(np.int64)
    iy = np.floor(cy + np.round(s * ty, 9) + 0.5).astype(np.int64)
    cells = np.stack([ix, iy], axis=1)
    nx, ny = grid.shape
    if (ix.min() < 0) or (iy.min() < 0) or (ix.max() >= nx) or (iy.max() >= ny):
        raise ValueError(
            f"transducer of {n_cells} cells at {centre_m} m does not fit in the grid "
            f"({grid.size_m[0]:.4f} x {grid.size_m[1]:.4f} m): move it or enlarge the grid"
        )
    if len({(int(a), int(b)) for a, b in cells}) != n_cells:
        raise ValueError("transducer cells overlap after rasterisation: use direction_deg in steps of 90")
    return cells


def line_transducer(
    grid: Grid,
    centre_m: tuple[float, float],
    *,
    n_cells: int | None = None,
    diameter_m: float | None = None,
    direction_deg: float = 0.0,
    signal: Signal | None = None,
    weights=None,
    lags_s=None,
    injection: Literal["soft", "hard"] = "soft",
) -> PointSources:
    """A line transducer (the paper's model: a line of vibrating cells as long as the diameter).

    Give `n_cells`, or `diameter_m` (n_cells = round(diameter / dx)). Default signal: a 5-cycle
    Hann burst at the grid frequency. Default weights 1 and lags 0.
    """
    if (n_cells is None) == (diameter_m is None):
        raise ValueError("give exactly one of n_cells or diameter_m")
    if n_cells is None:
        n_cells = max(1, int(round(diameter_m / grid.dx_m)))
    cells = line_cells(grid, centre_m, n_cells, direction_deg)
    dtype = grid.jnp_dtype
    w = jnp.ones(n_cells, dtype) if weights is None else jnp.asarray(weights, dtype)
    lag = jnp.zeros(n_cells, dtype) if lags_s is None else jnp.asarray(lags_s, dtype)
    sig = signal if signal is not None else ToneBurst(grid.frequency_hz, 5.0)
    return PointSources(cells=cells, signal=sig, weights=w, lags_s=lag, injection=injection)


