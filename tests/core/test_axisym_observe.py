"""Observables of the axisymmetric lattice on analytic fields (no simulation): the Rayleigh
quadrature reference and the scan-line sampler (the disc transducer's geometry:
`test_sources_sensors.py`; the Kirchhoff-Helmholtz transform over a closed cylinder, free and
baffled, with the other kinds' surfaces in `test_farfield_kinds.py`)."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice.grid import make_grid
from difflattice.observe import analytic as an
from difflattice.observe.farfield_rz import field_sampler, scan_line


def _grid(ppw=20, shape=(200, 120)):
    return make_grid(
        frequency_hz=50e3, cells_per_wavelength=ppw, c_max_m_s=343.0, shape=shape, dtype="float64", kind="rz"
    )


def test_rayleigh_quadrature_is_converged_and_exact_on_axis():
    """The reference the piston is checked against: on the axis it must reproduce the closed form
    exp(ikz) - exp(ik sqrt(z^2 + a^2)) (an independent formula) to round-off, and doubling its
    nodes anywhere on the scan line must change nothing (spectral convergence)."""
    k, a = 2 * math.pi / (343.0 / 50e3), 0.0192
    z = np.array([0.002, 0.0165, 0.05, 0.3])
    on_axis = an.rayleigh_piston(np.stack([np.zeros_like(z), z], 1), a, k)
    assert np.abs(on_axis - an.piston_on_axis(z, a, k)).max() < 1e-10
    pts = np.stack([np.linspace(-0.03, 0.03, 13), np.full(13, 0.0165)], 1)
    p1 = an.rayleigh_piston(pts, a, k)
    p2 = an.rayleigh_piston(pts, a, k, n_r=2 * (2 * math.ceil(k * a) + 64), n_phi=2 * (2 * math.ceil(k * 0.0492) + 64))
    assert np.abs(p1 - p2).max() < 1e-10 * np.abs(p1).max()
    # the far field of the quadrature is the 2 J1(x)/x lobe
    th = np.radians(np.array([0.0, 5.0, 10.0, 20.0]))
    far = an.rayleigh_piston(np.stack([30.0 * np.sin(th), 30.0 * np.cos(th)], 1), a, k)
    lobe = np.abs(far) / np.abs(far[0])
    assert np.abs(lobe - np.abs(an.piston_directivity(th, k * a))).max() < 1e-3  # range 30 m: (k a^2 / 2R) ~ 0.6e-3
    assert (
        abs(
            an.PISTON_FIRST_SIDELOBE_DB
            - 20 * math.log10(abs(an.piston_directivity(math.asin(an.PISTON_FIRST_SIDELOBE_KA_SIN / 10.0), 10.0)))
        )
        < 1e-6
    )


def test_scan_line_interpolation():
    """Cubic interpolation in z and r, even in r: exact for a field that is a cubic in z times an
    even quartic-free polynomial in r (1 + r^2), at any point, either side of the axis."""
    g = _grid(20, (40, 30))
    f = lambda z, r: (1 + 0.3 * z - 0.02 * z**2 + 0.001 * z**3) * (2 + 0.05 * r**2)  # cells
    x_m = np.array([-0.004, -0.0011, 0.0, 0.00017, 0.0023, 0.006])
    z_m = 0.0061
    sl = scan_line(g, x_m, z_m)
    cells = sl.cells
    ph = jnp.asarray(f(cells[:, 0] + 0.5, cells[:, 1] + 0.5).astype(complex))
    got = np.asarray(sl(ph)).real
    want = f(z_m / g.dx_m, np.abs(x_m) / g.dx_m)
    assert np.abs(got - want).max() < 1e-12 * np.abs(want).max()
    with pytest.raises(ValueError, match="outside the grid"):
        field_sampler(g, [[0.0, 0.0]])  # needs a row below z = 0
