"""An independent reference for recessed radiators: a piston at the bottom of a rigid circular
tube set in an infinite rigid baffle (a flanged opening), by mode matching (NumPy/SciPy only).

The method is the generalised radiation impedance of a flanged duct (Zorumski 1973, "Generalized
radiation impedances and reflection coefficients of circular and annular ducts", J. Acoust. Soc.
Am. 54, 1667-1673; Morse & Ingard, "Theoretical Acoustics", ch. 9). Lengths are in units of the
tube radius `a`, the time factor exp(-i omega t), rho c = 1:

- inside the tube (-d <= z <= 0) the pressure is a sum of the axisymmetric duct modes
  psi_n(r) = J0(alpha_n r) (alpha_0 = 0, alpha_n the zeros of J1: a rigid wall at r = 1),
  p = sum_n psi_n(r) [A_n exp(i k_n (z + d)) + C_n exp(-i k_n z)], k_n = sqrt(K^2 - alpha_n^2)
  (K = ka; Im k_n > 0, the evanescent modes decay away from the face they are referenced to, so no
  amplitude grows exponentially); the axial velocity's modal amplitudes are Y_n (A_n e - C_n) with
  the modal admittance Y_n = k_n / K;
- at the bottom (z = -d) the modal velocities equal the projection U_n of the piston's velocity
  (uniform, 1, for r <= beta = b / a; rigid, 0, on the annulus beta < r <= 1);
- at the opening (z = 0) the aperture pressure is the baffled radiation of the aperture velocity:
  projected on psi_n, nu_n P_n = K sum_m I_nm V_m with nu_n = int_0^1 psi_n^2 r dr = J0(alpha_n)^2 / 2
  and the modal radiation integral I_nm = int_0^inf phi_n(x) phi_m(x) x dx / sqrt(K^2 - x^2)
  (the spectral form of the Rayleigh integral: Z_mn = rho c k int Psi_m Psi_n kappa dkappa /
  sqrt(k^2 - kappa^2)), phi_n(x) = int_0^1 psi_n(r) J0(x r) r dr = J0(alpha_n) x J1(x) / (x^2 - alpha_n^2)
  the mode's Hankel transform over the aperture (J1(x) / x for the plane mode).

The integral's 1/sqrt singularity at x = K is removed by x = K sin(theta) on [0, K] and x = K cosh(t)
just beyond; the oscillating remainder is integrated by Gauss-Legendre panels to `x_max` and its
tail beyond by the integrand's mean, J0(alpha_n) J0(alpha_m) / (pi x^3) (a relative error
O(1 / x_max) of a term itself O(1 / x_max^2)). The far field is the Rayleigh integral's, the
aperture velocity's Hankel transform at x = K sin(theta): F(theta) = sum_m V_m phi_m(K sin theta).

Checked in tests/fit/test_housed_modes.py: depth 0 gives the baffled piston of radius b; the lobe
converges in the number of modes and quadrature points; the plane mode's reflection at the opening
gives the flanged end correction 0.8216 a for ka << 1 (Norris & Sheng 1989).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special

__all__ = [
    "duct_mode_numbers",
    "modal_radiation_integrals",
    "recessed_piston_aperture",
    "recessed_piston_far_field",
    "recessed_piston_lobe_db",
    "recessed_piston_near_field",
    "opening_reflection",
    "flanged_end_correction",
]


def duct_mode_numbers(n_modes: int) -> np.ndarray:
    """alpha_n, n = 0 .. n_modes - 1: 0 (the plane mode) and the first zeros of J1 (rigid wall at r = 1)."""
    if not (isinstance(n_modes, int) and n_modes >= 1):
        raise ValueError(f"n_modes = {n_modes!r} must be an int >= 1 (the plane mode and n_modes - 1 higher modes)")
    return np.concatenate([[0.0], special.jn_zeros(1, n_modes - 1)]) if n_modes > 1 else np.zeros(1)


def _mode_transforms(alpha: np.ndarray, x: np.ndarray) -> np.ndarray:
    """phi_n(x) (modes, points): the Hankel transform over the unit aperture of J0(alpha_n r)."""
    a, xx = alpha[:, None], np.asarray(x, float)[None, :]
    j1 = special.j1(xx)
    den = xx * xx - a * a
    near = np.abs(den) < 1e-9 * (1 + a * a)
    safe = np.where(near, 1.0, den)
    phi = special.j0(a) * xx * j1 / safe
    # the removable point x = alpha_n: phi_n(alpha_n) = nu_n = J0(alpha_n)^2 / 2; the plane mode's J1(x) / x -> 1/2 at 0
    return np.where(near, 0.5 * special.j0(a) ** 2, phi)


def _quadrature(ka: float, n_quad: int, x_max: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nodes x and complex weights w of int_0^x_max f(x) x dx / sqrt(K^2 - x^2) (sqrt's branch:
    -i / sqrt(x^2 - K^2) beyond K), plus the points where the tail's mean is taken."""
    g, gw = np.polynomial.legendre.leggauss(n_quad)
    # [0, K]: x = K sin(theta), x dx / sqrt(K^2 - x^2) = K sin(theta) dtheta
    th = 0.25 * math.pi * (g + 1)
    x1, w1 = ka * np.sin(th), 0.25 * math.pi * gw * ka * np.sin(th)
    # [K, x_s]: x = K cosh(t), x dx / sqrt(x^2 - K^2) = K cosh(t) dt, times -i
    x_s = ka + 2.0
    t1 = math.acosh(x_s / ka)
    t = 0.5 * t1 * (g + 1)
    x2, w2 = ka * np.cosh(t), -1j * 0.5 * t1 * gw * ka * np.cosh(t)
    # [x_s, x_max]: panels about a quarter of J1's period wide, n_quad // 2 points each
    n_pan = max(1, int(math.ceil((x_max - x_s) / 2.0)))
    gp, gpw = np.polynomial.legendre.leggauss(max(8, n_quad // 2))
    edges = np.linspace(x_s, x_max, n_pan + 1)
    h = np.diff(edges)[:, None]
    x3 = (edges[:-1, None] + 0.5 * h * (gp[None, :] + 1)).ravel()
    w3 = (0.5 * h * gpw[None, :]).ravel() * (-1j) * x3 / np.sqrt(x3 * x3 - ka * ka)
    return np.concatenate([x1, x2, x3]), np.concatenate([w1, w2, w3]), edges


def modal_radiation_integrals(ka: float, n_modes: int, *, n_quad: int = 64, x_max: float | None = None) -> np.ndarray:
    """I_nm (n_modes, n_modes), complex: the flanged aperture's modal radiation integrals (the
    generalised radiation impedance Z_nm = rho c k a^4 I_nm in units where the mode shapes are
    J0(alpha_n r / a)). `n_quad`: Gauss-Legendre points of each piece near K (half of it per
    panel beyond); `x_max`: where the panels end (default max(400, 6 alpha_max + 40 K))."""
    if not (math.isfinite(ka) and ka > 0):
        raise ValueError(f"ka = {ka} must be > 0 (the wavenumber times the tube radius)")
    alpha = duct_mode_numbers(n_modes)
    x_max = float(x_max if x_max is not None else max(400.0, 6 * alpha[-1] + 40 * ka))
    if x_max <= ka + 2:
        raise ValueError(f"x_max = {x_max} must exceed ka + 2 = {ka + 2}")
    x, w, _ = _quadrature(ka, n_quad, x_max)
    phi = _mode_transforms(alpha, x)
    integral = (phi * w[None, :]) @ phi.T
    # tail beyond x_max: phi_n phi_m x / sqrt(x^2 - K^2) -> J0(a_n) J0(a_m) J1(x)^2 / x^2 ~ J0 J0 / (pi x^3) on average
    j0a = special.j0(alpha)
    return integral - 1j * np.outer(j0a, j0a) / (2 * math.pi * x_max**2)


def _piston_projection(alpha: np.ndarray, beta: float) -> np.ndarray:
    """U_n: modal velocities of a unit piston of radius beta (<= 1) at the tube's bottom."""
    nu = 0.5 * special.j0(alpha) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        proj = np.where(alpha > 0, beta * special.j1(alpha * beta) / np.where(alpha > 0, alpha, 1.0), 0.5 * beta**2)
    return proj / nu


def _check(ka: float, depth: float, beta: float) -> None:
    if not (math.isfinite(ka) and ka > 0):
        raise ValueError(f"ka = {ka} must be > 0 (the wavenumber times the tube radius)")
    if not (math.isfinite(depth) and depth >= 0):
        raise ValueError(f"depth = {depth} must be >= 0 (the piston's depth behind the opening, in tube radii)")
    if not 0 < beta <= 1:
        raise ValueError(f"piston radius = {beta} tube radii must be in (0, 1]: the piston lies inside the tube")


def recessed_piston_aperture(
    ka: float, depth: float, beta: float = 1.0, *, n_modes: int = 40, n_quad: int = 64, x_max: float | None = None
) -> np.ndarray:
    """V_n (n_modes,): the modal amplitudes of the axial velocity in the opening of a tube of
    radius 1 (`ka`: wavenumber x tube radius), with a unit piston of radius `beta` at depth
    `depth` (both in tube radii) behind it."""
    _check(ka, depth, beta)
    alpha = duct_mode_numbers(n_modes)
    kn = np.sqrt(ka * ka - alpha * alpha + 0j)  # Im >= 0: evanescent modes decay
    y = kn / ka
    e = np.exp(1j * kn * depth)
    nu = 0.5 * special.j0(alpha) ** 2
    kiy = ka * modal_radiation_integrals(ka, n_modes, n_quad=n_quad, x_max=x_max) * y[None, :]
    n = n_modes
    m = np.zeros((2 * n, 2 * n), complex)
    # bottom: Y (A - E C) = U
    m[:n, :n] = np.diag(y)
    m[:n, n:] = np.diag(-y * e)
    # opening: nu (E A + C) = K I Y (E A - C)
    m[n:, :n] = np.diag(nu * e) - kiy * e[None, :]
    m[n:, n:] = np.diag(nu) + kiy
    rhs = np.concatenate([_piston_projection(alpha, beta), np.zeros(n)])
    sol = np.linalg.solve(m, rhs)
    a, c = sol[:n], sol[n:]
    return y * (e * a - c)


def recessed_piston_far_field(theta_rad, ka: float, depth: float, beta: float = 1.0, **kw) -> np.ndarray:
    """Complex far-field pattern F(theta) (arbitrary units, the Rayleigh integral's angular factor:
    the aperture velocity's Hankel transform at ka sin(theta)) of the recessed piston; keywords
    as `recessed_piston_aperture`."""
    v = recessed_piston_aperture(ka, depth, beta, **kw)
    alpha = duct_mode_numbers(len(v))
    x = ka * np.sin(np.asarray(theta_rad, float)).reshape(-1)
    return (v @ _mode_transforms(alpha, x)).reshape(np.shape(theta_rad))


def recessed_piston_lobe_db(
    angle_deg,
    *,
    tube_radius_m: float,
    depth_m: float,
    frequency_hz: float,
    piston_radius_m: float | None = None,
    c_m_s: float = 343.2,
    n_modes: int = 40,
    n_quad: int = 64,
) -> np.ndarray:
    """Far-field level (dB re the axis) at `angle_deg` from the axis of a piston of radius
    `piston_radius_m` (default: the tube's) at the bottom of a rigid tube of radius `tube_radius_m`
    and depth `depth_m` in an infinite rigid baffle, at `frequency_hz` in air of `c_m_s`."""
    b = tube_radius_m if piston_radius_m is None else piston_radius_m
    if not (tube_radius_m > 0 and frequency_hz > 0 and c_m_s > 0):
        raise ValueError(
            f"tube_radius_m = {tube_radius_m}, frequency_hz = {frequency_hz}, c_m_s = {c_m_s} must all be > 0"
        )
    ka = 2 * math.pi * frequency_hz / c_m_s * tube_radius_m
    ang = np.concatenate([[0.0], np.radians(np.asarray(angle_deg, float).reshape(-1))])
    f = recessed_piston_far_field(ang, ka, depth_m / tube_radius_m, b / tube_radius_m, n_modes=n_modes, n_quad=n_quad)
    return (20 * np.log10(np.abs(f[1:]) / np.abs(f[0]))).reshape(np.shape(angle_deg))


def recessed_piston_near_field(
    r, z, ka: float, depth: float, beta: float = 1.0, *, n_modes: int = 40, n_quad: int = 64, x_max: float | None = None
) -> np.ndarray:
    """Complex pressure (units of rho c times the piston's velocity) at radius `r` and height `z`
    > 0 above the opening (both in tube radii; arrays of one shape) of the recessed piston, by the
    baffled half-space's spectral integral p = K int U(x) J0(x r) exp(i sqrt(K^2 - x^2) z) x dx /
    sqrt(K^2 - x^2), U the aperture velocity's Hankel transform (the same quadrature as the
    radiation integrals; beyond x_max the integrand is below exp(-x_max z))."""
    r, z = np.broadcast_arrays(np.asarray(r, float), np.asarray(z, float))
    if not np.all(z > 0):
        raise ValueError(
            "near-field points need z > 0 (in front of the opening); use the far field on the baffle plane"
        )
    v = recessed_piston_aperture(ka, depth, beta, n_modes=n_modes, n_quad=n_quad, x_max=x_max)
    alpha = duct_mode_numbers(n_modes)
    x_max = float(x_max if x_max is not None else max(400.0, 6 * alpha[-1] + 40 * ka))
    x, w, _ = _quadrature(ka, n_quad, x_max)
    u = v @ _mode_transforms(alpha, x)  # (Q,)
    kz = np.sqrt(ka * ka - x * x + 0j)  # Im >= 0: evanescent beyond K
    rr, zz = r.reshape(-1, 1), z.reshape(-1, 1)
    p = ka * (special.j0(x[None, :] * rr) * np.exp(1j * kz[None, :] * zz)) @ (u * w)
    return p.reshape(r.shape)


def opening_reflection(ka: float, *, n_modes: int = 40, n_quad: int = 64, x_max: float | None = None) -> complex:
    """Reflection coefficient R = C_0 of the plane mode at the flanged opening (incident plane
    wave of unit pressure at z = 0, every reflected mode solved for)."""
    _check(ka, 0.0, 1.0)
    alpha = duct_mode_numbers(n_modes)
    y = np.sqrt(ka * ka - alpha * alpha + 0j) / ka
    nu = 0.5 * special.j0(alpha) ** 2
    kiy = ka * modal_radiation_integrals(ka, n_modes, n_quad=n_quad, x_max=x_max) * y[None, :]
    # nu (delta_0 + C) = K I Y (delta_0 - C)
    c = np.linalg.solve(np.diag(nu) + kiy, kiy[:, 0] - nu * (np.arange(n_modes) == 0))
    return complex(c[0])


def flanged_end_correction(ka: float, **kw) -> float:
    """End correction delta / a of the flanged opening from R = -exp(2 i k delta) (the pressure's
    node lies delta beyond the opening); keywords as `opening_reflection`."""
    r = opening_reflection(ka, **kw)
    return float(np.angle(-r) / (2 * ka))
