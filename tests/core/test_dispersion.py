"""The discrete dispersion relation sin^2(w/2) = c^2 (sin^2(kx/2) + sin^2(ky/2)).

An exact discrete plane wave cos(k.x - w t), started from its values at t = 0 and t = -1, must stay
exact (to round-off) in the part of the grid the edges cannot yet influence (the five-point stencil
carries information at most one cell per step). A wave with the continuum frequency w = c|k| must
not (which shows the test can fail).
"""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import Medium
from difflattice.observe.analytic import lattice_wavenumber, phase_velocity_error
from difflattice.solver import Stepper, run

N_STEPS = 60


def _evolve(c_lat, ppw, theta, omega_of_k):
    grid = make_grid(
        frequency_hz=1.0, cells_per_wavelength=ppw, c_max_m_s=c_lat, shape=(160, 160), courant=c_lat, dtype="float64"
    )
    k = 2 * math.pi / ppw
    kx, ky = k * math.cos(theta), k * math.sin(theta)
    w = omega_of_k(kx, ky)
    x, y = np.meshgrid(np.arange(160), np.arange(160), indexing="ij")
    p0 = np.cos(kx * x + ky * y)
    pm1 = np.cos(kx * x + ky * y + w)
    stepper = Stepper.build(grid, Medium(c_lat, 1.0), edges=Edges.all("rigid"))
    st = stepper.init()
    st = st.__class__(**{**st.__dict__, "p": jnp.asarray(p0), "p_prev": jnp.asarray(pm1)})
    res = run(stepper, N_STEPS, state=st)
    exact = np.cos(kx * x + ky * y - w * N_STEPS)
    inner = slice(N_STEPS + 1, 160 - N_STEPS - 1)
    return np.abs(np.asarray(res.final.p) - exact)[inner, inner].max()


@pytest.mark.parametrize("c_lat", [0.3, 0.6, 1 / math.sqrt(2)])
@pytest.mark.parametrize("ppw", [6.0, 20.0])
@pytest.mark.parametrize("theta", [0.0, math.pi / 4])
def test_discrete_plane_wave_is_exact(c_lat, ppw, theta):
    def w_lattice(kx, ky):
        return 2 * math.asin(c_lat * math.sqrt(math.sin(kx / 2) ** 2 + math.sin(ky / 2) ** 2))

    assert _evolve(c_lat, ppw, theta, w_lattice) < 1e-10  # round-off only


def test_continuum_frequency_is_not_a_lattice_solution():
    c_lat, ppw = 0.5, 6.0
    err = _evolve(c_lat, ppw, 0.0, lambda kx, ky: c_lat * math.hypot(kx, ky))
    # phase error after N steps ~ N * |w_c - w_lattice| ~ 0.2 rad here
    assert err > 1e-2


def test_phase_velocity_error_is_second_order():
    # numerical phase speed error falls like (cells per wavelength)^-2 on the axis and diagonal
    for theta in (0.0, math.pi / 4):
        e1 = abs(phase_velocity_error(20, 0.5, theta))
        e2 = abs(phase_velocity_error(40, 0.5, theta))
        assert e1 / e2 == pytest.approx(4.0, rel=0.02)
    # at the magic 1-D Courant number on the axis there is no error: c = 1 not reachable in 2-D, but
    # the diagonal at c = 1/sqrt(2) is exact (sin^2 terms balance)
    assert abs(phase_velocity_error(20, 1 / math.sqrt(2), math.pi / 4)) < 1e-12
    k = lattice_wavenumber(0.2, 0.5, np.array([0.0, 0.3, 0.7]))
    assert np.all(k > 0.2 / 0.5)  # lattice waves are slower than the continuum
