"""Air: the one model of the medium the transducers radiate into (speed of sound, density,
absorption), in SI units, importable without JAX (the capture host and the rig emulator use it).

- speed of sound of dry air, ideal gas: ``c = 331.3 sqrt(1 + T / 273.15)`` m/s (T in deg C);
- density of dry air, ideal gas with R = 287.05 J/(kg K): ``rho = p / (R (T + 273.15))``;
- classical + relaxation absorption is not modelled here: a scene gives `absorption_db_per_m`
  at its drive frequency (ISO 9613-1 values, e.g. ~1.3 dB/m at 40 kHz, 20 deg C, 50 % RH).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

ABSOLUTE_ZERO_C = -273.15
STANDARD_PRESSURE_PA = 101_325.0
GAS_CONSTANT_AIR_J_KG_K = 287.05
REFERENCE_TEMPERATURE_C = 20.0


def speed_of_sound_m_s(temperature_c: ArrayLike = REFERENCE_TEMPERATURE_C):
    """Speed of sound in dry air, m/s, at `temperature_c` (deg C; float or array)."""
    t = np.asarray(temperature_c, dtype=float)
    if np.any(t <= ABSOLUTE_ZERO_C):
        raise ValueError(f"temperature_c = {temperature_c!r} is at or below absolute zero")
    c = 331.3 * np.sqrt(1.0 + t / 273.15)
    return float(c) if c.ndim == 0 else c


def density_kg_m3(temperature_c: float = REFERENCE_TEMPERATURE_C, pressure_pa: float = STANDARD_PRESSURE_PA) -> float:
    """Density of dry air, kg/m^3, at `temperature_c` (deg C) and `pressure_pa` (Pa)."""
    if temperature_c <= ABSOLUTE_ZERO_C:
        raise ValueError(f"temperature_c = {temperature_c!r} is at or below absolute zero")
    if not pressure_pa > 0:
        raise ValueError(f"pressure_pa = {pressure_pa} must be > 0")
    return pressure_pa / (GAS_CONSTANT_AIR_J_KG_K * (temperature_c - ABSOLUTE_ZERO_C))


def wavelength_m(frequency_hz: float, temperature_c: float = REFERENCE_TEMPERATURE_C) -> float:
    """Wavelength in air, m, at `frequency_hz` (Hz) and `temperature_c` (deg C)."""
    return speed_of_sound_m_s(temperature_c) / frequency_hz


SPEED_OF_SOUND_20C_M_S = speed_of_sound_m_s(REFERENCE_TEMPERATURE_C)
"""343.2 m/s: dry air at 20 deg C."""
