"""A 38.4 mm circular piston in a rigid baffle on the rz lattice at 20 cells per wavelength,
continuous wave, against references independent of the lattice (`observe.analytic`): the exact
on-axis field, the far-field lobe 2 J1(x)/x and a Rayleigh-integral quadrature on the scan line
z = 16.5 mm, at 50 kHz and 40 kHz. The absolute level follows from the velocity source (no fitted
scale): the drive is rho c u0 = 1 Pa, so the on-axis maxima are 2 Pa.

Where the tolerances come from: the five-point leapfrog's phase speed is anisotropic (along the
axis 0.22 % fast at 20 cells per wavelength and courant 0.69, about 0 at 45 deg), so the plane
wave from the face and the edge wave from the rim, which run in different directions, drift apart
in phase by up to 0.02 rad over the near field: that costs up to ~2 % of 2 rho c u0 in |p| on the
axis (0.8 % RMS) and moves the broad last axial maximum (at z = a^2/lambda, where the path
difference changes slowly) by ~2 cells. The same two-ray formula with each ray's lattice
wavenumber (`analytic.piston_on_axis_lattice`) removes that: what is left is the scheme's
truncation error, second order (0.10 %, 0.04 %, 0.02 % RMS at 20, 30, 40 cells per wavelength),
and the extrema then sit within 0.15 cell. The issue's criteria are checked as stated where the
physics allows them at 20 cells per wavelength (RMS 1 %, far-field null 0.1 deg, side lobe 0.3 dB,
scan-line phase 2 deg and amplitude 0.3 dB) and the extrema against the lattice-consistent
reference (0.5 cell). `difflattice.apps.accuracy_piston.piston_sweep` tabulates all of them against run
time from 6 to 40 cells per wavelength.
"""

import jax
import pytest

from difflattice.apps.accuracy_piston import piston_errors, run_piston

jax.config.update("jax_enable_x64", True)


@pytest.fixture(scope="module")
def piston_50k():
    return piston_errors(run_piston(20.0, frequency_hz=50e3, on_axis=True, repeats=0))


@pytest.fixture(scope="module")
def piston_40k():
    return piston_errors(run_piston(20.0, frequency_hz=40e3, on_axis=False, repeats=0))


def test_on_axis_field(piston_50k):
    r = piston_50k
    # the criterion: RMS over a^2/(4 lambda) .. 5 a^2/lambda within 1 % of 2 rho c U
    assert r["axis_rms_error"] < 0.01, r["axis_rms_error"]
    # against the lattice-consistent two-ray field: the truncation error only (0.10 % measured;
    # second order) and every maximum and minimum within half a cell
    assert r["axis_rms_error_lattice_k"] < 0.003, r["axis_rms_error_lattice_k"]
    assert r["axis_extrema_error_cells_lattice_k"] < 0.5, r["axis_extrema_lattice_k"]
    # (against the physical k the extrema are off by what the dispersion relation predicts:
    # 0.65 cell for the minimum at 23.4 mm, 2.1 cells for the broad maximum at 52 mm; reported by
    # the accuracy sweep, not asserted)


@pytest.mark.parametrize("which", ["50k", "40k"])
def test_far_field_lobe(which, piston_50k, piston_40k):
    r = piston_50k if which == "50k" else piston_40k
    for sfx in ("", "_lattice_k"):  # continuum (physical) and lattice-dispersion transforms
        assert abs(r["null_error_deg" + sfx]) < 0.1, r
        assert abs(r["sidelobe_error_db" + sfx]) < 0.3, r


@pytest.mark.parametrize("which", ["50k", "40k"])
def test_scan_line_at_16_5_mm(which, piston_50k, piston_40k):
    """Absolute phase (the lattice's accumulated phase error over 2.4 wavelengths, ~1.9 deg at 50
    kHz, is most of it) and level within 10 dB of the line's maximum, over |x| <= 20 mm."""
    r = piston_50k if which == "50k" else piston_40k
    assert r["line_phase_rms_deg"] < 2.0, r
    assert r["line_amp_rms_db"] < 0.3, r
    assert r["line_complex_error"] < 0.03, r  # ~ the phase error in radians, relative to the line's peak


@pytest.fixture(scope="module")
def piston_50k_isotropic():
    return piston_errors(run_piston(20.0, frequency_hz=50e3, on_axis=True, repeats=0, stencil="isotropic"))


def test_isotropic_stencil_meets_every_criterion_with_the_physical_k(piston_50k_isotropic):
    """The isotropic (9-point) stencil (`Grid.stencil`), courant 20/24 = 0.833: its phase speed is
    the same in every direction to O((k dx)^4), so the face's plane wave and the rim's edge wave
    no longer drift apart. What its dispersion relation predicts for the two-ray extrema with the
    physical k (`analytic.lattice_wavenumber(..., stencil="isotropic")`, evaluated in the test
    below): 0.20 cell at the broad maximum; the issue's 0.5 cell is asserted against the exact
    formula itself, with the issue's other criteria (RMS 1 %, null 0.1 deg, side lobe 0.3 dB,
    line phase 2 deg and amplitude 0.3 dB)."""
    r = piston_50k_isotropic
    assert r["stencil"] == "isotropic"
    assert r["axis_extrema_error_cells"] < 0.5, r["axis_extrema"]
    assert r["axis_rms_error"] < 0.01, r
    assert abs(r["null_error_deg"]) < 0.1 and abs(r["sidelobe_error_db"]) < 0.3, r
    assert r["line_phase_rms_deg"] < 2.0 and r["line_amp_rms_db"] < 0.3, r
    # and it is the stencil that does it: against its own lattice two-ray field the truncation
    # error is left (second order, smaller than the standard stencil's 0.1 %)
    assert r["axis_rms_error_lattice_k"] < 0.003, r


def test_two_ray_extrema_shift_predicted_by_the_dispersion_relations():
    """The extrema shift is the dispersion relation's, computed without the lattice: the path
    difference phase error k_edge R - k_axis z over d(phase)/dz at each extremum, in cells, at 20
    cells per wavelength: standard stencil (courant 20/29) ~2 cells, isotropic (20/24) ~0.2."""
    import math

    from difflattice.observe.analytic import lattice_wavenumber

    a, lam = 19.2e-3, 343.0 / 50e3
    worst = {}
    for stencil, spp in (("standard", 29), ("isotropic", 24)):
        c, om, h, kp = 20 / spp, 2 * math.pi / spp, lam / 20, 2 * math.pi / lam
        errs = []
        for m in range(1, 8):  # extrema where the path difference is m half wavelengths
            d = m * lam / 2
            z = (a * a - d * d) / (2 * d)
            if not a * a / (4 * lam) <= z <= 5 * a * a / lam:
                continue
            R = math.hypot(z, a)
            ka = float(lattice_wavenumber(om, c, 0.0, stencil=stencil)) / h
            ke = float(lattice_wavenumber(om, c, math.atan2(a, z), stencil=stencil)) / h
            errs.append(abs(((ke - kp) * R - (ka - kp) * z) / (kp * (z / R - 1))) / h)
        worst[stencil] = max(errs)
    assert 1.5 < worst["standard"] < 2.5 and worst["isotropic"] < 0.3, worst
