"""Work-precision sweep: errors against the analytic continuous line fall with resolution."""

from difflattice.apps.accuracy import sweep


def test_errors_fall_with_resolution():
    rows = sweep((10, 20), ("float64",))["rows"]
    by = {(r["cells_per_wavelength"], r["farfield_dispersion"]): r for r in rows}
    c10, c20 = by[(10, "continuum")], by[(20, "continuum")]
    # second-order scheme: arrival (phase) error falls ~4x per doubling; allow 2.5x
    assert c20["arrival_error_periods"] < c10["arrival_error_periods"] / 2.5
    assert c20["lobe_db_max_error"] < c10["lobe_db_max_error"]
    # propagating the far field with the continuum k beats the lattice's own dispersion
    assert c20["lobe_db_max_error"] < by[(20, "lattice")]["lobe_db_max_error"]
    assert c20["lobe_db_max_error"] < 0.2
