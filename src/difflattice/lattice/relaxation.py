"""Humid air's absorption on the lattice (ISO 9613-1 relaxation, `difflattice.air`): the step's
coefficients (`AirRelaxation`), the largest stable courant with them (`absorbing_courant`) and the
refusal of a grid that passes it. Used by `coefficients.build_lattice` and the scene builder."""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .grid import Grid, GridKind, StencilKind, stability_limit
from .kinds import LatticeKind, as_kind

__all__ = ["AirRelaxation", "absorbing_courant", "air_relaxation"]


class AirRelaxation(eqx.Module):
    """Air's absorption in the time domain (lattice units; `medium.AirConditions`, the model in
    `difflattice.air`): the step's operand is

        P_eff(n) = P(n) + eta (P(n) - P(n-1)) + sum_i eps_i Q_i(n)

    with Q_i = P - M_i, M_i the pressure relaxed through process i (tau_i dM_i/dt = P - M_i), so
    ``dQ_i/dt + Q_i / tau_i = dP/dt``, advanced exactly for P linear over a step (recursive
    convolution): ``Q_i(n+1) = a_i Q_i(n) + g_i (P(n+1) - P(n))``, a_i = exp(-theta_i),
    g_i = (1 - a_i) / theta_i, theta_i = dt / tau_i. eta = tau_v / dt is the classical term.

    Discrete energy (docs/air.md): with A = -L (symmetric, positive semi-definite in the lattice's
    inner product) and v = P(n+1) - P(n), the quantity

        E = |v|^2 / 2 - (c^2 / 8)(1 + 2 eta)|v|_A^2 + (c^2 / 2)|(P(n+1) + P(n)) / 2|_A^2
            + sum_i (c^2 eps_i / (2 g_i)) [(1 + a_i) / 2 |Q_i(n)|_A^2 + g_i <v, Q_i(n)>_A]

    changes per step by ``-(c^2 eta / 4)|v(n+1/2) + v(n-1/2)|_A^2
    - sum_i (c^2 eps_i (1 - a_i) / (4 g_i)) |Q_i(n) + Q_i(n-1)|_A^2 <= 0``, and is a norm while
    ``c^2 rho(A) (1 + 2 eta + sum_i 2 eps_i g_i / (1 + a_i)) <= 4``: the lattice's limit is
    lowered by the square root of that factor (`stiffening`).
    """

    eta: Float[Array, ""]
    eps: tuple[Float[Array, ""], ...]
    a: tuple[Float[Array, ""], ...]
    g: tuple[Float[Array, ""], ...]

    @property
    def stiffening(self):
        """(1 + 2 eta + sum 2 eps g / (1 + a)): the factor by which the absorbing step raises c^2
        at the lattice's highest frequency (the stability limit divides by its square root)."""
        out = 1 + 2 * self.eta
        for e, a, g in zip(self.eps, self.a, self.g):
            out = out + 2 * e * g / (1 + a)
        return out

    def wavenumber(self, omega: float, c: float) -> complex:
        """Complex wavenumber (radians/cell, imaginary part: Np/cell) of a plane wave along an axis
        of the standard stencil at lattice frequency `omega` (radians/step) and lattice speed `c`
        (cells/step): the step's own dispersion relation. With P(n) ~ exp(-i omega n), zeta =
        exp(i omega): ``4 sin^2(omega / 2) = c^2 4 sin^2(k / 2) K(zeta)``,
        ``K = 1 + eta (1 - zeta) + sum_i eps_i g_i (1 - zeta) / (1 - a_i zeta)`` (NumPy, concrete)."""
        z = np.exp(1j * omega)
        k_eff = 1 + float(self.eta) * (1 - z)
        for e, a, g in zip(self.eps, self.a, self.g):
            k_eff = k_eff + float(e) * float(g) * (1 - z) / (1 - float(a) * z)
        return complex(2 * np.arcsin(np.sin(omega / 2) / (c * np.sqrt(k_eff))))


def air_relaxation(grid: Grid, air, dtype) -> AirRelaxation:
    """The `AirRelaxation` of `air` (`medium.AirConditions`) on `grid`'s time step (`dtype`: a JAX
    dtype, or None for NumPy floats)."""
    from ..air import relaxation

    xp = np if dtype is None else jnp
    as_arr = (lambda v: np.asarray(v, float)) if dtype is None else (lambda v: jnp.asarray(v, dtype))
    r = relaxation(as_arr(air.temperature_c), as_arr(air.humidity_pct), as_arr(air.pressure_pa))
    dt = grid.dt_s
    eps, a, g = [], [], []
    for e, f_r in ((r.eps_oxygen, r.f_r_oxygen_hz), (r.eps_nitrogen, r.f_r_nitrogen_hz)):
        theta = 2 * math.pi * f_r * dt
        eps.append(e)
        a.append(xp.exp(-theta))
        g.append(-xp.expm1(-theta) / theta)
    return AirRelaxation(eta=r.tau_viscous_s / dt, eps=tuple(eps), a=tuple(a), g=tuple(g))


def absorbing_courant(
    frequency_hz: float,
    cells_per_wavelength: float,
    c_max_m_s: float,
    air,
    kind: LatticeKind | GridKind = "2d",
    stencil: StencilKind = "standard",
    margin: float = 0.9999,
) -> float:
    """The largest grid courant (times `margin`) at which a lattice with air absorption (`air`: a
    `medium.AirConditions`) is stable: the kind's limit over sqrt(`AirRelaxation.stiffening`),
    which itself depends on the time step (a few fixed-point passes, converging at once: the
    stiffening is ~1e-3)."""
    kind = as_kind(kind)
    limit = kind.stability_limit(stencil)
    courant = limit * margin
    for _ in range(4):
        g = Grid(
            shape=(3,) * kind.ndim,
            frequency_hz=frequency_hz,
            cells_per_wavelength=cells_per_wavelength,
            c_max_m_s=c_max_m_s,
            courant=courant,
            dtype="float64",
            kind=kind,
            stencil=stencil,
        )
        factor = float(air_relaxation(g, air, None).stiffening)
        courant = margin * limit / math.sqrt(factor)
    return courant


def _check_absorbing_speed(c, relax: AirRelaxation, grid: Grid) -> None:
    """Refuse a grid whose fastest speed, raised by the absorption's stiffening, passes the limit."""
    try:
        cmax = float(np.max(np.asarray(c)))  # on the host: no eager XLA program for a number
        factor = float(relax.stiffening)
    except Exception:  # traced: the caller bounds it
        return
    limit = stability_limit(grid.kind, grid.stencil)
    if cmax * math.sqrt(factor) > limit * (1 + 1e-9):  # absorbing_courant(margin=1) sits on it
        ok = limit / math.sqrt(factor) * (grid.courant / cmax if cmax > 0 else 1.0)
        raise ValueError(
            f"air absorption stiffens the lattice by x{factor:.6f} in c^2 at its highest frequency, so the "
            f"fastest speed {cmax:.6f} cells/step passes the absorbing limit {limit / math.sqrt(factor):.6f} "
            f"(= {limit:.6f} / sqrt({factor:.6f}); docs/air.md): lower grid.courant to <= {ok:.5f} "
            "(or use absorbing_courant(...))"
        )
