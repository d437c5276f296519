"""The environment end to end: a scene's `[air]` section sets the speed, density and absorption,
lowers the default courant to the absorbing limit, and is refused where it contradicts the
scene; without it a scene is the dry, lossless air it always was."""

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
