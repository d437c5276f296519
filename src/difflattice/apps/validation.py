"""Measurement set-ups shared by the tests, the accuracy report and the stability suite.

Each function runs small simulations and measures one quantity the analytic references in
`analytic.py` predict: plane-wave reflection/transmission at an interface, reflection of a window
edge, the discrete energy of a closed box.

Precision is the caller's: the float64 runs (the default `dtype`) need
`jax.config.update("jax_enable_x64", True)` at start-up (tests/conftest.py and the benchmark
scripts do it); without it the stepper refuses them with a `ValueError`. Nothing here changes it.
"""

from __future__ import annotations

import math
from typing import Literal

import jax.numpy as jnp
import numpy as np

from ..air import SPEED_OF_SOUND_20C_M_S
from ..lattice.coefficients import EdgeKind, Edges
from ..lattice.grid import make_grid
from ..lattice.medium import BoundaryModel, Medium
from ..observe.analytic import lattice_wavenumber
from ..solver.loop import Result, simulate
from ..solver.sensors import Sensors
from ..solver.sources import PointSources, ToneBurst
from ..solver.stepper import Stepper

Precision = Literal["float32", "float64"]
"""The grid's float type (`make_grid(dtype=...)`)."""


def _probes(result: Result) -> np.ndarray:
    """The probe records of a run whose sensors have probes, (n_steps, n_probes)."""
    if result.probes is None:
        raise ValueError("the run recorded no probes: give Sensors(probes=...)")
    return np.asarray(result.probes)


def _dft(x, omega):
    n = np.arange(1, len(x) + 1)
    return np.sum(np.asarray(x) * np.exp(1j * omega * n))


def plane_wave_rt(
    *,
    c1_m_s: float,
    c2_m_s: float,
    rho1: float,
    rho2: float,
    model: BoundaryModel,
    cells_per_wavelength_1: float = 20.0,
    frequency_hz: float = 50e3,
    cycles: float = 12.0,
    dtype: Precision = "float64",
    wall: Literal["rigid", "soft"] | None = None,
) -> tuple[complex, complex]:
    """Measure R and T of a normal-incidence plane wave at the face between medium 1 (cells
    <= i0) and medium 2 (cells > i0), at the drive frequency, in the conventions of
    `analytic.discrete_rt` (R referenced to cell i0, T to cell i0 + 1).

    A 1-cell-high strip with rigid top and bottom carries an exact plane wave; PMLs absorb both
    ends. `wall` = "rigid"/"soft" replaces medium 2 by an ideal obstacle (then T is 0).
    """
    c_max = max(c1_m_s, c2_m_s)
    ppw_grid = cells_per_wavelength_1 * c_max / c1_m_s
    wl1 = cells_per_wavelength_1
    L = 20 if cells_per_wavelength_1 <= 40 else int(cells_per_wavelength_1 / 2)
    d_src = int(4 * wl1)  # source to interface
    burst = int(math.ceil(cycles * wl1))
    n1 = L + d_src + burst + 10
    n2 = int(max(3 * wl1 * c2_m_s / c1_m_s, 60)) + L if wall is None else L + 10
    nx = n1 + n2
    grid = make_grid(
        frequency_hz=frequency_hz, cells_per_wavelength=ppw_grid, c_max_m_s=c_max, shape=(nx, 1), dtype=dtype
    )
    i0 = n1 - 1
    c1 = grid.speed_to_lattice(c1_m_s)
    x = np.arange(nx)[:, None]
    xs = i0 - d_src
    probe_r, probe_t = i0 - int(1.5 * wl1), i0 + 1 + int(min(wl1 * c2_m_s / c1_m_s, n2 - L - 5) / 2)
    edges = Edges(x_lo="pml", x_hi="pml", y_lo="rigid", y_hi="rigid", thickness_cells=L)
    src = PointSources(
        cells=jnp.asarray([(xs, 0)]), signal=ToneBurst(frequency_hz, cycles), weights=jnp.ones(1), lags_s=jnp.zeros(1)
    )
    # enough steps for the burst to reach the probes, reflect and pass
    n_steps = int((2 * d_src + 2 * burst + 3 * wl1) / c1) + 200
    sens = Sensors(probes=jnp.asarray([(probe_r, 0), (i0, 0), (probe_t, 0)]))
    ref = simulate(grid, Medium(c1_m_s, rho1), src, sens, n_steps=n_steps, edges=edges)
    if wall is None:
        c = jnp.where(jnp.asarray(x) <= i0, c1_m_s, c2_m_s) * jnp.ones((nx, 1))
        rho = jnp.where(jnp.asarray(x) <= i0, rho1, rho2) * jnp.ones((nx, 1))
        med = Medium(c.astype(grid.jnp_dtype), rho.astype(grid.jnp_dtype), boundary_model=model)
    else:
        occ = jnp.asarray((x > i0) * np.ones((nx, 1)), grid.jnp_dtype)
        med = Medium(
            c1_m_s,
            rho1,
            rigid=occ if wall == "rigid" else None,
            soft=occ if wall == "soft" else None,
            boundary_model=model,
        )
    tot = simulate(grid, med, src, sens, n_steps=n_steps, edges=edges)
    w = grid.omega
    k1 = float(lattice_wavenumber(w, c1, 0.0))
    pr, pref0 = _probes(tot), _probes(ref)
    inc_r = _dft(pref0[:, 0], w)
    refl = _dft(pr[:, 0] - pref0[:, 0], w)
    d = i0 - probe_r
    R = refl / inc_r * np.exp(-2j * k1 * d)
    T = 0j
    if wall is None:
        c2 = grid.speed_to_lattice(c2_m_s)
        k2 = float(lattice_wavenumber(w, c2, 0.0))
        T = _dft(pr[:, 2], w) / _dft(pref0[:, 1], w) * np.exp(-1j * k2 * (probe_t - i0 - 1))
    return complex(R), complex(T)


def edge_reflection_db(
    kind: EdgeKind,
    *,
    thickness_cells: int = 20,
    cells_per_wavelength: float = 20.0,
    dtype: Precision = "float64",
    cycles: float = 4.0,
    **edge_kwargs,
) -> float:
    """Reflection of a window edge at normal incidence, in dB: a plane-wave burst hits the x_hi
    edge; the reflected part is the difference from a run in a long domain."""
    ppw = cells_per_wavelength
    L = thickness_cells
    far = int(50 * ppw)
    x0 = far
    d = int(5 * ppw)
    n_steps = int((2 * d + (cycles + 2) * ppw) / 0.7) + 100
    out = []
    for nx in (x0 + d + L, x0 + 4 * far):
        grid = make_grid(
            frequency_hz=50e3, cells_per_wavelength=ppw, c_max_m_s=SPEED_OF_SOUND_20C_M_S, shape=(nx, 1), dtype=dtype
        )
        src = PointSources(
            cells=jnp.asarray([(x0, 0)]), signal=ToneBurst(50e3, cycles), weights=jnp.ones(1), lags_s=jnp.zeros(1)
        )
        e = Edges(x_lo="rigid", x_hi=kind, y_lo="rigid", y_hi="rigid", thickness_cells=L, **edge_kwargs)
        probes = Sensors(probes=jnp.asarray([(x0 + d // 2, 0)]))
        r = simulate(grid, Medium(SPEED_OF_SOUND_20C_M_S, 1.2), src, probes, n_steps=n_steps, edges=e)
        out.append(_probes(r)[:, 0])
    p, pref = out
    return float(20 * np.log10(np.abs(p - pref).max() / np.abs(pref).max()))


def discrete_energy(stepper: Stepper, p_new, p_old) -> float:
    """The conserved discrete energy of the leapfrog between two successive fields (no sources,
    no damping): sum (P1 - P0)^2 / K + sum_faces b (q1_j - q1_i)(q0_j - q0_i) with q = P (the
    conservative and homogeneous forms; rigid (zero-flux) edges)."""
    lat = stepper.lattice
    if lat.q_scale is not None:
        raise ValueError("discrete_energy applies to the homogeneous and conservative forms")
    K = lat.K
    from ..lattice.operators import face_gradient

    dp = p_new - p_old
    kin = jnp.sum(dp * dp / K)
    pot = jnp.zeros((), dp.dtype)
    for axis in (0, 1):
        g1 = face_gradient(lat, p_new, axis)
        g0p = face_gradient(lat, p_old, axis)
        b = lat.bx if axis == 0 else lat.by
        # face_gradient already multiplies by b once: b (dq1)(dq0) = g1 * dq0
        dq0 = g0p if b is None else g0p / jnp.where(b == 0, 1, b)
        pot = pot + jnp.sum(g1 * dq0)
    return float(kin + pot)
