"""Media: materials (speed, density, impedance) and the maps a scene is made of.

A `Medium` holds SI maps (speed in m/s, density in kg/m^3) plus occupancy maps of ideal
obstacles ("rigid": R = +1, "soft": R = -1), and the static choice of boundary model:

- ``"conservative"`` (default): ``p_tt = rho c^2 div((1/rho) grad p)`` with face-averaged
  coefficients; correct reflection and transmission for any impedance contrast.
- ``"paper"``: eq. 10 with the impedance boundary of eqs. 17-19 at every face, as published.
- ``"speed_zero"``: eq. 10 with speed zero inside every obstacle (the paper's Fig. 4a):
  a pressure-release wall with phase reversal.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Literal

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .. import air as air_model
from ..air import density_kg_m3 as air_density_kg_m3
from ..air import speed_of_sound_m_s as air_speed_m_s

BoundaryModel = Literal["conservative", "paper", "speed_zero"]
BOUNDARY_MODELS = ("conservative", "paper", "speed_zero")


@dataclass(frozen=True)
class Material:
    """A material. `kind` is "fluid" (speed and density used), "rigid" (R = +1) or "soft" (R = -1).

    For the elastic solids the speed is the longitudinal bulk speed: the lattice model carries
    pressure only (no shear), as in the paper.
    """

    name: str
    speed_m_s: float
    density_kg_m3: float
    kind: Literal["fluid", "rigid", "soft"] = "fluid"

    @property
    def impedance(self) -> float:
        """Characteristic impedance Z = rho c, in Pa s/m (rayl)."""
        if self.kind == "rigid":
            return math.inf
        if self.kind == "soft":
            return 0.0
        return self.density_kg_m3 * self.speed_m_s


def air(temperature_c: float = 20.0, pressure_pa: float = 101_325.0, humidity_pct: float = 0.0) -> Material:
    """Air at a temperature in deg C, a pressure in Pa and a relative humidity in % (default dry)."""
    return Material(
        "air",
        air_speed_m_s(temperature_c, humidity_pct, pressure_pa),
        air_density_kg_m3(temperature_c, pressure_pa, humidity_pct),
    )


class AirConditions(eqx.Module):
    """The state of the air a scene is in: temperature (deg C), relative humidity (%) and static
    pressure (Pa). Given to a `Medium` as `air`, it switches on the air's absorption in the time
    domain (ISO 9613-1's O2 and N2 relaxations and the classical term, `difflattice.air`); the
    three values are array leaves, so a run is differentiable with respect to them (fit them or
    hold them with a filter spec). `speed_of_sound_m_s` / `density_kg_m3` give the same air's
    equilibrium speed and density (use them for the medium so speed and absorption agree)."""

    temperature_c: Float[Array, ""] | float = 20.0
    humidity_pct: Float[Array, ""] | float = 50.0
    pressure_pa: Float[Array, ""] | float = air_model.STANDARD_PRESSURE_PA

    def __check_init__(self):
        air_model._check(self.temperature_c, self.humidity_pct, self.pressure_pa)

    def speed_of_sound_m_s(self):
        """Equilibrium speed of sound, m/s (differentiable if the conditions are JAX arrays)."""
        return air_model.speed_of_sound_m_s(self.temperature_c, self.humidity_pct, self.pressure_pa)

    def density_kg_m3(self):
        """Density, kg/m^3."""
        return air_model.density_kg_m3(self.temperature_c, self.pressure_pa, self.humidity_pct)

    def absorption_db_per_m(self, frequency_hz):
        """ISO 9613-1 attenuation at `frequency_hz`, dB/m."""
        return air_model.absorption_db_per_m(frequency_hz, self.temperature_c, self.humidity_pct, self.pressure_pa)

    def medium(self, **kwargs) -> Medium:
        """A homogeneous absorbing `Medium` of this air (speed, density and absorption agree)."""
        return Medium(sound_speed_m_s=self.speed_of_sound_m_s(), density_kg_m3=self.density_kg_m3(), air=self, **kwargs)


MATERIALS: dict[str, Material] = {
    "air": air(20.0),
    "water": Material("water", 1482.0, 998.0),
    "pine": Material("pine", 3500.0, 500.0),  # Z = 1.75e6: air -> pine R = 0.9995 (paper)
    "aluminium": Material("aluminium", 6320.0, 2700.0),
    "steel": Material("steel", 5900.0, 7850.0),
    "rigid": Material("rigid", 0.0, math.inf, "rigid"),
    "soft": Material("soft", 0.0, 0.0, "soft"),
}


def material(name_or_material: str | Material) -> Material:
    """Look a material up by name (see `MATERIALS`)."""
    if isinstance(name_or_material, Material):
        return name_or_material
    try:
        return MATERIALS[name_or_material]
    except KeyError:
        raise ValueError(f"unknown material {name_or_material!r}; known: {', '.join(sorted(MATERIALS))}") from None


MIN_CELLS_PER_WAVELENGTH = 8.0
"""Below this many cells per wavelength a medium's waves are not resolved (phase-speed error
above ~2 % and growing fast; at 2 cells per wavelength a wave cannot propagate at all)."""


class ResolutionWarning(UserWarning):
    """A medium of a scene is resolved with too few cells per wavelength."""


def cells_per_wavelength_in(speed_m_s: float, frequency_hz: float, dx_m: float) -> float:
    """Cells per wavelength of a wave of `frequency_hz` in a medium of speed `speed_m_s` on cells of
    `dx_m`."""
    return speed_m_s / (frequency_hz * dx_m)


def warn_if_under_resolved(
    name: str,
    speed_m_s: float,
    frequency_hz: float,
    dx_m: float,
    *,
    fastest: str | None = None,
    minimum: float = MIN_CELLS_PER_WAVELENGTH,
    stacklevel: int = 3,
) -> float:
    """Warn (`ResolutionWarning`) if medium `name` gets fewer than `minimum` cells per wavelength;
    returns its cells per wavelength. `fastest` names the material the grid was scaled to."""
    cpw = cells_per_wavelength_in(speed_m_s, frequency_hz, dx_m)
    if cpw < minimum:
        why = f" because the cell is sized for the fastest fluid, {fastest}" if fastest and fastest != name else ""
        need = minimum / cpw
        warnings.warn(
            f"difflattice: medium {name!r} ({speed_m_s:.0f} m/s) gets only {cpw:.2f} cells per "
            f"wavelength at {frequency_hz:.4g} Hz (cell {dx_m * 1e3:.4g} mm){why}; below "
            f"{minimum:g} its waves are not resolved (at ~2 they cannot propagate and the medium "
            f"reflects almost totally, silently). Fix: raise grid.cells_per_wavelength by x{need:.1f} "
            f"or more"
            + (f', or model the {fastest} object as material = "rigid" (nothing simulated inside).' if why else "."),
            ResolutionWarning,
            stacklevel=stacklevel,
        )
    return cpw


def reflection_coefficient(z1: float, z2: float) -> float:
    """Pressure reflection coefficient from medium 1 into medium 2 (eq. 14)."""
    if math.isinf(z2):
        return 1.0
    return (z2 - z1) / (z2 + z1)


def transmission_coefficient(z1: float, z2: float) -> float:
    """Pressure transmission coefficient from medium 1 into medium 2 (eq. 15): T = 1 + R."""
    return 1.0 + reflection_coefficient(z1, z2)


class Medium(eqx.Module):
    """The acoustic medium of a scene in SI units.

    **Arguments:**
    - `sound_speed_m_s`: scalar or (nx, ny) map of fluid speeds, m/s.
    - `density_kg_m3`: scalar or (nx, ny) map of densities, kg/m^3.
    - `rigid`: optional (nx, ny) occupancy in [0, 1] of rigid obstacles (R = +1).
    - `soft`: optional (nx, ny) occupancy in [0, 1] of pressure-release obstacles (R = -1).
    - `boundary_model`: "conservative" (default), "paper" or "speed_zero" (static).
    - `absorption_db_per_m`: attenuation at the grid's drive frequency in dB/m, growing like f^2
      (viscous law); 0 (default) compiles no absorption term.
    - `air`: `AirConditions` for air's own absorption in the time domain (O2 and N2 relaxation
      memory fields plus the classical term, every frequency at once; None (default): lossless,
      no fields, no work). Exclusive with `absorption_db_per_m`. It applies in every fluid cell.
    """

    sound_speed_m_s: Float[Array, "nx ny"] | float
    density_kg_m3: Float[Array, "nx ny"] | float = 1.2
    rigid: Float[Array, "nx ny"] | None = None
    soft: Float[Array, "nx ny"] | None = None
    boundary_model: BoundaryModel = eqx.field(static=True, default="conservative")
    absorption_db_per_m: float = eqx.field(static=True, default=0.0)
    air: AirConditions | None = None

    def __check_init__(self):
        if self.air is not None and self.absorption_db_per_m > 0:
            raise ValueError(
                "give either absorption_db_per_m (one f^2 law at the drive frequency) or air = "
                "AirConditions(...) (air's relaxation absorption at every frequency), not both"
            )
        if self.boundary_model not in BOUNDARY_MODELS:
            raise ValueError(f"boundary_model = {self.boundary_model!r}; allowed: {', '.join(BOUNDARY_MODELS)}")
        if not (self.absorption_db_per_m >= 0):
            raise ValueError(f"absorption_db_per_m = {self.absorption_db_per_m} must be >= 0")

    @property
    def is_homogeneous(self) -> bool:
        return (
            jnp.ndim(self.sound_speed_m_s) == 0
            and jnp.ndim(self.density_kg_m3) == 0
            and self.rigid is None
            and self.soft is None
        )


def homogeneous(mat: str | Material = "air", **kwargs) -> Medium:
    """A medium filled with one fluid material."""
    m = material(mat)
    if m.kind != "fluid":
        raise ValueError(f"the background must be a fluid, got {m.name!r} ({m.kind})")
    return Medium(sound_speed_m_s=m.speed_m_s, density_kg_m3=m.density_kg_m3, **kwargs)
