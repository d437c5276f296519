"""The paper's gallery renders (coarse), and field images show what they should."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.image as mpimg  # noqa: E402
import numpy as np  # noqa: E402

from difflattice import plots  # noqa: E402
from difflattice.gallery import render_gallery, scene_files  # noqa: E402


def test_every_gallery_scene_parses_and_builds():
    from difflattice.scene import load_scene

    files = scene_files()
    assert len(files) >= 12
    for f in files:
        grid, medium, sources, sensors, edges, n_steps, _ = load_scene(f).build()
        assert n_steps > 0 and sources


def test_gallery_renders_coarse(tmp_path):
    names = ["fig04a_wall_speed_zero", "fig06_concave_corner", "fig10_parabolic_reflector"]
    res = render_gallery(tmp_path, scale=0.25, names=names, progress=False)
    assert [r["name"] for r in res] == names
    for r in res:
        assert r["finite"]
        img = mpimg.imread(tmp_path / r["name"] / "field.png")
        assert img.shape[0] > 200 and img.shape[1] > 200
        assert img[..., :3].std() > 0.01  # not blank
    assert (tmp_path / "index.md").read_text().count("![") == 3


def test_plane_wave_image_has_expected_bands(tmp_path):
    """cos(k x) over a window 6 wavelengths wide: 6 bright bands across the image."""
    nx, ny, wl = 240, 120, 40
    x = np.arange(nx)[:, None] * np.ones((1, ny))
    fig = plots.field_image(np.cos(2 * np.pi * x / wl), 1e-3, every=1, clip=1.0)
    ax = fig.axes[0]
    path = plots.save(fig, tmp_path / "pw.png", dpi=100)
    img = mpimg.imread(path)[..., :3].mean(-1)
    # the row through the middle of the axes, within the axes' pixel extent
    fig2 = plots.field_image(np.cos(2 * np.pi * x / wl), 1e-3, every=1, clip=1.0)
    bbox = fig2.axes[0].get_window_extent()
    h = img.shape[0]
    row = img[h // 2]
    inside = row[int(bbox.x0 * img.shape[1] / fig2.bbox.width) + 3 : int(bbox.x1 * img.shape[1] / fig2.bbox.width) - 3]
    bright = inside > 0.75
    rising = np.count_nonzero(bright[1:] & ~bright[:-1]) + int(bright[0])
    assert rising in (6, 7)  # 6 crests; a crest cut at an edge may add one
