"""Scales of eqs. 11-12 and the stability limit."""

import pytest

from difflattice.lattice.grid import MAX_COURANT, make_grid
from difflattice.lattice.medium import MATERIALS, air, air_speed_m_s, reflection_coefficient


def test_paper_scales():
    # Paper: 50 kHz, 20 cells per wavelength, c ~ 343 m/s -> wavelength 6.86 mm, cell 0.343 mm
    g = make_grid(frequency_hz=50e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(840, 630))
    assert g.dx_m == pytest.approx(343.0 / 50e3 / 20, rel=1e-12)
    # eq. 12: R = c S / 0.707 steps per second
    S = 20 * 50e3 / 343.0
    assert 1 / g.dt_s == pytest.approx(343.0 * S / 0.707, rel=1e-12)
    assert g.speed_to_lattice(343.0) == pytest.approx(0.707, rel=1e-12)
    assert g.steps_per_period == pytest.approx(20 / 0.707, rel=1e-12)
    # the paper's image width: 840 cells at 0.34 mm = 286-288 mm
    assert 0.285 < g.size_m[0] < 0.289


def test_courant_above_limit_refused():
    with pytest.raises(ValueError, match="stability limit"):
        make_grid(frequency_hz=50e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(10, 10), courant=0.7072)
    g = make_grid(frequency_hz=50e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(10, 10), courant=MAX_COURANT)
    assert g.courant == MAX_COURANT


def test_materials():
    assert air_speed_m_s(0.0) == pytest.approx(331.3)
    assert air(20).speed_m_s == pytest.approx(343.2, abs=0.1)
    # paper: air to pine R = 0.9995
    r = reflection_coefficient(air(20).impedance, MATERIALS["pine"].impedance)
    assert r == pytest.approx(0.9995, abs=1e-4)
    assert reflection_coefficient(1.0, MATERIALS["rigid"].impedance) == 1.0
    assert reflection_coefficient(1.0, MATERIALS["soft"].impedance) == -1.0
    with pytest.raises(ValueError, match="below absolute zero"):
        air_speed_m_s(-300)
