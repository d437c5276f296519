"""Normal-incidence reflection and transmission at interfaces, walls and edges.

References:
- `analytic.discrete_rt`: the exact R and T of the discrete equations (independent derivation from
  the scheme's equations at the two interface cells). The simulation must match it to the level of
  PML reflection (< 1e-6), so the tolerance is 1e-5.
- the continuum eqs. 14-15, which the conservative form approaches at second order in the cell size.
"""

import math

import numpy as np
import pytest

from difflattice.apps.validation import edge_reflection_db, plane_wave_rt
from difflattice.lattice.grid import make_grid
from difflattice.observe.analytic import continuum_rt, discrete_rt, lattice_wavenumber

CASES = {
    "equal speeds, rho x3": (343.0, 343.0, 1.2, 3.6),
    "unequal speeds, equal rho": (343.0, 171.5, 1.2, 1.2),
    "air to pine (R = 0.9995)": (343.0, 3500.0, 1.2, 500.0),
    "water to air": (1482.0, 343.0, 998.0, 1.2),
}


def _theory(c1, c2, r1, r2, model, ppw=20.0):
    cmax = max(c1, c2)
    g = make_grid(frequency_hz=50e3, cells_per_wavelength=ppw * cmax / c1, c_max_m_s=cmax, shape=(3, 1))
    w = g.omega
    l1, l2 = g.speed_to_lattice(c1), g.speed_to_lattice(c2)
    R, T = discrete_rt(w, l1, l2, r1, r2, model)
    k1 = float(lattice_wavenumber(w, l1, 0.0))
    k2 = float(lattice_wavenumber(w, l2, 0.0))
    # move the references from the cells next to the face to the face itself
    return R, T, R * np.exp(-1j * k1), T * np.exp(-1j * k2 / 2) * np.exp(-1j * k1 / 2)


@pytest.mark.parametrize("model", ["conservative", "paper"])
@pytest.mark.parametrize("case", list(CASES))
def test_simulation_matches_discrete_theory(case, model):
    c1, c2, r1, r2 = CASES[case]
    R, T = plane_wave_rt(c1_m_s=c1, c2_m_s=c2, rho1=r1, rho2=r2, model=model)
    Rd, Td, _, _ = _theory(c1, c2, r1, r2, model)
    assert abs(R - Rd) < 1e-5
    assert abs(T - Td) < 1e-5


@pytest.mark.parametrize("case", list(CASES))
def test_conservative_form_converges_to_eq14_at_second_order(case):
    c1, c2, r1, r2 = CASES[case]
    Rc, Tc = continuum_rt(r1 * c1, r2 * c2)
    errs = []
    for ppw in (20.0, 40.0, 80.0):
        _, _, Rf, Tf = _theory(c1, c2, r1, r2, "conservative", ppw)
        errs.append(max(abs(abs(Rf) - abs(Rc)), abs(abs(Tf) - abs(Tc))))
    # at 20 cells per wavelength within 2 % of eq. 14-15
    assert errs[0] < 0.02 * max(1.0, abs(Tc))
    slopes = [math.log2(errs[i] / errs[i + 1]) for i in range(2)]
    if errs[0] > 1e-9:
        assert min(slopes) > 1.8, slopes


def test_paper_boundary_wrong_for_unequal_speeds():
    """Eqs. 17-19 give eq. 14 for equal speeds but act like the impedance ratio Z2c2/(Z1c1)
    when the speeds differ (the reason the conservative form is the default)."""
    c1, c2, r1, r2 = CASES["unequal speeds, equal rho"]
    z1, z2 = r1 * c1, r2 * c2
    R_eq14, _ = continuum_rt(z1, z2)
    R_wrong, _ = continuum_rt(z1 * c1, z2 * c2)
    _, _, Rf, _ = _theory(c1, c2, r1, r2, "paper", ppw=80.0)
    assert abs(abs(Rf) - abs(R_wrong)) < 0.01
    assert abs(abs(Rf) - abs(R_eq14)) > 0.2
    # equal speeds: paper and conservative agree
    c1, c2, r1, r2 = CASES["equal speeds, rho x3"]
    assert abs(_theory(c1, c2, r1, r2, "paper")[0] - _theory(c1, c2, r1, r2, "conservative")[0]) < 1e-12


@pytest.mark.parametrize(
    "wall, model, expected, offset",
    [
        ("rigid", "conservative", 1.0, 0.5),  # wall at the face, no phase reversal
        ("rigid", "paper", 1.0, 0.5),
        ("soft", "conservative", -1.0, 0.5),
        ("soft", "speed_zero", -1.0, 1.0),  # speed zero: pressure release at the obstacle's cell
        ("rigid", "speed_zero", -1.0, 1.0),  # speed zero reverses the phase whatever the material
    ],
)
def test_wall_phase(wall, model, expected, offset):
    R, _ = plane_wave_rt(c1_m_s=343.0, c2_m_s=343.0, rho1=1.2, rho2=1.2, model=model, wall=wall)
    g = make_grid(frequency_hz=50e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(3, 1))
    k1 = float(lattice_wavenumber(g.omega, g.courant, 0.0))
    R_wall = R * np.exp(-2j * k1 * offset)  # referenced to the wall position
    assert abs(R_wall - expected) < 1e-4


def test_pml_reflection_target():
    # issue target: a 20-cell PML at 20 cells per wavelength reflects at most -85 dB
    assert edge_reflection_db("pml", thickness_cells=20, cells_per_wavelength=20) < -85


def test_mur_reflection_matches_its_discrete_theory():
    from difflattice.observe.analytic import mur_reflection

    g = make_grid(frequency_hz=50e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(3, 1))
    expected_db = 20 * math.log10(abs(mur_reflection(g.omega, g.courant)))
    # a 4-cycle burst is broadband: allow the spread of |R| over its main band (+-1.5 dB)
    assert edge_reflection_db("mur") == pytest.approx(expected_db, abs=1.5)
