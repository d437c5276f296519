"""3-D mesh objects: a closed triangle mesh rasterised on a 3-D grid (inside by ray parity, exact
distance near the surface) gives the built-in solid's occupancy where the built-in SDF is exact,
keeps a cavity empty, and comes in through a 3-D scene file."""

import tomllib

import numpy as np
import pytest
import trimesh

from difflattice.lattice import geometry3d as g3
from difflattice.lattice.grid import make_grid
from difflattice.scene import SceneError, parse_scene


def _grid():
    return make_grid(frequency_hz=50e3, cells_per_wavelength=6, shape=(40, 36, 32), kind="3d", c_max_m_s=343.0)


def _rotated_box(c, size, angles):
    box = trimesh.creation.box(extents=size)
    t = np.eye(4)
    t[:3, :3] = np.asarray(g3.rotation_matrix(np.asarray(angles, float)))
    t[:3, 3] = c
    box.apply_transform(t)
    return box


def test_a_box_mesh_rasterises_as_the_oriented_box():
    """A rotated box as 12 triangles against `OrientedBox` with the same pose: both signed
    distances are exact within the smooth ramp (the nearest face inside, the Euclidean distance
    to the nearest face, edge or corner outside), so the occupancies agree to round-off."""
    g = _grid()
    dx = g.dx_m
    c, size, ang = np.array([20.3, 18.1, 15.7]) * dx, np.array([14.0, 9.0, 11.0]) * dx, [20.0, 15.0, -10.0]
    box = _rotated_box(c, size, ang)
    mesh_occ = np.asarray(g3.rasterise3d(g3.MeshSolid(np.asarray(box.vertices), np.asarray(box.faces)), g, "smooth"))
    ref = np.asarray(g3.rasterise3d(g3.OrientedBox(c, size, np.asarray(ang, float)), g, "smooth"))
    assert np.max(np.abs(mesh_occ - ref)) <= 1e-5  # float32 occupancies


def test_a_hollow_shell_keeps_its_cavity_empty():
    """Two nested spheres (the inner one inverted) make a shell: by ray parity the cavity is
    outside; the occupied volume is the shell's to within the smooth ramp's curvature error
    (relative (h / R)^2 / 12 per surface at R = 6 cells: under 0.5 %)."""
    g = _grid()
    dx = g.dx_m
    c = np.array([20.3, 18.1, 15.7]) * dx
    outer = trimesh.creation.icosphere(subdivisions=3, radius=10 * dx)
    inner = trimesh.creation.icosphere(subdivisions=3, radius=6 * dx)
    inner.invert()
    shell = trimesh.util.concatenate([outer, inner])
    shell.apply_translation(c)
    occ = np.asarray(g3.rasterise3d(g3.MeshSolid(np.asarray(shell.vertices), np.asarray(shell.faces)), g, "smooth"))
    i, j, k = np.round(c / dx).astype(int)
    assert occ[i, j, k] == 0.0 and occ[i + 8, j, k] == 1.0
    assert occ.sum() * dx**3 == pytest.approx(shell.volume, rel=5e-3)


TINY = """
[grid]
kind = "3d"
frequency_hz = 40000.0
cells_per_wavelength = 8.0
size_m = [0.03, 0.025, 0.02]

[medium]
rasterise = "smooth"

[edges]
kind = "pml"
thickness_cells = 4

[[transducers]]
type = "disc"
centre_m = [0.008, 0.0125, 0.01]
axis = [1.0, 0.0, 0.0]
diameter_m = 0.0086

[run]
n_steps = 4
"""


def test_a_3d_scene_takes_a_mesh_file_as_its_solid(tmp_path):
    """The same box as a `shape = "mesh"` STL (millimetres) and as a built-in box: the same
    medium; an open mesh is refused naming the object's file."""
    d = tomllib.loads(TINY)
    c, size, ang = np.array([0.02, 0.0125, 0.01]), np.array([0.004, 0.006, 0.005]), [30.0, 0.0, 10.0]
    box = _rotated_box(c * 1e3, size * 1e3, ang)
    box.export(tmp_path / "box.stl")
    media = []
    for obj in (
        {"shape": "mesh", "file": "box.stl", "material": "rigid"},
        {"shape": "box", "centre_m": c.tolist(), "size_m": size.tolist(), "angles_deg": ang, "material": "rigid"},
    ):
        d["objects"] = [obj]
        media.append(parse_scene(d, str(tmp_path / "s.toml")).build().medium)
    a, b = (np.asarray(m.rigid) for m in media)
    assert a.max() == 1.0 and np.max(np.abs(a - b)) <= 1e-4  # the STL stores float32 millimetres
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-1])
    open_box.export(tmp_path / "open.stl")
    d["objects"] = [{"shape": "mesh", "file": "open.stl", "material": "rigid"}]
    with pytest.raises(SceneError, match=r"objects\[0\]\.file.*not watertight"):
        parse_scene(d, str(tmp_path / "s.toml")).build()
