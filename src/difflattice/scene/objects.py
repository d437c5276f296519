"""A scene's objects as shapes: the plane (2d/rz) shapes and mesh sections, the 3-D solids, and
the 3-D disc rings and snapshot planes that the objects' keys describe."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .common import _OBJECT_KEYS_3D, SceneError, _fail, _validate_table, _vector

if TYPE_CHECKING:
    from ..lattice.geometry3d import Shape3D
    from ..lattice.grid import Grid
    from .model import Scene


def _mesh_shape(path, where, o: dict, geo, axisymmetric: bool):
    """A mesh file's section (`scene.meshes`) as a union of polygons (holes cut out)."""
    from .meshes import mesh_outlines

    f = Path(o["file"])
    f = f if f.is_absolute() else Path(str(path)).parent / f
    try:
        polys = mesh_outlines(f, axisymmetric=axisymmetric, unit=o["unit"])
    except ValueError as err:
        _fail(path, f"{where}.file", str(err))
    shapes = []
    for outer, holes in polys:
        s = geo.Polygon(outer)
        for h in holes:
            s = geo.Difference(s, geo.Polygon(h))
        shapes.append(s)
    return shapes[0] if len(shapes) == 1 else geo.Union(tuple(shapes))


def _shape(path, where, o: dict, geo, axisymmetric: bool = False):
    kind = o["shape"]
    need = {
        "segment": ("a_m", "b_m", "thickness_m"),
        "box": ("lo_m", "hi_m"),
        "circle": ("centre_m", "radius_m"),
        "polygon": ("vertices_m",),
        "polyline": ("points_m", "thickness_m"),
        "mesh": ("file",),
    }
    if kind not in need:
        extra = ' (3-D shapes need [grid] kind = "3d")' if kind in _SHAPES_3D else ""
        _fail(path, f"{where}.shape", f"= {kind!r}; allowed: {', '.join(need)}{extra}")
    for k in _OBJECT_KEYS_3D:
        if o.get(k) is not None:
            _fail(path, f"{where}.{k}", 'is for 3d objects ([grid] kind = "3d")')
    for k in need[kind]:
        if o.get(k) is None:
            _fail(path, f"{where}.{k}", f"is required for shape = {kind!r}")

    def a(k):
        return np.asarray(o[k], dtype=float)

    try:
        s = {
            "segment": lambda: geo.Segment(a("a_m"), a("b_m"), a("thickness_m")),
            "box": lambda: geo.Box(a("lo_m"), a("hi_m")),
            "circle": lambda: geo.Circle(a("centre_m"), a("radius_m")),
            "polygon": lambda: geo.Polygon(a("vertices_m")),
            "polyline": lambda: geo.Polyline(a("points_m"), a("thickness_m")),
            "mesh": lambda: _mesh_shape(path, where, o, geo, axisymmetric),
        }[kind]()
    except SceneError:
        raise
    except Exception as e:  # malformed coordinates
        _fail(path, where, f"bad {kind} parameters: {e}")
    if o.get("cut"):
        cut = _validate_table(path, "objects", o["cut"], f"{where}.cut")
        s = geo.Difference(s, _shape(path, f"{where}.cut", cut, geo, axisymmetric))
    return s


_SHAPES_3D = {
    "box": (),
    "sphere": ("centre_m", "radius_m"),
    "cylinder": ("centre_m", "axis", "radius_m", "length_m"),
    "halfspace": ("point_m", "normal"),
    "slab": ("point_m", "normal", "thickness_m"),
    "union": ("parts",),
    "intersection": ("parts",),
    "mesh": ("file",),
}


_VECTORS_3D = ("centre_m", "size_m", "angles_deg", "axis", "point_m", "normal", "lo_m", "hi_m")


def shape3d(path, where: str, o: dict):
    """The `lattice.geometry3d` solid of a validated `[[objects]]` table on a 3-D grid (box by
    lo_m/hi_m or centre_m/size_m/angles_deg, sphere, cylinder, halfspace, slab, union and
    intersection of `parts`, a closed mesh file, each with an optional `cut`); parameters as float
    arrays."""
    import jax.numpy as jnp

    from ..lattice import geometry3d as g3

    kind = o["shape"]
    if kind not in _SHAPES_3D:
        _fail(path, f"{where}.shape", f"= {kind!r}; allowed on a 3d grid: {', '.join(_SHAPES_3D)}")
    need = _SHAPES_3D[kind]
    if kind == "box":
        need = ("lo_m", "hi_m") if o.get("centre_m") is None and o.get("size_m") is None else ("centre_m", "size_m")
    for k in need:
        if o.get(k) is None:
            extra = " (or centre_m and size_m)" if k in ("lo_m", "hi_m") else ""
            _fail(path, f"{where}.{k}", f"is required for shape = {kind!r}{extra}")
    for k in _VECTORS_3D:
        if o.get(k) is not None:
            _vector(path, f"{where}.{k}", o[k])
    for k in ("a_m", "b_m", "vertices_m", "points_m"):
        if o.get(k) is not None:
            _fail(path, f"{where}.{k}", "is for 2d objects; see the 3d shapes' keys in docs/scene-files.md")

    def a(k):
        return jnp.asarray(o[k], dtype=float)

    s: Shape3D
    if kind == "box":
        if "lo_m" in need:
            lo, hi = np.asarray(o["lo_m"], float), np.asarray(o["hi_m"], float)
            if np.any(hi <= lo):
                _fail(path, f"{where}.hi_m", f"= {list(o['hi_m'])} must exceed lo_m = {list(o['lo_m'])} on every axis")
            s = g3.OrientedBox(jnp.asarray(0.5 * (lo + hi)), jnp.asarray(hi - lo))
        else:
            angles = o["angles_deg"] if o.get("angles_deg") is not None else [0.0, 0.0, 0.0]
            s = g3.OrientedBox(a("centre_m"), a("size_m"), jnp.asarray(angles, dtype=float))
    elif kind == "sphere":
        s = g3.Sphere(a("centre_m"), a("radius_m"))
    elif kind == "cylinder":
        s = g3.Cylinder(a("centre_m"), a("axis"), a("radius_m"), a("length_m"))
    elif kind == "halfspace":
        s = g3.HalfSpace(a("point_m"), a("normal"))
    elif kind == "slab":
        s = g3.Slab(a("point_m"), a("normal"), a("thickness_m"))
    elif kind == "mesh":  # the whole closed mesh, in the file's unit, in grid coordinates
        from .meshes import load_closed_mesh

        f = Path(o["file"])
        f = f if f.is_absolute() else Path(str(path)).parent / f
        try:
            verts, faces = load_closed_mesh(f, unit=o["unit"])
        except ValueError as err:
            _fail(path, f"{where}.file", str(err))
        s = g3.MeshSolid(verts, faces)
    else:
        parts = o["parts"]
        if not isinstance(parts, (list, tuple)) or not parts:
            _fail(path, f"{where}.parts", 'give a list of inline tables, e.g. [{ shape = "halfspace", ... }, ...]')
        solids = []
        for j, part in enumerate(parts):
            w = f"{where}.parts[{j}]"
            if not isinstance(part, dict):
                _fail(path, w, f"= {part!r} must be an inline table {{ shape = ..., ... }}")
            solids.append(shape3d(path, w, _validate_table(path, "objects", part, w)))
        s = g3.Union3D(tuple(solids)) if kind == "union" else g3.Intersection3D(tuple(solids))
    if o.get("cut"):
        w = f"{where}.cut"
        s = g3.Difference3D(s, shape3d(path, w, _validate_table(path, "objects", o["cut"], w)))
    return s


def _union3d(occs):
    """Union of 3-D occupancies: one is kept as it is (bitwise), several combine as
    1 - prod(1 - o) (the 2-D `union_occupancy`, without its no-op for a single one)."""
    if len(occs) == 1:
        return occs[0]
    free = 1 - occs[0]
    for o in occs[1:]:
        free = free * (1 - o)
    return 1 - free


def _rings_3d(scene: Scene, where: str, t: dict) -> tuple[dict | None, float | None]:
    """(rings dict for `disc_transducer_3d` or None, diameter in m or None) of a 3-D disc: from
    `fit_report` (`rings_from_fit_report`), or `ring_edges_m` with per-ring weights and lags."""
    from ..solver.sources import rings_from_fit_report

    p = scene.path
    diameter = t["diameter_m"]
    if t["fit_report"] is not None:
        if t["ring_edges_m"] is not None or t["weights"] is not None or t["lags_s"] is not None:
            _fail(p, f"{where}.fit_report", "gives the rings: leave out ring_edges_m, weights and lags_s")
        report = Path(p).parent / t["fit_report"]
        try:
            rings = rings_from_fit_report(report)
        except OSError as e:
            _fail(p, f"{where}.fit_report", f"= {t['fit_report']!r}: cannot read {report} ({e.strerror})")
        except (ValueError, KeyError) as e:
            _fail(p, f"{where}.fit_report", f"= {t['fit_report']!r}: {e}")
        d = rings.pop("diameter_m", None)
        return rings, diameter if diameter is not None else d
    if t["ring_edges_m"] is not None:
        if t["weights"] is None:
            _fail(p, f"{where}.weights", "is required with ring_edges_m (one weight per ring)")
        edges = t["ring_edges_m"]
        if not all(isinstance(e, (list, tuple)) and len(e) == 2 for e in edges):
            _fail(p, f"{where}.ring_edges_m", "give [[inner, outer], ...] radii in metres, one pair per ring")
        rings = {"ring_edges_m": [list(e) for e in edges], "weights": list(t["weights"])}
        if t["lags_s"] is not None:
            rings["lags_s"] = list(t["lags_s"])
        return rings, diameter
    if t["weights"] is not None or t["lags_s"] is not None:
        _fail(
            p,
            f"{where}.weights",
            "a 3d disc's weights and lags_s are per ring: give ring_edges_m = [[r0, r1], ...] with them",
        )
    if diameter is None:
        _fail(p, f"{where}.diameter_m", "is required for a disc (its diameter, m), or give ring_edges_m or fit_report")
    return None, diameter


def _slice_planes(scene: Scene, grid: Grid, sources) -> tuple[tuple[int, int], ...]:
    """The (axis, index) planes of `[sensors] snapshot_slices_m`, default the three planes
    through the first transducer's centre (the cell nearest its mean cell)."""
    sl = scene.sensors["snapshot_slices_m"]
    if sl is None:
        c = np.rint(np.asarray(sources[0].cells_array, float).mean(axis=0)).astype(int)
        return tuple((a, int(c[a])) for a in range(3))
    planes = []
    for j, item in enumerate(sl):
        key = f"sensors.snapshot_slices_m[{j}]"
        if not (isinstance(item, (list, tuple)) and len(item) == 2 and item[0] in ("x", "y", "z")):
            _fail(scene.path, key, f'= {item!r}: give ["x", position_m] (axis x, y or z and a position in metres)')
        if isinstance(item[1], bool) or not isinstance(item[1], (int, float)):
            _fail(scene.path, key, f"= {item!r}: the position must be a number of metres")
        a = "xyz".index(item[0])
        i = int(round(float(item[1]) / grid.dx_m))
        if not 0 <= i < grid.shape[a]:
            _fail(scene.path, key, f"= {item!r} lies outside the grid (0 .. {grid.size_m[a]:.4g} m along {item[0]})")
        planes.append((a, i))
    if not planes:
        _fail(scene.path, "sensors.snapshot_slices_m", "is empty: give at least one plane, or leave it out")
    return tuple(planes)
