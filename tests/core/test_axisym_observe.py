"""Observables of the axisymmetric lattice on analytic fields (no simulation): the Rayleigh
quadrature reference, the Kirchhoff-Helmholtz transform over a closed cylinder (free and baffled),
and the scan-line sampler (the disc transducer's geometry: `test_sources_sensors.py`)."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice.grid import make_grid
from difflattice.observe import analytic as an
from difflattice.observe.farfield_rz import CylinderSurface, far_field_rz, field_at_rz, field_sampler, scan_line


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


def _monopole(cells, zs, k, baffled):
    z, r = cells[:, 0] + 0.5, cells[:, 1] + 0.5
    R = np.hypot(z - zs, r)
    p = np.exp(1j * k * R) / (4 * math.pi * R)
    if baffled:
        Ri = np.hypot(z + zs, r)
        p = p + np.exp(1j * k * Ri) / (4 * math.pi * Ri)
    return p


@pytest.mark.parametrize("baffled", [False, True], ids=["free", "baffled"])
def test_kirchhoff_transform_of_a_monopole(baffled):
    """A monopole (with its image in the baffle plane z = 0 when baffled) sampled on the cylinder's
    cells: the transform gives its far field exp(-ik z_s cos t) / 4 pi (+ image) and its field at
    finite range. The surface quadrature is second order in k dx (cell means for p, a difference
    for dp/dn, midpoint rule along the faces: ~(k dx)^2 / 8 = 1.2 % at 20 cells per wavelength):
    < 2 % at 20 and at least 4x smaller at 40 cells per wavelength."""
    errs = []
    for ppw in (20, 40):
        g = _grid(ppw, (10 * ppw, 6 * ppw))
        k = 2 * math.pi / ppw
        if baffled:
            surf, zs = CylinderSurface(0, int(1.5 * ppw), int(1.25 * ppw), baffled=True), 0.31 * ppw
        else:
            surf, zs = CylinderSurface(ppw, 3 * ppw, int(1.25 * ppw)), 1.87 * ppw
        ph = jnp.asarray(_monopole(surf.cells, zs, k, baffled))
        ang = np.arange(0.0, 91.0, 5.0)
        F = np.asarray(far_field_rz(ph, surf, g, ang))
        th = np.radians(ang)
        ex = np.exp(-1j * k * zs * np.cos(th)) / (4 * math.pi)
        if baffled:
            ex = ex + np.exp(1j * k * zs * np.cos(th)) / (4 * math.pi)
        pts = np.array([[10.0 * ppw, 0.0], [7.5 * ppw, 4.0 * ppw], [15.0 * ppw, 15.0 * ppw]])
        P = np.asarray(field_at_rz(ph, surf, g, pts))
        exn = _monopole(pts - 0.5, zs, k, baffled)  # _monopole takes cell indices
        errs.append(max(np.abs(F - ex).max() / np.abs(ex).max(), (np.abs(P - exn) / np.abs(exn)).max()))
    assert errs[0] < 0.02 and errs[1] < errs[0] / 4, errs


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
