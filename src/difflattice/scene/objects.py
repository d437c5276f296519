"""A scene's objects as shapes: the plane (2d/rz) shapes and mesh sections, the 3-D solids, and
the 3-D disc rings and snapshot planes that the objects' keys describe."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .common import SceneError, _fail, _vector
from .schema import (
    BoxObject,
    CircleObject,
    CylinderObject,
    HalfspaceObject,
    IntersectionObject,
    MeshObject,
    Object,
    PolygonObject,
    PolylineObject,
    SegmentObject,
    SlabObject,
    SphereObject,
    UnionObject,
)

if TYPE_CHECKING:
    from ..lattice.geometry3d import Shape3D
    from ..lattice.grid import Grid
    from .model import Scene
    from .schema import DiscTransducer

_SHAPES_2D = (SegmentObject, BoxObject, CircleObject, PolygonObject, PolylineObject, MeshObject)
"""The object shapes of a plane (2d) or rz grid."""
_SHAPES_3D = (
    BoxObject,
    SphereObject,
    CylinderObject,
    HalfspaceObject,
    SlabObject,
    UnionObject,
    IntersectionObject,
    MeshObject,
)
"""The object shapes of a 3-D grid."""


def _names(classes) -> str:
    return ", ".join(c.__dataclass_fields__["shape"].default for c in classes)


def _mesh_file(path, o: MeshObject) -> Path:
    f = Path(o.file)
    return f if f.is_absolute() else Path(str(path)).parent / f


def _mesh_shape(path, where, o: MeshObject, geo, axisymmetric: bool):
    """A mesh file's section (`scene.meshes`) as a union of polygons (holes cut out)."""
    from .meshes import mesh_outlines

    try:
        polys = mesh_outlines(_mesh_file(path, o), axisymmetric=axisymmetric, unit=o.unit)
    except ValueError as err:
        _fail(path, f"{where}.file", str(err))
    shapes = []
    for outer, holes in polys:
        s = geo.Polygon(outer)
        for h in holes:
            s = geo.Difference(s, geo.Polygon(h))
        shapes.append(s)
    return shapes[0] if len(shapes) == 1 else geo.Union(tuple(shapes))


def _shape(path, where, o: Object, geo, axisymmetric: bool = False):
    """The `lattice.geometry` shape of a plane (2d or rz) scene's object, with its `cut`."""
    if not isinstance(o, _SHAPES_2D):
        _fail(
            path,
            f"{where}.shape",
            f'= {o.shape!r}; allowed: {_names(_SHAPES_2D)} (3-D shapes need [grid] kind = "3d")',
        )
    if isinstance(o, BoxObject):
        for k in ("centre_m", "size_m", "angles_deg"):
            if getattr(o, k) is not None:
                _fail(path, f"{where}.{k}", 'is for 3d boxes ([grid] kind = "3d"); a 2d box is lo_m and hi_m')
        for k in ("lo_m", "hi_m"):
            if getattr(o, k) is None:
                _fail(path, f"{where}.{k}", f"is required for shape = {o.shape!r}")

    def a(v):
        return np.asarray(v, dtype=float)

    try:
        if isinstance(o, SegmentObject):
            s = geo.Segment(a(o.a_m), a(o.b_m), a(o.thickness_m))
        elif isinstance(o, BoxObject):
            s = geo.Box(a(o.lo_m), a(o.hi_m))
        elif isinstance(o, CircleObject):
            s = geo.Circle(a(o.centre_m), a(o.radius_m))
        elif isinstance(o, PolygonObject):
            s = geo.Polygon(a(o.vertices_m))
        elif isinstance(o, PolylineObject):
            s = geo.Polyline(a(o.points_m), a(o.thickness_m))
        else:
            s = _mesh_shape(path, where, o, geo, axisymmetric)
    except SceneError:
        raise
    except Exception as e:  # malformed coordinates
        _fail(path, where, f"bad {o.shape} parameters: {e}")
    if o.cut is not None:
        s = geo.Difference(s, _shape(path, f"{where}.cut", o.cut, geo, axisymmetric))
    return s


_VECTORS_3D = ("centre_m", "size_m", "angles_deg", "axis", "point_m", "normal", "lo_m", "hi_m")


def shape3d(path, where: str, o: Object):
    """The `lattice.geometry3d` solid of a scene's object on a 3-D grid (box by lo_m/hi_m or
    centre_m/size_m/angles_deg, sphere, cylinder, halfspace, slab, union and intersection of
    `parts`, a closed mesh file, each with an optional `cut`); parameters as float arrays."""
    import jax.numpy as jnp

    from ..lattice import geometry3d as g3

    if not isinstance(o, _SHAPES_3D):
        _fail(path, f"{where}.shape", f"= {o.shape!r}; allowed on a 3d grid: {_names(_SHAPES_3D)}")
    for k in _VECTORS_3D:
        if getattr(o, k, None) is not None:
            _vector(path, f"{where}.{k}", getattr(o, k))

    def a(v):
        return jnp.asarray(v, dtype=float)

    s: Shape3D
    if isinstance(o, BoxObject):
        s = _box3d(path, where, o)
    elif isinstance(o, SphereObject):
        s = g3.Sphere(a(o.centre_m), a(o.radius_m))
    elif isinstance(o, CylinderObject):
        s = g3.Cylinder(a(o.centre_m), a(o.axis), a(o.radius_m), a(o.length_m))
    elif isinstance(o, HalfspaceObject):
        s = g3.HalfSpace(a(o.point_m), a(o.normal))
    elif isinstance(o, SlabObject):
        s = g3.Slab(a(o.point_m), a(o.normal), a(o.thickness_m))
    elif isinstance(o, MeshObject):  # the whole closed mesh, in the file's unit, in grid coordinates
        from .meshes import load_closed_mesh

        try:
            verts, faces = load_closed_mesh(_mesh_file(path, o), unit=o.unit)
        except ValueError as err:
            _fail(path, f"{where}.file", str(err))
        s = g3.MeshSolid(verts, faces)
    else:
        if not o.parts:
            _fail(path, f"{where}.parts", 'give a list of inline tables, e.g. [{ shape = "halfspace", ... }, ...]')
        solids = tuple(shape3d(path, f"{where}.parts[{j}]", part) for j, part in enumerate(o.parts))
        s = g3.Union3D(solids) if isinstance(o, UnionObject) else g3.Intersection3D(solids)
    if o.cut is not None:
        s = g3.Difference3D(s, shape3d(path, f"{where}.cut", o.cut))
    return s


def _box3d(path, where: str, o: BoxObject):
    """A 3-D box: by its corners, or by centre and size turned by angles."""
    import jax.numpy as jnp

    from ..lattice import geometry3d as g3

    corners = o.centre_m is None and o.size_m is None
    for k in ("lo_m", "hi_m") if corners else ("centre_m", "size_m"):
        if getattr(o, k) is None:
            extra = " (or centre_m and size_m)" if corners else ""
            _fail(path, f"{where}.{k}", f"is required for shape = 'box'{extra}")
    if corners:
        lo, hi = np.asarray(o.lo_m, float), np.asarray(o.hi_m, float)
        if np.any(hi <= lo):
            _fail(path, f"{where}.hi_m", f"= {hi.tolist()} must exceed lo_m = {lo.tolist()} on every axis")
        return g3.OrientedBox(jnp.asarray(0.5 * (lo + hi)), jnp.asarray(hi - lo))
    angles = o.angles_deg if o.angles_deg is not None else [0.0, 0.0, 0.0]
    return g3.OrientedBox(
        jnp.asarray(o.centre_m, dtype=float), jnp.asarray(o.size_m, dtype=float), jnp.asarray(angles, dtype=float)
    )


def _union3d(occs):
    """Union of 3-D occupancies: one is kept as it is (bitwise), several combine as
    1 - prod(1 - o) (the 2-D `union_occupancy`, without its no-op for a single one)."""
    if len(occs) == 1:
        return occs[0]
    free = 1 - occs[0]
    for o in occs[1:]:
        free = free * (1 - o)
    return 1 - free


def _rings_3d(scene: Scene, where: str, t: DiscTransducer) -> tuple[dict | None, float | None]:
    """(rings dict for `disc_transducer_3d` or None, diameter in m or None) of a 3-D disc: from
    `fit_report` (`rings_from_fit_report`), or `ring_edges_m` with per-ring weights and lags."""
    from ..solver.sources import rings_from_fit_report

    p = scene.path
    diameter = t.diameter_m
    if t.fit_report is not None:
        if t.ring_edges_m is not None or t.weights is not None or t.lags_s is not None:
            _fail(p, f"{where}.fit_report", "gives the rings: leave out ring_edges_m, weights and lags_s")
        report = Path(p).parent / t.fit_report
        try:
            rings = rings_from_fit_report(report)
        except OSError as e:
            _fail(p, f"{where}.fit_report", f"= {t.fit_report!r}: cannot read {report} ({e.strerror})")
        except (ValueError, KeyError) as e:
            _fail(p, f"{where}.fit_report", f"= {t.fit_report!r}: {e}")
        d = rings.pop("diameter_m", None)
        return rings, diameter if diameter is not None else d
    if t.ring_edges_m is not None:
        if t.weights is None:
            _fail(p, f"{where}.weights", "is required with ring_edges_m (one weight per ring)")
        edges = t.ring_edges_m
        if not all(isinstance(e, (list, tuple)) and len(e) == 2 for e in edges):
            _fail(p, f"{where}.ring_edges_m", "give [[inner, outer], ...] radii in metres, one pair per ring")
        rings = {"ring_edges_m": [list(e) for e in edges], "weights": list(t.weights)}
        if t.lags_s is not None:
            rings["lags_s"] = list(t.lags_s)
        return rings, diameter
    if t.weights is not None or t.lags_s is not None:
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
    sl = scene.sensors.snapshot_slices_m
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
