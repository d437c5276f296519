"""The lattice kind as a type: each kind owns its rank, axes, stability limit and cell lookup;
strings name kinds only at the boundary; every kind's scene is estimated and refused before any
grid-sized array exists; rz images are labelled z/r."""

import math
import subprocess
import sys
import tomllib
from pathlib import Path

import jax
import numpy as np
import pytest

from difflattice.lattice import AXISYMMETRIC, KINDS, PLANE, VOLUME, LatticeKind, as_kind, make_grid
from difflattice.lattice.grid import stability_limit

ROOT = Path(__file__).resolve().parents[2]


def _grid(kind, shape, **kw):
    return make_grid(frequency_hz=40e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=shape, kind=kind, **kw)


def test_kinds_are_types_named_by_strings_at_the_boundary():
    assert [as_kind(n) for n in ("2d", "rz", "3d")] == [PLANE, AXISYMMETRIC, VOLUME]
    for name, kind in KINDS.items():
        assert as_kind(kind) is kind and kind == name and str(kind) == name
        assert hash(kind) == hash(as_kind(name))
        g = _grid(name, (8,) * kind.ndim)
        assert isinstance(g.kind, LatticeKind) and g.kind is kind and g.ndim == kind.ndim
        assert g.describe()["kind"] == name  # summaries stay plain JSON
    assert PLANE != AXISYMMETRIC and PLANE != "rz"
    with pytest.raises(ValueError, match="grid kind = '3x'; allowed: '2d', 'rz', '3d'"):
        as_kind("3x")


def test_stability_limits_are_the_spectral_radius_bounds():
    """c^2 rho(-L) <= 4 with rho < 8 (5-point, and the rz ring operator), 12 (7-point), 16/3
    (isotropic 9-point, and the 3-D 19-point): the limits 1/sqrt(2), 1/sqrt(3), sqrt(3)/2 (derivations in grid.py)."""
    for kind, rho in ((PLANE, 8), (AXISYMMETRIC, 8), (VOLUME, 12)):
        assert kind.stability_limit() == pytest.approx(math.sqrt(4 / rho), rel=1e-15)
        assert stability_limit(kind.name) == kind.stability_limit()
    for kind in (PLANE, AXISYMMETRIC, VOLUME):
        assert kind.stability_limit("isotropic") == pytest.approx(math.sqrt(4 / (16 / 3)), rel=1e-15)
    with pytest.raises(ValueError, match="exceeds the 3-D stability limit 1/sqrt\\(3\\)"):
        _grid("3d", (4, 4, 4), courant=0.58)


@pytest.mark.parametrize("name", list(KINDS))
def test_every_cell_centre_is_found_in_its_own_cell(name):
    """`Grid.cells_of` inverts `Grid.coordinates_m` on every kind (centres at (i + origin) dx)."""
    kind = KINDS[name]
    g = _grid(name, (5, 4, 3)[: kind.ndim])
    axes = g.coordinates_m()
    mesh = np.stack([a.ravel() for a in np.meshgrid(*axes, indexing="ij")], axis=1)
    want = np.stack([a.ravel() for a in np.meshgrid(*[np.arange(n) for n in g.shape], indexing="ij")], axis=1)
    np.testing.assert_array_equal(g.cells_of(mesh), want)
    assert g.cell_of(tuple(mesh[7])) == tuple(want[7])


def test_shapes_that_a_kind_cannot_have_are_refused():
    with pytest.raises(ValueError, match=r"a 2-D grid needs shape \(nx, ny\).*kind='3d'"):
        _grid("2d", (4, 4, 4))
    with pytest.raises(ValueError, match=r"a rz grid needs shape \(nz, nr\)"):
        _grid("rz", (4,))
    with pytest.raises(ValueError, match="at least 3 cells along x and 3 along every axis"):
        _grid("3d", (4, 2, 4))


def _scene_file(tmp_path: Path, shape) -> Path:
    text = (ROOT / "data" / "scenes" / "fig02_polaroid.toml").read_text()
    path = tmp_path / "big.toml"
    path.write_text(text.replace("shape = [840, 630]", f"shape = [{shape[0]}, {shape[1]}]"))
    return path


def test_a_2d_scene_too_large_for_memory_is_refused_before_any_grid_sized_array(tmp_path):
    """60000 x 40000 cells (two float32 leapfrog fields alone: 19 GB) on this machine: exit 2 with
    the estimate, and the process never came near one field's 9.6 GB (peak RSS < 2 GiB)."""
    path = _scene_file(tmp_path, (60000, 40000))
    # the CLI runs as the only child of a fresh process, which reports its children's peak RSS (this
    # test process's own RUSAGE_CHILDREN also counts every earlier test's subprocesses)
    cli = [sys.executable, "-m", "difflattice.cli", "simulate", str(path), "--out", str(tmp_path / "o")]
    probe = (
        "import resource, subprocess, sys\n"
        f"r = subprocess.run({cli!r}, capture_output=True, text=True, timeout=120)\n"
        "sys.stderr.write(r.stderr)\n"
        "print(r.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n"
    )
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=180)
    rc, peak_kib = (int(x) for x in r.stdout.split())
    assert rc == 2, r.stderr
    assert "estimated memory" in r.stderr and "60000 x 40000" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    assert peak_kib < 2 * 2**20, f"peak RSS {peak_kib / 2**20:.2f} GiB"
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_every_kind_is_estimated_in_the_library_too(tmp_path):
    from difflattice.scene import load_scene
    from difflattice.scene.model import SceneTooLargeError

    scene = load_scene(_scene_file(tmp_path, (840, 630)))
    with pytest.raises(SceneTooLargeError, match=r"\[grid\].*estimated memory"):
        scene.build(available_bytes=2**20)
    assert scene.build().grid.shape == (840, 630)  # fits in the memory here


def test_rz_images_are_labelled_z_and_r(tmp_path, monkeypatch):
    """The field image of an rz scene: z along, r across, r from -R to R (the mirrored section)."""
    from difflattice import plots
    from difflattice.apps.scene_run import run_scene, write_outputs
    from difflattice.scene import parse_scene

    d = tomllib.loads((ROOT / "data" / "scenes" / "disc_piston_rz.toml").read_text())
    d["grid"].update(cells_per_wavelength=8.0, size_m=[0.02, 0.035])
    d["edges"]["thickness_cells"] = 6
    d["run"] = {"n_steps": 20}
    d.pop("farfield", None)
    d["sensors"] = {"p_max": True}
    d.pop("output", None)
    sr = run_scene(parse_scene(d, "rz-labels"), progress=False)
    figs = {}
    save = plots.save
    monkeypatch.setattr(
        plots, "save", lambda fig, path, **kw: (figs.__setitem__(Path(path).name, fig), save(fig, path))[1]
    )
    write_outputs(sr, tmp_path, frames=False, animation="none")
    for name in ("field.png", "peak_level.png"):
        ax = figs[name].axes[0]
        assert (ax.get_xlabel(), ax.get_ylabel()) == ("z (mm)", "r (mm)"), name
        r_mm = 1e3 * sr.grid.size_m[1]
        assert ax.get_ylim() == pytest.approx((-r_mm, r_mm)), name


@pytest.mark.parametrize("kind", ["2d", "rz", "3d"])
def test_default_edges_fit_every_kind(kind):
    """`simulate`/`Stepper.build` without `edges` use the kind's default window (a PML on every
    side; rz: the axis at y_lo), where `Edges()` alone is refused on an rz grid."""
    from difflattice.lattice import Edges
    from difflattice.lattice.medium import Medium
    from difflattice.solver import Stepper

    shape = (30, 30, 30) if kind == "3d" else (30, 30)
    grid = make_grid(frequency_hz=40e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=shape, kind=kind)
    edges = Edges.default_for(grid.kind)
    assert edges.uses_pml and (edges.y_lo == "axis") == (kind == "rz")
    stepper = Stepper.build(grid, Medium(343.0, 1.2))  # no edges given: the kind's default
    explicit = Stepper.build(grid, Medium(343.0, 1.2), edges=edges)
    assert stepper.staggered and explicit.staggered
    assert jax.tree_util.tree_all(
        jax.tree_util.tree_map(lambda a, b: bool(np.array_equal(a, b)), stepper.lattice, explicit.lattice)
    )
    if kind == "rz":
        with pytest.raises(ValueError, match="the y_lo side is the axis"):
            Stepper.build(grid, Medium(343.0, 1.2), edges=Edges())
