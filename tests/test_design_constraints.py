"""A maker's constraints (maximum length and mouth, minimum wall, the transducer's can as the
throat, no self-intersection, printable overhang): bounds and penalties in the optimiser, measured
again on the exported part, and reported active / inactive."""

import math

import numpy as np
import pytest
import trimesh

from difflattice.design.constraints import (
    MakerConstraints,
    _min_wall,
    limits_for,
    max_wall_angle_deg,
    part_report,
    penalty,
)
from difflattice.design.parts import check_watertight, part_mesh, read_profile, wall_outlines
from difflattice.design.presets import FIG09_CONE, HORN_LIMITS, PAPER_FACE_M
from difflattice.design.problem import horn_design
from difflattice.design.shapes import HornParams


def test_cli_design_horn_writes_an_stl_that_meets_the_declared_constraints(tmp_path, capsys):
    """`difflattice design horn` with a can, a length and a mouth limit (coarse, one step): the STL
    read back from disk is watertight, its extents are within the declared limits (measured on the
    vertices, not the parameters), the throat holds the can, and the console and report name each
    constraint with its state. The 120 mm length moves the 125 mm start onto its bound: active."""
    from difflattice.cli import main

    out = tmp_path / "horn"
    args = ["design", "horn", "--out", str(out), "--cells-per-wavelength", "4", "--steps", "1"]
    args += ["--no-gradient-check", "--can-diameter-mm", "38", "--can-clearance-mm", "0.2"]
    args += ["--max-length-mm", "120", "--max-mouth-mm", "80", "--min-wall-mm", "2.5"]
    assert main(args) == 0
    console = capsys.readouterr().out
    assert "constraints: length" in console and "(active)" in console and "all satisfied" in console
    assert "converged:" in console and "expected phase error" in console
    mesh = trimesh.load(out / "optimised_horn.stl")
    assert check_watertight(mesh)["watertight"]
    b = np.asarray(mesh.bounds)
    assert b[1, 0] - b[0, 0] <= 120.0 + 1e-3  # mm, float32 STL
    assert b[1, 1] - b[0, 1] <= 80.0 + 1e-3
    outlines = read_profile(out / "optimised_horn_profile.csv")
    from shapely.geometry import Polygon

    up, lo = (Polygon(o) for o in outlines)
    assert up.distance(lo) >= 0.0384 - 1e-5  # the bore: can + 2 x clearance
    assert min(_min_wall(o) for o in outlines) >= 0.0025 - 1e-5
    report = (out / "report.md").read_text()
    assert "| length_m | <= 120.00 mm |" in report and "| throat_bore_m | >= 38.00 mm |" in report


def test_min_wall_and_overhang_measured_on_a_revolved_cone():
    """On the Fig. 9 cone revolved: the thinnest wall is the 3 mm wall, and, printed axis up, the
    outer face's overhang from the vertical is the cone's half-angle (5 deg), as the N planar
    facets of the revolved cone have it: atan(tan 5 deg cos(pi / N)). A neck in an outline is found as the thinner wall."""
    pb = horn_design(
        limits=HORN_LIMITS, face_m=PAPER_FACE_M, cells_per_wavelength=6.0, wall="rigid", lattice="rz", reference=False
    )
    c = MakerConstraints(min_wall_m=0.002, max_overhang_deg=45.0)
    rows = {
        r["constraint"]: r
        for r in part_report(pb, FIG09_CONE, part_mesh(pb, FIG09_CONE), wall_outlines(pb, FIG09_CONE), c)
    }
    assert rows["min_wall_m"]["part"] == pytest.approx(0.003, rel=1e-4)
    n = 128  # the facets between revolved vertices lean by cos(pi / N) less than the cone
    want = math.degrees(math.atan(math.tan(math.radians(5.0)) * math.cos(math.pi / n)))
    assert rows["overhang_deg"]["part"] == pytest.approx(want, abs=1e-6)
    assert all(r["satisfied"] for r in rows.values())
    # a 4 mm bar with a notch 1.5 mm deep: the neck under the notch's tip is 2.5 mm
    neck = np.array([[0, 0], [0.01, 0], [0.0115, 0.0015], [0.013, 0], [0.02, 0], [0.02, 0.004], [0, 0.004]])
    assert _min_wall(neck) == pytest.approx(0.0025, abs=1e-6)


def test_limits_from_constraints_and_their_refusals():
    c = MakerConstraints(
        max_length_m=0.120, max_mouth_diameter_m=0.080, min_wall_m=0.0025, can_diameter_m=0.038, can_clearance_m=0.0002
    )
    lim = limits_for(c, HORN_LIMITS)
    assert lim.length_max_m == pytest.approx(0.120 - 1.5 * HORN_LIMITS.wall_max_m)
    assert lim.mouth_max_m == pytest.approx(0.080 - 2 * HORN_LIMITS.wall_max_m)
    assert lim.throat_min_m == lim.throat_max_m == pytest.approx(0.0384)
    assert lim.wall_min_m == 0.0025
    with pytest.raises(ValueError, match="min_wall_m"):
        limits_for(MakerConstraints(min_wall_m=0.01), HORN_LIMITS)
    with pytest.raises(ValueError, match="no admissible design: throat_min_m"):
        limits_for(MakerConstraints(can_diameter_m=0.07, max_mouth_diameter_m=0.07), HORN_LIMITS)
    with pytest.raises(ValueError, match="max_length_m"):
        MakerConstraints(max_length_m=-1.0)
    with pytest.raises(ValueError, match="max_overhang_deg"):
        MakerConstraints(max_overhang_deg=120.0)


def test_overhang_penalty_is_zero_inside_and_grows_outside():
    """The rz horn's penalty: its steepest wall angle (the cone's atan((mouth - throat) / 2L)) over
    the limit, squared; zero below it, and its gradient pushes the mouth in."""
    import jax

    p = HornParams(0.04, 0.12, 0.05, 0.003, 0.0)
    angle = math.degrees(math.atan(0.04 / 0.05))
    assert float(max_wall_angle_deg(p)) == pytest.approx(angle, rel=1e-6)
    c = MakerConstraints(max_overhang_deg=30.0)
    assert float(penalty(c, p, ring_metric=True)) == pytest.approx((angle - 30.0) ** 2, rel=1e-6)
    assert float(penalty(MakerConstraints(max_overhang_deg=45.0), p, ring_metric=True)) == 0.0
    assert float(penalty(c, p, ring_metric=False)) == 0.0  # a 2-D part prints standing: no overhang
    g = jax.grad(lambda m: penalty(c, HornParams(0.04, m, 0.05, 0.003, 0.0), ring_metric=True))(0.12)
    assert float(g) > 0
