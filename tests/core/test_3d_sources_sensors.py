"""3-D sources and sensors: the disc transducer's cells and weights (area held per cell, rings from
a plain dict), snapshots as slices, the memory refusal before a 3-D run, and bad input named.

Area tolerance: each cell's covered area is counted on a 12 x 12 sub-grid per cell face; the
count of a rim cell errs by up to ~1/12 of its area with random sign, so the total over ~60-130
rim cells is within a few tenths of a cell: 0.2 % of a 314-cell disc."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges, Medium
from difflattice.lattice.grid import make_grid
from difflattice.solver import Sensors, simulate
from difflattice.solver.estimate import RunTooLargeError
from difflattice.solver.sources import disc_cells_3d, disc_transducer_3d, line_transducer

G = make_grid(frequency_hz=40e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(60, 50, 50), kind="3d")
H = G.dx_m
C = (30 * H, 25 * H, 24.5 * H)


def test_disc_cells_hold_the_disc_area():
    a = 10.0
    cells, w, lags, area = disc_cells_3d(G, C, (1, 0, 0), 2 * a * H)
    assert set(cells[:, 0]) == {30}  # a disc facing +x lies in one layer of cells
    assert w.sum() == pytest.approx(math.pi * a * a, rel=2e-3)
    r = np.hypot(cells[:, 1] - 25, cells[:, 2] - 24.5)
    assert np.allclose(w[r < a - 1], 1.0)  # cells well inside are fully covered
    assert np.all((w > 0) & (w <= 1 + 1e-12)) and np.all(lags == 0)
    # any orientation: the same area, spread over the layers the tilted plane crosses
    cells2, w2, _, _ = disc_cells_3d(G, C, (1.0, 0.6, -0.3), 2 * a * H)
    assert w2.sum() == pytest.approx(math.pi * a * a, rel=2e-3)
    assert len(set(cells2[:, 0])) > 3


def test_rings_from_a_fit_report_dict():
    edges = [[0.0, 4 * H], [4 * H, 8 * H]]
    cells, w, lags, area = disc_cells_3d(
        G, C, (0, 0, 1), rings={"ring_edges_m": edges, "weights": [1.0, 0.5], "lags_s": [0.0, 2e-6]}
    )
    assert w.sum() == pytest.approx(math.pi * (16 + 0.5 * 48), rel=3e-3)
    r = np.hypot(cells[:, 0] - 30, cells[:, 1] - 25)
    assert np.allclose(lags[r < 3], 0.0) and np.allclose(lags[(r > 5) & (r < 7)], 2e-6)
    assert np.all((lags >= 0) & (lags <= 2e-6 + 1e-18))
    # ring centres instead of edges: edges half-way, the outer one at the diameter
    c2, w2, _, _ = disc_cells_3d(G, C, (0, 0, 1), 16 * H, rings={"radii_m": [2 * H, 6 * H], "weights": [1.0, 0.5]})
    assert w2.sum() == pytest.approx(w.sum(), rel=1e-9)
    src = disc_transducer_3d(
        G, C, (1, 0, 0), diameter_m=16 * H, rings={"radii_m": [2 * H, 6 * H], "weights": [1.0, 0.5]}
    )
    assert src.cells.shape[1] == 3 and float(jnp.sum(src.weights)) == pytest.approx(w.sum(), rel=1e-6)


def test_bad_discs_are_refused():
    with pytest.raises(ValueError, match="does not fit"):
        disc_cells_3d(G, (2 * H, 25 * H, 25 * H), (0, 0, 1), 20 * H)
    with pytest.raises(ValueError, match="3-D grid"):
        disc_cells_3d(
            make_grid(frequency_hz=40e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(40, 40)),
            C[:2],
            (1, 0, 0),
            5 * H,
        )
    with pytest.raises(ValueError, match="axis"):
        disc_cells_3d(G, C, (0, 0, 0), 5 * H)
    with pytest.raises(ValueError, match="ring_edges_m"):
        disc_cells_3d(G, C, (1, 0, 0), rings={"weights": [1.0]})
    with pytest.raises(ValueError, match="2 rings but 3 weights"):
        disc_cells_3d(G, C, (1, 0, 0), rings={"ring_edges_m": [[0, H], [H, 2 * H]], "weights": [1, 1, 1]})
    with pytest.raises(ValueError, match="disc_transducer_3d"):
        line_transducer(G, C, n_cells=5)


def test_snapshots_are_slices_unless_asked():
    g = make_grid(frequency_hz=40e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(20, 18, 16), kind="3d")
    src = disc_transducer_3d(g, (10 * g.dx_m, 9 * g.dx_m, 8 * g.dx_m), (1, 0, 0), diameter_m=6 * g.dx_m)
    r = simulate(g, Medium(343.0, 1.2), src, Sensors(snapshot_every=10), n_steps=25, edges=Edges.all("rigid"))
    assert [s.shape for s in r.snapshots] == [(3, 18, 16), (3, 20, 16), (3, 20, 18)]
    assert r.chunk_steps == (10, 20, 25)
    sens = Sensors(snapshot_every=10, snapshot_slices=((2, 8),))
    r2 = simulate(g, Medium(343.0, 1.2), src, sens, n_steps=25, edges=Edges.all("rigid"))
    assert np.array_equal(np.asarray(r2.snapshots[0]), np.asarray(r.snapshots[2]))
    rv = simulate(
        g,
        Medium(343.0, 1.2),
        src,
        Sensors(snapshot_every=10, snapshot_slices="volume"),
        n_steps=25,
        edges=Edges.all("rigid"),
    )
    assert rv.snapshots.shape == (3, 20, 18, 16)
    assert np.array_equal(np.asarray(rv.snapshots[-1][:, :, 8]), np.asarray(r.snapshots[2][-1]))
    with pytest.raises(ValueError, match="outside the grid"):
        simulate(g, Medium(343.0, 1.2), src, Sensors(snapshot_every=10, snapshot_slices=((0, 40),)), n_steps=5)
    with pytest.raises(ValueError, match="3-D grids only"):
        Sensors(snapshot_slices=((0, 1),)).check_inside(
            make_grid(frequency_hz=40e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(20, 18))
        )
    with pytest.raises(ValueError, match="needs 3"):
        simulate(g, Medium(343.0, 1.2), src, Sensors(probes=[(1, 2)]), n_steps=5)


def test_run_that_does_not_fit_is_refused_before_it_starts():
    huge = make_grid(frequency_hz=40e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(4000, 4000, 4000), kind="3d")
    with pytest.raises(RunTooLargeError, match=r"4000 x 4000 x 4000.*estimated memory.*Fix"):
        simulate(huge, Medium(343.0, 1.2), (), Sensors(), n_steps=10)


def test_rings_from_a_disc_fit_report(tmp_path):
    import json

    from difflattice.solver.sources import rings_from_fit_report

    report = {
        "parameters": {
            "diameter_m": 14 * H,
            "weights": [1.0, 0.8, 0.3],
            "ring_fraction": [1.0, 1.0, 0.5],
            "lags_s": [0.0, 1e-6, 2e-6],
        },
        "model": {"dx_m": 3 * H, "n_cells": 3},
    }
    f = tmp_path / "fit_report.json"
    f.write_text(json.dumps(report))
    rings = rings_from_fit_report(f)
    assert np.allclose(rings["ring_edges_m"], [[0, 3 * H], [3 * H, 6 * H], [6 * H, 9 * H]])
    assert np.allclose(rings["weights"], [1.0, 0.8, 0.6])  # the profile: the rim fraction divided out
    src = disc_transducer_3d(G, C, (1, 0, 0), diameter_m=rings["diameter_m"], rings=rings)
    # the disc holds rings 0-1 fully and ring 2 out to r = 7 cells, with the profile weights
    expect = math.pi * (9 * 1.0 + 27 * 0.8 + (49 - 36) * 0.6)
    assert float(jnp.sum(src.weights)) == pytest.approx(expect, rel=3e-3)
