"""Measurements as the fit sees them: lobe levels in dB and wavefront phases, with uncertainties.

Sources: capture files (`difflattice.capture.files.load_capture`, complete or not: a gap of
missing points is fitted with what is there) and plain two-column lobe tables (angle_deg,
level_db; e.g. a digitised datasheet beam pattern, `load_lobe_table`), whose frequency, range,
temperature and sigma the caller gives. `mask_lobe` / `mask_wave` leave ranges out.

Phase convention. The rig reports `phase_mdeg`, the LAG of the received carrier behind the drive,
in [0, 360000) (rig protocol, "Field conventions"): a later arrival has a larger lag. The fit's
models use the time convention exp(-i omega t), in which a field p = |p| exp(i arg p) is the signal
|p| cos(omega t - arg p): the lag is arg p, and the models' wavefront phase is -arg p
(`fit.model.wave_model_phase`). `WaveData.phase_rad` is therefore minus the rig's lag, in radians;
`wave_from_capture` converts, and nothing assumes a range of the reported values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np


@dataclass(frozen=True)
class LobeData:
    """A lobe pattern at `range_m`: levels in dB (re 1 uV, or re any reference for a table)
    against angle (deg), with 1-sigma in dB."""

    angle_deg: np.ndarray
    level_db: np.ndarray
    sigma_db: np.ndarray
    range_m: float
    frequency_hz: float
    cycles: float
    temperature_c: float
    source: str = ""

    def __post_init__(self):
        n = len(self.angle_deg)
        if n < 3 or len(self.level_db) != n or len(self.sigma_db) != n:
            raise ValueError(f"lobe data needs >= 3 points with matching arrays, got {n} ({self.source})")
        if not np.all(np.isfinite(self.level_db)) or not np.all(self.sigma_db > 0):
            raise ValueError(f"lobe data has non-finite levels or non-positive sigmas ({self.source})")
        if not np.all(np.isfinite(self.angle_deg)):
            raise ValueError(f"lobe data has non-finite angles ({self.source})")


@dataclass(frozen=True)
class WaveData:
    """A near-field wavefront at distance `z_m`: carrier phase against lateral position (m), with
    1-sigma in rad, plus arrival times (s) and amplitudes.

    `phase_rad` is in the fit models' convention, -arg p with exp(-i omega t): minus the rig's
    lag (see the module docstring); `lag_deg` gives the rig's value back."""

    x_m: np.ndarray
    phase_rad: np.ndarray
    sigma_rad: np.ndarray
    z_m: float
    frequency_hz: float
    cycles: float
    temperature_c: float
    tof_s: np.ndarray | None = None
    amp: np.ndarray | None = None
    source: str = ""

    def __post_init__(self):
        n = len(self.x_m)
        if n < 3 or len(self.phase_rad) != n or len(self.sigma_rad) != n:
            raise ValueError(f"wavefront data needs >= 3 points with matching arrays, got {n} ({self.source})")
        if not np.all(np.isfinite(self.phase_rad)) or not np.all(self.sigma_rad > 0):
            raise ValueError(f"wavefront data has non-finite phases or non-positive sigmas ({self.source})")

    @property
    def lag_deg(self) -> np.ndarray:
        """The rig's convention: lag of the carrier behind the drive, degrees in [0, 360)."""
        return np.mod(-np.degrees(self.phase_rad), 360.0)


AMP_FLOOR_UV = 1e-3


def lobe_from_capture(cap, *, min_sigma_db: float = 0.05) -> LobeData:
    """LobeData from a loaded lobe capture (`difflattice.capture.files.load_capture`; the points
    present, whether or not the scan is complete). The sigma of the mean of n_avg bursts in dB is
    20 log10(e) * sd / (amp sqrt(n_avg)), floored at `min_sigma_db` (the protocol: some rigs
    report a fixed sd estimate, so the reported sd is a floor, not the truth)."""
    m = cap.metadata
    amp = np.maximum(np.asarray(cap.amp_uV, float), AMP_FLOOR_UV)
    n_avg = float(m.get("n_avg", 1) or 1)
    sd = np.asarray(cap.amp_sd_uV, float) / math.sqrt(n_avg)
    sigma = np.maximum(20 / math.log(10) * sd / amp, min_sigma_db)
    order = np.argsort(cap.angle_deg, kind="stable")
    return LobeData(
        angle_deg=np.asarray(cap.angle_deg, float)[order],
        level_db=20 * np.log10(amp)[order],
        sigma_db=sigma[order],
        range_m=float(m["range_m"]),
        frequency_hz=float(m["freq_hz"]),
        cycles=float(m.get("cycles", 0) or 0),
        temperature_c=float(np.mean(cap.temp_c)) if len(cap.temp_c) else float(m.get("temperature_c", 20.0)),
        source=str(cap.path),
    )


def lobe_from_table(table, *, frequency_hz: float, range_m: float, temperature_c: float, sigma_db: float) -> LobeData:
    """LobeData from a plain lobe table (`difflattice.capture.files.load_lobe_table`): the levels
    as given (any dB reference: the fit's gain absorbs it), with the stated frequency (Hz), range
    (m), air temperature (degC) and 1-sigma (dB) that the table itself does not carry."""
    order = np.argsort(table.angle_deg, kind="stable")
    return LobeData(
        angle_deg=np.asarray(table.angle_deg, float)[order],
        level_db=np.asarray(table.level_db, float)[order],
        sigma_db=np.full(len(order), float(sigma_db)),
        range_m=float(range_m),
        frequency_hz=float(frequency_hz),
        cycles=0.0,
        temperature_c=float(temperature_c),
        source=str(table.path),
    )


def wave_from_capture(cap, *, sigma_deg: float) -> WaveData:
    """WaveData from a loaded wavefront capture: the rig's lag `phase_mdeg` (any value; reduced
    modulo 360 deg) becomes the models' phase -lag in radians; `sigma_deg` is the 1-sigma of
    the measured phase (deg, > 0), used as given."""
    if not sigma_deg > 0:
        raise ValueError(f"wave sigma_deg = {sigma_deg} must be > 0 deg")
    m = cap.metadata
    order = np.argsort(cap.x_m, kind="stable")
    lag_rad = np.radians(np.mod(np.asarray(cap.phase_deg, float), 360.0))
    return WaveData(
        x_m=np.asarray(cap.x_m, float)[order],
        phase_rad=-lag_rad[order],
        sigma_rad=np.full(len(order), math.radians(sigma_deg)),
        z_m=float(np.median(cap.z_m)) if len(cap.z_m) else float(m["z_um"]) * 1e-6,
        frequency_hz=float(m["freq_hz"]),
        cycles=float(m.get("cycles", 0) or 0),
        temperature_c=float(np.mean(cap.temp_c)) if len(cap.temp_c) else float(m.get("temperature_c", 20.0)),
        tof_s=np.asarray(cap.tof_s, float)[order],
        amp=np.asarray(cap.amp_uV, float)[order],
        source=str(cap.path),
    )


def wave_from_table(table, *, frequency_hz: float, z_m: float, temperature_c: float, sigma_deg: float) -> WaveData:
    """WaveData from a plain wavefront table (`difflattice.capture.files.load_wave_table`): the
    lag (deg, or 360 f delay) becomes the models' phase -lag in radians, with the stated
    frequency (Hz), scan distance `z_m` (m), air temperature (degC) and phase 1-sigma (deg) that
    the table does not carry."""
    if not sigma_deg > 0:
        raise ValueError(f"wave sigma_deg = {sigma_deg} must be > 0 deg")
    lag_deg = table.lag_deg if table.lag_deg is not None else 360.0 * frequency_hz * np.asarray(table.delay_s)
    order = np.argsort(table.x_m, kind="stable")
    return WaveData(
        x_m=np.asarray(table.x_m, float)[order],
        phase_rad=-np.radians(np.mod(np.asarray(lag_deg, float), 360.0))[order],
        sigma_rad=np.full(len(order), math.radians(sigma_deg)),
        z_m=float(z_m),
        frequency_hz=float(frequency_hz),
        cycles=0.0,
        temperature_c=float(temperature_c),
        source=str(table.path),
    )


def _outside(values: np.ndarray, ranges) -> np.ndarray:
    keep = np.ones(len(values), bool)
    for lo, hi in ranges:
        keep &= ~((values >= lo) & (values <= hi))
    return keep


def mask_counts(values, ranges) -> int:
    """How many of `values` fall inside the closed `ranges` [(lo, hi), ...]."""
    return int(np.sum(~_outside(np.asarray(values, float), ranges)))


def mask_lobe(lobe: LobeData, ranges_deg) -> LobeData:
    """The lobe without the angles inside the closed ranges [(lo, hi), ...] (deg). Raises
    ValueError when fewer than 3 points are left."""
    keep = _outside(lobe.angle_deg, ranges_deg)
    return replace(lobe, angle_deg=lobe.angle_deg[keep], level_db=lobe.level_db[keep], sigma_db=lobe.sigma_db[keep])


def mask_wave(wave: WaveData, ranges_m) -> WaveData:
    """The wavefront without the positions inside the closed ranges [(lo, hi), ...] (m)."""
    keep = _outside(wave.x_m, ranges_m)
    return replace(
        wave,
        x_m=wave.x_m[keep],
        phase_rad=wave.phase_rad[keep],
        sigma_rad=wave.sigma_rad[keep],
        tof_s=None if wave.tof_s is None else wave.tof_s[keep],
        amp=None if wave.amp is None else wave.amp[keep],
    )


NOISE_LIMITED_SIGMA_DB = 20 / math.log(10) / 5
"""A lobe point whose sigma exceeds this (SNR of its mean below 5) is at the measurement's noise floor."""


def floor_limited_level_db(lobe: LobeData) -> float | None:
    """The level (dB) below which the lobe data say nothing about the transducer, or None when
    they are not floor-limited: the highest level of a point at the noise floor (SNR < 5), or a
    clipped bottom (>= 3 points within 0.05 dB of the lowest level, as in a digitised plot cut at
    its axis). A residual floor below it fits noise or clipping at face value."""
    levels = []
    noisy = lobe.sigma_db > NOISE_LIMITED_SIGMA_DB
    if np.any(noisy):
        levels.append(float(np.max(lobe.level_db[noisy])))
    low = float(np.min(lobe.level_db))
    if np.sum(lobe.level_db <= low + 0.05) >= 3:
        levels.append(low)
    return max(levels) if levels else None


def one_sided(values, tol: float = 1e-9) -> bool:
    """True when all `values` lie on one side of 0 (a scan of 0..90 deg only, or x >= 0 only)."""
    v = np.asarray(values, float)
    return bool(len(v)) and bool(np.all(v >= -tol) or np.all(v <= tol))
