"""Ground-truth transducers and the documented conventions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from difflattice.capture.groundtruth import (
    Piston,
    TableTransducer,
    lobe_truth,
    make_transducer,
    speed_of_sound,
    wave_truth,
)

F = 40_000.0
PISTON = Piston(0.0384, sensitivity_uV=50_000.0)
FRAUNHOFER = Piston(0.0384, sensitivity_uV=50_000.0, lobe="fraunhofer")  # the far-field pattern spread as 1/r


def test_speed_of_sound() -> None:
    assert speed_of_sound(0.0) == pytest.approx(331.3)
    assert speed_of_sound(20.0) == pytest.approx(343.2, abs=0.05)


@pytest.mark.parametrize("z_m", [0.005, 0.0165, 0.1])
def test_rayleigh_integral_on_axis_matches_closed_form(z_m: float) -> None:
    c = speed_of_sound(21.0)
    k, a = 2 * np.pi * F / c, PISTON.radius_m
    exact = (
        50_000.0
        * (-1j / (np.pi * a**2))
        * 2
        * np.pi
        * (np.exp(1j * k * np.hypot(z_m, a)) - np.exp(1j * k * z_m))
        / (1j * k)
    )
    assert PISTON.near_field(np.array([0.0]), z_m, F, c)[0] == pytest.approx(exact, rel=1e-9)


def test_near_field_tends_to_lobe_in_far_field() -> None:
    c, r = speed_of_sound(21.0), 5.0
    angles = np.array([0.0, 10.0, 25.0])
    x, z = r * np.sin(np.deg2rad(angles)), r * np.cos(np.deg2rad(angles))
    near = np.array([PISTON.near_field(np.array([xi]), zi, F, c)[0] for xi, zi in zip(x, z, strict=True)])
    amp, tof = lobe_truth(PISTON, angles, range_m=r, freq_hz=F, temperature_c=21.0)
    np.testing.assert_allclose(np.abs(near), amp, rtol=2e-3)
    assert tof == pytest.approx(r / c)


def test_lobe_conventions() -> None:
    amp, _ = lobe_truth(PISTON, [0.0, 30.0, -30.0, 90.0, 135.0], range_m=2.0, freq_hz=F, temperature_c=21.0)
    k, a = 2 * np.pi * F / speed_of_sound(21.0), PISTON.radius_m  # on axis at 2 m: the Rayleigh integral's closed form
    assert amp[0] == pytest.approx(50_000.0 * 4 * abs(np.sin(k * (np.hypot(2.0, a) - 2.0) / 2)) / (k * a**2), rel=1e-9)
    far, _ = lobe_truth(FRAUNHOFER, [0.0], range_m=2.0, freq_hz=F, temperature_c=21.0)
    assert far[0] == pytest.approx(25_000.0) and amp[0] == pytest.approx(25_000.0, rel=1e-3)  # sensitivity at 1 m, 1/r
    assert amp[1] == pytest.approx(amp[2])
    assert amp[4] == 0 and 0 < amp[3] < 0.05 * amp[0]  # nothing behind the baffle; grazing in its plane


def test_wave_conventions() -> None:
    c = speed_of_sound(21.0)
    tof, phase, amp = wave_truth(PISTON, [0.0, 0.0192, 0.03], z_m=0.0165, freq_hz=F, temperature_c=21.0)
    np.testing.assert_allclose(tof, [0.0165 / c, 0.0165 / c, np.hypot(0.0165, 0.03 - 0.0192) / c])
    # far on axis the received carrier lags the drive by k z - 90 deg (the rig's phase_mdeg is
    # that lag, reduced to [0, 360) deg: rig protocol, "Field conventions")
    z = 50.0
    _, phase_far, _ = wave_truth(PISTON, [0.0], z_m=z, freq_hz=F, temperature_c=21.0)
    expected = (np.rad2deg(2 * np.pi * F / c * z) - 90.0) % 360
    assert (phase_far[0] - expected + 180) % 360 - 180 == pytest.approx(0.0, abs=0.5)
    assert np.all((0 <= phase) & (phase < 360)) and np.all(amp > 0)
    # moving the microphone away by a small dz delays the carrier by dz / c: the lag grows
    _, phase_near, _ = wave_truth(PISTON, [0.0], z_m=z - 0.001, freq_hz=F, temperature_c=21.0)
    assert (phase_far[0] - phase_near[0]) % 360 == pytest.approx(360 * F * 0.001 / c, abs=0.05)


def test_table_round_trip_and_interpolation(tmp_path: Path) -> None:
    c = speed_of_sound(21.0)
    angles = np.linspace(-90, 90, 181)
    x = np.linspace(-0.03, 0.03, 61)
    table = TableTransducer(
        lobe_angle_deg=angles,
        lobe=PISTON.far_field(angles, F, c) / 50_000.0,
        near_z_m=0.0165,
        near_x_m=x,
        near=PISTON.near_field(x, 0.0165, F, c) / 50_000.0,
        near_tof_s=PISTON.arrival_s(x, 0.0165, c),
        freq_hz=F,
    )
    path = table.save(tmp_path / "truth.json")
    loaded = make_transducer({"kind": "table", "path": str(path), "sensitivity_uV": 50_000.0})
    a_t, _ = lobe_truth(loaded, angles, range_m=1.0, freq_hz=F, temperature_c=21.0)
    a_p, _ = lobe_truth(FRAUNHOFER, angles, range_m=1.0, freq_hz=F, temperature_c=21.0)
    np.testing.assert_allclose(a_t, a_p, atol=1e-6)
    w_t, w_p = (wave_truth(t, x, z_m=0.0165, freq_hz=F, temperature_c=21.0) for t in (loaded, PISTON))
    for got, want in zip(w_t, w_p, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)
    with pytest.raises(ValueError, match="z = 0.0165"):
        wave_truth(loaded, x, z_m=0.02, freq_hz=F, temperature_c=21.0)
    with pytest.raises(ValueError, match="40000"):
        lobe_truth(loaded, [0.0], range_m=1.0, freq_hz=41_000.0, temperature_c=21.0)
    with pytest.raises(ValueError, match="outside"):
        lobe_truth(loaded, [120.0], range_m=1.0, freq_hz=F, temperature_c=21.0)


def test_table_amp_arg_form(tmp_path: Path) -> None:
    path = tmp_path / "t.json"
    path.write_text('{"lobe": {"angle_deg": [-10, 10], "amp": [1, 3], "arg_deg": [0, 90]}}')
    amp, _ = lobe_truth(TableTransducer.load(path, sensitivity_uV=2.0), [0.0], range_m=1.0, freq_hz=F, temperature_c=20)
    assert amp[0] == pytest.approx(4.0)


def test_bad_spec() -> None:
    with pytest.raises(ValueError, match="piston"):
        make_transducer({"kind": "horn"})
