"""Shared emulated data for the fit tests: a Polaroid-like line (tapered weights, edge lags) whose
lobe and wavefront are computed from transfer matrices (optionally on a finer lattice than the
fit's, so the fit sees a realistic discretisation error), plus Gaussian noise of known sigma."""

import math
from functools import lru_cache

import jax.numpy as jnp
import numpy as np

from difflattice.fit.data import LobeData, WaveData
from difflattice.fit.model import LineParams, ModelSpec, lobe_model_db, wave_model_phase
from difflattice.fit.transfer import free_field_transfer

F, C = 50e3, 343.2
LINE_M = 0.040
ANG = np.arange(-90, 90.1, 1.0)
XS = np.linspace(-0.024, 0.024, 49)
Z_M = 0.0165
TRUE_RAW = {"w": [-0.45, 0.12, 0.0], "lag": [0.35, 0.12, 0.0], "frac": 0.89}  # D = 0.89 x 40 mm = 35.6 mm


@lru_cache(maxsize=8)
def transfer(cells_per_wavelength: float, lobe_range_m: float = 1.0, wave: bool = True):
    dx = C / (F * cells_per_wavelength)
    return free_field_transfer(
        frequency_hz=F,
        c_m_s=C,
        n_cells=int(round(LINE_M / dx)),
        cells_per_wavelength=cells_per_wavelength,
        lobe_angle_deg=ANG,
        lobe_range_m=lobe_range_m,
        wave_x_m=XS if wave else None,
        wave_z_m=Z_M if wave else None,
    )


def spec(T, **kw) -> ModelSpec:
    return ModelSpec(T.n_cells, T.grid.dx_m, F, **{"weights": "smooth", "lags": "smooth", "n_basis": 3, **kw})


def truth_params(lag_sign: float = 1.0) -> LineParams:
    f = TRUE_RAW["frac"]
    return LineParams(
        w=jnp.asarray(TRUE_RAW["w"]),
        lag=lag_sign * jnp.asarray(TRUE_RAW["lag"]),
        diam=jnp.asarray(math.log(f / (1 - f))),
        gain_db=jnp.asarray(80.0),
        phase0=jnp.asarray(0.3),
    )


def data(T, *, sig_db=0.1, sig_deg=0.3, seed=1, lag_sign=1.0):
    """(lobe, wave, truth) from the true transducer on the transfer `T` plus noise."""
    s = spec(T)
    pt = truth_params(lag_sign)
    rng = np.random.default_rng(seed)
    ldb = np.asarray(lobe_model_db(s, pt, T.lobe)) + rng.normal(0, sig_db, len(ANG))
    lobe = LobeData(ANG, ldb, np.full(len(ANG), sig_db), 1.0, F, 16, 20.0)
    wave = None
    if T.wave is not None:
        wph = np.asarray(wave_model_phase(s, pt, T.wave)) + rng.normal(0, math.radians(sig_deg), len(XS))
        wave = WaveData(XS, wph, np.full(len(XS), math.radians(sig_deg)), Z_M, F, 16, 20.0)
    ph = s.physical(pt)
    truth = {
        "diameter_mm": float(ph["diameter_m"]) * 1e3,
        "y_m": s.y_m,
        "weights": np.asarray(ph["weights"]),
        "lags_s": np.asarray(ph["lags_s"]),
    }
    for key in ("w", "lag"):
        for i, c in enumerate(np.asarray(getattr(pt, key))):
            truth[f"{key}.T{2 * (i + 1)}"] = float(c)
    return lobe, wave, truth
