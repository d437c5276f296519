"""Transfer matrices of a disc of ring source cells: the complex response at the measured points
(lobe angles at a range, positions on the wavefront scan line) per unit drive of each ring.

The field is linear in the ring amplitudes a_i (`fit.disc.DiscSpec.amplitudes`), p = T a; ring
i of T is the field of ring i alone vibrating with unit normal velocity over its whole area
[r_in_i, r_out_i]. Two ways to compute T, with the same `DiscTransfer` result:

- `rayleigh_disc_transfer` (NumPy, the independent reference): the Rayleigh integral of each
  annulus in an infinite rigid baffle, p(x) = -i k / (2 pi) integral exp(i k R) / R dS (per unit
  rho c v; time convention exp(-i omega t)), by Gauss-Legendre quadrature across each ring and the
  periodic trapezoid rule in azimuth, refined until two resolutions agree to `rtol`. A baffled
  velocity source is a planar monopole layer of twice its strength in free space, so this is
  also the free-field field of the lattice's ring monopoles in front of the face (z > 0) and its
  mirror image behind. At any range: the lobe is evaluated at the file's range, never by the
  Fraunhofer approximation.
- `disc_transfer` (the axisymmetric lattice, one simulated response per ring, batched): lobe
  through the axisymmetric far-field transform at the data's range, wavefront on the scan line;
  phasors divided by the drive's discrete spectrum, as `fit.transfer` does. Its `baffle` also
  models a bare disc ("none") or one in a closed can ("can"), where the Rayleigh reference holds
  for the baffled disc only.

The rig's wavefront scan is a line through the axis at distance z: by symmetry p(x, z) =
p(|x|, z), so a wavefront point at lateral position x is the ring field at rho = |x|; a lobe point
at angle t and range R is at rho = R |sin t|, z = R cos t (the transducer turns about an axis in
its face through its centre).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal, cast

import numpy as np

from .disc import AxisLayout, DiscSpec, ring_edges

if TYPE_CHECKING:
    from ..lattice.grid import Grid, StencilKind
    from ..lattice.window import Window


@dataclass
class DiscTransfer:
    """Complex transfer matrices (measured point x ring) and their provenance. Duck-types
    `fit.transfer.Transfer` (`n_cells`, `lobe`, `wave`, `info`, `grid`, `cell_offset_m`) so
    `fit.solve` takes it; `grid` is the lattice grid (None for the Rayleigh reference)."""

    grid: Grid | None
    n_cells: int
    ring_edges_m: np.ndarray  # (N, 2) inner and outer radius of each ring, m
    lobe: np.ndarray | None  # (A, N)
    wave: np.ndarray | None  # (J, N)
    info: dict = field(default_factory=dict)

    @property
    def cell_offset_m(self) -> np.ndarray:
        """Ring-centre radii (m)."""
        return self.ring_edges_m.mean(1)

    @property
    def dr_m(self) -> float:
        """Ring width (the lattice's cell size), m."""
        return float(self.ring_edges_m[-1, 1] - self.ring_edges_m[-1, 0])


def lobe_points(angle_deg, range_m: float | None) -> tuple[np.ndarray, np.ndarray]:
    """(rho_m, z_m) of lobe points at `angle_deg` and `range_m` from the face's centre."""
    if range_m is None or not range_m > 0:
        raise ValueError(f"lobe range_m = {range_m} must be > 0 m (the microphone's distance from the face's centre)")
    t = np.radians(np.asarray(angle_deg, float))
    return range_m * np.abs(np.sin(t)), range_m * np.cos(t)


def _ring_quadrature(
    edges: np.ndarray, rho: np.ndarray, z: np.ndarray, k: float, n_r: int, n_phi: int, chunk: int = 16
) -> np.ndarray:
    """-i k / (2 pi) * integral over each ring of exp(i k R) / R dS at points (rho, z): (P, N)."""
    g, gw = np.polynomial.legendre.leggauss(n_r)
    r_in, r_out = edges[:, :1], edges[:, 1:]
    r = 0.5 * (r_in + r_out) + 0.5 * (r_out - r_in) * g[None, :]  # (N, n_r)
    w_r = 0.5 * (r_out - r_in) * gw[None, :] * r  # area element r dr
    # even in phi: the periodic trapezoid rule on [0, 2 pi) with n_phi nodes, folded onto [0, pi]
    m = n_phi // 2
    phi = np.pi * np.arange(m + 1) / m
    w_phi = np.full(m + 1, 2 * np.pi / n_phi * 2)
    w_phi[[0, -1]] *= 0.5
    cos_phi = np.cos(phi)
    out = np.empty((len(rho), len(edges)), complex)
    rf, wf = r.reshape(-1), w_r.reshape(-1)
    for s in range(0, len(rho), chunk):
        rh, zz = rho[s : s + chunk, None, None], z[s : s + chunk, None, None]
        R = np.sqrt(zz**2 + rh**2 + rf[None, :, None] ** 2 - 2 * rh * rf[None, :, None] * cos_phi[None, None, :])
        inner = (np.exp(1j * k * R) / R) @ w_phi  # (p, N n_r)
        out[s : s + chunk] = (inner * wf[None, :]).reshape(len(rh), len(edges), n_r).sum(-1)
    return -1j * k / (2 * np.pi) * out


def rayleigh_ring_field(
    edges_m,
    rho_m,
    z_m,
    k_rad_m: float,
    *,
    rtol: float = 1e-8,
    n_r: int = 6,
    n_phi: int | None = None,
    max_refine: int = 4,
) -> np.ndarray:
    """(P, N) field of each ring of `edges_m` (N, 2) (unit normal velocity, per rho c; Rayleigh
    integral, exp(-i omega t)) at points at lateral distance `rho_m` and axial distance `z_m` from
    the face's centre. Refines (n_r + 4, 2 n_phi) until the change is below `rtol` times the
    largest value, else raises."""
    edges = np.asarray(edges_m, float).reshape(-1, 2)
    rho = np.atleast_1d(np.asarray(rho_m, float))
    z = np.broadcast_to(np.asarray(z_m, float), rho.shape).copy()
    if np.any(rho < 0):
        raise ValueError("rho_m (lateral distance from the axis) must be >= 0")
    r_max = float(edges[:, 1].max())
    if np.any(np.hypot(np.abs(rho) - np.clip(rho, 0, r_max), z) < 1e-9 * max(r_max, 1e-3)):
        raise ValueError("a point lies on the radiating face: the Rayleigh integral is singular there")
    if n_phi is None:
        n_phi = 2 * int(math.ceil(k_rad_m * r_max)) + 48
    n_phi += n_phi % 2
    prev = _ring_quadrature(edges, rho, z, k_rad_m, n_r, n_phi)
    for _ in range(max_refine):
        n_r, n_phi = n_r + 4, 2 * n_phi
        cur = _ring_quadrature(edges, rho, z, k_rad_m, n_r, n_phi)
        err = np.abs(cur - prev).max() / np.abs(cur).max()
        if err < rtol:
            return cur
        prev = cur
    raise RuntimeError(
        f"Rayleigh ring quadrature did not converge to rtol = {rtol} (last change {err:.2e}); "
        "the points may be too close to the face"
    )


def rayleigh_disc_transfer(
    *,
    frequency_hz: float,
    c_m_s: float,
    n_rings: int,
    dr_m: float,
    lobe_angle_deg=None,
    lobe_range_m: float | None = None,
    wave_x_m=None,
    wave_z_m: float | None = None,
    axis: AxisLayout = "face",
    rtol: float = 1e-8,
) -> DiscTransfer:
    """The reference `DiscTransfer` of `n_rings` rings of width `dr_m` (layout `axis`, see
    `fit.disc.ring_edges`) by the Rayleigh integral: exact at any range (no lattice)."""
    edges = ring_edges(n_rings, dr_m, axis)
    k = 2 * math.pi * frequency_hz / c_m_s
    lobe = wave = None
    if lobe_angle_deg is not None:
        rho, z = lobe_points(lobe_angle_deg, lobe_range_m)
        lobe = rayleigh_ring_field(edges, rho, z, k, rtol=rtol)
    if wave_x_m is not None:
        if wave_z_m is None or not wave_z_m > 0:
            raise ValueError(f"wave_z_m = {wave_z_m} must be > 0 m (in front of the face)")
        x = np.abs(np.asarray(wave_x_m, float))
        wave = rayleigh_ring_field(edges, x, np.full_like(x, wave_z_m), k, rtol=rtol)
    info = {
        "method": "rayleigh",
        "dr_m": dr_m,
        "axis": axis,
        "rtol": rtol,
        "frequency_hz": frequency_hz,
        "c_m_s": c_m_s,
    }
    return DiscTransfer(grid=None, n_cells=n_rings, ring_edges_m=edges, lobe=lobe, wave=wave, info=info)


# ------------------------------------------------------------------------------------------
# The axisymmetric lattice


def surface_cells(surface, order: int = 4) -> np.ndarray:
    """Phasor cells to record for the Kirchhoff-Helmholtz `surface` (`observe.farfield_rz.
    CylinderSurface`): its own pairs (`order` 2), or two cells on each side of every face
    (`order` 4: offsets -1, 0, +1, +2 cells along the outward normal from the inner cell),
    grouped by offset."""
    inner, outer, *_ = surface.samples()
    if order == 2:
        return np.concatenate([inner, outer])
    if order != 4:
        raise ValueError(f"surface order = {order}; allowed: 2, 4")
    n = outer - inner
    return np.concatenate([inner - n, inner, outer, outer + n])


def surface_pairs(phasors, order: int = 4):
    """The surface's (inner, outer) phasor pairs from phasors recorded at `surface_cells(...,
    order)`: for `order` 4, pairs whose mean and difference are the fourth-order face value
    (-p_-1 + 9 p_0 + 9 p_1 - p_2) / 16 and normal derivative (p_-1 - 27 p_0 + 27 p_1 - p_2) / 24,
    so `observe.farfield_rz`'s transforms (which take the mean and the difference of a pair) get
    them. Why: the pair's own mean and difference are off by (k h)^2 / 8 and (k h)^2 / 24 (1.2 %
    and 0.4 % at 20 cells per wavelength, depending on the direction a wave crosses the surface);
    at fourth order (k h)^4 terms remain (measured: a 38.4 mm piston's wavefront at z = 16.5 mm,
    phase deviation 0.035 deg RMS instead of 0.12 deg, below the rig's 0.106 deg noise)."""
    ph = np.asarray(phasors)
    if order == 2:
        return ph
    m = ph.shape[-1] // 4
    q = [ph[..., k * m : (k + 1) * m] for k in range(4)]
    p = (-q[0] + 9 * q[1] + 9 * q[2] - q[3]) / 16
    dpdn = (q[0] - 27 * q[1] + 27 * q[2] - q[3]) / 24
    return np.concatenate([p - 0.5 * dpdn, p + 0.5 * dpdn], axis=-1)


@dataclass(frozen=True)
class _HousingLayout:
    surface: Any  # observe.farfield_rz.CylinderSurface
    face_row: int  # the row whose low face is the disc's face plane
    depth_m: float | None  # the housing's depth behind the face (None: no housing)
    window: Window  # (z, r): the grid around the cylinder (before a lattice wavefront line widens it)


def _housing_layout(
    baffle: str, n_rings: int, dx: float, gap: int, pml_cells: int, can_depth_m: float | None, can_wall_m: float
) -> _HousingLayout:
    """Where the face and the Kirchhoff-Helmholtz cylinder go for `baffle`. "rigid": the face on
    z = 0, the cylinder `gap` cells above it and beyond the rim, open at the baffle. Otherwise the
    housing (depth d, outer radius R) lies behind a face at row zf, and the cylinder keeps the
    fourth-order stencil (two cells inside each face, `surface_cells`) in the air: the lower cap
    1 + `gap` cells below the housing's lowest row, the side `gap` rings beyond its outermost ring
    (as the "rigid" side is `gap` rings beyond the rim); below the lower cap's outer cells lie a
    4-cell margin and the PML."""
    from ..lattice.window import Span, Window
    from ..observe.farfield_rz import CylinderSurface

    if baffle not in ("rigid", "none", "can"):
        raise ValueError(f"baffle = {baffle!r}; allowed: 'rigid', 'none', 'can'")
    pad = 5  # the cylinder's outer stencil cells, then a 4-cell margin, then the PML
    if baffle == "rigid":
        win = Window(
            (
                Span.closed(gap=gap, layer=pml_cells, pad=pad),
                Span.closed(gap=gap, layer=pml_cells, pad=pad, fwd=n_rings - 1),
            )
        )
        (z0, z1), (_, jr) = win.box
        return _HousingLayout(CylinderSurface(z0, z1, jr, baffled=True), 0, None, win)
    if baffle == "can":
        if can_depth_m is None or not can_depth_m > 0:
            raise ValueError(
                f"baffle = 'can' needs can_depth_m > 0 (the can's depth behind the face, m), got {can_depth_m}"
            )
        if not can_wall_m >= 0:
            raise ValueError(f"can_wall_m = {can_wall_m} m must be >= 0")
        depth_m = float(can_depth_m)
        outer = n_rings + can_wall_m / dx
    else:
        depth_m, outer = dx, float(n_rings)  # a rigid disc one cell thick behind the face
    depth = depth_m / dx
    # the lower cap (its inner cells) at pml + 4 + 2 + gap, the housing's lowest row 1 + gap above
    # it, the face at the housing's top; rings jr, jr - 1 (the side's inner stencil) clear of it
    span_z = Span.open(gap=gap, layer=pml_cells, pad=6 + gap, back=1 + int(math.ceil(depth - 1e-9)), pad_hi=pad)
    span_r = Span.closed(gap=gap, layer=pml_cells, pad=pad, fwd=int(math.ceil(outer - 1e-9)))
    win = Window((span_z, span_r))
    (low, z1), (_, jr) = win.box
    return _HousingLayout(CylinderSurface(low, z1, jr, baffled=False), span_z.source, depth_m, win)


def disc_transfer(
    *,
    frequency_hz: float,
    c_m_s: float,
    n_rings: int,
    cells_per_wavelength: float = 20.0,
    lobe_angle_deg=None,
    lobe_range_m: float | None = None,
    wave_x_m=None,
    wave_z_m: float | None = None,
    wave_method: str = "transform",
    dtype: Literal["float32", "float64"] = "float64",
    pml_cells: int = 20,
    surface_gap: int = 1,
    surface_order: int = 4,
    batch: int | None = None,
    baffle: Literal["rigid", "none", "can"] = "rigid",
    can_depth_m: float | None = None,
    can_wall_m: float = 0.0,
    stencil: StencilKind = "standard",
) -> DiscTransfer:
    """Transfer matrices of a disc of `n_rings` ring cells on the axisymmetric lattice at
    `cells_per_wavelength`: one simulated response per ring (a 4-cycle burst driving the ring's
    face velocity alone, `solver.sources.disc_transducer` with one-hot weights; the rings batched
    by `jax.vmap`, `batch` at a time, default all), phasors divided by the drive's discrete
    spectrum, in pressure per unit rho c v (the units of `rayleigh_disc_transfer`).

    `baffle` (`solver.sources.disc_housing`): "rigid" (default) an infinite rigid baffle in the
    face plane (the face on the rigid z_lo window face; nothing behind it); "none" a bare disc:
    the modelled face (n_rings cells in radius) on a rigid disc one cell thick, in free space
    (PML all round), so the field reaches behind the face and lobe angles beyond 90 deg are
    modelled; "can" the face flush with the front of a closed rigid can of depth `can_depth_m`
    (m, required) and wall `can_wall_m` (m) around the modelled face. For "none" and "can" the
    Kirchhoff-Helmholtz cylinder closes round the housing (both caps and the side), and lobe and
    wavefront points are measured from the face's centre as for "rigid".

    - lobe: the Kirchhoff-Helmholtz integral (`observe.farfield_rz.field_at_rz`, continuum
      wavenumber) over a cylinder `surface_gap` cells around the disc, closed by the baffle, at
      `lobe_angle_deg` and `lobe_range_m`: exact at any range, and the lattice's dispersion acts
      only over the gap;
    - wavefront at distance `wave_z_m`, positions `wave_x_m` (p(x) = p(|x|)): `wave_method`
      "transform" (the same integral; default) or "lattice" (the field on the scan line itself:
      its 0.2 % slower axial waves add ~1.8 deg over 16.5 mm at 20 cells per wavelength);
    - `surface_order`: 4 (default, see `surface_pairs`) or 2 (the surface's own cell pairs)."""
    import jax.numpy as jnp

    from ..air import density_kg_m3
    from ..lattice.coefficients import Edges
    from ..lattice.grid import make_grid
    from ..lattice.medium import Medium
    from ..observe.farfield_rz import scan_line
    from ..solver.loop import simulate
    from ..solver.sensors import Sensors
    from ..solver.sources import ToneBurst, disc_housing, disc_transducer
    from .transfer import _source_spectrum

    z_line = _checked_request(wave_method, surface_gap, lobe_angle_deg, lobe_range_m, wave_x_m, wave_z_m)
    dx = c_m_s / (frequency_hz * cells_per_wavelength)
    layout = _housing_layout(baffle, n_rings, dx, surface_gap, pml_cells, can_depth_m, can_wall_m)
    surf, zf = layout.surface, layout.face_row
    z_face = zf * dx  # the face plane in grid coordinates, m (0: the baffle)
    lattice_x = wave_x_m if wave_method == "lattice" else None
    nz, nr = _grid_shape(layout.window, dx, z_face + z_line, lattice_x)
    grid = make_grid(
        frequency_hz=frequency_hz,
        cells_per_wavelength=cells_per_wavelength,
        c_max_m_s=c_m_s,
        shape=(nz, nr),
        dtype=dtype,
        kind="rz",
        stencil=stencil,
    )
    cells = [surface_cells(surf, surface_order)]
    sampler = None
    if wave_x_m is not None and wave_method == "lattice":
        sampler = scan_line(grid, np.asarray(wave_x_m, float), z_face + z_line)
        cells.append(sampler.cells)
    m_surf = len(cells[0])
    sensors = Sensors(phasor_cells=cast(Any, np.concatenate(cells)))  # concrete cells: data, not traced
    sig = ToneBurst(frequency_hz, 4.0)
    n_steps = int(math.hypot(nz, nr) / grid.courant + 10 * grid.steps_per_period)
    housing = disc_housing(
        grid, radius_m=n_rings * dx, z_m=z_face, baffle=baffle, depth_m=layout.depth_m, wall_m=can_wall_m
    )
    # air (the transfer does not depend on rho), rigid where the housing is
    medium = Medium(c_m_s, density_kg_m3(20.0), rigid=housing)
    edges = Edges.axisymmetric("rigid" if baffle == "rigid" else "pml", "pml", "pml", thickness_cells=pml_cells)

    def one(w):
        src = disc_transducer(
            grid, radius_m=n_rings * dx, z_m=z_face, n_rings=n_rings, weights=w, signal=sig, baffle=baffle
        )
        # checked for instability after the batch (check_finite): a program without eqx.error_if's
        # host callback goes to the persistent compilation cache
        r = simulate(grid, medium, src, sensors, n_steps=n_steps, edges=edges, throw=False)
        return r.phasors, r.peak_history

    b = n_rings if batch is None else max(1, int(batch))
    t0 = time.perf_counter()
    ph = _batched_responses(one, n_rings, b, grid.jnp_dtype)
    sim_s = time.perf_counter() - t0
    ph = ph / _source_spectrum(sig, grid, n_steps)
    pairs = np.asarray(surface_pairs(ph[:, :m_surf], surface_order))  # host: the far fields in NumPy
    lobe = wave = None
    if lobe_angle_deg is not None:
        lobe = _lobe_matrix(pairs, surf, grid, lobe_angle_deg, lobe_range_m, z_face, baffle, n_rings)
    if wave_x_m is not None:
        if sampler is not None:
            wave = np.asarray(sampler(jnp.asarray(ph[:, m_surf:]))).T
        else:
            wave = _wave_matrix(pairs, surf, grid, np.asarray(wave_x_m, float), z_face + z_line)
    request = dict(surface_gap_cells=surface_gap, surface_order=surface_order, wave_method=wave_method)
    request |= dict(n_rings=n_rings, batch=b, baffle=baffle, stencil=stencil, face_row=zf)
    request |= dict(can_depth_m=layout.depth_m if baffle == "can" else None)
    request |= dict(can_wall_m=can_wall_m if baffle == "can" else None)
    info = _transfer_info(grid, (nz, nr), n_steps, sim_s, request)
    return DiscTransfer(
        grid=grid, n_cells=n_rings, ring_edges_m=ring_edges(n_rings, dx, "face"), lobe=lobe, wave=wave, info=info
    )


def _transfer_info(grid, shape: tuple[int, int], n_steps: int, sim_s: float, request: dict) -> dict:
    """The transfer's record: the lattice it ran on, its cost and what was asked."""
    return {
        "method": "rz lattice, one response per ring (vmap)",
        "grid_shape": list(shape),
        "n_steps": n_steps,
        "simulation_s": sim_s,
        "cells_per_wavelength": grid.cells_per_wavelength,
        "dx_m": grid.dx_m,
        "dt_s": grid.dt_s,
        "farfield_dispersion": "continuum",
        "courant": grid.courant,
    } | request


def _grid_shape(win: Window, dx: float, z_line_m: float, lattice_wave_x_m) -> tuple[int, ...]:
    """(nz, nr): the Kirchhoff-Helmholtz cylinder, a 4-cell margin and the PML; with a wavefront
    sampled on the lattice itself (`lattice_wave_x_m`), its scan line at `z_line_m` too (3 cells
    past its cell, then the margin)."""
    from ..lattice.window import Window

    if lattice_wave_x_m is not None:
        span_z, span_r = win.spans
        win = Window(
            (
                span_z.with_reach(int(math.ceil(z_line_m / dx)) + 7),
                span_r.with_reach(int(math.ceil(np.max(np.abs(lattice_wave_x_m)) / dx)) + 7),
            )
        )
    return win.shape


def _checked_request(wave_method: str, surface_gap: int, lobe_angle_deg, lobe_range_m, wave_x_m, wave_z_m) -> float:
    """Check what `disc_transfer` is asked for; returns the wavefront's distance (m; NaN: none)."""
    if wave_method not in ("transform", "lattice"):
        raise ValueError(f"wave_method = {wave_method!r}; allowed: 'transform', 'lattice'")
    if surface_gap < 1:
        raise ValueError(f"surface_gap = {surface_gap} must be >= 1 cell (the surface must not cut the source cells)")
    if lobe_angle_deg is None and wave_x_m is None:
        raise ValueError(
            "nothing to compute: give lobe angles and a range, wavefront positions and a distance, or both"
        )
    if lobe_angle_deg is not None:
        lobe_points(lobe_angle_deg, lobe_range_m)  # checks the range
    z_line = float(wave_z_m) if wave_z_m is not None else math.nan
    if wave_x_m is not None and not z_line > 0:
        raise ValueError(f"wave_z_m = {wave_z_m} must be > 0 m (in front of the face)")
    return z_line


def _batched_responses(one, n_rings: int, batch: int, dtype) -> np.ndarray:
    """Every ring's phasors (n_rings, m): `one` (one-hot ring weights -> phasors, peak history)
    vmapped `batch` rings at a time, each batch checked for instability."""
    import jax
    import jax.numpy as jnp

    from ..solver.loop import check_finite

    run = jax.jit(jax.vmap(one))
    eye = np.eye(n_rings)
    parts = []
    for s in range(0, n_rings, batch):
        ph_s, peaks = run(jnp.asarray(eye[s : s + batch], dtype))
        check_finite(peaks)
        parts.append(np.asarray(ph_s))
    return np.concatenate(parts)


def _lobe_matrix(pairs, surf, grid, lobe_angle_deg, lobe_range_m, z_face: float, baffle: str, n_rings: int):
    """(n_angles, n_rings) far field of each ring by the Kirchhoff-Helmholtz integral over the
    surface (continuum wavenumber); 0 behind a rigid baffle."""
    from ..observe.farfield_rz import field_at_rz

    dx = grid.dx_m
    k = 2 * math.pi / grid.cells_per_wavelength  # continuum wavenumber, radians per cell
    r_src = surf.jr + 1.0  # outermost surface radius, cells
    rho, z = lobe_points(lobe_angle_deg, lobe_range_m)
    front = z >= -1e-12 * np.max(np.hypot(rho, z))  # 0 behind the baffle; its plane (90 deg) is the grazing limit
    if baffle != "rigid":  # no baffle: the field reaches round the housing
        front = np.ones_like(front)
    lobe = np.zeros((len(rho), n_rings), complex)
    if front.any():
        zz = z[front] if baffle != "rigid" else np.maximum(z[front], 0.0)
        pts = np.stack([z_face + zz, rho[front]], 1) / dx
        n_phi = 2 * int(math.ceil(k * r_src + 32))  # far points: the phase varies by k r' sin t over the ring
        lobe[front] = np.asarray(field_at_rz(pairs, surf, grid, pts, dispersion="continuum", n_phi=n_phi)).T
    return lobe


def _wave_matrix(pairs, surf, grid, x: np.ndarray, z_m: float):
    """(n_points, n_rings) field of each ring on the scan line at `z_m` (grid coordinates, m),
    positions `x` (p(x) = p(|x|)), by the same integral (near points: also the 1/R peak)."""
    from ..observe.farfield_rz import field_at_rz

    dx = grid.dx_m
    k = 2 * math.pi / grid.cells_per_wavelength
    r_src = surf.jr + 1.0
    pts = np.stack([np.full_like(x, z_m), np.abs(x)], 1) / dx
    d_min = max(z_m / dx - surf.iz1 - 1, 1.0)
    n_phi = 2 * int(math.ceil(k * r_src + 12 * r_src / d_min + 32))  # near: also the 1/R peak of width ~ d / r'
    return np.asarray(field_at_rz(pairs, surf, grid, pts, dispersion="continuum", n_phi=n_phi)).T


def disc_field_figure(fitted, transfer: DiscTransfer, path):
    """Simulate the fitted disc (an 8-cycle burst, its ring weights and lags) on the rz lattice of
    `transfer` and render the meridian plane mirrored about the axis (z across, x up), like the
    paper's Fig. 2; saved to `path` (PNG)."""
    from .. import plots

    args, kwargs = disc_field_image_args(fitted, transfer)
    return plots.save(plots.field_image(*args, **kwargs), path)


def disc_field_image_args(fitted, transfer: DiscTransfer) -> tuple[tuple, dict]:
    """The simulation of `disc_field_figure`: the arguments of `plots.field_image` (NumPy), for
    `fit.report` (a disc model's field image, drawn in its figure worker)."""
    import jax.numpy as jnp

    from ..air import density_kg_m3
    from ..lattice.coefficients import Edges
    from ..lattice.grid import make_grid
    from ..lattice.medium import Medium
    from ..solver.loop import simulate
    from ..solver.sensors import Sensors
    from ..solver.sources import ToneBurst, disc_housing, disc_transducer

    g0 = transfer.grid
    if g0 is None:
        raise ValueError("disc_field_figure needs a lattice transfer (disc_transfer), not the Rayleigh reference")
    n = fitted.spec.n_cells
    pml = 20
    info = transfer.info
    baffle = info.get("baffle", "rigid")
    depth_m = info.get("can_depth_m") or g0.dx_m
    wall_m = info.get("can_wall_m") or 0.0
    back = 0 if baffle == "rigid" else pml + 4 + int(math.ceil(depth_m / g0.dx_m - 1e-9)) + int(0.5 * n)
    nz, nr = int(4.5 * n) + pml + back, int(1.6 * n + wall_m / g0.dx_m) + pml
    grid = make_grid(
        frequency_hz=g0.frequency_hz,
        cells_per_wavelength=g0.cells_per_wavelength,
        c_max_m_s=g0.c_max_m_s,
        shape=(nz, nr),
        dtype="float32",
        kind="rz",
        stencil=g0.stencil,
    )
    ph = fitted.physical
    z_face = back * grid.dx_m
    src = disc_transducer(
        grid,
        radius_m=n * grid.dx_m,
        z_m=z_face,
        n_rings=n,
        signal=ToneBurst(g0.frequency_hz, 8.0),
        weights=jnp.asarray(ph["weights"], jnp.float32),
        lags_s=jnp.asarray(ph["lags_s"], jnp.float32),
        baffle=baffle,
    )
    housing = disc_housing(grid, radius_m=n * grid.dx_m, z_m=z_face, baffle=baffle, depth_m=depth_m, wall_m=wall_m)
    steps = int((nz - back - pml - 10) / grid.courant)
    res = simulate(
        grid,
        Medium(g0.c_max_m_s, density_kg_m3(20.0), rigid=housing),
        src,
        Sensors(),
        n_steps=steps,
        edges=Edges.axisymmetric("rigid" if baffle == "rigid" else "pml", "pml", "pml", thickness_cells=pml),
    )
    p = np.asarray(res.final.pressure)
    full = np.concatenate([p[:, ::-1], p], axis=1)  # x = -r .. r: the scan plane through the axis
    cells = np.asarray(src.cells_array)
    mirrored = np.concatenate(
        [np.stack([cells[:, 0], nr - 1 - cells[:, 1]], 1), np.stack([cells[:, 0], nr + cells[:, 1]], 1)]
    )
    kwargs = {
        "step": steps,
        "dt_s": grid.dt_s,
        "sources": [mirrored],
        "obstacles": None
        if housing is None
        else np.concatenate([np.asarray(housing)[:, ::-1], np.asarray(housing)], axis=1),
        "title": f"fitted disc ({'rigid baffle' if baffle == 'rigid' else baffle if baffle == 'can' else 'no baffle'}), "
        "meridian plane (8-cycle burst)",
    }
    return (full, grid.dx_m), kwargs


@dataclass(frozen=True)
class DiscSetup:
    """What a fit of the disc model needs (`disc_setup`): the model `spec`, its `transfer`, the
    untuned uniform piston `uniform_spec` of the same size (the report's baseline) and
    `make_transfer(cells_per_wavelength)` (the same transfer at another resolution, for the error
    budget's resolution term)."""

    spec: Any
    transfer: DiscTransfer
    uniform_spec: Any
    make_transfer: Any


def disc_setup(
    *,
    frequency_hz: float,
    c_m_s: float,
    face_diameter_m: float,
    cells_per_wavelength: float,
    lobe=None,
    wave=None,
    lobe_range_m: float | None = None,
    weights: str = "uniform",
    lags: str = "uniform",
    n_basis: int = 2,
    fit_diameter: bool = True,
    diameter_m: float | None = None,
    rim_width_m: float | None = None,
    baffle: str = "rigid",
    can_depth_m: float | None = None,
    can_wall_m: float = 0.0,
    stencil: StencilKind = "standard",
) -> DiscSetup:
    """The disc model of a transducer face `face_diameter_m` across (the modelled disc: the fitted
    diameter lies inside it) for the data `lobe` / `wave` (`fit.data.LobeData` / `WaveData`;
    the lobe modelled at `lobe_range_m`, default the data's range), with its transfer from the
    axisymmetric lattice at `cells_per_wavelength`, the face in `baffle` ("rigid", "none" or "can"
    with `can_depth_m` and `can_wall_m` in metres; see `disc_transfer`). Raises ValueError for a
    face of fewer than 2 rings, a bad profile or baffle (the message names the value)."""
    _housing_layout(baffle, 2, 1.0, 1, 0, can_depth_m, can_wall_m)  # checks the baffle before any simulation

    def n_rings(ppw: float) -> int:
        return int(round(0.5 * face_diameter_m * ppw * frequency_hz / c_m_s))

    def make_transfer(ppw: float) -> DiscTransfer:
        return disc_transfer(
            frequency_hz=frequency_hz,
            c_m_s=c_m_s,
            n_rings=n_rings(ppw),
            cells_per_wavelength=ppw,
            lobe_angle_deg=None if lobe is None else lobe.angle_deg,
            lobe_range_m=None if lobe is None else (lobe_range_m or lobe.range_m),
            wave_x_m=None if wave is None else wave.x_m,
            wave_z_m=None if wave is None else wave.z_m,
            baffle=cast(Any, baffle),
            can_depth_m=can_depth_m,
            can_wall_m=can_wall_m,
            stencil=stencil,
        )

    n = n_rings(cells_per_wavelength)
    dx = c_m_s / (frequency_hz * cells_per_wavelength)
    if n < 2:
        raise ValueError(
            f"a modelled face of {face_diameter_m} m is {n} rings of {dx * 1e3:.3g} mm at {cells_per_wavelength:g} "
            "cells per wavelength; the disc needs >= 2 rings: give its diameter in metres"
        )
    spec = DiscSpec(
        n_cells=n,
        dx_m=dx,
        frequency_hz=frequency_hz,
        weights=cast(Any, weights),
        lags=cast(Any, lags),
        n_basis=n_basis,
        fit_diameter=fit_diameter,
        diameter_m=diameter_m,
        rim_width_m=rim_width_m,
        baffle=cast(Any, baffle),
    )
    uniform = DiscSpec(
        n_cells=n,
        dx_m=dx,
        frequency_hz=frequency_hz,
        fit_diameter=False,
        diameter_m=diameter_m or 0.97 * 2 * n * dx,
        baffle=cast(Any, baffle),
    )
    return DiscSetup(
        spec=spec, transfer=make_transfer(cells_per_wavelength), uniform_spec=uniform, make_transfer=make_transfer
    )
