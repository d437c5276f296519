"""Independent 3-D references (NumPy only, lattice units: cells, steps, cells/step).

- the discrete dispersion relation of the 7-point leapfrog,
  ``sin^2(omega/2) = c^2 (sin^2(kx/2) + sin^2(ky/2) + sin^2(kz/2))``, and of the 19-point
  isotropic one (``- (2/3) sum s_i s_j`` added), solved for |k| along any direction
  (`lattice_wavenumber_3d`) or for omega (`lattice_omega_3d`), with the group velocity;
- the field of a point source on the lattice: the time-discrete recursion
  ``P(n+1) = 2 P(n) - P(n-1) + c^2 Lap P(n) + v(n+1)`` gives, for the phasors
  ``X^ = sum_n x(n) exp(+i omega n)``, ``-4 sin^2(omega/2) P^ = c^2 Lap P^ + exp(-i omega) v^``, so
  ``P^(r) = exp(-i omega) v^ G(r) / c^2`` with G the Green's function of ``-Lap_h - kappa^2``,
  ``kappa^2 = 4 sin^2(omega/2) / c^2``. Far from the source (stationary phase) G is
  ``A exp(i k0.x) / (4 pi r)`` with ``A = 2 / (|grad D(k0)| sqrt(K(k0)))`` (D(k) = sum 4 sin^2(k_i/2),
  K the Gaussian curvature of the surface D = kappa^2 at the point k0 whose normal points along x;
  the continuum D = |k|^2 gives A = 1): `lattice_green_amplitude`. Along an axis A = 1 exactly;
  along a diagonal A = 1 / cos(k/sqrt 3) (1.7 % above the continuum at 20 cells per wavelength);
- the pulse-echo signal of a rigid plane wall (image source, R = +1) for a transducer of point
  cells used as transmitter and receiver (`image_source_echo`, `image_source_echo_phasor`).

Time convention exp(-i omega t): a field ``p(t) = Re(P exp(-i omega t))`` has phasor ``P``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

INJECTION_ADVANCE_STEPS = 1.0
"""A value added to P at step n acts as the continuum source term at time n - 1 (a linear ramp
P(n) = v (n - n0 + 1) after a kick v at n0): the lattice's soft source leads the continuum by one
step (the factor exp(-i omega) of the phasor relation above)."""


def _unit(direction) -> np.ndarray:
    d = np.asarray(direction, dtype=float)
    if d.shape[-1] != 3:
        raise ValueError(f"direction must have 3 components on its last axis, got shape {d.shape}")
    n = np.linalg.norm(d, axis=-1, keepdims=True)
    if np.any(n == 0):
        raise ValueError("direction has zero length")
    return d / n


STENCILS_3D = ("standard", "isotropic", "wide")
WIDE_A, WIDE_E = 0.08, 0.25
"""The wide stencil's pair weight a and axis weight e (`lattice.kinds.WIDE_PAIR_WEIGHT`,
`WIDE_AXIS_WEIGHT`; repeated here, the reference does not read the lattice)."""


def _weights(stencil: str) -> tuple[float, float]:
    """(w, e) of the symbol ``sum s_i + e sum s_i^2 - w sum_(i<j) s_i s_j`` (w = 4a)."""
    if stencil not in STENCILS_3D:
        raise ValueError(f"stencil = {stencil!r}; allowed: {', '.join(map(repr, STENCILS_3D))}")
    return {"standard": (0.0, 0.0), "isotropic": (2.0 / 3.0, 0.0), "wide": (4 * WIDE_A, WIDE_E)}[stencil]


def lattice_symbol_3d(k_vec, stencil: str = "standard") -> np.ndarray:
    """``F(k) = -symbol(L) / 4`` of the spatial stencil at wave vector `k_vec` (radians/cell, last
    axis 3): ``sum s_i`` (7-point) or ``sum s_i - (2/3) sum_(i<j) s_i s_j`` (19-point isotropic,
    `lattice.operators._across_faces`), s_i = sin^2(k_i / 2). The leapfrog's dispersion relation
    is ``sin^2(omega / 2) = c^2 F(k)``. The wide stencil adds ``e sum s_i^2`` (its second axis
    neighbours) to a pair weight w = 4a: ``sum s_i + (1/4) sum s_i^2 - 0.32 sum s_i s_j``."""
    w, e = _weights(stencil)
    sv = np.sin(np.asarray(k_vec, dtype=float) / 2) ** 2
    sx, sy, sz = sv[..., 0], sv[..., 1], sv[..., 2]
    return sx + sy + sz + e * (sx * sx + sy * sy + sz * sz) - w * (sx * sy + sy * sz + sz * sx)


def lattice_omega_3d(k_vec, c: float, stencil: str = "standard") -> np.ndarray:
    """Angular frequency (radians/step) of the lattice plane wave of wave vector `k_vec`
    (radians/cell, last axis 3) at speed `c` (cells/step) with the spatial `stencil`."""
    return 2 * np.arcsin(np.clip(c * np.sqrt(lattice_symbol_3d(k_vec, stencil)), 0.0, 1.0))


def _symbol_along(k, d, we):
    """F(k d) and dF/dk along the unit direction d (..., 3) for |k| = k (...); we = (w, e)."""
    w, e = we
    a = k[..., None] * d / 2
    sv = np.sin(a) ** 2
    dv = 0.5 * d * np.sin(2 * a)  # d s_i / dk
    sx, sy, sz = sv[..., 0], sv[..., 1], sv[..., 2]
    dx, dy, dz = dv[..., 0], dv[..., 1], dv[..., 2]
    f = sx + sy + sz + e * (sx * sx + sy * sy + sz * sz) - w * (sx * sy + sy * sz + sz * sx)
    df = dx + dy + dz + 2 * e * (sx * dx + sy * dy + sz * dz) - w * (dx * (sy + sz) + dy * (sx + sz) + dz * (sx + sy))
    return f, df


def lattice_wavenumber_3d(
    omega: float, c: float, direction=(1.0, 0.0, 0.0), iters: int = 60, stencil: str = "standard"
) -> np.ndarray:
    """|k| (radians/cell) of the lattice plane wave of angular frequency `omega` (radians/step) and
    speed `c` (cells/step) whose wave vector points along `direction` (..., 3), for the spatial
    `stencil`. Newton's method on the dispersion relation from the continuum k = omega / c
    (monotone below the first band edge); exact to round-off."""
    d = _unit(direction)
    w = _weights(stencil)
    target = math.sin(omega / 2) ** 2 / c**2
    k = np.full(d.shape[:-1], omega / c, dtype=float)
    for _ in range(iters):
        f, df = _symbol_along(k, d, w)
        step = (f - target) / df
        k = k - step
        if np.all(np.abs(step) <= 1e-15 * np.abs(k)):
            break
    resid = _symbol_along(k, d, w)[0] - target
    if not np.all(np.isfinite(k)) or np.max(np.abs(resid)) > 1e-12 * max(target, 1e-300):
        raise ValueError(
            f"no lattice wave of omega = {omega} rad/step at c = {c} cells/step along some direction "
            "(above the lattice's band edge): use more cells per wavelength"
        )
    return k


def phase_velocity_3d(omega: float, c: float, direction=(1.0, 0.0, 0.0), stencil: str = "standard") -> np.ndarray:
    """Phase velocity omega / |k| (cells/step) of the lattice wave along `direction`."""
    return omega / lattice_wavenumber_3d(omega, c, direction, stencil=stencil)


def group_velocity_3d(omega: float, c: float, direction=(1.0, 0.0, 0.0), stencil: str = "standard") -> np.ndarray:
    """Group velocity d omega / d|k| (cells/step) of the lattice wave whose wave vector points
    along `direction`: the speed of a tone burst's envelope, from differentiating
    ``sin^2(omega/2) = c^2 F``: ``d omega / dk = c^2 F'(k) / (sin(omega/2) cos(omega/2))``."""
    d = _unit(direction)
    k = lattice_wavenumber_3d(omega, c, d, stencil=stencil)
    _, df = _symbol_along(k, d, _weights(stencil))
    return c**2 * df / (math.sin(omega / 2) * math.cos(omega / 2))


def _surface_point(omega: float, c: float, x_dir: np.ndarray, iters: int = 200) -> np.ndarray:
    """The point k0 of the dispersion surface whose outward normal grad D points along `x_dir`
    (the stationary-phase point for an observer in that direction). Fixed-point iteration on the
    direction of k0 (the surface is nearly a sphere: contraction factor ~ its anisotropy)."""
    u = x_dir.copy()
    for _ in range(iters):
        k = lattice_wavenumber_3d(omega, c, u)[..., None] * u
        g = np.sin(k)  # grad D / 2
        n = g / np.linalg.norm(g, axis=-1, keepdims=True)
        du = x_dir - n
        u = _unit(u + du)
        if np.max(np.abs(du)) < 1e-14:
            break
    return lattice_wavenumber_3d(omega, c, u)[..., None] * u


def lattice_green_amplitude(omega: float, c: float, direction) -> np.ndarray:
    """Far-field amplitude A of the lattice Green's function relative to the continuum's
    1 / (4 pi r), in `direction` (..., 3): ``A = 2 / (|grad D| sqrt(K))`` at the surface point k0
    whose normal points along `direction` (see the module docstring)."""
    x = _unit(direction)
    k0 = _surface_point(omega, c, x)
    g = 2 * np.sin(k0)  # grad D
    h = 2 * np.cos(k0)  # diagonal Hessian of D
    gn2 = np.sum(g * g, axis=-1)
    # Gaussian curvature of an implicit surface with diagonal Hessian H:
    # K = (g_x^2 h_y h_z + g_y^2 h_x h_z + g_z^2 h_x h_y) / |g|^4
    num = (
        g[..., 0] ** 2 * h[..., 1] * h[..., 2]
        + g[..., 1] ** 2 * h[..., 0] * h[..., 2]
        + g[..., 2] ** 2 * h[..., 0] * h[..., 1]
    )
    K = num / gn2**2
    return 2.0 / (np.sqrt(gn2) * np.sqrt(K))


def lattice_green_phase_wavenumber(omega: float, c: float, direction) -> np.ndarray:
    """k0 . x_hat (radians/cell): the far-field phase growth rate of the lattice Green's function
    along `direction` (the support function of the dispersion surface; equals the phase
    wavenumber along axes and diagonals, and differs from it at second order elsewhere)."""
    x = _unit(direction)
    return np.sum(_surface_point(omega, c, x) * x, axis=-1)


def point_source_phasor(r_vec, omega: float, c: float, v_hat: complex = 1.0, *, lattice: bool = True) -> np.ndarray:
    """Far-field phasor ``P^`` (convention sum_n p(n) exp(+i omega n)) at offsets `r_vec` (..., 3)
    cells from a lattice point source whose added values have phasor `v_hat`:
    ``exp(-i omega) v_hat A exp(i k r) / (4 pi c^2 r)``. With `lattice`, k and A follow the lattice
    (valid for k r >> 1); otherwise the continuum (k = omega / c, A = 1)."""
    r_vec = np.asarray(r_vec, dtype=float)
    r = np.linalg.norm(r_vec, axis=-1)
    if lattice:
        k = lattice_green_phase_wavenumber(omega, c, r_vec)
        A = lattice_green_amplitude(omega, c, r_vec)
    else:
        k, A = np.full_like(r, omega / c), np.ones_like(r)
    return np.exp(-1j * omega) * v_hat * A * np.exp(1j * k * r) / (4 * math.pi * c**2 * r)


# ------------------------------------------------------------------------------------------
# pulse-echo of a plane wall by the image source


def mirror_points(points, wall_point, wall_normal) -> np.ndarray:
    """Mirror images of `points` (..., 3) in the plane through `wall_point` with normal
    `wall_normal` (any length, either sign)."""
    p = np.asarray(points, dtype=float)
    n = _unit(wall_normal)
    d = np.sum((p - np.asarray(wall_point, float)) * n, axis=-1, keepdims=True)
    return p - 2 * d * n


def _pair_distances(points, wall_point, wall_normal):
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    img = mirror_points(p, wall_point, wall_normal)
    return np.linalg.norm(p[:, None, :] - img[None, :, :], axis=-1)  # (receiver i, source j)


def image_source_echo(
    points,
    weights,
    lags_steps,
    wall_point,
    wall_normal,
    signal: Callable[[np.ndarray], np.ndarray],
    t_steps,
    c: float,
    *,
    reflection: float = 1.0,
    advance_steps: float = INJECTION_ADVANCE_STEPS,
) -> np.ndarray:
    """The wall echo received by a transducer of point cells (continuum, lattice units).

    Cell j at `points[j]` (cells) adds ``w_j s(t - lag_j)`` to the pressure (a lattice soft source,
    `signal` s(t) of time in steps); a plane wall (point, normal) reflects with `reflection`
    (rigid: +1), so the echo is the field of the mirrored cells,
    ``p_i(t) = R sum_j w_j s(t + advance - lag_j - R_ij / c) / (4 pi c^2 R_ij)``, and the
    transducer receives (reciprocity) ``e(t) = sum_i w_i p_i(t - lag_i)``. The direct field is not
    included. Returns e at `t_steps`."""
    w = np.asarray(weights, dtype=float).ravel()
    lag = np.broadcast_to(np.asarray(lags_steps, dtype=float).ravel(), w.shape)
    R = _pair_distances(points, wall_point, wall_normal)
    t = np.asarray(t_steps, dtype=float)
    out = np.zeros_like(t)
    for i in range(len(w)):
        delay = lag[i] + lag + R[i] / c - advance_steps  # (j,)
        amp = w[i] * w / (4 * math.pi * c**2 * R[i])
        out += np.sum(amp[:, None] * signal(t[None, :] - delay[:, None]), axis=0)
    return reflection * out


def image_source_echo_phasor(
    points,
    weights,
    lags_steps,
    wall_point,
    wall_normal,
    omega: float,
    c: float,
    *,
    reflection: float = 1.0,
    lattice: bool = False,
) -> complex:
    """The echo's transfer function at `omega` (radians/step): phasor of `image_source_echo` per
    unit phasor of the drive signal, ``R e^{-i omega} sum_ij w_i w_j e^{i omega (lag_i + lag_j)}
    e^{i k R_ij} A / (4 pi c^2 R_ij)`` (continuum k = omega / c, A = 1, or the lattice's)."""
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    w = np.asarray(weights, dtype=float).ravel()
    lag = np.broadcast_to(np.asarray(lags_steps, dtype=float).ravel(), w.shape)
    img = mirror_points(p, wall_point, wall_normal)
    d = p[:, None, :] - img[None, :, :]
    R = np.linalg.norm(d, axis=-1)
    if lattice:
        k = lattice_green_phase_wavenumber(omega, c, d)
        A = lattice_green_amplitude(omega, c, d)
    else:
        k, A = np.full_like(R, omega / c), np.ones_like(R)
    g = A * np.exp(1j * k * R) / (4 * math.pi * c**2 * R)
    ph = np.exp(1j * omega * (lag[:, None] + lag[None, :]))
    return complex(reflection * np.exp(-1j * omega) * np.sum(w[:, None] * w[None, :] * ph * g))
