"""The Kirchhoff-Helmholtz near-to-far-field transform.

1. Against direct simulation at cells on an arc that fits in the grid: the transform is a midpoint
   rule (error O((k h)^2 / 24) ~ 0.4 % at 20 cells per wavelength) of an integral of the lattice
   field with the continuum Green's function (another O((k h)^2) term), so the relative error,
   normalised by the peak, must be below 2 %.
2. The far-field lobe of a uniform 104-cell line (the Polaroid) against the analytic array factor
   with the lattice's direction-dependent wavenumber: first null within 0.05 deg and first
   side-lobe level within 0.1 dB (the element pattern of one lattice cell is flat to 0.01 dB,
   measured by the third test).

"""

import numpy as np

from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import Medium
from difflattice.observe.analytic import line_array_pattern
from difflattice.observe.farfield import box_around, far_field, field_at, level_db
from difflattice.solver import simulate
from difflattice.solver.sensors import Sensors, arc_cells
from difflattice.solver.sources import ToneBurst, line_transducer


def _run(n_cells, shape, extra_cells=None, n_steps=None, ppw=20.0):
    g = make_grid(frequency_hz=50e3, cells_per_wavelength=ppw, c_max_m_s=343.0, shape=shape, dtype="float64")
    xc, yc = 40, shape[1] // 2
    src = line_transducer(g, (xc * g.dx_m, yc * g.dx_m), n_cells=n_cells, signal=ToneBurst(50e3, 6))
    box = box_around(src.cells_array, 4)
    cells = box.cells if extra_cells is None else np.concatenate([box.cells, extra_cells])
    n_steps = n_steps or int((box.ix1 - box.ix0 + box.iy1 - box.iy0) / 0.7 + 6 * 29 + 100)
    r = simulate(g, Medium(343.0, 1.2), src, Sensors(phasor_cells=cells), n_steps=n_steps)
    return g, src, box, r.phasors, (xc, yc)


def test_transform_matches_direct_simulation():
    shape = (260, 300)
    g = make_grid(frequency_hz=50e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=shape)
    ang = np.linspace(-50, 50, 41)
    arc = arc_cells(g, (40 * g.dx_m, 150 * g.dx_m), 150 * g.dx_m, ang)
    g, src, box, ph, centre = _run(30, shape, extra_cells=arc, n_steps=900)
    m2 = len(box.cells)
    direct = np.asarray(ph[m2:])
    kh = np.asarray(field_at(ph[:m2], box, g, arc))
    err = np.abs(kh - direct).max() / np.abs(direct).max()
    assert err < 0.02, err


def test_polaroid_line_lobe_against_array_factor():
    n = 104
    g, src, box, ph, centre = _run(n, (90, n + 50))
    ang = np.linspace(0, 40, 4001)
    model = np.abs(np.asarray(far_field(ph, box, g, ang, 1.0, centre)))
    model_db = 20 * np.log10(model / model[0])
    theta = np.radians(ang)
    ref_db = 20 * np.log10(line_array_pattern(n, g.omega, g.courant, theta))
    i_null = np.argmin(model_db[:2000])
    j_null = np.argmin(ref_db[:2000])
    assert abs(ang[i_null] - ang[j_null]) < 0.05
    # first side lobe: the maximum between the first and second nulls
    sl_model = model_db[i_null : i_null + 1000].max()
    sl_ref = ref_db[j_null : j_null + 1000].max()
    assert abs(sl_model - sl_ref) < 0.1


def test_single_cell_is_nearly_isotropic():
    """The lattice's amplitude anisotropy is O((k h)^2): under 0.02 dB at 20 cells per wavelength
    ((k h)^2 / 48 = 0.2 %), and about 4x smaller at 40."""
    spread = []
    for ppw, n in ((20.0, 90), (40.0, 170)):
        g, src, box, ph, centre = _run(1, (n, n), ppw=ppw)
        ang = np.linspace(-90, 90, 37)
        spread.append(np.ptp(np.asarray(level_db(far_field(ph, box, g, ang, 1.0, centre)))))
    assert spread[0] < 0.02
    assert 3.0 < spread[0] / spread[1] < 5.0


def test_hankel_expansion_against_scipy():
    """The four-term large-argument expansion of H0 and H1 against scipy's Bessel functions over
    the transform's range k R >= 30. Bound: the first two omitted terms, |a4| / z^4 + |a5| / z^5
    (a4 = 0.112 for H0 and -0.144 for H1: 1.4e-7 and 1.8e-7 at z = 30), plus the rounding of the
    phase z (z eps relative: 1.1e-12 at z = 5000)."""
    import scipy.special as sp

    from difflattice.observe.farfield import _hankel

    z = np.geomspace(30.0, 5000.0, 400)
    for nu in (0, 1):
        mu = 4.0 * nu * nu
        a = [1.0]
        for k in range(1, 6):
            a.append(a[-1] * (mu - (2 * k - 1) ** 2) / (k * 8))
        bound = abs(a[4]) / z**4 + abs(a[5]) / z**5 + z * np.finfo(float).eps * 2
        err = np.abs(_hankel(nu, z) - sp.hankel1(nu, z)) / np.abs(sp.hankel1(nu, z))
        assert np.all(err <= bound), (nu, float(np.max(err / bound)))
