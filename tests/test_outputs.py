"""`simulate` outputs: the render stride follows the resolution, frames can be switched off,
`[output]` moments give fields at exactly those steps, and under-resolved media are warned about."""

import math
import os
import warnings

os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from difflattice import plots  # noqa: E402
from difflattice.apps.scene_run import run_scene, write_outputs  # noqa: E402
from difflattice.cli import main  # noqa: E402
from difflattice.lattice.medium import ResolutionWarning  # noqa: E402
from difflattice.scene import SceneError, parse_scene, render_stride  # noqa: E402
from difflattice.solver import run  # noqa: E402


def _scene(cpw=20.0, **output):
    data = {
        "grid": {"frequency_hz": 50e3, "cells_per_wavelength": cpw, "size_m": [0.024, 0.018]},
        "edges": {"kind": "pml", "thickness_cells": 6},
        "transducers": [{"centre_m": [0.006, 0.009], "n_cells": 8, "cycles": 2}],
        "sensors": {"snapshot_every_steps": 25, "probes_m": [[0.012, 0.009]]},
        "run": {"n_steps": 90},
    }
    if output:
        data["output"] = output
    return parse_scene(data, "<test>")


@pytest.mark.parametrize("cpw, stride", [(20, 3), (19.9, 2), (13.4, 2), (13.3, 1), (10, 1), (5, 1), (40, 6), (28, 4)])
def test_render_stride_keeps_the_paper_and_never_aliases(cpw, stride):
    assert render_stride(cpw) == stride
    # never fewer than 20/3 rendered pixels per wavelength (the paper's every 3rd cell at 20)
    assert cpw / render_stride(cpw) >= 20 / 3 - 1e-9 or render_stride(cpw) == 1


def test_render_stride_override_and_bad_values():
    assert render_stride(20, 5) == 5
    for bad in (0, -1, 2.5, True):
        with pytest.raises(ValueError, match="whole number"):
            render_stride(20, bad)
    with pytest.raises(ValueError, match="must be > 0"):
        render_stride(0)
    with pytest.raises(SceneError, match=r"output.render_every_cells"):
        _scene(render_every_cells=0).build()


@pytest.mark.parametrize("cpw, override", [(20.0, None), (10.0, None), (20.0, 2)])
def test_snapshots_and_images_follow_the_stride(cpw, override):
    sr = run_scene(_scene(cpw, **({"render_every_cells": override} if override else {})), progress=False)
    r = override or render_stride(cpw)
    assert sr.render_every == r
    nx, ny = sr.grid.shape
    # snapshots are held thinned (no full-resolution history)
    assert sr.snapshots and all(f.shape == (math.ceil(nx / r), math.ceil(ny / r)) for f in sr.snapshots)
    assert sr.snapshot_steps == [25, 50, 75, 90]
    # the rendered raster has one pixel per kept cell, over the whole window
    fig = plots.field_image(sr.snapshots[0], sr.grid.dx_m, every=1, size_m=sr.grid.size_m)
    im = fig.axes[0].images[0]
    assert im.get_array().shape == (math.ceil(ny / r), math.ceil(nx / r))
    assert im.get_extent()[1] == pytest.approx(sr.grid.size_m[0] * 1e3)
    fig = plots.field_image(sr.result.final.pressure, sr.grid.dx_m, every=r)
    assert fig.axes[0].images[0].get_array().shape == (math.ceil(ny / r), math.ceil(nx / r))
    assert sr.summary["output"]["pixels_per_wavelength"] == pytest.approx(cpw / r)


def test_moments_are_fields_at_exactly_those_steps(tmp_path):
    scene = _scene(20.0, show_steps=[37, 90], show_times_s=[30e-6])
    sr = run_scene(scene, progress=False)
    t_step = int(round(30e-6 / sr.grid.dt_s))
    assert sorted(sr.moments) == sorted({37, 90, t_step})
    # snapshots stay on multiples of snapshot_every_steps despite the extra stops
    assert sr.snapshot_steps == [25, 50, 75, 90]
    # the kept field is the field after exactly that many steps
    ref = run(sr.stepper, 37)
    np.testing.assert_allclose(
        sr.moments[37], np.asarray(ref.final.pressure), rtol=0, atol=1e-6 * float(np.abs(sr.moments[37]).max())
    )
    assert float(np.abs(sr.moments[37]).max()) > 0
    files = write_outputs(sr, tmp_path / "o", animation="none")
    names = sorted(os.path.basename(f) for f in files["moments"])
    assert names == sorted(f"moment_{s:06d}.png" for s in {37, 90, t_step})
    assert all((tmp_path / "o" / n).is_file() for n in names)


def test_moment_outside_the_run_is_refused():
    with pytest.raises(SceneError, match=r"\[output\] moment at step 91"):
        _scene(show_steps=[91]).build()
    with pytest.raises(SceneError, match=r"output.show_steps\[0\]"):
        _scene(show_steps=[1.5]).build()


def test_no_frames_switch(tmp_path):
    sr = run_scene(_scene(20.0), progress=False)
    files = write_outputs(sr, tmp_path / "a", frames=False, animation="none")
    assert "frames" not in files and not (tmp_path / "a" / "frames").exists()
    assert not list((tmp_path / "a").glob("animation.*"))
    files = write_outputs(sr, tmp_path / "b", animation="none")
    assert len(list((tmp_path / "b" / "frames").glob("frame_*.png"))) == len(sr.snapshot_steps) == 4
    # the scene's [output] section is the default; the CLI switch overrides it
    sr2 = run_scene(_scene(20.0, frames=False, animation="none"), progress=False)
    write_outputs(sr2, tmp_path / "c")
    assert not (tmp_path / "c" / "frames").exists()
    with pytest.raises(ValueError, match="animation"):
        write_outputs(sr, tmp_path / "d", animation="avi")


def test_cli_no_frames(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text(
        "[grid]\nfrequency_hz = 50000.0\ncells_per_wavelength = 10.0\nsize_m = [0.024, 0.018]\n"
        "[edges]\nthickness_cells = 5\n[[transducers]]\ncentre_m = [0.006, 0.009]\nn_cells = 4\n"
        "[sensors]\nsnapshot_every_steps = 20\n[run]\nn_steps = 40\n"
    )
    assert (
        main(
            [
                "simulate",
                str(scene),
                "--out",
                str(tmp_path / "o"),
                "--quiet",
                "--no-frames",
                "--no-animation",
                "--render-every",
                "2",
            ]
        )
        == 0
    )
    assert not (tmp_path / "o" / "frames").exists() and (tmp_path / "o" / "field.png").is_file()
    import json

    assert json.loads((tmp_path / "o" / "summary.json").read_text())["output"]["render_every_cells"] == 2


def test_time_series_legend_is_capped():
    t = np.arange(50) * 1e-6
    few = plots.time_series_plot(t, np.random.default_rng(0).normal(size=(50, 3)), [f"p{i}" for i in range(3)])
    assert len(few.axes[0].get_legend().get_texts()) == 3
    many = plots.time_series_plot(t, np.zeros((50, 20)), [f"p{i}" for i in range(20)])
    assert many.axes[0].get_legend() is None
    assert len(many.axes) == 2 and "20 probes" in many.axes[1].get_ylabel()  # colour bar instead


# ------------------------------------------------------------------------------------------
# warnings: under-resolved media, ignored materials


def _pine_scene(model="conservative", material="pine"):
    return parse_scene(
        {
            "grid": {"frequency_hz": 50e3, "cells_per_wavelength": 20.0, "size_m": [0.2, 0.1]},
            "medium": {"boundary_model": model},
            "transducers": [{"centre_m": [0.05, 0.05], "n_cells": 4}],
            "objects": [{"shape": "box", "material": material, "lo_m": [0.1, 0.02], "hi_m": [0.12, 0.08]}],
            "run": {"n_steps": 10},
        },
        "<pine>",
    )


def test_pine_in_air_warns_that_air_is_under_resolved():
    with pytest.warns(ResolutionWarning) as rec:
        _pine_scene().build()
    msg = str(rec[0].message)
    # the cell is sized for pine (3500 m/s): air gets 20 * 343.2 / 3500 = 1.96 cells per wavelength
    assert "'air'" in msg and "1.96 cells per wavelength" in msg and "pine" in msg
    assert "rigid" in msg and "cells_per_wavelength" in msg  # the fixes


def test_air_alone_and_rigid_objects_do_not_warn():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _pine_scene(material="rigid").build()
        _scene(10.0).build()  # 10 cells per wavelength: above the 8 threshold


def test_coarse_air_warns():
    with pytest.warns(ResolutionWarning, match=r"'air' \(343 m/s\) gets only 5.00 cells"):
        _scene(5.0).build()


def test_speed_zero_says_the_material_speed_is_ignored():
    with pytest.warns(UserWarning, match=r"'pine' is ignored under boundary_model = \"speed_zero\"") as rec:
        _pine_scene("speed_zero").build()
    assert not any(isinstance(w.message, ResolutionWarning) for w in rec)  # pine is not simulated
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _pine_scene("speed_zero", material="soft").build()


def test_scene_files_page_is_generated_from_the_schema():
    """docs/scene-files.md's key tables are docs/gen_scene_files.py's output (rerun it after a
    schema change)."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "docs" / "gen_scene_files.py"
    spec = importlib.util.spec_from_file_location("gen_scene_files", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.main(["--check"]) == 0
    assert "| `show_steps` |" in mod.PAGE.read_text()


def test_gallery_scenes_ship_with_the_package():
    """difflattice/scenes (a symlink to data/scenes, package data in pyproject.toml) holds the
    gallery's scene files, so an installed package finds them without the repository."""
    from pathlib import Path

    import difflattice

    pkg = Path(difflattice.__file__).parent / "scenes"
    names = {p.name for p in pkg.glob("fig*.toml")}
    repo = Path(__file__).resolve().parents[1] / "data" / "scenes"
    assert names and names == {p.name for p in repo.glob("fig*.toml")}


# --- data files (issue 32): CSV tables pandas reads as they are, NetCDF with coordinates and units


def test_every_csv_of_a_2d_run_reads_in_pandas_and_netcdf_has_units(tmp_path):
    pd = pytest.importorskip("pandas")
    xr = pytest.importorskip("xarray")
    h5py = pytest.importorskip("h5py")
    sr = run_scene(_scene(20.0), progress=False)
    files = write_outputs(sr, tmp_path / "o", frames=False, animation="none", data_format="netcdf")
    probes = pd.read_csv(files["probes_csv"])
    assert list(probes.columns) == ["t_s", "probe_0_pa"]
    assert len(probes) == 90 and probes["t_s"].iloc[0] == pytest.approx(sr.grid.dt_s)
    np.testing.assert_allclose(probes["probe_0_pa"], np.asarray(sr.result.probes)[:, 0], rtol=1e-6, atol=1e-12)
    ds = xr.open_dataset(files["sensors"])
    assert ds["probes_pa"].attrs["units"] == "Pa" and ds["t"].attrs["units"] == "s" and ds["x"].attrs["units"] == "m"
    np.testing.assert_allclose(ds["x"].values, sr.grid.coordinates_m()[0])
    np.testing.assert_allclose(ds["final_field_pa"].values, np.asarray(sr.result.final.pressure))
    ds.close()
    with h5py.File(files["sensors"]) as f:
        assert f["final_field_pa"].attrs["units"] in (b"Pa", "Pa")
    assert not (tmp_path / "o" / "sensors.npz").exists()
    # a CSV for every table the scene has: the lobe too
    sr.lobe = (np.array([-1.0, 0.0, 1.0]), np.array([-3.0, 0.0, -3.0]))
    files = write_outputs(sr, tmp_path / "p", frames=False, animation="none")
    lobe = pd.read_csv(files["lobe_csv"])
    assert list(lobe.columns) == ["angle_deg", "level_db"] and lobe["level_db"].max() == 0.0
    for csv in (tmp_path / "p").glob("*.csv"):
        assert not csv.read_text().startswith("#"), csv


def test_a_3d_run_writes_csv_netcdf_and_the_last_field_that_holds_a_wave(tmp_path):
    pd = pytest.importorskip("pandas")
    xr = pytest.importorskip("xarray")
    from difflattice.apps import scenes3d

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    scene = scenes3d.load_scene_at(os.path.join(root, "data", "scenes", "wall3d_00deg.toml"), 8.0)
    sr = scenes3d.run_scene3d(scene, mlups=100.0, quiet=True)
    files = scenes3d.write_outputs3d(sr, tmp_path / "o", data_format="netcdf")
    a = pd.read_csv(files["a_scan_csv"])
    assert list(a.columns) == ["t_s", "disc_pa_x_weight"]
    np.testing.assert_allclose(a["disc_pa_x_weight"], sr.a_scans["disc"][1], rtol=1e-6, atol=1e-12)
    ds = xr.open_dataset(files["sensors"])
    assert ds["a_scan_disc"].attrs["units"] == "Pa x cell weight" and ds["z"].attrs["units"] == "m"
    assert ds.sizes["t"] == sr.summary["run"]["n_steps"]
    ds.close()
    # the field slice shows a step where the field is not empty
    planes = sr.built.sensors.snapshot_planes(tuple(sr.grid.shape))
    step, shown = scenes3d._last_field_planes(sr, planes)
    peak = sr.summary["stability"]["peak_pa"]
    assert max(float(np.abs(v).max()) for _, v in shown.values()) >= scenes3d.EMPTY_FIELD * peak
    assert 0 < step <= sr.summary["run"]["n_steps"]
    # compile time kept apart from the throughput
    r = sr.summary["run"]
    assert 0 < r["compile_s"] < r["wall_time_s"] and r["mlups_excl_compile"] > r["mlups"]


def test_capture_files_read_in_pandas_with_their_comment_header(tmp_path):
    """Capture files (`difflattice capture`, format difflattice-capture/1) start with `#` metadata
    lines: `pandas.read_csv(path, comment="#")` gives the named columns, units in the names."""
    pd = pytest.importorskip("pandas")
    from pathlib import Path

    from difflattice.capture.files import is_capture_file, load_capture

    data = Path(__file__).resolve().parents[1] / "data" / "emulated"
    caps = [p for p in sorted(data.rglob("*.csv")) if is_capture_file(p)][:3]
    assert caps, data
    for p in caps:
        cap = load_capture(p, allow_incomplete=True)
        df = pd.read_csv(p, comment="#")
        assert list(df.columns) == list(cap.columns), p
        assert sorted(df["seq"].unique()) == sorted(cap.seq.tolist()), p
