"""The free-field fast path (one simulated cell, translated) against the reference: a direct
simulation of the whole line with the same weights and lags.

- wavefront: evaluated at cells (interpolation weights exactly 0/1), both are the lattice field
  itself; they differ only by DFT truncation of the 2-D wake and PML reflections: 1e-3.
- lobe: both are Kirchhoff-Helmholtz transforms of lattice fields, each with a quadrature error
  ~ (k h)^2 / 24 relative; two independent errors: tolerance 2 (k h)^2 / 24 (0.8 % at 20 cells
  per wavelength).
"""

import math

import jax.numpy as jnp
import numpy as np

from difflattice.fit.transfer import _source_spectrum, free_field_transfer
from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import Medium
from difflattice.observe.farfield import box_around, field_at
from difflattice.solver import simulate
from difflattice.solver.sensors import Sensors
from difflattice.solver.sources import PointSources, ToneBurst


def test_fast_path_equals_direct_line_simulation():
    ppw, n, c, f = 20.0, 12, 343.0, 50e3
    dx = c / (f * ppw)
    lateral = np.arange(-16, 17, 4)
    zc = 25
    ang = np.linspace(-80, 80, 33)
    T = free_field_transfer(
        frequency_hz=f,
        c_m_s=c,
        n_cells=n,
        cells_per_wavelength=ppw,
        lobe_angle_deg=ang,
        lobe_range_m=1.0,
        wave_x_m=(lateral + 0.5) * dx,
        wave_z_m=zc * dx,
        dispersion="lattice",
    )
    rng = np.random.default_rng(0)
    w = rng.uniform(0.5, 1.5, n)
    lags = rng.uniform(0, 5e-6, n)
    g = make_grid(frequency_hz=f, cells_per_wavelength=ppw, c_max_m_s=c, shape=(110, 120), dtype="float64")
    x0, yc = 35, 60
    cells = np.stack([np.full(n, x0), yc - n // 2 + np.arange(n)], 1)  # centre of the line at yc - 0.5
    sig = ToneBurst(f, 4.0)
    src = PointSources(cells=cells, signal=sig, weights=jnp.asarray(w), lags_s=jnp.asarray(lags))
    box = box_around(cells, 4)
    line = np.stack([np.full(len(lateral), x0 + zc), yc + lateral], 1)
    n_steps = 1100
    r = simulate(g, Medium(c, 1.2), src, Sensors(phasor_cells=np.concatenate([box.cells, line])), n_steps=n_steps)
    ph = np.asarray(r.phasors) / _source_spectrum(sig, g, n_steps)
    m2 = len(box.cells)
    th = np.radians(ang)
    R = 1.0 / dx
    obs = np.stack([x0 + R * np.cos(th), yc - 0.5 + R * np.sin(th)], 1)
    direct_lobe = np.asarray(field_at(jnp.asarray(ph[:m2]), box, g, obs))
    a = w * np.exp(1j * 2 * math.pi * f * lags)
    kh = 2 * math.pi / ppw
    lobe_err = np.abs(T.lobe @ a - direct_lobe).max() / np.abs(direct_lobe).max()
    assert lobe_err < 2 * kh**2 / 24
    wave_err = np.abs(T.wave @ a - ph[m2:]).max() / np.abs(ph[m2:]).max()
    assert wave_err < 1e-3
