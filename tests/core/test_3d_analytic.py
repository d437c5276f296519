"""The 3-D references (`observe/analytic3d.py`) checked against themselves by independent routes:
the dispersion relation solved both ways, exact limits (the diagonal at the Courant limit, the
continuum limit), the stationary-phase amplitude against its closed forms on the axis and
diagonal, and the image-source echo in the time domain against its phasor form."""

import math

import numpy as np
import pytest

from difflattice.observe.analytic3d import (
    image_source_echo,
    image_source_echo_phasor,
    lattice_green_amplitude,
    lattice_green_phase_wavenumber,
    lattice_omega_3d,
    lattice_wavenumber_3d,
    mirror_points,
    phase_velocity_3d,
)

C3 = 1 / math.sqrt(3)


def test_dispersion_relation_both_ways():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for c, ppw in ((C3, 6.0), (0.4, 20.0)):
        w = 2 * math.pi * c / ppw
        k = lattice_wavenumber_3d(w, c, d)
        assert np.abs(lattice_omega_3d(k[:, None] * d, c) - w).max() < 1e-13
        assert np.all(k >= w / c * (1 - 1e-14))  # lattice waves are never faster than the continuum
    # at the 3-D Courant limit the body diagonal is exact; the axis is slowest
    w = 2 * math.pi * C3 / 20
    assert phase_velocity_3d(w, C3, [1, 1, 1]) == pytest.approx(C3, rel=1e-14)
    # second order: the axis error falls 4x from 20 to 40 cells per wavelength
    e = [phase_velocity_3d(2 * math.pi * 0.4 / m, 0.4, [1, 0, 0]) / 0.4 - 1 for m in (20, 40)]
    assert e[0] / e[1] == pytest.approx(4.0, rel=0.01)
    with pytest.raises(ValueError, match="band edge"):
        lattice_wavenumber_3d(3.0, 0.2, [1, 0, 0])


def test_green_amplitude_closed_forms_and_continuum_limit():
    w = 2 * math.pi * C3 / 20
    k_d = lattice_wavenumber_3d(w, C3, [1, 1, 1])
    A = lattice_green_amplitude(w, C3, [[1, 0, 0], [0, 1, 0], [1, 1, 1], [-1, 1, -1]])
    assert A[0] == pytest.approx(1.0, abs=1e-12) and A[1] == pytest.approx(1.0, abs=1e-12)
    assert A[2] == pytest.approx(1 / math.cos(k_d / math.sqrt(3)), rel=1e-12) and A[3] == pytest.approx(A[2], rel=1e-12)
    # an off-symmetry direction tends to 1 like (k h)^2
    dev = [abs(lattice_green_amplitude(2 * math.pi * C3 / m, C3, [1, 0.4, 0.2]) - 1) for m in (20, 40)]
    assert dev[0] / dev[1] == pytest.approx(4.0, rel=0.05)
    # the support function is never below the phase wavenumber and equals it on the axes
    kp = lattice_wavenumber_3d(w, C3, [1, 0.4, 0.2])
    ks = lattice_green_phase_wavenumber(w, C3, [1, 0.4, 0.2])
    assert ks >= kp and (ks - kp) / kp < 1e-4


def test_image_source_echo_time_against_phasor():
    rng = np.random.default_rng(1)
    pts = np.c_[np.zeros(7), rng.uniform(-6, 6, (7, 2))]
    w = rng.uniform(0.5, 1, 7)
    lags = rng.uniform(0, 3, 7)
    wall_p, wall_n = np.array([40.0, 0, 0]), np.array([1.0, 0.3, 0.0])
    c, f = C3, 1 / 34.64  # cycles per step
    omega = 2 * math.pi * f
    n_cyc = 4

    def burst(t):
        u = t * f / n_cyc
        return np.where((u >= 0) & (u <= 1), (0.5 - 0.5 * np.cos(2 * math.pi * u)) * np.sin(2 * math.pi * f * t), 0.0)

    t = np.arange(0, 1200)
    e = image_source_echo(pts, w, lags, wall_p, wall_n, burst, t, c)
    E = np.sum(e * np.exp(1j * omega * t))
    S = np.sum(burst(np.arange(-200, 1200)) * np.exp(1j * omega * np.arange(-200, 1200)))
    ref = image_source_echo_phasor(pts, w, lags, wall_p, wall_n, omega, c) * S
    assert abs(E / ref - 1) < 1e-3  # sampled band-limited signal: DFT = continuous transform
    # one cell at normal incidence: a delayed, scaled copy
    d = 30.0
    e1 = image_source_echo([[0, 0, 0]], [1.0], [0.0], [d, 0, 0], [1, 0, 0], burst, t, c)
    assert np.allclose(e1, burst(t + 1 - 2 * d / c) / (4 * math.pi * c**2 * 2 * d))
    assert np.allclose(mirror_points([[1.0, 2, 3]], [0, 0, 0], [0, 0, 5]), [[1, 2, -3]])
