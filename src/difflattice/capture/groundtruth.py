"""Ground-truth transducers for the rig emulator, and the conventions the emulated rig reports.

Conventions (the fitting code relies on them)
---------------------------------------------
* Speed of sound in air at ``T`` degrees Celsius: ``c = 331.3 * sqrt(1 + T / 273.15)`` m/s
  (:func:`speed_of_sound`); wavenumber ``k = 2 pi f / c`` at the drive frequency ``f``.
* Time convention ``exp(-i omega t)``: a complex pressure ``p`` is the physical signal
  ``Re{p exp(-i omega t)}``, and an outgoing wave goes as ``exp(+i k r) / r``.
* Pressures are in microvolts at the microphone output (the microphone is ideal: flat, in phase).

Lobe rig (``LOB`` lines)
    The transducer turns about an axis through the centre of its face; the microphone is at
    ``range_m`` from that centre. ``angle_deg = 0`` is on axis. ``amp_uV = |P(angle)| / range_m``
    (spherical spreading, ``range_m`` in metres), where ``P`` is the far-field pressure referred
    to 1 m. For a circular piston of radius ``a`` in an infinite baffle
    ``P = S * 2 J1(k a sin(angle)) / (k a sin(angle))`` for ``|angle| < 90`` degrees and ``P = 0``
    behind the baffle; ``S = sensitivity_uV`` is the on-axis amplitude at 1 m.
    ``tof_s = range_m / c``: the travel time from the centre of the face.

Wavefront rig (``WAV`` lines)
    The microphone is at lateral offset ``x_m`` along a line parallel to the face, at distance
    ``z_m > 0`` from it; ``x = 0`` is on axis. The piston moves uniformly, its velocity in phase
    with the drive ``cos(omega t)``, and the pressure is the Rayleigh integral over the disc
    ``p(x, z) = S * (-i / (pi a^2)) * integral exp(i k R) / R dS`` (``R`` from the surface element
    to the microphone), normalised so that on axis in the far field ``|p| -> S / r``.

    * ``amp_uV = |p|``.
    * ``phase_deg = -arg(p)``, wrapped to ``[-180, 180)``: the received carrier is
      ``amp * cos(omega t + phase)`` against the drive ``cos(omega t)``; the phase falls (the
      carrier lags more) with distance, ``phase ~ 90 deg - k R`` in the far field.
    * ``tof_s`` = arrival time of the wavefront: the geometric first arrival, the travel time from
      the nearest point of the face, ``sqrt(z^2 + max(|x| - a, 0)^2) / c``. It is the leading edge
      of the direct wave; it depends on neither the burst length nor the frequency.

A :class:`TableTransducer` gives ``P(angle)`` and ``p(x)`` at one ``z`` (and ``tof_s(x)``) as
tables, so that any model (for instance a difflattice simulation) can be the ground truth
without the emulator importing JAX; it is used as tabulated, whatever the temperature.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

TABLE_FORMAT = "difflattice-transducer-table/1"


def speed_of_sound(temperature_c: ArrayLike) -> NDArray[np.float64] | float:
    """Speed of sound in dry air [m/s] at ``temperature_c`` [degC]: ``331.3 sqrt(1 + T/273.15)``."""
    t = np.asarray(temperature_c, dtype=float)
    c = 331.3 * np.sqrt(1.0 + t / 273.15)
    return float(c) if c.ndim == 0 else c


class Transducer(Protocol):
    """What the emulator needs from a ground-truth transducer (all pressures in uV)."""

    def far_field(self, angle_deg: NDArray[np.float64], freq_hz: float, c_m_s: float) -> NDArray[np.complex128]:
        """Far-field pressure referred to 1 m [uV m] at ``angle_deg`` (0 = on axis)."""
        ...

    def near_field(self, x_m: NDArray[np.float64], z_m: float, freq_hz: float, c_m_s: float) -> NDArray[np.complex128]:
        """Complex pressure [uV] at lateral offsets ``x_m`` and distance ``z_m`` from the face."""
        ...

    def arrival_s(self, x_m: NDArray[np.float64], z_m: float, c_m_s: float) -> NDArray[np.float64]:
        """Arrival time of the wavefront [s] at ``(x_m, z_m)``."""
        ...


@dataclass(frozen=True)
class Piston:
    """A rigid circular piston of diameter ``diameter_m`` [m] in an infinite baffle.

    ``sensitivity_uV`` is the on-axis far-field amplitude at 1 m [uV]. ``n_quad`` Gauss-Legendre
    nodes per dimension integrate the Rayleigh integral (relative error below 1e-6 for
    ``z_m >= 5 mm`` at 40 kHz for a 38 mm piston).
    """

    diameter_m: float
    sensitivity_uV: float = 50_000.0
    n_quad: int = 96

    def __post_init__(self) -> None:
        if not self.diameter_m > 0:
            raise ValueError(f"piston diameter must be > 0 m, got {self.diameter_m}")

    @property
    def radius_m(self) -> float:
        return 0.5 * self.diameter_m

    def far_field(self, angle_deg: NDArray[np.float64], freq_hz: float, c_m_s: float) -> NDArray[np.complex128]:
        from scipy.special import j1  # on first use: the capture host imports this module, not scipy

        theta = np.deg2rad(np.asarray(angle_deg, dtype=float))
        u = 2 * np.pi * freq_hz / c_m_s * self.radius_m * np.sin(theta)
        small = np.abs(u) < 1e-8
        d = np.where(small, 1.0, 2 * j1(np.where(small, 1.0, u)) / np.where(small, 1.0, u))
        front = np.cos(theta) > 1e-12
        return (self.sensitivity_uV * d * front).astype(complex)

    def near_field(self, x_m: NDArray[np.float64], z_m: float, freq_hz: float, c_m_s: float) -> NDArray[np.complex128]:
        if not z_m > 0:
            raise ValueError(f"z_m must be > 0 (in front of the face), got {z_m}")
        a, k = self.radius_m, 2 * np.pi * freq_hz / c_m_s
        g, w = np.polynomial.legendre.leggauss(self.n_quad)
        rho, w_rho = 0.5 * a * (g + 1), 0.5 * a * w  # [0, a]
        phi, w_phi = 0.5 * np.pi * (g + 1), 0.5 * np.pi * w  # [0, pi], doubled by symmetry
        x = np.asarray(x_m, dtype=float)[:, None, None]
        r = np.sqrt(z_m**2 + x**2 + rho[None, :, None] ** 2 - 2 * x * rho[None, :, None] * np.cos(phi))
        weights = 2 * (w_rho * rho)[:, None] * w_phi[None, :]
        integral = np.sum(weights * np.exp(1j * k * r) / r, axis=(1, 2))
        return self.sensitivity_uV * (-1j / (np.pi * a**2)) * integral

    def arrival_s(self, x_m: NDArray[np.float64], z_m: float, c_m_s: float) -> NDArray[np.float64]:
        lateral = np.maximum(np.abs(np.asarray(x_m, dtype=float)) - self.radius_m, 0.0)
        return np.sqrt(z_m**2 + lateral**2) / c_m_s


@dataclass(frozen=True)
class TableTransducer:
    """A transducer given by tables (any model, e.g. a difflattice simulation, as ground truth).

    ``lobe_angle_deg``/``lobe``: far-field pressure referred to 1 m (complex, in units that
    ``sensitivity_uV`` turns into uV m) at increasing angles. ``near_x_m``/``near``/
    ``near_tof_s``: complex pressure (``exp(-i omega t)`` convention, units as ``lobe``) and
    arrival time [s] at increasing ``x`` on the line ``z = near_z_m``. ``freq_hz``, when given,
    is the only drive frequency the table is valid for. Values are interpolated linearly
    (amplitude, unwrapped phase, arrival time); outside the tables is an error.

    JSON file (:meth:`load`, :meth:`save`)::

        {"format": "difflattice-transducer-table/1", "freq_hz": 40000,
         "lobe": {"angle_deg": [...], "re": [...], "im": [...]},
         "near": {"z_m": 0.0165, "x_m": [...], "re": [...], "im": [...], "tof_s": [...]}}

    where each ``"re"``/``"im"`` pair may instead be ``"amp"``/``"arg_deg"`` with
    ``p = amp * exp(i arg_deg pi/180)``; either section may be left out.
    """

    lobe_angle_deg: NDArray[np.float64] | None = None
    lobe: NDArray[np.complex128] | None = None
    near_z_m: float | None = None
    near_x_m: NDArray[np.float64] | None = None
    near: NDArray[np.complex128] | None = None
    near_tof_s: NDArray[np.float64] | None = None
    freq_hz: float | None = None
    sensitivity_uV: float = 1.0

    def __post_init__(self) -> None:
        for axis, values in ((self.lobe_angle_deg, self.lobe), (self.near_x_m, self.near)):
            if (axis is None) != (values is None):
                raise ValueError("a table needs both its axis and its values")
            if axis is not None and (len(axis) != len(values) or len(axis) < 2 or np.any(np.diff(axis) <= 0)):
                raise ValueError("table axes must be increasing, with >= 2 points matching the values")
        if self.near is not None and (self.near_z_m is None or self.near_tof_s is None):
            raise ValueError("a near-field table needs near_z_m and near_tof_s")

    @classmethod
    def load(cls, path: str | Path, *, sensitivity_uV: float = 1.0) -> TableTransducer:
        """Read a table from its JSON file (format in the class docstring)."""
        doc = json.loads(Path(path).read_text())
        if doc.get("format", TABLE_FORMAT) != TABLE_FORMAT:
            raise ValueError(f"{path}: format {doc['format']!r}, expected {TABLE_FORMAT!r}")
        lobe, near = doc.get("lobe"), doc.get("near")
        return cls(
            lobe_angle_deg=None if lobe is None else np.asarray(lobe["angle_deg"], float),
            lobe=None if lobe is None else _complex_from(lobe, path, "lobe"),
            near_z_m=None if near is None else float(near["z_m"]),
            near_x_m=None if near is None else np.asarray(near["x_m"], float),
            near=None if near is None else _complex_from(near, path, "near"),
            near_tof_s=None if near is None else np.asarray(near["tof_s"], float),
            freq_hz=doc.get("freq_hz"),
            sensitivity_uV=sensitivity_uV,
        )

    def save(self, path: str | Path) -> Path:
        """Write the table as JSON (complex values as ``re``/``im``)."""
        doc: dict[str, Any] = {"format": TABLE_FORMAT}
        if self.freq_hz is not None:
            doc["freq_hz"] = self.freq_hz
        if self.lobe is not None:
            doc["lobe"] = {"angle_deg": list(map(float, self.lobe_angle_deg)), **_re_im(self.lobe)}
        if self.near is not None:
            doc["near"] = {
                "z_m": self.near_z_m,
                "x_m": list(map(float, self.near_x_m)),
                **_re_im(self.near),
                "tof_s": list(map(float, self.near_tof_s)),
            }
        path = Path(path)
        path.write_text(json.dumps(doc, indent=1))
        return path

    def _check_freq(self, freq_hz: float) -> None:
        if self.freq_hz is not None and abs(freq_hz - self.freq_hz) > 0.5:
            raise ValueError(f"the table is for {self.freq_hz} Hz, not {freq_hz} Hz")

    def far_field(self, angle_deg: NDArray[np.float64], freq_hz: float, c_m_s: float) -> NDArray[np.complex128]:
        if self.lobe is None:
            raise ValueError("the table has no lobe section")
        self._check_freq(freq_hz)
        return self.sensitivity_uV * _interp_complex(angle_deg, self.lobe_angle_deg, self.lobe, "angle")

    def near_field(self, x_m: NDArray[np.float64], z_m: float, freq_hz: float, c_m_s: float) -> NDArray[np.complex128]:
        self._check_z(z_m)
        self._check_freq(freq_hz)
        return self.sensitivity_uV * _interp_complex(x_m, self.near_x_m, self.near, "x")

    def arrival_s(self, x_m: NDArray[np.float64], z_m: float, c_m_s: float) -> NDArray[np.float64]:
        self._check_z(z_m)
        return np.interp(_inside(x_m, self.near_x_m, "x"), self.near_x_m, self.near_tof_s)

    def _check_z(self, z_m: float) -> None:
        if self.near is None:
            raise ValueError("the table has no near-field section")
        if abs(z_m - self.near_z_m) > 1e-6:
            raise ValueError(f"the table is for z = {self.near_z_m} m, not {z_m} m")


def _complex_from(section: dict[str, Any], path: str | Path, name: str) -> NDArray[np.complex128]:
    if "re" in section:
        return np.asarray(section["re"], float) + 1j * np.asarray(section["im"], float)
    if "amp" in section:
        return np.asarray(section["amp"], float) * np.exp(1j * np.deg2rad(np.asarray(section["arg_deg"], float)))
    raise ValueError(f"{path}: section {name!r} needs 're'/'im' or 'amp'/'arg_deg'")


def _re_im(values: NDArray[np.complex128]) -> dict[str, list[float]]:
    return {"re": list(map(float, values.real)), "im": list(map(float, values.imag))}


def _inside(x: ArrayLike, axis: NDArray[np.float64], name: str) -> NDArray[np.float64]:
    x = np.asarray(x, dtype=float)
    if np.any(x < axis[0] - 1e-12) or np.any(x > axis[-1] + 1e-12):
        raise ValueError(f"{name} outside the table [{axis[0]}, {axis[-1]}]")
    return x


def _interp_complex(
    x: ArrayLike, axis: NDArray[np.float64], values: NDArray[np.complex128], name: str
) -> NDArray[np.complex128]:
    x = _inside(x, axis, name)
    amp = np.interp(x, axis, np.abs(values))
    arg = np.interp(x, axis, np.unwrap(np.angle(values)))
    return amp * np.exp(1j * arg)


def make_transducer(spec: dict[str, Any]) -> Piston | TableTransducer:
    """Build a ground truth from its JSON-able spec.

    ``{"kind": "piston", "diameter_m": 0.0384, "sensitivity_uV": 50000}`` or
    ``{"kind": "table", "path": "truth.json", "sensitivity_uV": 1.0}``.
    """
    spec = dict(spec)
    kind = spec.pop("kind", None)
    if kind == "piston":
        return Piston(**spec)
    if kind == "table":
        return TableTransducer.load(spec.pop("path"), **spec)
    raise ValueError(f"transducer kind must be 'piston' or 'table', got {kind!r}")


def wrap_deg(angle_deg: ArrayLike) -> NDArray[np.float64]:
    """Wrap angles [deg] to ``[-180, 180)``."""
    return (np.asarray(angle_deg, dtype=float) + 180.0) % 360.0 - 180.0


def lobe_truth(
    tr: Transducer, angle_deg: ArrayLike, *, range_m: float, freq_hz: float, temperature_c: float
) -> tuple[NDArray[np.float64], float]:
    """Noise-free lobe measurement: ``(amp_uV, tof_s)`` at ``angle_deg`` (conventions above)."""
    c = speed_of_sound(temperature_c)
    amp = np.abs(tr.far_field(np.atleast_1d(np.asarray(angle_deg, float)), freq_hz, c)) / range_m
    return amp, range_m / c


def wave_truth(
    tr: Transducer, x_m: ArrayLike, *, z_m: float, freq_hz: float, temperature_c: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Noise-free wavefront measurement: ``(tof_s, phase_deg, amp_uV)`` at ``x_m`` (conventions above)."""
    c = speed_of_sound(temperature_c)
    x = np.atleast_1d(np.asarray(x_m, float))
    p = tr.near_field(x, z_m, freq_hz, c)
    return tr.arrival_s(x, z_m, c), wrap_deg(-np.rad2deg(np.angle(p))), np.abs(p)
