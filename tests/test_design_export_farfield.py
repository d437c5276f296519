"""One far-field surface rule for scenes: the surface encloses the transducer and every object
(or the scene is refused with the reason), so an exported horn design simulated as a scene file
gives the beam its design report gives."""

import tomllib
from pathlib import Path

import numpy as np
import pytest

from difflattice.apps.scene_run import run_scene
from difflattice.design import pattern_metrics
from difflattice.design.export import write_scene
from difflattice.design.presets import FIG09_CONE, HORN_LIMITS, PAPER_FACE_M
from difflattice.design.problem import horn_design
from difflattice.design.study import trust_estimate
from difflattice.scene import SceneError, load_scene, parse_scene

ROOT = Path(__file__).resolve().parents[1]


def test_an_exported_horn_simulates_to_the_designs_beam(tmp_path):
    """The Fig. 9 cone as `difflattice design horn` sets it up (8 cells per wavelength, soft walls):
    the design's -6 dB width at 1 m and the exported scene's agree within 0.3 deg (the issue's
    bound; the two transforms integrate the same lattice field over different enclosing surfaces,
    the design's around its limits, the scene's around the walls it has)."""
    pb = horn_design(limits=HORN_LIMITS, face_m=PAPER_FACE_M, cells_per_wavelength=8.0, wall="soft", cycles=5.0)
    design_width = float(pattern_metrics(pb.pattern(FIG09_CONE), pb.angles_deg)["beam_width_deg"])
    path = write_scene(pb, FIG09_CONE, tmp_path / "cone.toml")
    scene = load_scene(path)
    built = scene.build()
    c = built.contour
    walls = np.argwhere(np.asarray(built.medium.soft) > 0)
    assert walls.size, "the exported walls are rasterised"
    assert c.ix0 < walls[:, 0].min() and walls[:, 0].max() < c.ix1, "the surface encloses the walls along x"
    assert c.iy0 < walls[:, 1].min() and walls[:, 1].max() < c.iy1, "the surface encloses the walls along y"
    sr = run_scene(scene, progress=False)
    width = sr.summary["farfield"]["width_6db_deg"]
    assert abs(width - design_width) <= 0.3, (width, design_width)
    # the design's trust estimate is the scene runner's for the same grid and run length, and at
    # 8 cells per wavelength it is above the threshold (the design says so)
    trust = trust_estimate(pb)
    assert trust["expected_phase_error_periods"] == pytest.approx(
        sr.summary["accuracy"]["expected_phase_error_periods"], rel=1e-12
    )
    assert not trust["trustworthy"] and trust["expected_phase_error_periods"] > trust["threshold_periods"]


def test_a_surface_that_cannot_enclose_the_objects_is_refused():
    d = tomllib.loads((ROOT / "data" / "scenes" / "fig09_cone_horn.toml").read_text())
    d["farfield"] = {"range_m": 1.0, "angles_deg": [-90.0, 90.0, 1.0], "gap_cells": 60}
    with pytest.raises(SceneError, match=r"farfield\.gap_cells.*encloses the transducer and the 2 object\(s\)"):
        parse_scene(d, "horn-ff").build()
    d["farfield"]["gap_cells"] = 4  # the walls plus 4 cells fit inside the PML
    assert parse_scene(d, "horn-ff").build().contour is not None
