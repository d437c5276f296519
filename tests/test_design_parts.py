"""Designs as parts: the walls of a horn or reflector as watertight STL in millimetres, checked
against exact volumes (Pappus' theorem for the revolved N-gon, area x depth for an extrusion),
inside the declared limits, and written beside the design report."""

import math

import numpy as np
import pytest
import trimesh
from shapely.geometry import Polygon

from difflattice.design.parts import check_watertight, part_mesh, wall_outlines, write_parts
from difflattice.design.presets import FIG09_CONE, FIG10_PARABOLA, HORN_LIMITS, PAPER_FACE_M, REFLECTOR_LIMITS
from difflattice.design.problem import horn_design, reflector_design


def _horn(lattice):
    return horn_design(
        limits=HORN_LIMITS,
        face_m=PAPER_FACE_M,
        cells_per_wavelength=6.0,
        wall="rigid",
        lattice=lattice,
        reference=False,
    )


def _reflector(lattice):
    return reflector_design(
        limits=REFLECTOR_LIMITS,
        face_m=PAPER_FACE_M,
        cells_per_wavelength=4.0,
        wall="rigid",
        lattice=lattice,
        reference=False,
    )


@pytest.mark.parametrize("which", ["horn", "reflector"])
def test_revolved_parts_are_watertight_with_the_exact_volume(which):
    """A closed (z, r) outline revolved in N straight segments: each of the N wedges has volume
    sin(2 pi / N) * integral(r dA) (its Jacobian is r sin(dphi)), so V = N sin(2 pi / N) A r_c
    exactly (A the outline's area, r_c its centroid radius). Tolerance: float64 round-off."""
    pb, params = (_horn("rz"), FIG09_CONE) if which == "horn" else (_reflector("rz"), FIG10_PARABOLA)
    n = 96
    mesh = part_mesh(pb, params, segments=n)
    checks = check_watertight(mesh)
    assert checks["watertight"], checks
    assert mesh.is_watertight and mesh.is_winding_consistent  # trimesh's own checks agree
    want = 0.0
    for o in wall_outlines(pb, params):
        poly = Polygon(o * 1e3)
        want += n * math.sin(2 * math.pi / n) * poly.area * poly.centroid.y
    assert checks["volume"] == pytest.approx(want, rel=1e-9)


def test_plane_parts_are_extrusions_with_the_exact_volume():
    pb = _horn("2d")
    depth = 0.05
    mesh = part_mesh(pb, FIG09_CONE, depth_m=depth)
    checks = check_watertight(mesh)
    assert checks["watertight"], checks
    area_mm2 = sum(Polygon(o * 1e3).area for o in wall_outlines(pb, FIG09_CONE))
    assert checks["volume"] == pytest.approx(area_mm2 * depth * 1e3, rel=1e-9)
    assert np.asarray(mesh.bounds)[:, 2] == pytest.approx([-25.0, 25.0])
    with pytest.raises(ValueError, match="depth must be > 0"):
        part_mesh(pb, FIG09_CONE, depth_m=-1.0)


def test_a_revolved_horn_stays_inside_its_declared_limits():
    """The horn's outer radius is at most mouth / 2 + wall (the inner face plus one wall), within
    the limits' mouth_max / 2 + wall_max; its axial extent is its length plus the wall's round ends."""
    pb = _horn("rz")
    v = np.asarray(part_mesh(pb, FIG09_CONE).vertices)
    r_max = np.hypot(v[:, 0], v[:, 1]).max()
    p = FIG09_CONE
    assert r_max <= 1e3 * (float(p.mouth_m) / 2 + float(p.wall_m)) * (1 + 1e-9)
    assert r_max <= 1e3 * (HORN_LIMITS.mouth_max_m / 2 + HORN_LIMITS.wall_max_m)
    r_min = np.hypot(v[:, 0], v[:, 1]).min()
    assert r_min >= 1e3 * float(p.throat_m) / 2 * (1 - 1e-9) - 1e3 * float(p.wall_m) / 2  # the round cap at the throat
    z_extent = v[:, 2].max() - v[:, 2].min()
    assert z_extent <= 1e3 * (float(p.length_m) + float(p.wall_m)) * (1 + 1e-6)


def test_write_parts_writes_stl_and_profile_that_load_back(tmp_path):
    pb = _horn("rz")
    out = write_parts(pb, FIG09_CONE, tmp_path, name="cone")
    assert out["watertight"]
    back = trimesh.load(out["stl"])
    assert back.is_watertight and back.volume == pytest.approx(out["volume"], rel=1e-5)  # STL stores float32
    rows = (tmp_path / "cone_profile.csv").read_text().splitlines()
    assert rows[0] == "wall,z_mm,r_mm" and len(rows) > 10


def test_an_exported_part_read_back_from_its_stl_gives_the_designs_beam(tmp_path):
    """Closed loop at the design's resolution (8 cells per wavelength, the `difflattice design
    horn` set-up): the Fig. 9 cone exported as an STL, read back into the exported scene as a mesh
    object (its section at z = 0) and simulated: the -6 dB width within 0.5 deg and the on-axis
    gain (re the bare transducer, both through the scene runner) within 0.3 dB of the design's."""
    import tomllib

    from difflattice.apps.scene_run import run_scene
    from difflattice.design import pattern_metrics
    from difflattice.design.export import scene_toml
    from difflattice.observe.farfield import far_field
    from difflattice.scene import parse_scene

    pb = horn_design(limits=HORN_LIMITS, face_m=PAPER_FACE_M, cells_per_wavelength=8.0, wall="soft", cycles=5.0)
    m = pattern_metrics(pb.pattern(FIG09_CONE), pb.angles_deg, reference_on_axis=pb.reference_on_axis)
    write_parts(pb, FIG09_CONE, tmp_path, name="cone")
    d = tomllib.loads(scene_toml(pb, FIG09_CONE))
    d["sensors"] = {"p_max": False}
    on_axis = {}
    for label, objects in (("mesh", [{"shape": "mesh", "file": "cone.stl", "material": "soft"}]), ("bare", [])):
        d["objects"] = objects
        scene = parse_scene(d, str(tmp_path / f"{label}.toml"))
        sr = run_scene(scene, progress=False)
        if label == "mesh":
            width = sr.summary["farfield"]["width_6db_deg"]
        built = scene.build()
        centre = tuple(np.asarray(built.sources[0].cells_array).mean(0))
        p0 = far_field(sr.result.phasors, built.contour, sr.grid, [0.0], 1.0, centre, dispersion="continuum")
        on_axis[label] = float(np.abs(p0[0]))
    gain_db = 20 * math.log10(on_axis["mesh"] / on_axis["bare"])
    assert abs(width - float(m["beam_width_deg"])) <= 0.5, (width, float(m["beam_width_deg"]))
    assert abs(gain_db - float(m["on_axis_db"])) <= 0.3, (gain_db, float(m["on_axis_db"]))
