"""Joint lobe + wavefront fits of the disc model to emulated circular transducers.

Data: the rig emulator's measurement model (`capture.emulator.RigModel`, in process: the same
noise as over the serial link: 0.5 % + 20 uV amplitude per burst, 0.3 deg phase per burst, 8
bursts averaged) with a ground truth that is independent of the lattice: the Rayleigh integral
of a piston or of a disc with a rim taper and a lag profile (`capture.groundtruth`), the lobe at
the rig's finite range (1 m). Sigmas as the capture loader sets them (`fit.data`). The model's
transfer comes from the axisymmetric lattice at 20 cells per wavelength.

Criteria (issue 12): chi2_red <= 1.5 on each block (its share of the degrees of freedom),
wavefront RMS <= 1 deg, the true diameter and profiles within 3 standard errors. The seeds are
fixed (a fresh draw would fail a 3-sigma criterion a few times in a thousand).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from difflattice.capture import protocol as P
from difflattice.capture.emulator import RigModel, make_config
from difflattice.fit.data import LobeData, WaveData
from difflattice.fit.disc import DiscSpec, profile_values
from difflattice.fit.solve import FitOptions, fit
from difflattice.fit.transfer_disc import disc_transfer

from ._sane import assert_sane_report

F = 50_000
T_C = 21.0
C = 331.3 * math.sqrt(1 + T_C / 273.15)
PPW = 20.0
DX = C / F / PPW
N_RINGS = int(round(0.021 / DX))  # a modelled disc of 42 mm
ANG = np.arange(-90, 90.1, 1.0)
XS = np.round(np.arange(-0.024, 0.02401, 0.001), 6)
Z = 0.0165
N_AVG = 8


def rig_data(transducer: dict, *, seed: int) -> tuple[LobeData, WaveData]:
    """A lobe scan (-90..90 deg, 1 deg, 1 m) and a wavefront scan (x = -24..24 mm, 1 mm, z = 16.5
    mm) as the emulated rig reports them, converted as the capture loader does."""
    cfg = make_config(
        link_path="/tmp/unused",
        transducer=transducer,
        seed=seed,
        rig={"temperature_c": T_C, "drift_c_per_h": 0.0, "wobble_c": 0.0, "range_m": 1.0},
    )
    rig = RigModel(cfg)
    lcmd = P.Lobe(1, 0, len(ANG), -90_000, 1000, N_AVG, 16, F)
    lob = [rig.measure(lcmd, s, T_C) for s in range(len(ANG))]
    amp = np.maximum(np.array([m.amp_uV for m in lob], float), 1e-3)
    sd = np.array([m.amp_sd_uV for m in lob], float) / math.sqrt(N_AVG)
    lobe = LobeData(
        np.array([m.angle_mdeg for m in lob]) / 1000,
        20 * np.log10(amp),
        np.maximum(20 / math.log(10) * sd / amp, 0.05),
        1.0,
        F,
        16,
        T_C,
    )
    wcmd = P.Wave(2, 0, len(XS), -24_000, 1000, int(round(Z * 1e6)), N_AVG, 16, F)
    wav = [rig.measure(wcmd, s, T_C) for s in range(len(XS))]
    sigma = math.radians(cfg.noise.phase_mdeg / 1000 / math.sqrt(N_AVG))
    wave = WaveData(
        np.array([m.x_um for m in wav]) * 1e-6,
        -np.radians(np.array([m.phase_mdeg for m in wav]) / 1000),
        np.full(len(wav), sigma),
        Z,
        F,
        16,
        T_C,
    )
    return lobe, wave


def block_chi2(r, lobe, wave) -> dict:
    """chi2 per block: its sum of squared normalised residuals over its share of the degrees of
    freedom, n_b (1 - n_params / n)."""
    n_par = len(r.raw_labels)
    n = len(lobe.angle_deg) + len(wave.x_m)
    floor = float(np.max(lobe.level_db)) - FitOptions().floor_db
    from difflattice.fit.model import soft_floor_db

    rl = (
        np.asarray(soft_floor_db(r.model_curves["lobe_db"], floor)) - np.asarray(soft_floor_db(lobe.level_db, floor))
    ) / lobe.sigma_db
    d = np.angle(np.exp(1j * (r.model_curves["wave_phase_rad"] - wave.phase_rad)))
    rw = 2 * np.sin(d / 2) / wave.sigma_rad
    return {
        "lobe": float(np.sum(rl**2) / (len(rl) * (1 - n_par / n))),
        "wave": float(np.sum(rw**2) / (len(rw) * (1 - n_par / n))),
    }


@pytest.fixture(scope="module")
def transfer():
    return disc_transfer(
        frequency_hz=F,
        c_m_s=C,
        n_rings=N_RINGS,
        cells_per_wavelength=PPW,
        lobe_angle_deg=ANG,
        lobe_range_m=1.0,
        wave_x_m=XS,
        wave_z_m=Z,
    )


def test_piston_joint_fit_reaches_the_noise(transfer):
    D = 0.0384
    lobe, wave = rig_data({"kind": "piston", "diameter_m": D}, seed=1)
    spec = DiscSpec(n_cells=N_RINGS, dx_m=DX, frequency_hz=F)
    r = fit(spec, transfer, lobe, wave, FitOptions())
    assert r.converged, r.warnings
    chi2 = block_chi2(r, lobe, wave)
    assert chi2["lobe"] <= 1.5 and chi2["wave"] <= 1.5, chi2
    assert r.rms["wave_phase_deg"] <= 1.0
    d_fit, se = float(r.physical["diameter_m"]) * 1e3, r.stderr["diameter_mm"]
    assert 0 < se < 0.05  # a real error bar, not a bound
    assert abs(d_fit - D * 1e3) < 3 * se, (d_fit, se)


@pytest.mark.slow
def test_tapered_disc_with_lags_recovers_profiles(transfer):
    D = 0.0384
    w_raw = [math.log(0.5), math.log(0.25 / 0.75)]  # the rim moves at half the centre's velocity, over a quarter
    lag_raw = [0.15, 0.05]  # the rim lags ~1.7 us behind the centre ring
    u = np.linspace(0, 1, 801)
    truth = {
        "kind": "disc",
        "diameter_m": D,
        "r_frac": u.tolist(),
        "weights": profile_values("rim_taper", w_raw, u, kind="weights", period_s=1 / F).tolist(),
        "lags_s": profile_values("smooth", lag_raw, u, kind="lags", period_s=1 / F).tolist(),
    }
    lobe, wave = rig_data(truth, seed=2)
    spec = DiscSpec(n_cells=N_RINGS, dx_m=DX, frequency_hz=F, weights="rim_taper", lags="smooth", n_basis=2)
    r = fit(spec, transfer, lobe, wave, FitOptions())
    assert r.converged, r.warnings
    chi2 = block_chi2(r, lobe, wave)
    assert chi2["lobe"] <= 1.5 and chi2["wave"] <= 1.5, chi2
    assert r.rms["wave_phase_deg"] <= 1.0
    true = spec.physical(spec.truth_params(diameter_m=D, w=w_raw, lag=lag_raw))
    assert abs(float(r.physical["diameter_m"]) - D) * 1e3 < 3 * r.stderr["diameter_mm"]
    rim = int(D / 2 / DX)
    for k in (rim - 12, rim - 8, rim - 4, rim - 1):  # weights inside the taper (1 elsewhere, by construction)
        assert abs(r.physical["weights"][k] - float(true["weights"][k])) < 3 * r.stderr[f"w[{k}]"]
    for k in (0, 15, 30, 45, rim - 1):
        got, want = r.physical["lags_s"][k] * 1e6, float(true["lags_s"][k]) * 1e6
        assert abs(got - want) < 3 * r.stderr[f"lag_us[{k}]"], (k, got, want)


@pytest.mark.slow
def test_shipped_config_recovers_the_piston(tmp_path):
    """`difflattice fit fitting/piston_disc.toml` (captures through the emulated rig): the true
    38.4 mm inside the quoted total uncertainty (statistical + resolution + model)."""
    from pathlib import Path

    from difflattice.apps.fitting import run_fit
    from difflattice.fit.config import load_config

    root = Path(__file__).resolve().parents[2]
    rep = run_fit(load_config(root / "fitting" / "piston_disc.toml"), out=tmp_path, verbose=False)
    assert rep["fit"]["converged"]
    assert rep["fit"]["outcome"]["exit_code"] == 0, rep["fit"]["outcome"]  # issue 27: consistent
    assert_sane_report(tmp_path)
    d = next(e for e in rep["budget"]["scalars"] if e["name"] == "diameter_mm")
    assert d["status"] == "determined" and abs(d["value"] - 38.4) <= d["total"], d
    assert rep["fit"]["rms"]["wave_phase_deg"] <= 1.0


def piston_capture(
    *, sig_db: float = 0.2, sig_deg: float = 0.1, seed: int = 7, diameter_m: float = 0.0384
) -> tuple[LobeData, WaveData]:
    """An ideal 38.4 mm piston as a capture made by code independent of the fit's model: the
    Rayleigh integral of `capture.groundtruth.Piston` (lobe at the rig's 1 m, wavefront at z =
    16.5 mm), plus Gaussian noise of exactly the stated 1-sigma (`sig_db` on the level,
    `sig_deg` on the phase)."""
    from difflattice.capture.groundtruth import Piston

    rng = np.random.default_rng(seed)
    pis = Piston(diameter_m=diameter_m)
    p_lobe = pis.at_range(ANG, 1.0, F, C)
    level = 20 * np.log10(np.maximum(np.abs(p_lobe), 1e-3)) + rng.normal(0, sig_db, len(ANG))
    lobe = LobeData(ANG, level, np.full(len(ANG), sig_db), 1.0, F, 16, T_C)
    lag = np.angle(pis.near_field(XS, Z, F, C)) + rng.normal(0, math.radians(sig_deg), len(XS))
    wave = WaveData(XS, -lag, np.full(len(XS), math.radians(sig_deg)), Z, F, 16, T_C)
    return lobe, wave


@pytest.mark.parametrize("sets", ["joint", "lobe", "wave"])
def test_chi2_is_counted_per_measured_datum(transfer, sets):
    """Issue 27: on an ideal piston measured at its stated noise (0.2 dB, 0.1 deg), the joint,
    lobe-only and wave-only fits report chi2_red in 0.8-1.25, counted with one residual per
    measured datum: the wavefront's chi-square is the sum over its points of (d / sigma)^2 (one
    phase each, not two residuals), and a lobe level counts as the share of a datum that the
    soft floor leaves of its noise, 1 / (1 + 10^((F - L)/10)) squared (1 above the floor).

    The band is the issue's; statistically, chi2_red scatters by sqrt(2 / dof): 0.13 for the
    lobe's ~117, 0.21 for the wavefront's 47 degrees of freedom, so a fresh seed can leave the
    band without a bias (seeds 7-10 in docs/fitting.md: lobe 0.78-1.14, wave 0.82-1.06). The
    seed is fixed; the unbiasedness is what `test_chi2_is_unbiased_over_seeds` checks."""
    lobe, wave = piston_capture(seed=8)
    lobe_in = None if sets == "wave" else lobe
    wave_in = None if sets == "lobe" else wave
    spec = DiscSpec(n_cells=N_RINGS, dx_m=DX, frequency_hz=F)
    r = fit(spec, transfer, lobe_in, wave_in, FitOptions())
    assert r.converged, r.warnings
    n_par = len(r.raw_labels)
    assert 0.8 <= r.chi2_reduced <= 1.25, (sets, r.chi2_reduced, r.goodness)
    g = r.goodness
    chi2_user, n_user = 0.0, 0.0
    if lobe_in is not None:
        floor = float(np.max(lobe.level_db)) - FitOptions().floor_db
        m = np.asarray(r.model_curves["lobe_db"])
        soft = lambda x: 10 * np.log10(10 ** (x / 10) + 10 ** (floor / 10))  # noqa: E731
        rl = (soft(m) - soft(lobe.level_db)) / lobe.sigma_db
        chi2_user += float(np.sum(rl**2))
        n_user += float(np.sum((1 / (1 + 10 ** ((floor - m) / 10))) ** 2))
        assert abs(g["lobe"]["chi2"] - np.sum(rl**2)) < 1e-6 * np.sum(rl**2)
    if wave_in is not None:
        d = np.angle(np.exp(1j * (r.model_curves["wave_phase_rad"] - wave.phase_rad)))
        rw = (d / wave.sigma_rad) ** 2
        chi2_user += float(np.sum(rw))
        n_user += len(d)
        assert g["wave"]["n"] == len(XS) and abs(g["wave"]["chi2"] - np.sum(rw)) < 1e-3 * np.sum(rw)
    user = chi2_user / (n_user - n_par)
    assert abs(r.chi2_reduced - user) < 1e-3 * user, (r.chi2_reduced, user)
    assert g["joint"]["p"] >= 1e-3 and abs(g["joint"]["dof"] - (n_user - n_par)) < 1e-6 * n_user


def test_chi2_is_unbiased_over_seeds(transfer):
    """Pooled over 4 independent noise draws of the ideal piston (joint fits), the chi-square
    per measured datum over the pooled degrees of freedom is 1 within 3 sqrt(2 / dof) (~0.17):
    the old count (two residuals per wavefront point) gave ~0.73 here."""
    spec = DiscSpec(n_cells=N_RINGS, dx_m=DX, frequency_hz=F)
    c2 = dof = 0.0
    for seed in (21, 22, 23, 24):
        lobe, wave = piston_capture(seed=seed)
        r = fit(spec, transfer, lobe, wave, FitOptions())
        assert r.converged, r.warnings
        c2 += r.goodness["joint"]["chi2"]
        dof += r.goodness["joint"]["dof"]
    assert abs(c2 / dof - 1) < 3 * math.sqrt(2 / dof), (c2 / dof, dof)


@pytest.mark.parametrize("start", [0.75, 1.3])
def test_a_far_start_reaches_the_same_diameter(transfer, start):
    """Issue 27: a lobe-only fit of a 30 mm piston started at 0.75 x or 1.3 x its diameter (the
    user's `model.diameter_m`, i.e. `params0` with `multistart`) reaches the diameter of the
    default start (the scan) to 0.01 mm (its standard error is ~0.01 mm) at the noise; without the
    multi-start it stayed at a null's local minimum (D = 21.7 and 38.1 mm, chi2_red ~1400:
    measured before the change)."""
    lobe, _ = piston_capture(seed=8, diameter_m=0.030)
    ref = fit(DiscSpec(n_cells=N_RINGS, dx_m=DX, frequency_hz=F), transfer, lobe, None, FitOptions())
    spec = DiscSpec(n_cells=N_RINGS, dx_m=DX, frequency_hz=F, diameter_m=start * 0.030)
    r = fit(spec, transfer, lobe, None, FitOptions(), params0=spec.init_params(), multistart=True)
    assert ref.converged and r.converged, r.warnings
    d_ref, d = (float(x.physical["diameter_m"]) * 1e3 for x in (ref, r))
    assert abs(d - d_ref) < 0.01 and abs(d - 30.0) < 3 * r.stderr["diameter_mm"], (d, d_ref)
    assert r.goodness["lobe"]["p"] >= 1e-3, r.goodness
