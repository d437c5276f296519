"""Fit configs' `[air]`: each key from [air], else the capture file's header, else dry air at one
atmosphere; the source of each is named, and the speed of sound is the humid air's."""

import pytest

from difflattice import air
from difflattice.capture.files import CaptureWriter
from difflattice.fit.config import config_from_dict
from difflattice.fit.loading import fit_air, load_fit_data

HEADER = {
    "kind": "lobe",
    "created_utc": "2026-01-01T00:00:00.000Z",
    "protocol": 1,
    "rig_id": "EMU-0001",
    "fw_version": "0.3.1-emu",
    "boot_id": 1,
    "scan_id": 7,
    "n_points": 5,
    "start_mdeg": -2000,
    "step_mdeg": 1000,
    "n_avg": 8,
    "cycles": 16,
    "freq_hz": 40000,
    "range_m": 1.0,
    "temperature_c": 21.0,
    "speed_of_sound_m_s": 343.8,
}


def _capture(path, **meta):
    with CaptureWriter.create(path, {**HEADER, **meta}) as w:
        for s in range(5):
            w.append((s, -2000 + 1000 * s, 40000 + 100 * s, 300, 2906203, 2100), 1.0)
        w.finish()
    return path


def _cfg(lobe, **air_keys):
    raw = {
        "data": {"lobe": str(lobe)},
        "model": {"line_length_m": 0.042, "lobe_range_m": 1000.0},
        "solver": {"floor_db": 0.05},
    }
    if air_keys:
        raw["air"] = air_keys
    return config_from_dict(raw)


def test_air_from_the_capture_then_the_config(tmp_path):
    lobe = _capture(tmp_path / "lobe.csv", humidity_pct=35.0, pressure_hpa=990.0)
    cfg = _cfg(lobe)
    used = fit_air(cfg, load_fit_data(cfg))
    assert used["temperature_c"] == pytest.approx(21.0)  # the recorded temperatures (21.00 degC)
    assert (used["humidity_pct"], used["pressure_pa"]) == (35.0, 99000.0)
    assert used["source"]["humidity_pct"] == "capture file" and used["source"]["pressure_pa"] == "capture file"
    assert used["speed_of_sound_m_s"] == pytest.approx(air.speed_of_sound_m_s(21.0, 35.0, 99000.0))
    cfg2 = _cfg(lobe, humidity_pct=80.0, temperature_c=25.0)
    used2 = fit_air(cfg2, load_fit_data(cfg2))
    assert (used2["temperature_c"], used2["humidity_pct"]) == (25.0, 80.0)
    assert used2["source"]["humidity_pct"] == "[air]"


def test_air_defaults_to_dry_when_nothing_says(tmp_path):
    lobe = _capture(tmp_path / "lobe.csv")
    cfg = _cfg(lobe)
    used = fit_air(cfg, load_fit_data(cfg))
    assert used["humidity_pct"] == 0.0 and "dry" in used["source"]["humidity_pct"]
    assert used["speed_of_sound_m_s"] == pytest.approx(air.speed_of_sound_m_s(21.0))
