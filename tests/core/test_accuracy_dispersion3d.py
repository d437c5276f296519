"""`difflattice accuracy --case dispersion3d`: the simulated 3-D phase speeds reproduce each
stencil's dispersion relation (within 0.1 percentage points: PML reflection and the far-field
corrections of the point source's phase), the isotropic stencil is isotropic to 0.2 points and
at 6 cells/wavelength has under half the 7-point stencil's worst error, the wide stencil and the
default scheme are within 1 % in every direction (issue 29's goal); the CLI writes the rows."""

import json

from difflattice.apps import accuracy_dispersion3d as acc
from difflattice.cli import main


def test_simulated_phase_speeds_match_the_dispersion_relations(tmp_path):
    rc = main(["accuracy", "--case", "dispersion3d", "--cells-per-wavelength", "6", "--out", str(tmp_path)])
    assert rc == 0
    doc = json.loads((tmp_path / acc.FILE).read_text())
    rows = doc["rows"]
    assert {(r["scheme"], r["direction"]) for r in rows} == {(s, d) for s in acc.SCHEMES for d in acc.DIRECTIONS}
    for r in rows:
        assert abs(r["phase_speed_error"] - r["phase_speed_error_formula"]) < 1e-3, r
    iso = [r["phase_speed_error"] for r in rows if r["scheme"] == "isotropic"]
    std = [r["phase_speed_error"] for r in rows if r["scheme"] == "standard"]
    assert max(iso) - min(iso) < 2e-3
    assert max(map(abs, iso)) < 0.5 * max(map(abs, std))
    assert doc["worst_abs_error_by_cpw"]["isotropic"]["6"] == max(map(abs, iso))
    wide = [r["phase_speed_error"] for r in rows if r["scheme"] == "wide"]
    assert max(map(abs, wide)) < 0.01 and max(map(abs, wide)) < 0.25 * max(map(abs, iso))
    assert doc["worst_abs_error_by_cpw"][doc["default_scheme"]]["6"] <= 0.01
