"""Work-precision with an obstacle: a point source in front of a flat rigid or soft wall against
the image-source solution (continuum 2-D Green's function), with tolerances from the lattice's
dispersion relation."""

import math

import numpy as np
import pytest

from difflattice.apps.accuracy_wall import (
    _delay_steps,
    edge_sweep,
    image_source_reference,
    reference_time_series,
    run_wall,
    wall_layout,
)


@pytest.mark.parametrize("wall", ["rigid", "soft"])
def test_wall_echo_matches_image_source_within_dispersion(wall):
    r = run_wall(10.0, "float64", wall=wall, repeats=0)
    # 1. echo arrival at the probe beside the source: the lattice echo is late by the dispersion
    #    relation's delay along the image path; a burst's cross-correlation arrival lies between
    #    the phase delay (carrier) and the group delay (envelope) predicted for that path
    assert r["predicted_echo_delay_periods"] > 0
    assert (
        r["predicted_echo_delay_periods"] <= r["echo_arrival_error_periods"] <= r["predicted_echo_group_delay_periods"]
    )
    # 2. the echo's size is right (R = +1 / -1 at the face): the two signals' sampled peaks can
    #    differ by the sampling of a peak, cos(pi / steps per period), and no more
    spp = 10.0 / 0.707
    assert abs(r["echo_amplitude_db_error"]) < -20 * math.log10(math.cos(math.pi / spp))
    # 3. the phasor field on the receiver line: most of its error is the dispersion relation's
    #    (the same image-source field with the lattice wavenumber along each path); what it does
    #    not explain is smaller than what it does. A wall face misplaced by half a cell, a wrong
    #    reflection sign or a wrong source normalisation would each break this.
    assert r["field_rel_l2_error_after_dispersion"] < r["field_rel_l2_error_predicted"]
    assert r["field_rel_l2_error"] < 2 * r["field_rel_l2_error_predicted"]


def test_wall_face_is_on_a_cell_face_at_every_resolution():
    for ppw in (6, 7.3, 10, 14, 20, 30):
        lay = wall_layout(ppw)
        i_s = lay["source"][0]
        assert lay["face_x_cells"] == lay["wall_cell"] - 0.5
        # image mirrored about the face, half-integer distances
        assert lay["image"][0] - lay["face_x_cells"] == lay["face_x_cells"] - i_s
        assert (lay["face_x_cells"] - i_s) % 1 == 0.5
    with pytest.raises(ValueError, match="needs >= 4"):
        wall_layout(3)


def test_reference_time_series_is_the_phasor_reference():
    """The FFT time-domain reference and the phasor formula are the same solution: the DFT at the
    drive frequency of the former equals the latter (checks the one-step source offset)."""
    c, spp = 0.707, 20 / 0.707
    omega = 2 * math.pi / spp
    n = np.arange(1, 2000)
    v = np.where(n * omega / (2 * math.pi) <= 4, np.sin(omega * n) * np.sin(omega * n / 8) ** 2, 0.0)
    p = reference_time_series(v, c, 30.0, 90.0, 1.0, len(n))
    dft = np.sum(p * np.exp(1j * omega * n))
    ref = np.sum(v * np.exp(1j * omega * n)) * image_source_reference(omega, c, 30.0, 90.0, 1.0)
    assert abs(dft - ref) < 1e-3 * abs(ref)


def test_delay_estimator():
    t = np.arange(400)
    sig = lambda t0: np.exp(-(((t - t0) / 20.0) ** 2)) * np.cos(2 * math.pi * (t - t0) / 28.3)
    assert _delay_steps(sig(200.37), sig(200.0)) == pytest.approx(0.37, abs=0.02)
    assert _delay_steps(sig(199.0), sig(200.0)) == pytest.approx(-1.0, abs=0.02)


def test_pml_reflects_less_than_mur_and_rigid():
    rows = edge_sweep((8,), (10,), "float32", repeats=0, kinds=("pml", "mur", "rigid"))["rows"]
    by = {r["edge"]: r for r in rows}
    # a rigid window edge reflects the whole wave (the difference is at least the incident wave)
    assert by["rigid"]["reflection_db_axis"] > -1
    # first-order Mur: the probe (3 wavelengths out on the axis, 1 from the x_hi edge) gets the
    # normal reflection from x_hi (image 5 wavelengths away) and, within the record, the two
    # oblique ones from y_lo and y_hi (images sqrt(3^2 + 8^2) away, incidence atan(3/8)). Bound each
    # by the lattice's normal-incidence |R| (analytic.mur_reflection) plus, when oblique, the
    # continuum first-order Mur (1 - cos)/(1 + cos), times the 2-D spreading sqrt(r_in / r_out).
    from difflattice.observe.analytic import mur_reflection

    r0 = abs(mur_reflection(2 * math.pi * 0.707 / 8, 0.707))
    th = math.atan2(3, 8)
    r_obl = r0 + (1 - math.cos(th)) / (1 + math.cos(th))
    bound = r0 * math.sqrt(3 / 5) + 2 * r_obl * math.sqrt(3 / math.hypot(3, 8))
    assert by["mur"]["reflection_db_axis"] < 20 * math.log10(bound)
    # the PML (10 cells) is far better than both
    assert by["pml"]["reflection_db_axis"] < by["mur"]["reflection_db_axis"] - 20


def test_cli_accuracy_cases_write_json_table_plot(tmp_path):
    import json

    from difflattice.cli import main

    out = tmp_path / "acc"
    assert (
        main(
            [
                "accuracy",
                "--case",
                "edges",
                "--cells-per-wavelength",
                "6",
                "--thickness-cells",
                "4",
                "--dtype",
                "float32",
                "--repeats",
                "0",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    rows = json.loads((out / "accuracy_edges.json").read_text())["rows"]
    assert {r["edge"] for r in rows} == {"pml", "sponge", "mur", "rigid", "reference (large window)"}
    assert (out / "accuracy_edges_table.md").is_file() and (out / "accuracy_edges.png").is_file()
    assert main(["accuracy", "--case", "wall", "--cells-per-wavelength", "3", "--out", str(out)]) == 2
