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
    ``range_m`` from that centre. ``angle_deg = 0`` is on axis. For a circular piston or disc
    (:class:`Piston`, :class:`Disc`) ``amp_uV = |p|`` with ``p`` the Rayleigh integral (below) at the
    microphone itself, at the finite range: a real near field, not a far-field pattern (the
    Fraunhofer pattern stands in only where it is exact to ``FRAUNHOFER_RTOL``), its grazing
    limit in the baffle plane (``|angle| = 90``) and 0 behind the baffle (``|angle| > 90``). In the far field this is ``|P(angle)| / range_m`` with
    ``P = S * 2 J1(k a sin(angle)) / (k a sin(angle))`` for a piston of radius ``a``;
    ``S = sensitivity_uV`` is the on-axis amplitude at 1 m. Other ground truths (tables) give the
    far-field pressure ``P`` referred to 1 m, and ``amp_uV = |P(angle)| / range_m``.
    ``tof_s = range_m / c``: the travel time from the centre of the face.

Wavefront rig (``WAV`` lines)
    The microphone is at lateral offset ``x_m`` along a line parallel to the face, at distance
    ``z_m > 0`` from it; ``x = 0`` is on axis. The piston moves uniformly, its velocity in phase
    with the drive ``cos(omega t)``, and the pressure is the Rayleigh integral over the disc
    ``p(x, z) = S * (-i / (pi a^2)) * integral exp(i k R) / R dS`` (``R`` from the surface element
    to the microphone), normalised so that on axis in the far field ``|p| -> S / r``.

    * ``amp_uV = |p|``.
    * ``phase_deg = arg(p)`` reduced to ``[0, 360)``: the LAG of the received carrier behind the
      drive, as the rig protocol defines ``phase_mdeg`` ("Field conventions"). With
      ``exp(-i omega t)`` the received carrier is ``Re{p exp(-i omega t)} = amp * cos(omega t -
      arg p)``, so ``arg p`` is the lag: a pure delay ``t`` gives ``360 f t`` (mod 360), and the
      lag grows with distance, ``phase ~ k R - 90 deg`` in the far field (mod 360). (The
      protocol writes fields as ``|p| exp(+i(omega t - phi))``, the conjugate convention: its
      ``phi`` is the same lag.)
    * ``tof_s`` = arrival time of the wavefront: the geometric first arrival, the travel time from
      the nearest point of the face, ``sqrt(z^2 + max(|x| - a, 0)^2) / c``. It is the leading edge
      of the direct wave; it depends on neither the burst length nor the frequency.

A :class:`TableTransducer` gives ``P(angle)`` and ``p(x)`` at one ``z`` (and ``tof_s(x)``) as
tables, so that any model (for instance a difflattice simulation) can be the ground truth
without the emulator importing JAX; it is used as tabulated, whatever the temperature.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..air import STANDARD_PRESSURE_PA, absorption_db_per_m, speed_of_sound_m_s

TABLE_FORMAT = "difflattice-transducer-table/1"


def speed_of_sound(temperature_c: ArrayLike) -> NDArray[np.float64] | float:
    """Speed of sound in dry air [m/s] at ``temperature_c`` [degC]: ``331.3 sqrt(1 + T/273.15)``
    (the package's one air model, :func:`difflattice.air.speed_of_sound_m_s`)."""
    return speed_of_sound_m_s(temperature_c)


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


@functools.lru_cache(maxsize=64)
def _leggauss(n: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Gauss-Legendre nodes and weights on [-1, 1] (cached: the emulator asks per point)."""
    return np.polynomial.legendre.leggauss(n)


def _rayleigh(
    rho_m: NDArray[np.float64],
    z_m: NDArray[np.float64],
    radius_m: float,
    k: float,
    n_quad: int,
    profile=None,
    knots: NDArray[np.float64] | None = None,
) -> NDArray[np.complex128]:
    """``integral over the disc of q(r) exp(i k R) / R dS`` at points ``(rho_m, z_m)`` (lateral and
    axial distance from the face's centre), ``q = profile(r)`` (complex; 1 if None). Gauss-Legendre
    in azimuth over ``[0, pi]`` (doubled: the integrand is even) and in radius, per interval
    between ``knots`` (radii where ``q`` has a kink; default none). Nodes per dimension:
    ``max(n_quad, 1.5 k a + 32)``, so the oscillation of ``exp(i k R)`` over the face is resolved."""
    a = radius_m
    n = max(n_quad, int(1.5 * k * a) + 32)
    g, w = _leggauss(n)
    edges = np.unique(np.concatenate([[0.0, a], np.clip(knots, 0, a)])) if knots is not None else np.array([0.0, a])
    per = max(4, int(np.ceil(n / (len(edges) - 1))))
    gr, wr = _leggauss(per)
    lo, hi = edges[:-1, None], edges[1:, None]
    rho_q = (0.5 * (lo + hi) + 0.5 * (hi - lo) * gr).ravel()
    w_rho = (0.5 * (hi - lo) * wr).ravel() * rho_q
    if profile is not None:
        w_rho = w_rho * profile(rho_q)
    phi, w_phi = 0.5 * np.pi * (g + 1), 0.5 * np.pi * w
    out = np.empty(len(rho_m), complex)
    for s in range(0, len(rho_m), 32):
        x, z = rho_m[s : s + 32, None, None], z_m[s : s + 32, None, None]
        r = np.sqrt(z**2 + x**2 + rho_q[None, :, None] ** 2 - 2 * x * rho_q[None, :, None] * np.cos(phi))
        out[s : s + 32] = 2 * np.sum((np.exp(1j * k * r) / r) @ w_phi * w_rho, axis=1)
    return out


FRAUNHOFER_RTOL = 1e-6
"""The Fraunhofer pattern stands in for the Rayleigh integral at a finite range only where its
relative error bound, ``max(k a^2 / (2 range), a / range)``, is below this."""


@dataclass(frozen=True)
class Piston:
    """A rigid circular piston of diameter ``diameter_m`` [m] in an infinite baffle.

    ``sensitivity_uV`` is the on-axis far-field amplitude at 1 m [uV]. ``n_quad`` Gauss-Legendre
    nodes per dimension (at least ``1.5 k a + 32``) integrate the Rayleigh integral (relative error
    below 1e-6 for ``z_m >= 5 mm`` at 40 kHz for a 38 mm piston). ``lobe``: what the lobe rig
    measures at its range: ``"rayleigh"`` (default: the Rayleigh integral at the microphone, a real
    near field; the Fraunhofer pattern stands in only where it is exact to ``FRAUNHOFER_RTOL``) or
    ``"fraunhofer"`` (the far-field pattern spread as ``1/range``, as earlier emulated data).
    """

    diameter_m: float
    sensitivity_uV: float = 50_000.0
    n_quad: int = 96
    lobe: str = "rayleigh"

    def __post_init__(self) -> None:
        if not self.diameter_m > 0:
            raise ValueError(f"piston diameter must be > 0 m, got {self.diameter_m}")
        if self.lobe not in ("rayleigh", "fraunhofer"):
            raise ValueError(f"piston lobe = {self.lobe!r}; allowed: 'rayleigh', 'fraunhofer'")

    @property
    def radius_m(self) -> float:
        return 0.5 * self.diameter_m

    def _profile(self, freq_hz: float):
        return None  # uniform normal velocity

    @property
    def _knots(self) -> NDArray[np.float64] | None:
        return None  # radii where the velocity profile has a kink

    def far_field(self, angle_deg: NDArray[np.float64], freq_hz: float, c_m_s: float) -> NDArray[np.complex128]:
        from scipy.special import j1  # on first use: the capture host imports this module, not scipy

        theta = np.deg2rad(np.asarray(angle_deg, dtype=float))
        u = 2 * np.pi * freq_hz / c_m_s * self.radius_m * np.sin(theta)
        small = np.abs(u) < 1e-8
        d = np.where(small, 1.0, 2 * j1(np.where(small, 1.0, u)) / np.where(small, 1.0, u))
        front = np.cos(theta) > 1e-12
        return (self.sensitivity_uV * d * front).astype(complex)

    def at_range(
        self, angle_deg: NDArray[np.float64], range_m: float, freq_hz: float, c_m_s: float
    ) -> NDArray[np.complex128]:
        """Complex pressure [uV] at the lobe rig's microphone, ``range_m`` from the face's centre
        at ``angle_deg`` off axis: the Rayleigh integral, normalised as :meth:`near_field`; at
        ``|angle| = 90`` (in the baffle plane) its grazing limit, 0 behind the baffle."""
        if not range_m > 0:
            raise ValueError(f"range_m must be > 0, got {range_m}")
        theta = np.deg2rad(np.atleast_1d(np.asarray(angle_deg, dtype=float)))
        k, a = 2 * np.pi * freq_hz / c_m_s, self.radius_m
        front = np.cos(theta) > -1e-12  # the baffle plane itself (90 deg) is the grazing limit of the field
        if self.lobe == "fraunhofer" or max(k * a**2 / (2 * range_m), a / range_m) < FRAUNHOFER_RTOL:
            return self.far_field(np.rad2deg(theta), freq_hz, c_m_s) * (-1j * np.exp(1j * k * range_m) / range_m)
        rho, z = range_m * np.abs(np.sin(theta)), range_m * np.cos(theta)
        p = np.zeros(len(theta), complex)
        p[front] = self._field(rho[front], z[front], freq_hz, c_m_s)
        return p

    def _field(self, rho_m, z_m, freq_hz: float, c_m_s: float) -> NDArray[np.complex128]:
        a, k = self.radius_m, 2 * np.pi * freq_hz / c_m_s
        integral = _rayleigh(
            np.asarray(rho_m, float), np.asarray(z_m, float), a, k, self.n_quad, self._profile(freq_hz), self._knots
        )
        return self.sensitivity_uV * (-1j / (np.pi * a**2)) * integral

    def near_field(self, x_m: NDArray[np.float64], z_m: float, freq_hz: float, c_m_s: float) -> NDArray[np.complex128]:
        if not z_m > 0:
            raise ValueError(f"z_m must be > 0 (in front of the face), got {z_m}")
        x = np.abs(np.atleast_1d(np.asarray(x_m, dtype=float)))
        return self._field(x, np.full_like(x, z_m), freq_hz, c_m_s)

    def arrival_s(self, x_m: NDArray[np.float64], z_m: float, c_m_s: float) -> NDArray[np.float64]:
        lateral = np.maximum(np.abs(np.asarray(x_m, dtype=float)) - self.radius_m, 0.0)
        return np.sqrt(z_m**2 + lateral**2) / c_m_s


@dataclass(frozen=True)
class Disc(Piston):
    """A circular transducer whose normal velocity varies with radius: a :class:`Piston` (same
    normalisation: a uniform disc is the piston) with relative amplitude ``weights`` and delay
    ``lags_s`` [s] (> 0: moves later) tabulated at ``r_frac`` = r / radius (increasing, from 0
    to 1), linearly interpolated. The Rayleigh quadrature integrates each interval between knots
    separately, so the interpolated profile is integrated to the quadrature's accuracy."""

    r_frac: tuple[float, ...] = (0.0, 1.0)
    weights: tuple[float, ...] = (1.0, 1.0)
    lags_s: tuple[float, ...] = (0.0, 0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        r = np.asarray(self.r_frac, float)
        if not (len(r) >= 2 and len(self.weights) == len(r) and len(self.lags_s) == len(r)):
            raise ValueError("disc profile: r_frac, weights and lags_s need >= 2 entries each, of equal length")
        if r[0] != 0 or r[-1] != 1 or np.any(np.diff(r) <= 0):
            raise ValueError("disc profile: r_frac must increase from 0 to 1 (r / radius)")

    @property
    def _knots(self) -> NDArray[np.float64]:
        return np.asarray(self.r_frac, float) * self.radius_m

    def _profile(self, freq_hz: float):
        r, w, lag = self._knots, np.asarray(self.weights, float), np.asarray(self.lags_s, float)
        return lambda rho: np.interp(rho, r, w) * np.exp(2j * np.pi * freq_hz * np.interp(rho, r, lag))

    def far_field(self, angle_deg: NDArray[np.float64], freq_hz: float, c_m_s: float) -> NDArray[np.complex128]:
        from scipy.special import j0

        theta = np.deg2rad(np.atleast_1d(np.asarray(angle_deg, dtype=float)))
        a, k = self.radius_m, 2 * np.pi * freq_hz / c_m_s
        edges = self._knots
        g, w = _leggauss(max(8, int(np.ceil(max(self.n_quad, 1.5 * k * a + 32) / (len(edges) - 1)))))
        lo, hi = edges[:-1, None], edges[1:, None]
        r = (0.5 * (lo + hi) + 0.5 * (hi - lo) * g).ravel()
        wr = (0.5 * (hi - lo) * w).ravel() * r * self._profile(freq_hz)(r)
        d = (2 / a**2) * (j0(k * np.sin(theta)[:, None] * r[None, :]) @ wr)
        return self.sensitivity_uV * d * (np.cos(theta) > 1e-12)


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
            if axis is None or values is None:
                if (axis is None) != (values is None):
                    raise ValueError("a table needs both its axis and its values")
            elif len(axis) != len(values) or len(axis) < 2 or np.any(np.diff(axis) <= 0):
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
            angle_deg, lobe = self._lobe_table()
            doc["lobe"] = {"angle_deg": list(map(float, angle_deg)), **_re_im(lobe)}
        if self.near is not None:
            z_m, x_m, near, tof_s = self._near_table()
            doc["near"] = {"z_m": z_m, "x_m": list(map(float, x_m)), **_re_im(near), "tof_s": list(map(float, tof_s))}
        path = Path(path)
        path.write_text(json.dumps(doc, indent=1))
        return path

    def _check_freq(self, freq_hz: float) -> None:
        if self.freq_hz is not None and abs(freq_hz - self.freq_hz) > 0.5:
            raise ValueError(f"the table is for {self.freq_hz} Hz, not {freq_hz} Hz")

    def _lobe_table(self) -> tuple[NDArray[np.float64], NDArray[np.complex128]]:
        """``(angle_deg, lobe)``; raises ``ValueError`` when the table has no lobe section."""
        if self.lobe_angle_deg is None or self.lobe is None:
            raise ValueError("the table has no lobe section")
        return self.lobe_angle_deg, self.lobe

    def _near_table(
        self,
    ) -> tuple[float, NDArray[np.float64], NDArray[np.complex128], NDArray[np.float64]]:
        """``(z_m, x_m, near, tof_s)``; raises ``ValueError`` when the table has no near-field section."""
        if self.near_z_m is None or self.near_x_m is None or self.near is None or self.near_tof_s is None:
            raise ValueError("the table has no near-field section")
        return self.near_z_m, self.near_x_m, self.near, self.near_tof_s

    def far_field(self, angle_deg: NDArray[np.float64], freq_hz: float, c_m_s: float) -> NDArray[np.complex128]:
        axis, lobe = self._lobe_table()
        self._check_freq(freq_hz)
        return self.sensitivity_uV * _interp_complex(angle_deg, axis, lobe, "angle")

    def near_field(self, x_m: NDArray[np.float64], z_m: float, freq_hz: float, c_m_s: float) -> NDArray[np.complex128]:
        axis, near, _ = self._near_at(z_m)
        self._check_freq(freq_hz)
        return self.sensitivity_uV * _interp_complex(x_m, axis, near, "x")

    def arrival_s(self, x_m: NDArray[np.float64], z_m: float, c_m_s: float) -> NDArray[np.float64]:
        axis, _, tof_s = self._near_at(z_m)
        return np.interp(_inside(x_m, axis, "x"), axis, tof_s)

    def _near_at(self, z_m: float) -> tuple[NDArray[np.float64], NDArray[np.complex128], NDArray[np.float64]]:
        """The near-field table ``(x_m, near, tof_s)``, checking that it is for distance ``z_m``."""
        table_z_m, x_m, near, tof_s = self._near_table()
        if abs(z_m - table_z_m) > 1e-6:
            raise ValueError(f"the table is for z = {table_z_m} m, not {z_m} m")
        return x_m, near, tof_s


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

    ``{"kind": "piston", "diameter_m": 0.0384, "sensitivity_uV": 50000}`` (optionally
    ``"lobe": "fraunhofer"``), ``{"kind": "disc", "diameter_m": 0.0384, "r_frac": [...],
    "weights": [...], "lags_s": [...]}`` or ``{"kind": "table", "path": "truth.json",
    "sensitivity_uV": 1.0}``.
    """
    spec = dict(spec)
    kind = spec.pop("kind", None)
    if kind == "piston":
        return Piston(**spec)
    if kind == "disc":
        args: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in spec.items()}
        return Disc(**args)
    if kind == "table":
        return TableTransducer.load(spec.pop("path"), **spec)
    raise ValueError(f"transducer kind must be 'piston', 'disc' or 'table', got {kind!r}")


def lag_deg(p: ArrayLike) -> NDArray[np.float64]:
    """The carrier's lag behind the drive [deg, in [0, 360)] of complex pressures ``p`` in the
    ``exp(-i omega t)`` convention: ``arg p`` reduced to one period (rig protocol, "Field
    conventions")."""
    return np.mod(np.rad2deg(np.angle(np.asarray(p))), 360.0)


def _air(temperature_c: float, humidity_pct: float | None, pressure_pa: float, freq_hz: float) -> tuple[float, float]:
    """(speed m/s, attenuation Np/m): dry and lossless (the rig's old convention) when
    `humidity_pct` is None, else humid air with ISO 9613-1 absorption (`difflattice.air`)."""
    if humidity_pct is None:
        return float(speed_of_sound(temperature_c)), 0.0
    c = float(speed_of_sound_m_s(temperature_c, humidity_pct, pressure_pa))
    alpha = float(absorption_db_per_m(freq_hz, temperature_c, humidity_pct, pressure_pa)) * np.log(10) / 20
    return c, alpha


def lobe_truth(
    tr: Transducer,
    angle_deg: ArrayLike,
    *,
    range_m: float,
    freq_hz: float,
    temperature_c: float,
    humidity_pct: float | None = None,
    pressure_pa: float = STANDARD_PRESSURE_PA,
) -> tuple[NDArray[np.float64], float]:
    """Noise-free lobe measurement: ``(amp_uV, tof_s)`` at ``angle_deg`` (conventions above). With
    `humidity_pct` the air is humid and absorbs (``exp(-alpha range_m)``, ISO 9613-1 at `freq_hz`)."""
    c, alpha = _air(temperature_c, humidity_pct, pressure_pa, freq_hz)
    angles = np.atleast_1d(np.asarray(angle_deg, float))
    at_range = getattr(tr, "at_range", None)  # a piston or disc: the field at the microphone itself
    amp = np.abs(at_range(angles, range_m, freq_hz, c) if at_range else tr.far_field(angles, freq_hz, c) / range_m)
    return amp * np.exp(-alpha * range_m), range_m / c


def wave_truth(
    tr: Transducer,
    x_m: ArrayLike,
    *,
    z_m: float,
    freq_hz: float,
    temperature_c: float,
    humidity_pct: float | None = None,
    pressure_pa: float = STANDARD_PRESSURE_PA,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Noise-free wavefront measurement: ``(tof_s, phase_deg, amp_uV)`` at ``x_m`` (conventions
    above: ``phase_deg`` is the lag in [0, 360)). With `humidity_pct` the air is humid and absorbs
    over the distance to the microphone, ``exp(-alpha sqrt(x^2 + z^2))`` (the path lengths across
    the face differ by millimetres against 1/alpha ~ 6 m at 40 kHz)."""
    c, alpha = _air(temperature_c, humidity_pct, pressure_pa, freq_hz)
    x = np.atleast_1d(np.asarray(x_m, float))
    p = tr.near_field(x, z_m, freq_hz, c) * np.exp(-alpha * np.hypot(x, z_m))
    return tr.arrival_s(x, z_m, c), lag_deg(p), np.abs(p)
