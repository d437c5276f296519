"""The disc transfer matrices from the axisymmetric lattice against the Rayleigh integral.

The reference (`rayleigh_disc_transfer`) is the exact baffled-annulus field by quadrature, in the
same units (pressure per unit rho c v), so the comparison needs no fitted scale. Tolerances:

- the issue's accuracy targets at 20 cells per wavelength for a 38.4 mm piston at 50 kHz: first
  null within 0.1 deg, first side lobe within 0.3 dB, field on the line z = 16.5 mm within 2 deg
  RMS and 0.3 dB (both wavefront methods);
- what a fit to the rig needs: the transfer's error below the rig's noise per point, so a fit can
  reach chi2_red ~ 1: wavefront phase (a constant removed: the fitted phase offset) RMS below
  0.106 deg (0.3 deg per burst / sqrt(8)) and main-lobe level (a constant removed: the gain) RMS
  below 0.05 dB (the lobe sigma floor);
- the absolute level: within 1 % (the surface's order-4 differences leave O((k h)^4)).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from difflattice.fit.disc import DiscSpec
from difflattice.fit.transfer_disc import disc_transfer, rayleigh_disc_transfer

F = 50e3
C = 331.3 * math.sqrt(1 + 21 / 273.15)
PPW = 20.0
DX = C / F / PPW
N_RINGS = int(round(0.021 / DX))
D = 0.0384
COARSE = np.arange(-90, 90.1, 1.0)
NULL = np.arange(11.8, 13.4, 0.01)  # around the first null (12.6 deg) and
SIDE = np.arange(16.0, 18.0, 0.01)  # the first side lobe (17.0 deg)
ANGLES = np.concatenate([COARSE, NULL, SIDE])
XS = np.round(np.arange(0.0, 0.02401, 0.001), 6)  # p(x) = p(|x|) on the rig's line
Z = 0.0165


@pytest.fixture(scope="module", params=["standard", "isotropic"])
def transfers(request):
    """Both stencils (`[model] stencil`) meet the same targets."""
    kw = dict(
        frequency_hz=F, c_m_s=C, n_rings=N_RINGS, lobe_angle_deg=ANGLES, lobe_range_m=1.0, wave_x_m=XS, wave_z_m=Z
    )
    lattice = disc_transfer(cells_per_wavelength=PPW, stencil=request.param, **kw)
    assert lattice.info["stencil"] == request.param
    ref = rayleigh_disc_transfer(dr_m=DX, rtol=1e-6, **kw)
    return lattice, ref


def _piston(T):
    spec = DiscSpec(n_cells=N_RINGS, dx_m=DX, frequency_hz=F, fit_diameter=False, diameter_m=D)
    a = np.asarray(spec.amplitudes(spec.init_params()))
    return (None if T.lobe is None else T.lobe @ a), T.wave @ a


def _null_and_side_lobe(lobe):
    db = 20 * np.log10(np.abs(lobe) / np.abs(lobe[np.argmin(np.abs(ANGLES))]))
    n0, s0 = len(COARSE), len(COARSE) + len(NULL)
    i = np.argmin(db[n0:s0])
    j = np.argmax(db[s0:])
    assert 0 < i < len(NULL) - 1 and 0 < j < len(SIDE) - 1  # interior extrema
    return NULL[i], SIDE[j], db[s0 + j]


def test_piston_lobe_null_and_side_lobe(transfers):
    lattice, ref = transfers
    null_l, side_l, level_l = _null_and_side_lobe(_piston(lattice)[0])
    null_r, side_r, level_r = _null_and_side_lobe(_piston(ref)[0])
    assert abs(null_l - null_r) < 0.1
    assert abs(level_l - level_r) < 0.3
    assert level_r == pytest.approx(-17.6, abs=0.3)  # the reference is the piston (at 1 m: Fresnel-filled nulls)
    assert abs(side_l - side_r) < 0.1


def test_piston_wavefront_and_levels_below_the_rig_noise(transfers):
    lattice, ref = transfers
    lobe_l, wave_l = _piston(lattice)
    lobe_r, wave_r = _piston(ref)
    ratio = wave_l / wave_r
    phase = np.degrees(np.angle(ratio))
    amp_db = 20 * np.log10(np.abs(ratio))
    assert math.sqrt(np.mean(phase**2)) < 2.0 and np.abs(amp_db).max() < 0.3  # the targets
    if lattice.info["stencil"] == "isotropic":
        # measured: phase std 0.125 deg at 20 cells per wavelength (courant 0.707), above the rig's
        # 0.106: why the fits default to the standard stencil (`[model] stencil`)
        return
    assert np.std(phase) < 0.106  # a fit's needs (constant removed: the fitted phase offset)
    main = np.abs(COARSE) <= 12
    lob = 20 * np.log10(np.abs(lobe_l[: len(COARSE)][main] / lobe_r[: len(COARSE)][main]))
    assert np.std(lob) < 0.05
    assert abs(np.mean(amp_db)) < 20 * math.log10(1.01) and abs(np.mean(lob)) < 20 * math.log10(1.01)  # absolute level


def test_each_ring_column(transfers):
    """Every ring's wavefront column (the fit weights rings independently), relative to its size."""
    lattice, ref = transfers
    err = np.abs(lattice.wave - ref.wave).max(0) / np.abs(ref.wave).max(0)
    assert err.max() < 0.02


def test_lattice_scan_line_method():
    """The field sampled on the lattice's own scan line (dispersion over the whole 16.5 mm)."""
    kw = dict(frequency_hz=F, c_m_s=C, n_rings=N_RINGS, wave_x_m=XS, wave_z_m=Z)
    lattice = disc_transfer(cells_per_wavelength=PPW, wave_method="lattice", **kw)
    ref = rayleigh_disc_transfer(dr_m=DX, rtol=1e-6, **kw)
    ratio = _piston(lattice)[1] / _piston(ref)[1]
    assert math.sqrt(np.mean(np.degrees(np.angle(ratio)) ** 2)) < 2.0
    assert np.abs(20 * np.log10(np.abs(ratio))).max() < 0.3


def test_refuses_bad_requests():
    with pytest.raises(ValueError, match="nothing to compute"):
        disc_transfer(frequency_hz=F, c_m_s=C, n_rings=10)
    with pytest.raises(ValueError, match="wave_method"):
        disc_transfer(frequency_hz=F, c_m_s=C, n_rings=10, wave_x_m=XS, wave_z_m=Z, wave_method="exact")
    with pytest.raises(ValueError, match="range_m"):
        disc_transfer(frequency_hz=F, c_m_s=C, n_rings=10, lobe_angle_deg=COARSE, lobe_range_m=-1.0)
