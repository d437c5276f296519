"""Air: the one model of the medium the transducers radiate into (speed of sound, density,
absorption), in SI units, importable without JAX (the capture host and the rig emulator use it).

Every function takes temperature in deg C, relative humidity in % and static pressure in Pa;
humidity defaults to 0 (dry air) and pressure to one standard atmosphere, so a caller that gives
the temperature only gets the dry-air values it always got.

- **Water vapour**: its molar concentration h (%) from the relative humidity by ISO 9613-1:1993
  eq. (B.1)-(B.3): ``h = h_r (p_sat / p_r) / (p_a / p_r)``, ``p_sat / p_r = 10^C``,
  ``C = -6.8346 (T01 / T)^1.261 + 4.6151``, T01 = 273.16 K, p_r = 101 325 Pa.
- **Speed of sound and density**: an ideal-gas mixture of dry air (M = 28.9645 g/mol, gamma =
  7/5) and water vapour (M = 18.015 g/mol, gamma = 4/3), mole fraction x = h / 100:
  ``c = sqrt(gamma_mix R T / M_mix)``, ``rho = p M_mix / (R T)``. Dry air gives exactly the old
  ``c = 331.3 sqrt(1 + T / 273.15)`` m/s (the ratio to it is a pure mixture factor); saturated
  air at 20 deg C is +0.37 % faster (Cramer 1993, JASA 93(5) 2510, gives +0.35 %; the ideal-gas
  mixture ignores the virial terms, which move c by < 0.1 %).
- **Absorption**: ISO 9613-1:1993 eqs. (3)-(5), the classical (viscothermal) term and the
  vibrational relaxation of O2 and N2 with their relaxation frequencies f_rO, f_rN. The standard
  states an accuracy of +-10 % for 0.05 % < h < 5 %, 253 K < T < 323 K, p < 200 kPa and
  4e-4 < f / p < 10 Hz/Pa (so up to ~1 MHz at one atmosphere).
- **The relaxation model behind it** (`relaxation`): each process i is a first-order relaxation
  of the bulk modulus, ``K(w) = K0 [1 + sum_i eps_i (-i w tau_i) / (1 - i w tau_i) - i w tau_v]``
  (time dependence e^(-i w t)), whose small-eps attenuation is ISO's term exactly when
  ``eps_i = B_i c0 / pi`` and ``tau_i = 1 / (2 pi f_ri)``, and ``tau_v = 2 c0 B_cl / (2 pi)^2``
  for the classical term ``alpha = B_cl f^2``. The same model gives the phase-speed dispersion
  (`wavenumber`). The lattice carries exactly this model in time (`lattice.coefficients`).

Functions accept floats, NumPy arrays or JAX arrays (then computed with jax.numpy, so they are
differentiable; JAX is imported only when given a JAX array).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

Value = Any
"""A float, a NumPy array or a JAX array (arithmetic broadcasts; the result has its kind)."""

ABSOLUTE_ZERO_C = -273.15
STANDARD_PRESSURE_PA = 101_325.0
GAS_CONSTANT_J_MOL_K = 8.314462618
MOLAR_MASS_DRY_AIR_KG_MOL = 0.0289645
MOLAR_MASS_WATER_KG_MOL = 0.018015
GAS_CONSTANT_AIR_J_KG_K = 287.05  # R / M of dry air (the package's value since its first release)
GAMMA_DRY_AIR = 1.4
GAMMA_WATER_VAPOUR = 4.0 / 3.0
REFERENCE_TEMPERATURE_C = 20.0
ISO_T0_K = 293.15  # ISO 9613-1 reference temperature
ISO_T01_K = 273.16  # triple-point isotherm
NEPER_TO_DB = 20.0 / math.log(10.0)  # 8.686


def _xp(*xs: Any):
    """jax.numpy if any argument is a JAX array (or tracer), else NumPy."""
    for x in xs:
        if type(x).__module__.startswith("jax"):
            import jax.numpy as jnp

            return jnp
    return np


def _is_concrete(*xs) -> bool:
    return _xp(*xs) is np


def _check(temperature_c, humidity_pct, pressure_pa) -> None:
    """Refuse unphysical air (concrete values only: traced values are the caller's to bound)."""
    if not _is_concrete(temperature_c, humidity_pct, pressure_pa):
        return
    t, h, p = (np.asarray(v, dtype=float) for v in (temperature_c, humidity_pct, pressure_pa))
    if np.any(t <= ABSOLUTE_ZERO_C):
        raise ValueError(f"temperature_c = {temperature_c!r} is at or below absolute zero")
    if np.any(h < 0) or np.any(h > 100):
        raise ValueError(f"humidity_pct = {humidity_pct!r} must be a relative humidity in 0..100 %")
    if not np.all(p > 0):
        raise ValueError(f"pressure_pa = {pressure_pa!r} must be > 0 (Pa; one atmosphere is 101325)")


def _out(v):
    """A float for a 0-d NumPy result (the old functions' contract), else the array."""
    if isinstance(v, np.ndarray | np.floating) and np.ndim(v) == 0:
        return float(v)
    return v


def saturation_pressure_ratio(temperature_c: Value):
    """p_sat / p_r, the saturation vapour pressure of water over the reference pressure
    (ISO 9613-1 eq. B.2-B.3)."""
    xp = _xp(temperature_c)
    t_k = temperature_c - ABSOLUTE_ZERO_C
    c = -6.8346 * (ISO_T01_K / t_k) ** 1.261 + 4.6151
    return 10.0**c if xp is not np else np.power(10.0, c)


def molar_concentration_water_pct(temperature_c: Value, humidity_pct: Value, pressure_pa: Value = STANDARD_PRESSURE_PA):
    """h, the molar concentration of water vapour in % (ISO 9613-1 eq. B.1)."""
    _check(temperature_c, humidity_pct, pressure_pa)
    return _out(humidity_pct * saturation_pressure_ratio(temperature_c) * (STANDARD_PRESSURE_PA / pressure_pa))


def _mixture(temperature_c, humidity_pct, pressure_pa):
    """(molar mass kg/mol, gamma) of the humid-air ideal-gas mixture."""
    x = molar_concentration_water_pct(temperature_c, humidity_pct, pressure_pa) / 100.0
    m = (1 - x) * MOLAR_MASS_DRY_AIR_KG_MOL + x * MOLAR_MASS_WATER_KG_MOL
    cp_dry = GAMMA_DRY_AIR / (GAMMA_DRY_AIR - 1)  # molar cp / R
    cp_wet = GAMMA_WATER_VAPOUR / (GAMMA_WATER_VAPOUR - 1)
    cp = (1 - x) * cp_dry + x * cp_wet
    return m, cp / (cp - 1)


def speed_of_sound_m_s(
    temperature_c: Value = REFERENCE_TEMPERATURE_C,
    humidity_pct: Value = 0.0,
    pressure_pa: Value = STANDARD_PRESSURE_PA,
):
    """Low-frequency (equilibrium) speed of sound in humid air, m/s: the ideal-gas mixture scaled
    so dry air gives ``331.3 sqrt(1 + T / 273.15)``. Pressure enters only through the water
    vapour's mole fraction."""
    _check(temperature_c, humidity_pct, pressure_pa)
    xp = _xp(temperature_c, humidity_pct, pressure_pa)
    m, gamma = _mixture(temperature_c, humidity_pct, pressure_pa)
    dry = 331.3 * xp.sqrt(1.0 + temperature_c / 273.15)
    return _out(dry * xp.sqrt((gamma / GAMMA_DRY_AIR) * (MOLAR_MASS_DRY_AIR_KG_MOL / m)))


def density_kg_m3(
    temperature_c: Value = REFERENCE_TEMPERATURE_C,
    pressure_pa: Value = STANDARD_PRESSURE_PA,
    humidity_pct: Value = 0.0,
):
    """Density of humid air, kg/m^3: dry air's ``p / (287.05 (T + 273.15))`` times the mixture's
    molar mass over dry air's (ideal-gas mixture)."""
    _check(temperature_c, humidity_pct, pressure_pa)
    m, _ = _mixture(temperature_c, humidity_pct, pressure_pa)
    dry = pressure_pa / (GAS_CONSTANT_AIR_J_KG_K * (temperature_c - ABSOLUTE_ZERO_C))
    return _out(dry * (m / MOLAR_MASS_DRY_AIR_KG_MOL))


def wavelength_m(
    frequency_hz: float,
    temperature_c: float = REFERENCE_TEMPERATURE_C,
    humidity_pct: float = 0.0,
    pressure_pa: float = STANDARD_PRESSURE_PA,
) -> float:
    """Wavelength in air, m, at `frequency_hz` (Hz)."""
    return speed_of_sound_m_s(temperature_c, humidity_pct, pressure_pa) / frequency_hz


class Relaxation(NamedTuple):
    """The parameters of ISO 9613-1's absorption as a relaxing medium (see the module docstring):
    relaxation frequencies f_r (Hz) and strengths eps (dimensionless) of O2 and N2, the classical
    term's viscous time tau_v (s) and the equilibrium speed c0 (m/s)."""

    f_r_oxygen_hz: Any
    f_r_nitrogen_hz: Any
    eps_oxygen: Any
    eps_nitrogen: Any
    tau_viscous_s: Any
    c0_m_s: Any


def relaxation_frequencies_hz(
    temperature_c: Value = REFERENCE_TEMPERATURE_C,
    humidity_pct: Value = 50.0,
    pressure_pa: Value = STANDARD_PRESSURE_PA,
):
    """(f_rO, f_rN) in Hz, ISO 9613-1 eqs. (3) and (4)."""
    xp = _xp(temperature_c, humidity_pct, pressure_pa)
    h = molar_concentration_water_pct(temperature_c, humidity_pct, pressure_pa)
    pr = pressure_pa / STANDARD_PRESSURE_PA
    tr = (temperature_c - ABSOLUTE_ZERO_C) / ISO_T0_K
    f_o = pr * (24.0 + 4.04e4 * h * (0.02 + h) / (0.391 + h))
    f_n = pr * tr**-0.5 * (9.0 + 280.0 * h * xp.exp(-4.170 * (tr ** (-1.0 / 3.0) - 1.0)))
    return _out(f_o), _out(f_n)


def _iso_factors(temperature_c, pressure_pa):
    """ISO 9613-1 eq. (5)'s f^2 factors, Np/m per Hz^2 (before the relaxation denominators):
    classical B_cl, oxygen B_O, nitrogen B_N."""
    xp = _xp(temperature_c, pressure_pa)
    t_k = temperature_c - ABSOLUTE_ZERO_C
    tr = t_k / ISO_T0_K
    b_cl = 1.84e-11 * (STANDARD_PRESSURE_PA / pressure_pa) * tr**0.5
    b_o = tr**-2.5 * 0.01275 * xp.exp(-2239.1 / t_k)
    b_n = tr**-2.5 * 0.1068 * xp.exp(-3352.0 / t_k)
    return b_cl, b_o, b_n


def absorption_db_per_m(
    frequency_hz: Value,
    temperature_c: Value = REFERENCE_TEMPERATURE_C,
    humidity_pct: Value = 50.0,
    pressure_pa: Value = STANDARD_PRESSURE_PA,
):
    """ISO 9613-1:1993 eq. (5): the pure-tone attenuation coefficient of air, dB/m (e.g. 1.32 dB/m
    at 40 kHz, 20 deg C, 50 % RH). Stated accuracy +-10 % (module docstring)."""
    _check(temperature_c, humidity_pct, pressure_pa)
    f_o, f_n = relaxation_frequencies_hz(temperature_c, humidity_pct, pressure_pa)
    b_cl, b_o, b_n = _iso_factors(temperature_c, pressure_pa)
    f2 = frequency_hz * frequency_hz
    return _out(NEPER_TO_DB * f2 * (b_cl + b_o / (f_o + f2 / f_o) + b_n / (f_n + f2 / f_n)))


def relaxation(
    temperature_c: Value = REFERENCE_TEMPERATURE_C,
    humidity_pct: Value = 50.0,
    pressure_pa: Value = STANDARD_PRESSURE_PA,
) -> Relaxation:
    """The relaxing-medium parameters whose attenuation is ISO 9613-1's (to first order in eps):
    ``alpha_i = (pi eps_i / c0) f^2 / (f_ri + f^2 / f_ri)`` = ISO's ``B_i f^2 / (f_ri + f^2 / f_ri)``
    gives ``eps_i = B_i c0 / pi``; the classical ``alpha = w^2 tau_v / (2 c0)`` = ``B_cl f^2``
    gives ``tau_v = 2 c0 B_cl / (2 pi)^2``."""
    _check(temperature_c, humidity_pct, pressure_pa)
    c0 = speed_of_sound_m_s(temperature_c, humidity_pct, pressure_pa)
    f_o, f_n = relaxation_frequencies_hz(temperature_c, humidity_pct, pressure_pa)
    b_cl, b_o, b_n = _iso_factors(temperature_c, pressure_pa)
    return Relaxation(
        f_r_oxygen_hz=f_o,
        f_r_nitrogen_hz=f_n,
        eps_oxygen=_out(b_o * c0 / math.pi),
        eps_nitrogen=_out(b_n * c0 / math.pi),
        tau_viscous_s=_out(2 * c0 * b_cl / (2 * math.pi) ** 2),
        c0_m_s=c0,
    )


def wavenumber(
    frequency_hz: Value,
    temperature_c: Value = REFERENCE_TEMPERATURE_C,
    humidity_pct: Value = 50.0,
    pressure_pa: Value = STANDARD_PRESSURE_PA,
):
    """Complex wavenumber k = w / c_phase + i alpha (1/m, alpha in Np/m) of the relaxing medium
    (NumPy only): ``k = (w / c0) / sqrt(K(w) / K0)``, exact in eps (not only first order)."""
    r = relaxation(temperature_c, humidity_pct, pressure_pa)
    w = 2 * np.pi * np.asarray(frequency_hz, dtype=float)
    ratio = 1.0 - 1j * w * r.tau_viscous_s
    for eps, f_r in ((r.eps_oxygen, r.f_r_oxygen_hz), (r.eps_nitrogen, r.f_r_nitrogen_hz)):
        x = -1j * w / (2 * np.pi * f_r)
        ratio = ratio + eps * x / (1 + x)
    return (w / r.c0_m_s) / np.sqrt(ratio)


def phase_speed_m_s(
    frequency_hz: Value,
    temperature_c: Value = REFERENCE_TEMPERATURE_C,
    humidity_pct: Value = 50.0,
    pressure_pa: Value = STANDARD_PRESSURE_PA,
):
    """Phase speed of the relaxing medium at `frequency_hz`, m/s (dispersion: above each f_r the
    speed rises towards the frozen one, by ~eps_i / 2)."""
    k = wavenumber(frequency_hz, temperature_c, humidity_pct, pressure_pa)
    return _out(2 * np.pi * np.asarray(frequency_hz, dtype=float) / k.real)


def describe(
    temperature_c: float = REFERENCE_TEMPERATURE_C,
    humidity_pct: float = 0.0,
    pressure_pa: float = STANDARD_PRESSURE_PA,
    frequency_hz: float | None = None,
) -> str:
    """One line naming the air (for a run's printout)."""
    c = speed_of_sound_m_s(temperature_c, humidity_pct, pressure_pa)
    rho = density_kg_m3(temperature_c, pressure_pa, humidity_pct)
    line = (
        f"air: {temperature_c:g} deg C, {humidity_pct:g} % RH, {pressure_pa:.0f} Pa -> c = {c:.2f} m/s, "
        f"rho = {rho:.4f} kg/m^3"
    )
    if frequency_hz is not None:
        a = absorption_db_per_m(frequency_hz, temperature_c, humidity_pct, pressure_pa)
        line += f", absorption {a:.3f} dB/m at {frequency_hz / 1e3:g} kHz (ISO 9613-1)"
    return line


SPEED_OF_SOUND_20C_M_S = speed_of_sound_m_s(REFERENCE_TEMPERATURE_C)
"""343.2 m/s: dry air at 20 deg C."""
