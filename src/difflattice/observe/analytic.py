"""Independent references: formulas the simulator is checked against (NumPy only).

- the discrete dispersion relation of the five-point leapfrog,
  ``sin^2(omega/2) = c^2 (sin^2(kx/2) + sin^2(ky/2))`` (lattice units);
- exact plane-wave reflection/transmission at a flat interface for each boundary model, from the
  discrete equations themselves (not from the continuum), and the continuum eqs. 14-15;
- the far-field pattern of a line of point sources on the lattice.
"""

from __future__ import annotations

import math

import numpy as np


def lattice_wavenumber(omega: float, c: float, theta_rad=0.0, iters: int = 30, stencil: str = "standard") -> np.ndarray:
    """Wavenumber k (radians/cell) of a lattice plane wave of angular frequency `omega`
    (radians/step) and speed `c` (cells/step) travelling at angle `theta_rad`: the root of the
    leapfrog's dispersion relation ``sin^2(omega/2) / c^2 = sx + sy`` (stencil "standard") or
    ``sx + sy - (2/3) sx sy`` ("isotropic"), sx = sin^2(kx/2), sy = sin^2(ky/2)."""
    if stencil not in ("standard", "isotropic"):
        raise ValueError(f"stencil = {stencil!r}; allowed: 'standard', 'isotropic'")
    w = 2.0 / 3.0 if stencil == "isotropic" else 0.0
    theta = np.asarray(theta_rad, dtype=float)
    cx, sy = np.cos(theta), np.sin(theta)
    target = math.sin(omega / 2) ** 2 / c**2
    k = np.full_like(theta, omega / c, dtype=float)
    for _ in range(iters):
        a, b = np.sin(k * cx / 2) ** 2, np.sin(k * sy / 2) ** 2
        da, db = 0.5 * cx * np.sin(k * cx), 0.5 * sy * np.sin(k * sy)
        f = a + b - w * a * b - target
        df = da * (1 - w * b) + db * (1 - w * a)
        k = k - f / df
    return k


def phase_velocity_error(
    cells_per_wavelength: float, courant: float, theta_rad=0.0, stencil: str = "standard"
) -> np.ndarray:
    """Relative phase-velocity error (c_lattice / c - 1) of a wave at `cells_per_wavelength` in the
    medium of lattice speed `courant`, travelling at `theta_rad`."""
    omega = 2 * math.pi * courant / cells_per_wavelength
    k = lattice_wavenumber(omega, courant, theta_rad, stencil=stencil)
    return (omega / k) / courant - 1.0


def phase_error_rad(
    cells_per_wavelength: float, courant: float, distance_wavelengths: float, stencil: str = "standard"
) -> float:
    """Worst-direction phase error in radians accumulated over a distance (in wavelengths)."""
    thetas = np.linspace(0, math.pi / 4, 46)
    err = np.abs(phase_velocity_error(cells_per_wavelength, courant, thetas, stencil=stencil)).max()
    return float(2 * math.pi * distance_wavelengths * err / (1 + err))


def continuum_rt(z1: float, z2: float) -> tuple[float, float]:
    """Continuum pressure R12 and T12 (eqs. 14-15)."""
    r = (z2 - z1) / (z2 + z1)
    return r, 1 + r


def discrete_rt(omega: float, c1: float, c2: float, rho1: float, rho2: float, model: str) -> tuple[complex, complex]:
    """Exact R and T of the discrete 1-D scheme for a plane wave exp(i(k n - omega t)) hitting the
    face between cell 0 (medium 1) and cell 1 (medium 2).

    R multiplies exp(-i k1 n) (referenced to cell 0); T multiplies exp(i k2 (n - 1)) (referenced to
    cell 1). `model` is "conservative" or "paper" (eqs. 17-19)."""
    s = math.sin(omega / 2) ** 2
    k1 = 2 * math.asin(math.sqrt(s) / c1)
    k2 = (
        2 * math.asin(min(1.0, math.sqrt(s) / c2))
        if math.sqrt(s) / c2 <= 1
        else complex(math.pi, 2 * math.acosh(math.sqrt(s) / c2))
    )
    lam = -4 * s  # second time difference of exp(-i omega t)
    z1, z2 = rho1 * c1, rho2 * c2
    # unknowns x = (R, T). P_{-1} = e^{-ik1} + R e^{ik1}, P_0 = 1 + R, P_1 = T, P_2 = T e^{ik2}
    e1, e2 = np.exp(1j * k1), np.exp(1j * k2)
    if model == "conservative":
        b = 2 / (rho1 + rho2)
        K1, K2 = rho1 * c1**2, rho2 * c2**2
        # lam P0 = K1 [ (P_-1 - P0)/rho1 + b (P1 - P0) ]
        A = np.array(
            [
                [lam - K1 * ((e1 - 1) / rho1 - b), -K1 * b],
                [-K2 * b, lam - K2 * (-b + (e2 - 1) / rho2)],
            ],
            dtype=complex,
        )
        rhs = np.array([-lam + K1 * ((1 / e1 - 1) / rho1 - b), K2 * b], dtype=complex)
    elif model == "paper":
        r12 = (z2 - z1) / (z2 + z1)
        u1, u2 = c1**2, c2**2
        # lam P0 = u1 (P_-1 - P0) + (1 - r12)(u2 P1 - u1 P0)
        # lam P1 = (1 + r12)(u1 P0 - u2 P1) + u2 (P2 - P1)
        A = np.array(
            [
                [lam - u1 * (e1 - 1) + (1 - r12) * u1, -(1 - r12) * u2],
                [-(1 + r12) * u1, lam + (1 + r12) * u2 - u2 * (e2 - 1)],
            ],
            dtype=complex,
        )
        rhs = np.array([-lam + u1 * (1 / e1 - 1) - (1 - r12) * u1, (1 + r12) * u1], dtype=complex)
    else:
        raise ValueError(f"model {model!r}: 'conservative' or 'paper'")
    R, T = np.linalg.solve(A, rhs)
    return complex(R), complex(T)


def line_array_pattern(
    n_cells: int, omega: float, c: float, theta_rad, weights=None, lattice: bool = True
) -> np.ndarray:
    """Far-field array factor |sum_k w_k exp(-i k_y(theta) y_k)| of a line of cells along y
    (spacing 1 cell), normalised to its value on axis. With `lattice`, k(theta) obeys the
    lattice dispersion relation; otherwise k = omega / c."""
    theta = np.asarray(theta_rad, dtype=float)
    w = np.ones(n_cells) if weights is None else np.asarray(weights, float)
    y = np.arange(n_cells) - (n_cells - 1) / 2
    k = lattice_wavenumber(omega, c, theta) if lattice else np.full_like(theta, omega / c)
    ky = k * np.sin(theta)
    af = np.abs(np.exp(-1j * ky[..., None] * y) @ w)
    return af / np.abs(w.sum())


def mur_reflection(omega: float, c: float) -> complex:
    """Exact reflection of the first-order Mur edge P_N(t+1) = P_{N-1}(t) + m (P_{N-1}(t+1) -
    P_N(t)), m = (c - 1)/(c + 1), for a lattice plane wave at normal incidence (lattice units)."""
    k = float(lattice_wavenumber(omega, c, 0.0))
    m = (c - 1) / (c + 1)
    z = np.exp(-1j * omega)
    ek = np.exp(1j * k)
    # incident A e^{ikn}, reflected B e^{-ikn}, referenced at the edge cell n = N
    a_coef = z - 1 / ek - m * (z / ek - 1)
    b_coef = z - ek - m * (z * ek - 1)
    return complex(-a_coef / b_coef)


# ------------------------------------------------------------------------------------------
# Circular piston in a rigid baffle (exp(-i omega t); pressures per rho c u0, u0 the face's
# normal velocity amplitude)


def piston_on_axis(z_m, radius_m: float, k_per_m: float) -> np.ndarray:
    """Exact on-axis pressure of a baffled circular piston, p / (rho c u0) =
    exp(i k z) - exp(i k sqrt(z^2 + a^2)) (its modulus is 2 |sin(k (sqrt(z^2 + a^2) - z) / 2)|)."""
    z = np.asarray(z_m, float)
    return np.exp(1j * k_per_m * z) - np.exp(1j * k_per_m * np.sqrt(z * z + radius_m**2))


def piston_directivity(theta_rad, ka: float) -> np.ndarray:
    """Far-field directivity of a baffled circular piston, 2 J1(ka sin t) / (ka sin t) (1 on axis)."""
    from scipy.special import j1

    x = ka * np.sin(np.asarray(theta_rad, float))
    small = np.abs(x) < 1e-8
    xs = np.where(small, 1.0, x)
    return np.where(small, 1.0 - x * x / 8, 2 * j1(xs) / xs)


PISTON_FIRST_NULL_KA_SIN = 3.8317059702075125
"""ka sin(theta) of the first null of 2 J1(x) / x (the first zero of J1)."""
PISTON_FIRST_SIDELOBE_KA_SIN = 5.135622301840683
"""ka sin(theta) of the first side lobe of 2 J1(x) / x (the first zero of J2)."""
PISTON_FIRST_SIDELOBE_DB = -17.570149934295284
"""Level of the first side lobe of 2 J1(x) / x, dB re the axis: 20 log10(2 |J1(x)| / x) at the
first zero of J2, x = 5.1356223 (J1 = -0.33966874)."""


def rayleigh_piston(
    points_m, radius_m: float, k_per_m: float, *, n_r: int | None = None, n_phi: int | None = None, weights=None
) -> np.ndarray:
    """Pressure of a baffled circular piston at points (x, z) in metres (z > 0 in front of the
    face, x from the axis), p / (rho c u0), by the Rayleigh integral

        p = -i k / (2 pi) integral over the face of w(r') exp(i k R) / R dS'

    with Gauss-Legendre nodes in r' and trapezoidal nodes in the azimuth (spectrally accurate for
    the periodic integrand). The defaults (n_r = 2 (k a) + 64, n_phi = 2 (k (a + |x|)) + 64) are
    converged to better than 1e-9 relative for z >= a / 10 (tests/core/test_axisym_piston.py checks
    that doubling them changes nothing). `weights`: optional velocity profile w(r'), a function of
    r' in metres (default 1).
    """
    pts = np.asarray(points_m, float).reshape(-1, 2)
    if (pts[:, 1] <= 0).any():
        raise ValueError("rayleigh_piston: every point needs z > 0 (in front of the face)")
    ka = k_per_m * radius_m
    n_r = int(n_r or 2 * math.ceil(ka) + 64)
    n_phi = int(n_phi or 2 * math.ceil(k_per_m * (radius_m + np.abs(pts[:, 0]).max())) + 64)
    u, wu = np.polynomial.legendre.leggauss(n_r)
    r = 0.5 * radius_m * (u + 1)
    wr = 0.5 * radius_m * wu * r  # r dr
    if weights is not None:
        wr = wr * np.asarray(weights(r), float)
    phi = (np.arange(n_phi) + 0.5) * (2 * math.pi / n_phi)
    wphi = 2 * math.pi / n_phi
    out = np.empty(len(pts), complex)
    for i, (x, z) in enumerate(pts):
        R = np.sqrt(x * x + r[:, None] ** 2 - 2 * x * r[:, None] * np.cos(phi)[None, :] + z * z)
        out[i] = np.sum(wr[:, None] * np.exp(1j * k_per_m * R) / R) * wphi
    return -1j * k_per_m / (2 * math.pi) * out


def piston_on_axis_lattice(
    z_m, radius_m: float, omega: float, c_lattice: float, dx_m: float, stencil: str = "standard"
) -> np.ndarray:
    """The on-axis field of a baffled piston as the lattice should give it: the exact two-ray form
    (the face's plane wave minus the rim's edge wave) with each ray's wavenumber from the lattice
    dispersion relation (`lattice_wavenumber`: the plane wave along the axis, the edge wave at
    atan(a / z) from it), p / (rho c u0). The rz lattice is the 2-D lattice in the meridian plane,
    so its dispersion is the five-point leapfrog's. `omega` in radians/step, `c_lattice` in
    cells/step."""
    z = np.asarray(z_m, float)
    re = np.sqrt(z * z + radius_m**2)
    k_axis = float(lattice_wavenumber(omega, c_lattice, 0.0, stencil=stencil)) / dx_m
    k_edge = lattice_wavenumber(omega, c_lattice, np.arctan2(radius_m, z), stencil=stencil) / dx_m
    return np.exp(1j * k_axis * z) - np.exp(1j * k_edge * re)
