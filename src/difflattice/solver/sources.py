"""Sources: drive signals and transducers (lines of source cells with per-cell weights and lags;
on an axisymmetric grid, discs of ring cells).

Per-cell weights (dimensionless) and phase lags (seconds) are arrays, so they can be fitted. Cell
positions are integer arrays: their number fixes the compiled shapes, their values do not, so a
moved transducer reuses the compiled simulation. The signal shape and the injection mode are static.

Injection modes (what the step does with ``v(t) = weights * signal(t - lags_s)``):

- "soft": adds v(t_(n+1)) to P at each new step n+1 (a pressure source, transparent to waves);
- "hard": sets P = v (a reflecting source);
- "velocity": a vibrating face: the low z face of each source cell (axis 0) moves with normal
  velocity u(t) = v(t) / (rho c), v in Pa (the plane-wave pressure rho c u of the face; rho c of
  the medium in the cell). It is the finite-volume flux through that face: with
  ``dP/dt = K (A / V) u`` per cell (K = rho c^2, A / V = 1 / dx for a face of the cell, plane or
  ring), the leapfrog gains ``c_lat (v(t_(n+1/2)) - v(t_(n-1/2)))`` per step, c_lat the cell's
  lattice speed. Put the face on a closed face (a rigid window edge or a rigid body behind the
  cell) to model a piston; the absolute level then follows without any fitted scale (a baffled
  disc's on-axis pressure is 2 rho c u |sin(k (sqrt(z^2 + a^2) - z) / 2)|).
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


# (n, d) int32 cell indices: NumPy when concrete (new positions are data, not a recompile), a JAX
# array when traced (`as_cells`)
Cells = Int[Array, "n d"] | Int[np.ndarray, "n d"]


class PointSources(eqx.Module):
    """A set of source cells sharing one drive signal.

    **Arguments:**
    - `cells`: (n, 2) integer cell indices (ix, iy).
    - `signal`: the drive signal.
    - `weights`: (n,) amplitude weights (dimensionless, differentiable).
    - `lags_s`: (n,) delays in seconds (differentiable; > 0 emits later).
    - `injection`: "soft" (add to P: transparent to waves), "hard" (set P: a reflecting source)
      or "velocity" (a vibrating low z face of each cell; see the module docstring).
    """

    cells: Cells = eqx.field(converter=lambda c: as_cells(c))
    signal: Signal
    weights: Float[Array, " n"]
    lags_s: Float[Array, " n"]
    injection: Literal["soft", "hard", "velocity"] = eqx.field(static=True, default="soft")

    def __check_init__(self):
        n = self.n_cells
        if jnp.shape(self.weights) != (n,) or jnp.shape(self.lags_s) != (n,):
            raise ValueError(
                f"weights {jnp.shape(self.weights)} and lags_s {jnp.shape(self.lags_s)} must both "
                f"have shape ({n},), one entry per source cell"
            )
        if self.injection not in INJECTIONS:
            raise ValueError(f"injection = {self.injection!r}; allowed: {', '.join(map(repr, INJECTIONS))}")

    @property
    def n_cells(self) -> int:
        return int(self.cells.shape[0])

    @property
    def cells_array(self) -> Int[np.ndarray, "n d"]:
        """The cells as a NumPy array (outside jit)."""
        return np.asarray(self.cells, dtype=np.int64).reshape(-1, self.cells.shape[-1])

    def values(self, t_s):
        """Source values at time t_s (scalar seconds): weights * signal(t - lags)."""
        return self.weights * self.signal(t_s - self.lags_s)

    @property
    def adds(self) -> bool:
        """True if the step adds the source to P ("soft", "velocity"), False if it sets it."""
        return self.injection != "hard"

    def injected(self, t_s, dt_s: float, c_lattice):
        """What the step adds to (or sets in) P at the new step's time `t_s` (seconds): v(t_s) for
        "soft" and "hard"; ``c_lattice (v(t_s - dt/2) - v(t_s - 3 dt/2))`` for "velocity"
        (`c_lattice`: the lattice speed at the cells, cells/step, scalar or (n,))."""
        if self.injection == "velocity":
            return c_lattice * (self.values(t_s - 0.5 * dt_s) - self.values(t_s - 1.5 * dt_s))
        return self.values(t_s)


INJECTIONS = ("soft", "hard", "velocity")


def as_cells(cells) -> Cells:
    """Cell indices as an (n, rank) int32 array ((n, 2); (n, 3) on a 3-D grid): NumPy when given concrete
    values (traced by `eqx.filter_jit` as data, so new positions do not recompile), left alone
    when traced. An empty set is (0, 2) (no cell to index on any grid)."""
    if isinstance(cells, jax.Array) and not isinstance(cells, np.ndarray):
        if cells.ndim != 2 or cells.shape[-1] < 1 or not jnp.issubdtype(cells.dtype, jnp.integer):
            raise ValueError(f"cells must be an (n, rank) integer array, e.g. (n, 2), got {cells.shape} {cells.dtype}")
        return cells
    arr = np.asarray(cells)
    if arr.size == 0:
        return np.zeros((0, 2), np.int32)
    if not np.issubdtype(arr.dtype, np.integer):
        if not np.all(np.equal(np.mod(arr, 1), 0)):
            raise ValueError(
                "cells must be integer cell indices (ix, iy[, iz]); convert positions in metres "
                "with difflattice.sensors.probe_cells or line_cells"
            )
    d = arr.shape[-1] if arr.ndim >= 1 else 0
    if d < 1 or arr.ndim > 2:
        raise ValueError(
            f"cells must be (n, rank) cell indices, one column per grid axis (e.g. (n, 2)), got an array of shape {arr.shape}"
        )
    return arr.astype(np.int32).reshape(-1, d)


def line_cells(grid: Grid, centre_m: tuple[float, float], n_cells: int, direction_deg: float = 0.0) -> np.ndarray:
    """Cells of a line transducer of `n_cells` cells, centred at `centre_m` (x_m, y_m), whose face
    points along `direction_deg` (0 = +x). The line runs perpendicular to the facing direction,
    rasterised to the nearest cells; cell k = 0 is at the start of the line."""
    if n_cells < 1:
        raise ValueError(f"n_cells = {n_cells} must be >= 1")
    if len(grid.shape) != 2:
        raise ValueError(
            f"a line transducer needs a 2-D grid, got shape {grid.shape}: on a 3-D grid use disc_transducer_3d"
        )
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
        assert diameter_m is not None  # exactly one of the two is given (checked above)
        n_cells = max(1, int(round(diameter_m / grid.dx_m)))
    cells = line_cells(grid, centre_m, n_cells, direction_deg)
    dtype = grid.jnp_dtype
    w = jnp.ones(n_cells, dtype) if weights is None else jnp.asarray(weights, dtype)
    lag = jnp.zeros(n_cells, dtype) if lags_s is None else jnp.asarray(lags_s, dtype)
    sig = signal if signal is not None else ToneBurst(grid.frequency_hz, 5.0)
    return PointSources(cells=cells, signal=sig, weights=w, lags_s=lag, injection=injection)


# ------------------------------------------------------------------------------------------
# Circular transducers on an axisymmetric (rz) grid

Baffle = Literal["rigid", "none", "can"]
BAFFLES = ("rigid", "none", "can")


def ring_fractions(radius_cells, n_rings: int) -> Float[Array, " n_rings"]:
    """Fraction of each ring's axial face (r in [j, j + 1] cells) covered by a disc of radius
    `radius_cells`: ``clip((a^2 - j^2) / (2 j + 1), 0, 1)``, the exact area fraction, so the disc's
    area is exactly pi a^2 and its radius a continuous, differentiable parameter (the derivative
    jumps only where the rim crosses a ring face)."""
    j = jnp.arange(n_rings)
    a = jnp.asarray(radius_cells)
    return jnp.clip((a * a - j * j) / (2 * j + 1), 0.0, 1.0)


def ring_radii_m(grid: Grid, n_rings: int) -> np.ndarray:
    """Centre radii (j + 1/2) dx of the first `n_rings` rings, metres (to build weight and lag
    profiles for `disc_transducer`)."""
    return (np.arange(n_rings) + 0.5) * grid.dx_m


def _check_rz(grid: Grid, what: str) -> None:
    if not grid.kind.ring_metric:
        raise ValueError(
            f"{what} needs an axisymmetric grid (make_grid(..., kind='rz')), got kind = {grid.kind.name!r}; "
            "on a 2-D grid use line_transducer"
        )


def face_row(grid: Grid, z_m: float) -> int:
    """The cell row whose low face is the plane z = `z_m` (snapped to the nearest cell face)."""
    return int(round(z_m / grid.dx_m))


def disc_transducer(
    grid: Grid,
    *,
    radius_m,
    z_m: float = 0.0,
    n_rings: int | None = None,
    weights=None,
    lags_s=None,
    signal: Signal | None = None,
    baffle: Baffle = "rigid",
) -> PointSources:
    """A circular piston on an rz grid: one ring of source cells per ring of the face, facing +z.

    The face is the plane z = `z_m` (snapped to a cell face, row `face_row(grid, z_m)`); each ring
    cell in front of it is a "velocity" source (see the module docstring): its low face vibrates
    with u(t) = weight_j signal(t - lag_j) / (rho c), times the fraction of the ring's face inside
    the radius (`ring_fractions`), so the radius is continuous and differentiable.

    **Arguments:**
    - `radius_m`: disc radius in metres (float or a traced scalar; differentiable).
    - `z_m`: the face plane, metres (z = 0 is the z_lo window face).
    - `n_rings`: number of ring cells (static); default: every ring the radius touches,
      ``ceil(radius / dx)``. Give it when `radius_m` is traced (fitted) with room to grow.
    - `weights`: (n_rings,) per-ring velocity weights (dimensionless, differentiable; default 1).
    - `lags_s`: (n_rings,) per-ring delays in seconds (differentiable; default 0).
    - `signal`: the drive, amplitude in Pa = rho c u0 (the plane-wave pressure of the face's
      velocity amplitude u0); default a 5-cycle Hann burst at the grid frequency, 1 Pa.
    - `baffle`: "rigid" (an infinite rigid baffle: the face must be the closed window face z = 0,
      `Edges.axisymmetric(z_lo="rigid")`), "none" (a bare disc, back at rest) or "can" (a housing);
      for the last two the face lies inside the window and `disc_housing` gives the rigid body
      behind it.
    """
    _check_rz(grid, "disc_transducer")
    if baffle not in BAFFLES:
        raise ValueError(f"baffle = {baffle!r}; allowed: {', '.join(map(repr, BAFFLES))}")
    i0 = face_row(grid, z_m)
    if baffle == "rigid" and i0 != 0:
        raise ValueError(
            f"baffle = 'rigid' puts the face on the rigid z_lo window face z = 0, got z_m = {z_m} m "
            f"(row {i0}): use z_m = 0 with Edges.axisymmetric(z_lo='rigid'), or baffle = 'none' / 'can' "
            "with disc_housing for a face inside the window"
        )
    if baffle != "rigid" and i0 < 1:
        raise ValueError(
            f"baffle = {baffle!r}: the face z_m = {z_m} m needs room behind it for the housing; move it up"
        )
    nx, ny = grid.shape
    if not 0 <= i0 < nx:
        raise ValueError(f"face z_m = {z_m} m (row {i0}) lies outside the grid (0 .. {nx - 1})")
    if n_rings is None:
        try:
            a_cells = float(radius_m) / grid.dx_m
        except Exception:  # traced radius
            raise ValueError("radius_m is traced: give n_rings (static) explicitly") from None
        n_rings = max(1, math.ceil(a_cells - 1e-9))
    n_rings = int(n_rings)
    if not 1 <= n_rings <= ny:
        raise ValueError(f"n_rings = {n_rings} must be in 1 .. {ny} (the grid's rings)")
    try:
        a_cells = float(radius_m) / grid.dx_m
        if not a_cells > 0:
            raise ValueError(f"radius_m = {radius_m} must be > 0")
        if a_cells > n_rings + 1e-9:
            raise ValueError(f"radius_m = {radius_m} ({a_cells:.3f} cells) exceeds n_rings = {n_rings}: raise n_rings")
    except (TypeError, jax.errors.ConcretizationTypeError):
        pass  # traced
    dtype = grid.jnp_dtype
    cells = np.stack([np.full(n_rings, i0), np.arange(n_rings)], 1)
    frac = ring_fractions(jnp.asarray(radius_m, dtype) / grid.dx_m, n_rings).astype(dtype)
    w = jnp.ones(n_rings, dtype) if weights is None else jnp.asarray(weights, dtype)
    lag = jnp.zeros(n_rings, dtype) if lags_s is None else jnp.asarray(lags_s, dtype)
    if w.shape != (n_rings,) or lag.shape != (n_rings,):
        raise ValueError(f"weights {w.shape} and lags_s {lag.shape} must have shape ({n_rings},), one per ring")
    sig = signal if signal is not None else ToneBurst(grid.frequency_hz, 5.0)
    return PointSources(cells=cells, signal=sig, weights=w * frac, lags_s=lag, injection="velocity")


def disc_housing(
    grid: Grid,
    *,
    radius_m,
    z_m: float,
    baffle: Baffle,
    depth_m=None,
    wall_m=0.0,
) -> Float[Array, "nz nr"] | None:
    """Rigid occupancy (nz, nr) of what lies behind a `disc_transducer` face, as a body of
    revolution: None for "rigid" (the baffle is the window face); for "none" a rigid disc of
    `radius_m` and thickness `depth_m` (default one cell) behind the face; for "can" a closed can of
    outer radius `radius_m + wall_m` and depth `depth_m` (required) whose front is flush with the
    face. Occupancies are exact ring-volume fractions (smooth in the radii and the depth), for the
    cut-cell model of `build_lattice`. Pass it as `Medium(..., rigid=...)` (combine with other
    bodies by `geometry.union_occupancy`)."""
    _check_rz(grid, "disc_housing")
    if baffle not in BAFFLES:
        raise ValueError(f"baffle = {baffle!r}; allowed: {', '.join(map(repr, BAFFLES))}")
    if baffle == "rigid":
        return None
    if baffle == "can" and depth_m is None:
        raise ValueError("baffle = 'can' needs depth_m (the can's depth behind the face, metres)")
    dx = grid.dx_m
    dtype = grid.jnp_dtype
    nx, ny = grid.shape
    depth = jnp.asarray(dx if depth_m is None else depth_m, dtype) / dx
    outer = (jnp.asarray(radius_m, dtype) + (jnp.asarray(wall_m, dtype) if baffle == "can" else 0.0)) / dx
    zf = face_row(grid, z_m)
    i = jnp.arange(nx, dtype=dtype)
    fz = jnp.clip(jnp.minimum(i + 1, zf) - jnp.maximum(i, zf - depth), 0.0, 1.0)
    fr = ring_fractions(outer, ny).astype(dtype)
    return (fz[:, None] * fr[None, :]).astype(dtype)


# ------------------------------------------------------------------------------------------
# a circular transducer on a 3-D grid


def _disc_basis(axis) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(unit axis, e1, e2): the disc's facing direction and two unit vectors spanning its face."""
    a = np.asarray(axis, dtype=float).reshape(-1)
    if a.shape != (3,) or not np.linalg.norm(a) > 0:
        raise ValueError(f"disc axis {axis!r}: give the 3-vector the face points to (any length, not zero)")
    a = a / np.linalg.norm(a)
    helper = np.array([0.0, 0.0, 1.0]) if abs(a[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(helper, a)
    e1 /= np.linalg.norm(e1)
    return a, e1, np.cross(a, e1)


def ring_table(rings: dict | None, radius_m: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(edges (n, 2) in m, weights (n,), lags (n,) in s) of a disc's rings from a plain dict:
    `ring_edges_m` (n, 2) inner/outer radii (a disc fit report's layout) or `radii_m` (n,) ring
    centre radii (edges half-way between them; the outer edge at `radius_m`, or as far beyond the
    last centre as the last half-spacing), with `weights` (n,) and optional `lags_s` (n,).
    None: one uniform ring of `radius_m`."""
    if rings is None:
        if radius_m is None:
            raise ValueError("give diameter_m, or rings with their radii")
        return np.array([[0.0, radius_m]]), np.ones(1), np.zeros(1)
    if not isinstance(rings, dict) or "weights" not in rings:
        raise ValueError(
            "rings must be a dict with 'weights' and 'ring_edges_m' (n, 2) or 'radii_m' (n,) (and optionally 'lags_s')"
        )
    w = np.asarray(rings["weights"], dtype=float).ravel()
    lag = np.asarray(rings.get("lags_s", np.zeros_like(w)), dtype=float).ravel()
    if "ring_edges_m" in rings:
        edges = np.asarray(rings["ring_edges_m"], dtype=float).reshape(-1, 2)
    elif "radii_m" in rings:
        r = np.asarray(rings["radii_m"], dtype=float).ravel()
        mid = 0.5 * (r[1:] + r[:-1])
        outer = radius_m if radius_m is not None else (r[-1] + (r[-1] - mid[-1]) if len(mid) else 2 * r[-1])
        edges = np.stack([np.r_[0.0, mid], np.r_[mid, outer]], axis=1)
    else:
        raise ValueError(f"rings needs 'ring_edges_m' (n, 2) or 'radii_m' (n,); got keys {sorted(rings)}")
    if not (len(edges) == len(w) == len(lag)):
        raise ValueError(f"rings: {len(edges)} rings but {len(w)} weights and {len(lag)} lags")
    if np.any(edges[:, 1] <= edges[:, 0]) or np.any(edges[1:, 0] < edges[:-1, 1] - 1e-12):
        raise ValueError("rings: ring edges must increase (inner < outer, rings in order, not overlapping)")
    return edges, w, lag


def rings_from_fit_report(report) -> dict:
    """The `rings` dict of `disc_transducer_3d` from a disc fit report (a dict, or the path of its
    JSON file): ring edges from `ring_edges_m` if the report has them, else rings of width
    `model.dx_m` from the axis (the r-z lattice's layout, axis on a cell face); weights from
    `weights_raw` (the profile alone: the 3-D disc applies the rim's covered area itself), else
    `weights` divided by `ring_fraction` where the report gives it; lags from `lags_s`; the
    diameter as `diameter_m` (pass it on as `diameter_m`)."""
    import json
    from pathlib import Path

    if not isinstance(report, dict):
        report = json.loads(Path(report).read_text())
    par = report.get("parameters", report)
    if "weights" not in par and "weights_raw" not in par:
        raise ValueError("fit report: no ring 'weights' (or 'weights_raw') under 'parameters'")
    w = np.asarray(par.get("weights_raw", par.get("weights")), dtype=float)
    if "weights_raw" not in par and "ring_fraction" in par:
        frac = np.asarray(par["ring_fraction"], dtype=float)
        w = np.where(frac > 0, w / np.where(frac > 0, frac, 1.0), 0.0)
    lags = np.asarray(par.get("lags_s", np.zeros_like(w)), dtype=float)
    if "ring_edges_m" in par or "ring_edges_m" in report.get("model", {}):
        edges = np.asarray(par.get("ring_edges_m", report.get("model", {}).get("ring_edges_m")), dtype=float)
    else:
        dx = report.get("model", {}).get("dx_m")
        if dx is None:
            raise ValueError("fit report: give 'ring_edges_m' or 'model.dx_m' (the ring width)")
        j = np.arange(len(w), dtype=float)
        edges = np.stack([j * dx, (j + 1) * dx], axis=1)
    out = {"ring_edges_m": edges.tolist(), "weights": w.tolist(), "lags_s": lags.tolist()}
    if "diameter_m" in par:
        out["diameter_m"] = float(par["diameter_m"])
    return out


def disc_cells_3d(
    grid: Grid,
    centre_m,
    axis,
    diameter_m: float | None = None,
    *,
    rings: dict | None = None,
    samples_per_cell: int = 12,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cells of a flat disc on a 3-D grid at any position and orientation, weighted by the area of
    the disc they hold: (cells (n, 3), weights (n,), lags_s (n,), area_cells (n,)).

    The disc (centre `centre_m`, face normal `axis`, diameter `diameter_m`, or the outer edge of
    `rings`) is sampled on a square sub-grid of `samples_per_cell` points per cell width in its
    plane; each sample goes to the nearest cell. A cell's weight is the disc area it holds (in
    cell faces: 1 for a cell a disc normal to an axis covers fully) times the ring weight there;
    its lag is the weight-averaged ring lag. A disc normal to a grid axis lies in one layer of
    cells and its rim cells get their covered fraction."""
    if len(grid.shape) != 3:
        raise ValueError(
            f"disc_cells_3d needs a 3-D grid (kind='3d'), got shape {grid.shape}; in 2-D use line_transducer"
        )
    if diameter_m is not None and not diameter_m > 0:
        raise ValueError(f"diameter_m = {diameter_m} must be > 0")
    if samples_per_cell < 2:
        raise ValueError(f"samples_per_cell = {samples_per_cell} must be >= 2")
    a, e1, e2 = _disc_basis(axis)
    edges, rw, rl = ring_table(rings, None if diameter_m is None else 0.5 * diameter_m)
    radius = 0.5 * diameter_m if diameter_m is not None else float(edges[-1, 1])
    h = grid.dx_m / samples_per_cell
    m = int(math.ceil(radius / h))
    u = (np.arange(-m, m) + 0.5) * h
    U, V = np.meshgrid(u, u, indexing="ij")
    rho = np.hypot(U, V)
    inside = rho < radius
    U, V, rho = U[inside], V[inside], rho[inside]
    ring = np.minimum(np.searchsorted(edges[:, 1], rho, side="right"), len(edges) - 1)
    in_ring = (rho >= edges[ring, 0]) & (rho < edges[ring, 1] + 1e-12 * radius)
    area = np.full(rho.shape, (h / grid.dx_m) ** 2)
    wt = np.where(in_ring, rw[ring], 0.0) * area
    pos = np.asarray(centre_m, dtype=float).reshape(1, 3) + U[:, None] * e1 + V[:, None] * e2
    idx = np.floor(pos / grid.dx_m + 0.5).astype(np.int64)
    cells, inv = np.unique(idx, axis=0, return_inverse=True)
    inv = inv.ravel()
    w = np.bincount(inv, wt, len(cells))
    a_cells = np.bincount(inv, area, len(cells))
    wl = np.bincount(inv, wt * rl[ring], len(cells))
    lags = np.where(w != 0, wl / np.where(w != 0, w, 1.0), 0.0)
    if (cells < 0).any() or (cells >= np.asarray(grid.shape)).any():
        raise ValueError(
            f"disc of diameter {2 * radius:.4g} m at {tuple(centre_m)} m does not fit in the grid "
            f"({' x '.join(f'{s:.4f}' for s in grid.size_m)} m): move it or enlarge the grid"
        )
    return cells, w, lags, a_cells


def disc_transducer_3d(
    grid: Grid,
    centre_m,
    axis,
    *,
    diameter_m: float | None = None,
    rings: dict | None = None,
    signal: Signal | None = None,
    injection: Literal["soft", "hard", "velocity"] = "soft",
    samples_per_cell: int = 12,
) -> PointSources:
    """A circular transducer on a 3-D grid: the cells of `disc_cells_3d` driven by one `signal`
    (default: a 5-cycle Hann burst at the grid frequency), weights = covered area x ring weight,
    lags from the rings. `rings` is a plain dict (see `ring_table`), e.g. the ring edges, weights
    and lags of a disc fit report. `injection`: "soft" (a pressure source, transparent), "hard",
    or "velocity" (each cell's low x face vibrates, see the module docstring: a disc facing +x,
    e.g. on a rigid x_lo window face as a baffled piston)."""
    if injection == "velocity" and not np.allclose(_disc_basis(axis)[0], (1.0, 0.0, 0.0)):
        raise ValueError(f"injection = 'velocity' moves each cell's low x face: the disc must face +x, got axis {axis}")
    cells, w, lags, _ = disc_cells_3d(grid, centre_m, axis, diameter_m, rings=rings, samples_per_cell=samples_per_cell)
    keep = w != 0
    dtype = grid.jnp_dtype
    sig = signal if signal is not None else ToneBurst(grid.frequency_hz, 5.0)
    return PointSources(
        cells=cells[keep],
        signal=sig,
        weights=jnp.asarray(w[keep], dtype),
        lags_s=jnp.asarray(lags[keep], dtype),
        injection=injection,
    )
