"""Measurements as the fit sees them: lobe levels in dB and wavefront phases, with uncertainties."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class LobeData:
    """A lobe pattern at `range_m`: levels in dB (re 1 uV) against angle, with 1-sigma in dB."""

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
            raise ValueError(f"lobe data needs >= 3 points with matching arrays ({self.source})")
        if not np.all(np.isfinite(self.level_db)) or not np.all(self.sigma_db > 0):
            raise ValueError(f"lobe data has non-finite levels or non-positive sigmas ({self.source})")


@dataclass(frozen=True)
class WaveData:
    """A near-field wavefront at distance `z_m`: carrier phase (rad, rig convention -arg p)
    against lateral position, with 1-sigma in rad, plus arrival times (s) and amplitudes."""

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
            raise ValueError(f"wavefront data needs >= 3 points with matching arrays ({self.source})")


AMP_FLOOR_UV = 1e-3


def lobe_from_capture(cap, *, min_sigma_db: float = 0.05) -> LobeData:
    """LobeData from a loaded lobe capture (`difflattice.capture.files.load_capture`). The sigma of
    the mean of n_avg bursts in dB is 20 log10(e) * sd / (amp sqrt(n_avg)), floored at
    `min_sigma_db`."""
    m = cap.metadata
    amp = np.maximum(np.asarray(cap.amp_uV, float), AMP_FLOOR_UV)
    n_avg = float(m.get("n_avg", 1) or 1)
    sd = np.asarray(cap.amp_sd_uV, float) / math.sqrt(n_avg)
    sigma = np.maximum(20 / math.log(10) * sd / amp, min_sigma_db)
    order = np.argsort(cap.angle_deg)
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


def wave_from_capture(cap, *, sigma_deg: float | None = None, min_sigma_deg: float = 0.5) -> WaveData:
    """WaveData from a loaded wavefront capture. Phase sigma: given, or from the amplitude's SNR
    when the metadata carries a noise level, floored at `min_sigma_deg`."""
    m = cap.metadata
    order = np.argsort(cap.x_m)
    s = np.full(len(order), math.radians(max(sigma_deg or min_sigma_deg, min_sigma_deg)))
    return WaveData(
        x_m=np.asarray(cap.x_m, float)[order],
        phase_rad=np.radians(np.asarray(cap.phase_deg, float))[order],
        sigma_rad=s,
        z_m=float(np.median(cap.z_m)),
        frequency_hz=float(m["freq_hz"]),
        cycles=float(m.get("cycles", 0) or 0),
        temperature_c=float(np.mean(cap.temp_c)) if len(cap.temp_c) else float(m.get("temperature_c", 20.0)),
        tof_s=np.asarray(cap.tof_s, float)[order],
        amp=np.asarray(cap.amp_uV, float)[order],
        source=str(cap.path),
    )
