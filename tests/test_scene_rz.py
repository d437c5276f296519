"""Scene files choose the lattice: an axisymmetric (rz) scene with a baffled disc runs end to end
and its lobe is the circular piston's; mismatched keys are refused naming the fix."""

import copy
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.special import j1

from difflattice.apps.scene_run import run_scene
from difflattice.scene import SceneError, parse_scene

SCENE = Path(__file__).resolve().parents[1] / "data" / "scenes" / "disc_piston_rz.toml"


def _data(**grid):
    d = tomllib.loads(SCENE.read_text())
    d["grid"].update(grid)
    return d


def _piston_first_null_and_sidelobe(ka: float) -> tuple[float, float]:
    x0 = brentq(j1, 3.0, 4.5)  # first zero of J1: 3.8317
    null = math.degrees(math.asin(x0 / ka))
    x = np.linspace(x0, 7.0, 20001)
    d = np.abs(2 * j1(x) / x)
    return null, 20 * math.log10(d.max())


def test_rz_scene_gives_the_circular_piston_lobe():
    """10 cells/lambda, a 38.4 mm baffled disc at 50 kHz, lobe at 1 m sampled every 0.1 deg.
    Tolerances: the first null within 0.15 deg (0.05 deg sampling + the lattice's far-field error,
    measured 0.0003 deg at 20 cells/lambda, growing as (kh)^2: x4 at 10) and the side lobe within
    0.5 dB of 2 J1(x)/x's -17.57 dB (the burst is 5 cycles: its spectrum is sampled at the drive
    frequency, as a CW lobe)."""
    d = _data(cells_per_wavelength=10.0, size_m=[0.03, 0.03])
    d["farfield"]["angles_deg"] = [0.0, 30.0, 0.1]
    d["sensors"] = {"p_max": True}
    d["edges"]["thickness_cells"] = 12
    scene = parse_scene(d, "rz-test")
    sr = run_scene(scene, progress=False)
    ff = sr.summary["farfield"]
    c = sr.grid.c_max_m_s
    ka = 2 * math.pi * 50e3 / c * 0.0192
    null, sll = _piston_first_null_and_sidelobe(ka)
    assert abs(ff["first_null_deg"] - null) <= 0.15, (ff["first_null_deg"], null)
    assert abs(ff["first_sidelobe_db"] - sll) <= 0.5, (ff["first_sidelobe_db"], sll)
    assert sr.summary["grid"]["kind"] == "rz"


@pytest.mark.parametrize(
    "edit, match",
    [
        (
            lambda d: (d["transducers"][0].update(type="line"), d["transducers"][0].pop("baffle")),
            r"transducers\[0\]\.type",
        ),
        (lambda d: d["transducers"][0].update(type="line"), r"transducers\[0\]\.baffle\] is a key of disc transducers"),
        (lambda d: d["edges"].update(x_lo="pml"), r"edges\.x_lo"),
        (lambda d: d["transducers"][0].update(centre_m=[0.0, 0.01]), r"centre_m"),
        (lambda d: d["grid"].update(kind="3x"), r"grid\.kind"),
        (lambda d: (d["grid"].update(kind="2d"), d["edges"].pop("z_lo")), r"transducers\[0\]\.type"),
        (lambda d: d["edges"].update(z_lo="pml"), r"baffle"),
    ],
)
def test_rz_scene_mismatches_are_refused(edit, match):
    d = copy.deepcopy(_data())
    edit(d)
    with pytest.raises(SceneError, match=match):
        parse_scene(d, "bad").build()


def test_scene_file_chooses_the_isotropic_stencil():
    """`[grid] stencil = "isotropic"` (the default on rz grids): the built lattice uses it and
    accepts a courant up to sqrt(3)/2 in air; above it, or on a 3-D grid, the key is named in the
    refusal; `stencil = "standard"` chooses the paper's."""
    from difflattice.lattice.coefficients import build_lattice

    built = parse_scene(_data(stencil="isotropic", courant=0.85), "iso").build()
    assert built.grid.stencil == "isotropic"
    assert build_lattice(built.grid, built.medium, built.edges).stencil == "isotropic"
    default = parse_scene(_data(), "default").build()  # rz scenes in air default to the isotropic stencil
    assert build_lattice(default.grid, default.medium, default.edges).stencil == "isotropic"
    housed = _data()  # a bare disc (a rigid housing: not uniform faces) keeps the standard one
    housed["transducers"][0].update(baffle="none", centre_m=[0.02, 0.0])
    housed["edges"]["z_lo"] = "pml"
    assert parse_scene(housed, "housed").build().grid.stencil == "standard"
    std = parse_scene(_data(stencil="standard"), "std").build()
    assert build_lattice(std.grid, std.medium, std.edges).stencil == "standard"
    with pytest.raises(SceneError, match=r"grid\.courant.*sqrt\(3\)/2"):
        parse_scene(_data(stencil="isotropic", courant=0.87), "iso").build()
    with pytest.raises(SceneError, match=r"grid\.stencil"):
        parse_scene(_data(stencil="nine"), "iso").build()
