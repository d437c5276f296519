"""The paper's gallery: every scene file renders (coarsely) into the expected files and images, and
field images show what they should (a plane wave has the right number of bright bands)."""

import json
import os

os.environ.setdefault("MPLBACKEND", "Agg")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.image as mpimg  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from difflattice import plots  # noqa: E402
from difflattice.apps.gallery import (  # noqa: E402
    COMPARISONS,
    load_scaled_scene,
    render_gallery,
    scene_description,
    scene_files,
)
from difflattice.scene import load_scene, parse_scene  # noqa: E402

SCALE = 0.25  # 5 cells per wavelength: a coarse look, about 4 s per scene on 2 cores

EXPECTED = {
    "fig02_polaroid",
    "fig03_nearfield",
    "fig04a_wall_speed_zero",
    "fig04b_wall_rigid",
    "fig05_gap",
    "fig06_concave_corner",
    "fig07a_convex_edge_sharp",
    "fig07b_convex_edge_rounded",
    "fig08_stepped_wall",
    "fig09_cone_horn",
    "fig09_no_horn",
    "fig10_parabolic_reflector",
}


@pytest.fixture(scope="module")
def gallery(tmp_path_factory):
    out = tmp_path_factory.mktemp("gallery")
    entries = render_gallery(out, scale=SCALE, progress=False)
    return out, entries


def test_scene_files_are_documented_and_valid():
    files = scene_files()
    assert EXPECTED <= {f.stem for f in files}
    for f in files:
        desc = scene_description(f)
        assert desc and desc[0].startswith("Paper Fig."), f"{f.name}: must start with a comment naming the figure"
        s = load_scene(f)
        assert s.grid.frequency_hz == 50e3 and s.grid.cells_per_wavelength == 20
        assert s.medium.air_temperature_c == 20
        assert s.edges.kind == "pml"
        if f.stem[:5] in ("fig06", "fig07", "fig08", "fig09", "fig10"):
            assert s.medium.boundary_model == "speed_zero"
            assert all(t.cycles == (10 if f.stem.startswith("fig10") else 5) for t in s.transducers)
    assert load_scene(scene_files()[0].parent / "fig04b_wall_rigid.toml").objects[0].material_name == "rigid"


def test_scaling_keeps_physical_sizes():
    f = next(p for p in scene_files() if p.stem == "fig03_nearfield")
    full, coarse = load_scene(f), load_scaled_scene(f, 0.5)
    assert coarse.grid.cells_per_wavelength == 10
    assert coarse.grid.size_m == full.grid.size_m
    assert coarse.run.n_steps == round(full.run.n_steps * 0.5)
    assert coarse.sensors.snapshot_every_steps == round(full.sensors.snapshot_every_steps * 0.5)
    assert coarse.edges.thickness_cells == 10
    # the per-cell lags are resampled onto the coarser line (52 cells), same end values
    lags = coarse.transducers[0].lags_s
    assert len(lags) == 52
    assert lags[0] == pytest.approx(full.transducers[0].lags_s[0]) and lags[26] == 0.0
    grid, _, sources, *_ = coarse.build()
    assert sources[0].n_cells == 52
    # a grid given in cells scales too; scale 1 is an unchanged copy
    d = {"grid": {"frequency_hz": 5e4, "shape": [840, 630]}, "transducers": [{"centre_m": [0.01, 0.1], "n_cells": 104}]}
    scene = parse_scene(d)
    s = scene.scaled(0.25)
    assert s.grid.shape == (210, 158) and s.transducers[0].n_cells == 26
    # moments in steps scale with the grid, moments in seconds stay
    d2 = d | {"output": {"show_steps": [1030, 1300], "show_times_s": [1e-4]}}
    o = parse_scene(d2).scaled(0.25).output
    assert (o.show_steps, o.show_times_s) == ((258, 325), (1e-4,))
    assert scene.grid.shape == (840, 630)
    assert scene.scaled(1.0) == scene


def test_unknown_scene_name_is_refused(tmp_path):
    with pytest.raises(FileNotFoundError, match="no gallery scene named"):
        render_gallery(tmp_path, scale=SCALE, names=["fig99_nothing"], progress=False)


def test_gallery_renders_every_scene(gallery):
    out, entries = gallery
    names = [e["name"] for e in entries]
    assert EXPECTED <= set(names)
    for e in entries:
        d = out / e["name"]
        for f in ("summary.json", "sensors.npz", "field.png", "peak_level.png", "figure.png"):
            assert (d / f).is_file(), f"{e['name']}: {f} missing"
        assert not (d / "animation.gif").exists()  # animations off below scale 1
        summ = json.loads((d / "summary.json").read_text())
        assert summ["stability"]["finite"] and e["stability_finite"]
        assert np.isfinite(summ["stability"]["peak_pa"]) and summ["stability"]["peak_pa"] > 0
        assert summ["grid"]["cells_per_wavelength"] == pytest.approx(20 * SCALE)
        nx, ny = summ["grid"]["shape"]
        # figure.png: one 600-pixel panel per moment of the scene's [output] show_steps (else the
        # last step), 600 * ny / nx + 105 pixels high; each moment also has its own image
        shown = load_scene(e["scene_file"]).output.show_steps
        n_panels = len(shown) or 1
        assert e["shown_steps"] == ([round(s * SCALE) for s in shown] or [e["n_steps"]])
        assert len(list(d.glob("moment_*.png"))) == len(shown)
        assert not (d / "frames").exists()  # no per-snapshot frames below scale 1
        img = mpimg.imread(d / "figure.png")
        assert img.shape[:2] == (round(600 * ny / nx) + 105, 600 * n_panels), e["name"]
        assert img[..., :3].std() > 0.02  # not blank
        # field.png (tight bounding box): about the grid's aspect ratio plus labels
        fimg = mpimg.imread(d / "field.png")
        assert 500 < fimg.shape[1] < 900
        assert 0.6 < (fimg.shape[0] / fimg.shape[1]) / (ny / nx) < 1.6
        # the run ended where the scene file says (scaled)
        assert e["n_steps"] == summ["run"]["n_steps"]
        assert (out / e["files"]["figure"]).is_file()
    # the paper's two moments of Fig. 6 are both shown, at exactly steps 1030 and 1300 (scaled)
    e6 = next(e for e in entries if e["name"] == "fig06_concave_corner")
    assert e6["shown_steps"] == [round(1030 * SCALE), round(1300 * SCALE)]
    # Fig. 3 records arrivals on its probe line -> a wavefront plot
    assert (out / "fig03_nearfield" / "wavefront.png").is_file()


def test_gallery_index_and_json(gallery):
    out, entries = gallery
    meta = json.loads((out / "gallery.json").read_text())
    assert meta["scale"] == SCALE
    assert [s["name"] for s in meta["scenes"]] == [e["name"] for e in entries]
    for s in meta["scenes"]:
        assert s["n_steps"] > 0 and s["render_wall_time_s"] > 0 and s["simulate_wall_time_s"] > 0
        assert (out / s["files"]["figure"]).is_file()
    index = (out / "index.md").read_text()
    for e in entries:
        assert f"]({e['name']}/figure.png)" in index
        assert e["title"] in index
    for key in COMPARISONS:
        assert (out / f"compare_{key}.png").is_file()
        assert f"](compare_{key}.png)" in index


def test_rigid_and_speed_zero_walls_reflect_with_opposite_phase(gallery):
    """Fig. 4: the echo on the reflected path is phase-reversed by the speed-zero wall and not by
    the rigid one; the side-lobe wave arriving first (no wall involved) is the same in both."""
    out, _ = gallery
    a = np.load(out / "fig04a_wall_speed_zero" / "sensors.npz")["probes_pa"][:, 0]
    b = np.load(out / "fig04b_wall_rigid" / "sensors.npz")["probes_pa"][:, 0]
    k = int(np.argmax(np.abs(b)))
    w = slice(max(0, k - 15), k + 15)
    assert np.corrcoef(a[w], b[w])[0, 1] < -0.5


# ------------------------------------------------------------------------------------------
# content: a plane wave's image has the expected number of bright bands


def _field_figure(p, dx_m, width_px, height_px):
    """`p` rendered with plots.field_image on axes filling the whole figure (no margins)."""
    fig = plt.figure(figsize=(width_px / 100, height_px / 100), dpi=100)
    ax = fig.add_axes([0, 0, 1, 1])
    plots.field_image(p, dx_m, ax=ax)
    ax.set_axis_off()
    return fig


@pytest.mark.parametrize("wavelength_cells", [40, 60, 75])
def test_plane_wave_image_has_expected_bands(tmp_path, wavelength_cells):
    nx, ny, dx = 600, 150, 1e-3
    x = np.arange(nx)[:, None] * np.ones((1, ny))
    # -cos: dark at both edges, bright bands centred half a wavelength in from the left
    p = -np.cos(2 * np.pi * x / wavelength_cells)
    fig = _field_figure(p, dx, nx, ny)
    path = tmp_path / "plane.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    img = mpimg.imread(path)
    assert img.shape[:2] == (ny, nx)
    gray = img[..., :3].mean(-1)
    row = gray[ny // 2]
    bright = row > 0.5
    rising = int(np.count_nonzero(bright[1:] & ~bright[:-1]))
    width_mm, wavelength_mm = nx * dx * 1e3, wavelength_cells * dx * 1e3
    assert rising == round(width_mm / wavelength_mm)
    # white = positive pressure: the middle of the first band (half a wavelength in) is white
    assert row[wavelength_cells // 2] > 0.9 and row[0] < 0.1


def test_a_scene_at_another_resolution_keeps_metres_and_scales_cells():
    """`Scene.at_resolution`: twice the cells per wavelength doubles the cell counts (grid, line,
    edges, steps) and keeps every size in metres (the window, the line's length)."""
    from pathlib import Path

    scene = load_scene(Path(__file__).resolve().parents[1] / "data" / "scenes" / "fig02_polaroid.toml")
    fine = scene.at_resolution(2 * scene.grid.cells_per_wavelength)
    assert fine.grid.cells_per_wavelength == 2 * scene.grid.cells_per_wavelength
    assert fine.grid.shape == tuple(2 * n for n in scene.grid.shape)
    assert fine.transducers[0].n_cells == 2 * scene.transducers[0].n_cells
    assert fine.edges.thickness_cells == 2 * scene.edges.thickness_cells
    assert fine.run.n_steps == 2 * scene.run.n_steps
    assert fine.transducers[0].centre_m == scene.transducers[0].centre_m
    assert scene.at_resolution(scene.grid.cells_per_wavelength).grid == scene.grid
