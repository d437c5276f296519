"""Plain lobe tables say their units in the header (issue 27): angle_deg | angle_rad and
level_db | level_linear | level_pa | level_v. The same pattern in any accepted units loads to the
same degrees and dB and fits to the same diameter; an unknown or missing unit is refused with one
line listing the accepted ones (exit 2), never read as degrees and dB."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from difflattice.capture.errors import CaptureFileError
from difflattice.capture.files import load_lobe_table
from difflattice.cli import main
from difflattice.fit.data import lobe_from_table
from difflattice.fit.model import lobe_model_db
from difflattice.fit.solve import FitOptions, fit

from ._emulated import ANG, F, spec, transfer, truth_params

UNITS = [("angle_deg", "level_db"), ("angle_rad", "level_linear"), ("angle_rad", "level_db"), ("angle_deg", "level_pa")]


def _write(path: Path, angle_deg: np.ndarray, level_db: np.ndarray, units: tuple[str, str]) -> Path:
    a = np.radians(angle_deg) if units[0] == "angle_rad" else angle_deg
    v = level_db if units[1] == "level_db" else 10 ** (level_db / 20) * (2e-5 if units[1] == "level_pa" else 1.0)
    path.write_text(f"{units[1]};{units[0]}\n" + "".join(f"{y:.12g};{x:.12g}\n" for x, y in zip(a, v)))
    return path


@pytest.fixture(scope="module")
def pattern():
    T = transfer(12.0, wave=False)
    level = np.asarray(lobe_model_db(spec(T), truth_params(), T.lobe))
    return T, level


def test_every_accepted_unit_loads_to_degrees_and_db(tmp_path: Path, pattern) -> None:
    _, level = pattern
    ref = load_lobe_table(_write(tmp_path / "ref.csv", ANG, level, UNITS[0]))
    for units in UNITS[1:]:
        t = load_lobe_table(_write(tmp_path / f"{'_'.join(units)}.csv", ANG, level, units))
        assert t.units == units
        np.testing.assert_allclose(t.angle_deg, ref.angle_deg, rtol=0, atol=1e-9)
        # an amplitude in Pa carries its own reference: the same pattern up to a constant in dB
        off = 20 * math.log10(2e-5) if units[1] == "level_pa" else 0.0
        np.testing.assert_allclose(t.level_db - off, ref.level_db, rtol=0, atol=1e-9)


def test_angle_rad_level_linear_fits_to_the_same_diameter(tmp_path: Path, pattern) -> None:
    T, level = pattern
    s = spec(T)
    d = []
    for units in (UNITS[0], UNITS[1]):
        table = load_lobe_table(_write(tmp_path / f"{'_'.join(units)}.csv", ANG, level, units))
        lobe = lobe_from_table(table, frequency_hz=F, range_m=1.0, temperature_c=20.0, sigma_db=0.1)
        r = fit(s, T, lobe, None, FitOptions())
        assert r.converged, r.warnings
        d.append(float(r.physical["diameter_m"]) * 1e3)
    true_d = float(s.physical(truth_params())["diameter_m"]) * 1e3
    assert abs(d[1] - d[0]) < 1e-6, d  # the same data in other units: the same fit
    assert abs(d[0] - true_d) < 0.05, (d, true_d)  # and it is the truth (noise-free data)


@pytest.mark.parametrize(
    ("header", "match"),
    [
        ("angle_grad,level_db", "does not name its two columns with their units"),
        ("angle,level", "does not name its two columns with their units"),
        (None, "no header line naming the columns' units"),
    ],
)
def test_unknown_or_missing_unit_is_refused(tmp_path: Path, capsys, header, match) -> None:
    rows = "".join(f"{a},{-abs(a) / 3:.2f}\n" for a in range(-60, 61, 5))
    table = tmp_path / "sheet.csv"
    table.write_text(("" if header is None else header + "\n") + rows)
    with pytest.raises(CaptureFileError, match=match):
        load_lobe_table(table)
    cfg = tmp_path / "fit.toml"
    cfg.write_text(
        f'[data]\nlobe = "{table}"\nfrequency_hz = 40000\nrange_m = 1.0\ntemperature_c = 20.0\n'
        "lobe_sigma_db = 0.5\n[model]\nline_length_m = 0.042\n"
    )
    code = main(["fit", str(cfg), "--out", str(tmp_path / "out")])
    out, err = capsys.readouterr()
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "[data.lobe]" in lines[0], err
    assert "angle_deg | angle_rad" in lines[0] and "level_db | level_linear | level_pa | level_v" in lines[0], err


WAVE_CAPTURE = Path(__file__).resolve().parents[2] / "data" / "emulated" / "piston_disc" / "wave.csv"


@pytest.mark.parametrize("units", [("x_mm", "phase_deg"), ("x_m", "phase_mdeg"), ("x_mm", "delay_us")])
def test_a_wavefront_table_in_any_unit_gives_the_capture_data(tmp_path: Path, units) -> None:
    """The shipped piston wavefront capture written as a plain table (its x and lag, in the
    header's units) loads to the same positions and phases as the capture itself (phase mod 360)."""
    from difflattice.capture.files import load_capture, load_wave_table
    from difflattice.fit.data import wave_from_capture, wave_from_table

    cap = load_capture(WAVE_CAPTURE)
    ref = wave_from_capture(cap, sigma_deg=0.106)
    f = float(cap.metadata["freq_hz"])
    x = np.asarray(cap.x_m, float) * (1e3 if units[0] == "x_mm" else 1.0)
    lag = np.asarray(cap.phase_deg, float)
    col = {"phase_deg": lag, "phase_mdeg": lag * 1e3, "delay_us": lag / (360 * f) * 1e6}[units[1]]
    p = tmp_path / "wave.csv"
    p.write_text(f"{units[0]},{units[1]}\n" + "".join(f"{a:.12g},{b:.12g}\n" for a, b in zip(x, col)))
    t = load_wave_table(p)
    w = wave_from_table(t, frequency_hz=f, z_m=ref.z_m, temperature_c=ref.temperature_c, sigma_deg=0.106)
    np.testing.assert_allclose(w.x_m, ref.x_m, rtol=0, atol=1e-12)
    d = np.angle(np.exp(1j * (w.phase_rad - ref.phase_rad)))
    assert np.max(np.abs(d)) < 1e-9


def test_unknown_wavefront_unit_is_refused(tmp_path: Path, capsys) -> None:
    table = tmp_path / "wave.csv"
    table.write_text("x_inch,phase_deg\n" + "".join(f"{x},{x * x:.3f}\n" for x in range(-5, 6)))
    cfg = tmp_path / "fit.toml"
    cfg.write_text(
        f'[data]\nwave = "{table}"\nfrequency_hz = 40000\ntemperature_c = 20.0\nwave_z_m = 0.0165\n'
        "[model]\nline_length_m = 0.042\n"
    )
    code = main(["fit", str(cfg), "--out", str(tmp_path / "out")])
    _, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "[data.wave]" in lines[0], err
    assert "x_m | x_mm" in lines[0] and "phase_deg | phase_mdeg | delay_us" in lines[0], err


def test_a_wavefront_table_through_the_config(tmp_path: Path) -> None:
    """`[data] wave` may be a plain table; the config gives its frequency, temperature and z (here
    the capture's own), and the fit data equal the capture's."""
    from difflattice.capture.files import load_capture
    from difflattice.fit.config import load_config
    from difflattice.fit.loading import load_fit_data

    cap = load_capture(WAVE_CAPTURE)
    p = tmp_path / "wave.csv"
    p.write_text(
        "x_mm;phase_mdeg\n" + "".join(f"{a * 1e3:.12g};{b * 1e3:.12g}\n" for a, b in zip(cap.x_m, cap.phase_deg))
    )
    base = f'lobe = "{WAVE_CAPTURE.parent / "lobe.csv"}"\nfrequency_hz = {cap.metadata["freq_hz"]}\n'
    z = float(np.median(cap.z_m))
    cfg = tmp_path / "fit.toml"
    cfg.write_text(
        f'[data]\n{base}wave = "{p}"\ntemperature_c = 21.0\nwave_z_m = {z}\n[model]\nline_length_m = 0.042\n'
    )
    table = load_fit_data(load_config(cfg)).wave
    cfg.write_text(f'[data]\n{base}wave = "{WAVE_CAPTURE}"\ntemperature_c = 21.0\n[model]\nline_length_m = 0.042\n')
    ref = load_fit_data(load_config(cfg)).wave
    assert table.z_m == pytest.approx(ref.z_m) and len(table.x_m) == len(ref.x_m)
    np.testing.assert_allclose(table.x_m, ref.x_m, rtol=0, atol=1e-12)
    assert np.max(np.abs(np.angle(np.exp(1j * (table.phase_rad - ref.phase_rad))))) < 1e-9
