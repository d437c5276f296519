"""A measured wavefront in a housed fit config (`[data] wave`, `wave_z_m`, `wave_mask_m`,
`[solver] wave_sigma_deg`): read into the phases `fit_housed(..., wave=)` takes, fitted jointly
with the datasheet lobe by `difflattice fit`, and refused with the key named where it is wrong."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from difflattice.config import ConfigError
from difflattice.fit.housed_config import housed_config_from_dict, load_housed_config, load_housed_wave

from .test_housed_modes import F_HZ, _mode_matching_data


def _write_case(tmp_path, *, wave_lines: str | None = None, data_extra: str = "", solver: str = "") -> object:
    """A flanged 15 mm tube 8 mm deep (the mode-matching reference's geometry) with the reference's
    lobe as a datasheet record and its wavefront as a plain table (x_mm, the rig's lag in deg)."""
    lobe, wave = _mode_matching_data()
    rec = tmp_path / "record.toml"
    rec.write_text(
        'notes = "SYNTHETIC: mode matching (observe.analytic_tube), test only"\n'
        '[source]\ndocument = "mode matching"\nrevision = "test"\nurl = "tests"\nlocation = "lobe"\nquote = "-"\n'
        f'[device]\npart = "recessed piston"\nfrequency_hz = {F_HZ}\n'
        f"[table]\nangle_deg = {[float(a) for a in lobe.angle_deg]}\nlevel_db = {[float(v) for v in lobe.level_db]}\n"
        f'method = "computed"\nsigma_db = {float(lobe.sigma_db[0])}\n'
    )
    if wave_lines is None:
        lag_deg = -np.degrees(wave.phase_rad)  # the models' phase is minus the rig's lag (fit.data)
        wave_lines = "x_mm,phase_deg\n" + "".join(f"{x * 1e3:.6f},{v:.9f}\n" for x, v in zip(wave.x_m, lag_deg))
    (tmp_path / "wave.csv").write_text(wave_lines)
    cfg = tmp_path / "housed.toml"
    cfg.write_text(
        f'[data]\ndatasheet = "record.toml"\nwave = "wave.csv"\n{data_extra}\n'
        '[model]\nmodel = "housed"\nfamily = "recessed"\n'
        "[model.housing]\nouter_diameter_m = 0.015\nlength_m = 0.008\nwall_m = 0.0\n"
        'front = "flange"\n'
        f"{solver}\n"
        f'[output]\ndir = "{tmp_path / "out"}"\n'
    )
    return cfg, wave


def test_config_wavefront_is_the_fit_wavefront(tmp_path):
    """The plain table's lags come back as the models' phases (to the 1e-9 deg the file prints),
    at the config's z and sigma."""
    cfg_path, wave = _write_case(tmp_path, data_extra="wave_z_m = 0.010", solver="[solver]\nwave_sigma_deg = 0.1")
    cfg = load_housed_config(cfg_path)
    got, notes = load_housed_wave(cfg, F_HZ)
    assert got is not None and got.z_m == 0.010 and len(got.x_m) == len(wave.x_m)
    np.testing.assert_allclose(got.x_m, wave.x_m, atol=1e-9)
    d = np.angle(np.exp(1j * (got.phase_rad - wave.phase_rad)))
    assert np.max(np.abs(d)) < math.radians(1e-8)
    np.testing.assert_allclose(got.sigma_rad, math.radians(0.1))
    assert "wavefront" in notes[-1]


@pytest.mark.slow
def test_config_with_a_wavefront_runs_a_joint_fit(tmp_path):
    """`difflattice fit` of a housed config with a wavefront fits lobe and wavefront together (the
    recessed family, a fitted phase offset) and reports both: the mode-matching data (lobe + 0.2 dB,
    wavefront + 0.1 deg, the noise stated to the fit) are described within their noise (joint
    chi-square probability > 1 %: a wavefront read with the wrong sign or at the wrong distance
    would not be), and the wavefront's RMS residual is of the order of its 0.1 deg noise (<
    0.3 deg: the lattice's own wavefront error at 12 cells per wavelength is 0.13 deg at most,
    docs/housed.md). 12 cells per wavelength, no resolution refit (`quick`)."""
    from difflattice.apps.fitting_housed import run_housed

    cfg_path, _ = _write_case(tmp_path, data_extra="wave_z_m = 0.010", solver="[solver]\nwave_sigma_deg = 0.1")
    rep = run_housed(load_housed_config(cfg_path), quick=True, verbose=False)
    fam = rep["families"][0]
    assert rep["chosen"] == "recessed" and rep["exit_code"] == 0, rep["reason"]
    assert set(rep["goodness"]) >= {"lobe", "wave", "joint"}
    assert rep["goodness"]["joint"]["p"] > 0.01, rep["goodness"]
    w = rep["wavefront"]
    assert w["points"] == 13 and w["z_m"] == 0.010 and w["sigma_deg"] == 0.1
    assert w["rms_deg"] is not None and w["rms_deg"] < 0.3, w
    assert len(w["residual_deg"]) == 13
    assert 8.0 < fam["diaphragm_mm"] < 10.0 and 2.0 < fam["recess_mm"] < 4.0, fam
    on_disk = json.loads((tmp_path / "out" / "report.json").read_text())
    assert on_disk["wavefront"]["points"] == 13
    assert "Wavefront (fitted with the lobe)" in (tmp_path / "out" / "report.md").read_text()


HOUSING = {"outer_diameter_m": 0.01, "length_m": 0.01}


@pytest.mark.parametrize(
    ("data", "solver", "match"),
    [
        ({"wave_z_m": 0.01}, None, r"\[data.wave_z_m\] is given but there is no wavefront"),
        ({"wave_mask_m": [[0.0, 0.001]]}, None, r"\[data.wave_mask_m\] is given but there is no wavefront"),
        ({}, {"wave_sigma_deg": 0.1}, r"\[solver.wave_sigma_deg\] is given but there is no wavefront"),
        ({"wave": "w.csv"}, {"name": "levenberg_marquardt"}, "name"),
        ({"wave": "w.csv", "wave_z_m": -0.01}, None, "wave_z_m"),
    ],
)
def test_bad_wavefront_keys_are_named(data, solver, match):
    raw = {"data": {"datasheet": "x.toml", **data}, "model": {"model": "housed", "housing": dict(HOUSING)}}
    if solver is not None:
        raw["solver"] = solver
    with pytest.raises(ConfigError, match=match):
        housed_config_from_dict(raw, path="cfg.toml")


@pytest.mark.parametrize(
    ("lines", "extra", "match"),
    [
        (None, "", r"\[data.wave_z_m\] is required: wave.csv is a plain table"),
        ("angle_deg,level_db\n0,0\n10,-1\n20,-3\n", "wave_z_m = 0.01", r"\[data.wave\] .* cannot be used"),
        ("x_mm,phase_deg\n0,10\n1,11\n", "wave_z_m = 0.01", r"\[data.wave\] .* cannot be used"),
        (None, "wave_z_m = 0.01\nwave_mask_m = [[-0.02, 0.009]]", r"\[data.wave_mask_m\] .* leaves 2 of 13"),
    ],
)
def test_bad_wavefront_files_are_refused_naming_the_key(tmp_path, lines, extra, match):
    cfg_path, _ = _write_case(tmp_path, wave_lines=lines, data_extra=extra)
    with pytest.raises(ConfigError, match=match):
        load_housed_wave(load_housed_config(cfg_path), F_HZ)


def test_missing_wave_file_is_named(tmp_path):
    cfg_path, _ = _write_case(tmp_path, data_extra="wave_z_m = 0.01")
    (tmp_path / "wave.csv").unlink()
    with pytest.raises(ConfigError, match=r'\[data.wave\] = "wave.csv": not found'):
        load_housed_wave(load_housed_config(cfg_path), F_HZ)


def test_scan_line_inside_the_can_is_refused_before_fitting(tmp_path):
    """A free can's scan line must clear the surface round the can: a line 1 mm in front of the
    face is refused as a ConfigError naming `[data.wave_z_m]` and the distance needed."""
    from difflattice.apps.fitting_housed import run_housed

    cfg_path, _ = _write_case(tmp_path, data_extra="wave_z_m = 0.001")
    cfg_path.write_text(cfg_path.read_text().replace('front = "flange"\n', ""))
    with pytest.raises(
        ConfigError, match=r"\[data.wave_z_m\] wave_z_m = 0.001 m puts the scan line inside .* give wave_z_m >"
    ):
        run_housed(load_housed_config(cfg_path), quick=True, verbose=False)


EMULATED = Path(__file__).resolve().parents[2] / "data" / "emulated" / "piston_disc"


@pytest.mark.parametrize(
    ("wave", "freq_hz", "z", "match"),
    [
        ("wave.csv", 50e3, None, None),  # the capture's own z and frequency
        ("wave.csv", 50e3, 0.0165, None),
        ("wave.csv", 40e3, None, r"\[data.wave\] .* captured at 50000 Hz but the datasheet record is at 40000 Hz"),
        ("wave.csv", 50e3, 0.02, r"\[data.wave_z_m\] = 0.02 m but wave.csv says z = 0.0165 m"),
        ("lobe.csv", 50e3, None, r"\[data.wave\] .* is a lobe capture"),
    ],
)
def test_a_wave_capture_carries_its_frequency_and_z(tmp_path, wave, freq_hz, z, match):
    """A rig capture (`difflattice capture wave`) gives z and frequency itself: they are checked
    against the config and the datasheet record, and a lobe capture is refused as the wave."""
    raw = {
        "data": {"datasheet": "x.toml", "wave": str(EMULATED / wave)},
        "model": {"model": "housed", "housing": HOUSING},
    }
    if z is not None:
        raw["data"]["wave_z_m"] = z
    cfg = housed_config_from_dict(raw, path=tmp_path / "cfg.toml")
    if match is not None:
        with pytest.raises(ConfigError, match=match):
            load_housed_wave(cfg, freq_hz)
        return
    got, _ = load_housed_wave(cfg, freq_hz)
    assert got.z_m == pytest.approx(0.0165, abs=1e-4) and got.frequency_hz == 50e3 and len(got.x_m) >= 3
