"""The rig's wavefront phase convention, end to end (rig protocol, "Field conventions"):
`phase_mdeg` is the LAG of the received carrier behind the drive, in [0, 360000), equal to
`round(360000 f t) mod 360000` for a pure delay t.

A ground truth that is a pure delay profile t(x) (later at the edges, like the curved wavefront
of a transducer whose edges lag) goes through the emulated rig, a capture file, the loader and the
fit's data conversion; the phases must be the protocol's, and a fit of them must find edge lags
(delays, tau > 0), not leads. The mirror profile (earlier at the edges) must give leads.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from difflattice.capture import protocol as P
from difflattice.capture.emulator import RigModel, make_config
from difflattice.capture.files import CaptureWriter, load_capture
from difflattice.capture.groundtruth import TableTransducer, speed_of_sound
from difflattice.fit.data import wave_from_capture

F_HZ = 40_000
Z_M = 0.0165
X0_UM, DX_UM, N = -12_000, 1_000, 25  # x = -12..12 mm, inside the modelled line
T0_S = Z_M / speed_of_sound(20.0)  # ~1.9 periods: the reported lag wraps
EDGE_DELAY_S = 8e-6  # 0.32 period more at |x| = 12 mm than on axis


def delay_s(x_m, sign: float = 1.0):
    """A pure delay: t0 + sign * EDGE_DELAY * (x / 12 mm)^2."""
    return T0_S + sign * EDGE_DELAY_S * (np.asarray(x_m) / 0.012) ** 2


def emulated_lines(tmp_path: Path, sign: float) -> list[P.Wav]:
    """The WAV lines the emulated rig sends for a pure-delay ground truth (noise off)."""
    x = (X0_UM + DX_UM * np.arange(N)) * 1e-6
    t = delay_s(x, sign)
    table = TableTransducer(
        near_z_m=Z_M,
        near_x_m=x,
        near=np.exp(1j * 2 * np.pi * F_HZ * t),  # exp(-i w t): delay t
        near_tof_s=t,
        freq_hz=F_HZ,
    ).save(tmp_path / "delay.json")
    cfg = make_config(
        link_path=tmp_path / "rig",
        transducer={"kind": "table", "path": str(table)},
        noise=False,
        rig={"temperature_c": 20.0, "drift_c_per_h": 0.0, "wobble_c": 0.0},
    )
    model = RigModel(cfg)
    cmd = P.Wave(1, 0, N, X0_UM, DX_UM, round(Z_M * 1e6), 8, 16, F_HZ)
    return [model.measure(cmd, s, 20.0) for s in range(N)]


def write_capture(path: Path, lines: list[P.Wav]) -> Path:
    header = {
        "kind": "wave",
        "created_utc": "2026-11-23T00:00:00.000Z",
        "protocol": 1,
        "rig_id": "EMU-0001",
        "fw_version": "0.3.1-emu",
        "boot_id": 1,
        "scan_id": 1,
        "n_points": N,
        "x0_um": X0_UM,
        "dx_um": DX_UM,
        "z_um": round(Z_M * 1e6),
        "n_avg": 8,
        "cycles": 16,
        "freq_hz": F_HZ,
        "temperature_c": 20.0,
        "speed_of_sound_m_s": round(float(speed_of_sound(20.0)), 3),
    }
    with CaptureWriter.create(path, header) as w:
        for m in lines:
            w.append((m.seq, m.x_um, m.z_um, m.tof_ns, m.phase_mdeg, m.amp_uV, m.temp_cC), 1.0)
        w.finish()
    return path


def test_pure_delay_gives_the_protocols_lag(tmp_path: Path) -> None:
    lines = emulated_lines(tmp_path, +1.0)
    phase = np.array([m.phase_mdeg for m in lines])
    x = np.array([m.x_um for m in lines]) * 1e-6
    expected = np.round(360_000 * F_HZ * delay_s(x)).astype(np.int64) % 360_000
    assert np.all((0 <= phase) & (phase < 360_000))
    # exact up to the float rounding of a value on a .5 boundary
    assert np.max(np.abs((phase - expected + 180_000) % 360_000 - 180_000)) <= 1
    # a later arrival has a larger lag, modulo one period: the edges lag the centre by 360 f dt
    centre = N // 2
    rel = (phase - phase[centre]) % 360_000
    assert rel[0] == pytest.approx(360_000 * F_HZ * EDGE_DELAY_S, abs=2)
    assert np.all(np.diff(rel[centre:]) > 0) and np.all(np.diff(rel[: centre + 1]) < 0)


def test_loader_and_fit_data_keep_the_sign(tmp_path: Path) -> None:
    cap = load_capture(write_capture(tmp_path / "w.csv", emulated_lines(tmp_path, +1.0)))
    assert np.all((cap.phase_deg >= 0) & (cap.phase_deg < 360))
    wave = wave_from_capture(cap, sigma_deg=0.1)
    np.testing.assert_allclose(wave.lag_deg, cap.phase_deg, atol=1e-9)
    # the fit's phase is -lag (exp(-i omega t)); the arrival it implies is later at the edges
    arrival_s = -np.unwrap(wave.phase_rad) / (2 * math.pi * F_HZ)
    arrival_s -= arrival_s[N // 2]
    np.testing.assert_allclose(arrival_s, delay_s(wave.x_m) - T0_S, atol=1e-9)


@pytest.mark.parametrize("sign", [+1.0, -1.0], ids=["edges-later", "edges-earlier"])
def test_fit_finds_edge_lags_of_the_right_sign(tmp_path: Path, sign: float) -> None:
    """A symmetric smooth lag profile fitted to the pure-delay wavefront: its edge cells must lag
    the centre (tau > 0) when the edges arrive later, lead when they arrive earlier. The line
    model cannot reproduce a pure delay exactly (diffraction), so only the sign and a magnitude
    of at least a quarter of the imposed delay are required."""
    from difflattice.fit.model import ModelSpec
    from difflattice.fit.solve import FitOptions, fit
    from difflattice.fit.transfer import free_field_transfer

    wave = wave_from_capture(
        load_capture(write_capture(tmp_path / "w.csv", emulated_lines(tmp_path, sign))), sigma_deg=0.5
    )
    c = float(speed_of_sound(20.0))
    ppw = 12.0
    n = int(round(0.030 / (c / (F_HZ * ppw))))  # a 30 mm line: the scan (+-12 mm) lies over it
    T = free_field_transfer(
        frequency_hz=F_HZ, c_m_s=c, n_cells=n, cells_per_wavelength=ppw, wave_x_m=wave.x_m, wave_z_m=wave.z_m
    )
    spec = ModelSpec(
        n, T.grid.dx_m, F_HZ, weights="uniform", lags="smooth", n_basis=3, symmetric=True, fit_diameter=False
    )
    r = fit(spec, T, None, wave, FitOptions(max_steps=300))
    lags = np.asarray(r.physical["lags_s"])
    y = spec.y_m
    edge = np.abs(y) > 0.011  # cells beyond |y| = 11 mm, under the scan's ends
    edge_lag = float(np.mean(lags[edge]) - lags[np.argmin(np.abs(y))])
    assert np.all(np.isfinite(lags))
    assert np.sign(edge_lag) == sign, (edge_lag, r.warnings)
    assert abs(edge_lag) > 0.25 * EDGE_DELAY_S, edge_lag
