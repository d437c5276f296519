"""The environment end to end: a scene's `[air]` section sets the speed, density and absorption,
lowers the default courant to the absorbing limit, and is refused where it contradicts the
scene; without it a scene is the dry, lossless air it always was."""

import numpy as np
import pytest

from difflattice import air
from difflattice.lattice.coefficients import absorbing_courant
from difflattice.scene import SceneError, parse_scene


def _scene(**extra):
    data = {
        "grid": {"frequency_hz": 40e3, "cells_per_wavelength": 10.0, "size_m": [0.02, 0.015]},
        "edges": {"kind": "pml", "thickness_cells": 6},
        "transducers": [{"centre_m": [0.006, 0.0075], "n_cells": 6, "cycles": 2}],
        "run": {"n_steps": 40},
    }
    data.update(extra)
    return parse_scene(data, "<test>")


def test_air_section_sets_speed_density_absorption_and_courant():
    sc = _scene(air={"temperature_c": 30.0, "humidity_pct": 80.0, "pressure_pa": 95000.0})
    built = sc.build()
    c = air.speed_of_sound_m_s(30.0, 80.0, 95000.0)
    assert built.medium.sound_speed_m_s == pytest.approx(c, rel=1e-12)
    assert built.medium.density_kg_m3 == pytest.approx(air.density_kg_m3(30.0, 95000.0, 80.0), rel=1e-12)
    a = built.medium.air
    assert (a.temperature_c, a.humidity_pct, a.pressure_pa) == (30.0, 80.0, 95000.0)
    assert built.grid.courant == pytest.approx(absorbing_courant(40e3, 10.0, c, a), rel=1e-12)
    assert built.grid.courant < 0.707
    line = sc.describe_air()
    assert "30 deg C, 80 % RH, 95000 Pa" in line and "dB/m at 40 kHz" in line


def test_without_air_section_the_scene_is_dry_and_lossless():
    sc = _scene(medium={"temperature_c": 25.0})
    built = sc.build()
    assert built.medium.air is None and built.grid.courant == 0.707
    assert built.medium.sound_speed_m_s == pytest.approx(air.speed_of_sound_m_s(25.0))
    assert "lossless" in sc.describe_air()
    lossless = _scene(air={"humidity_pct": 90.0, "absorption": False}).build()
    assert lossless.medium.air is None
    assert lossless.medium.sound_speed_m_s == pytest.approx(air.speed_of_sound_m_s(20.0, 90.0))


def test_air_section_refusals():
    with pytest.raises(SceneError, match="medium.temperature_c"):
        _scene(air={"temperature_c": 20.0}, medium={"temperature_c": 25.0}).build()
    with pytest.raises(SceneError, match="background"):
        _scene(air={}, medium={"background": "water"}).build()
    with pytest.raises(SceneError, match="humidity_pct"):
        _scene(air={"humidity_pct": 120.0})
    with pytest.raises(SceneError, match="courant"):
        _scene(air={}, grid={"frequency_hz": 40e3, "size_m": [0.02, 0.015], "courant": 0.707}).build()


def test_emulator_ground_truth_uses_the_same_air():
    """The rig emulator's truths with a humidity: humid speed of sound (time of flight) and ISO
    absorption over the range; without one, the old dry, lossless truth."""
    from difflattice.capture.groundtruth import Piston, lobe_truth, wave_truth

    tr = Piston(0.0384, lobe="fraunhofer")
    kw = dict(range_m=2.5, freq_hz=40e3, temperature_c=20.0)
    dry, tof_dry = lobe_truth(tr, [0.0], **kw)
    wet, tof_wet = lobe_truth(tr, [0.0], humidity_pct=50.0, **kw)
    loss_db = 20 * np.log10(dry[0] / wet[0])
    assert loss_db == pytest.approx(2.5 * air.absorption_db_per_m(40e3, 20.0, 50.0), rel=1e-9)
    assert tof_wet == pytest.approx(2.5 / air.speed_of_sound_m_s(20.0, 50.0), rel=1e-12)
    assert tof_dry == pytest.approx(2.5 / air.speed_of_sound_m_s(20.0), rel=1e-12)
    _, _, a_dry = wave_truth(tr, [0.0], z_m=0.3, freq_hz=40e3, temperature_c=20.0)
    _, _, a_wet = wave_truth(tr, [0.0], z_m=0.3, freq_hz=40e3, temperature_c=20.0, humidity_pct=50.0)
    # the humid speed shifts the near field slightly too: the loss alone within 2 %
    assert 20 * np.log10(a_dry[0] / a_wet[0]) == pytest.approx(0.3 * air.absorption_db_per_m(40e3, 20, 50), rel=2e-2)


def test_simulate_prints_the_air(tmp_path, capsys):
    from difflattice.cli import main

    scene = tmp_path / "scene.toml"
    scene.write_text(
        "[grid]\nfrequency_hz = 40000.0\ncells_per_wavelength = 8.0\nsize_m = [0.03, 0.02]\n\n"
        "[air]\ntemperature_c = 25.0\nhumidity_pct = 60.0\n\n"
        '[edges]\nkind = "pml"\nthickness_cells = 6\n\n'
        "[[transducers]]\ncentre_m = [0.01, 0.01]\nn_cells = 4\ncycles = 1\n\n[run]\nn_steps = 20\n"
    )
    rc = main(["simulate", str(scene), "--out", str(tmp_path / "out"), "--no-frames", "--no-animation"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "air: 25 deg C, 60 % RH, 101325 Pa" in out and "dB/m at 40 kHz (ISO 9613-1)" in out
