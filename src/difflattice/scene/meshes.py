"""Objects from mesh files (STL, OBJ, ...; read with `trimesh`) as outlines in a scene's plane.

A plane (2-D) scene takes the mesh's section by the plane z = 0 (an extruded part, e.g. from
`design.parts`, is its outline); an axisymmetric (rz) scene takes the section by a half-plane
that contains the mesh's z axis (the axis of revolution), as (z, r) outlines: a body of
revolution is its meridian profile. The outlines become polygon objects, rasterised with cut
cells like the built-in shapes. A 3-D scene takes the whole mesh (`load_closed_mesh`) as a
`lattice.geometry3d.MeshSolid`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

UNITS_M = {"mm": 1e-3, "m": 1.0, "um": 1e-6, "cm": 1e-2, "in": 0.0254}
"""Length units a mesh file may be written in (its `unit` key), in metres."""

_ROUND = 9
"""Decimals (of the file's unit) to which section points are rounded, so that the end of one
triangle's segment meets the start of its neighbour's."""


_WELD = 1e-6
"""Section points closer than this fraction of the mesh's size are one point: a float32 STL
(7 digits) puts the two ends of one triangle edge's section a few 1e-7 of the size apart."""


def _weld(segments: np.ndarray, tol: float) -> np.ndarray:
    """`segments` (n, 2, 2) with every endpoint replaced by the first of its cluster of endpoints
    within `tol` (union-find over a k-d tree's close pairs), so neighbouring triangles' sections join."""
    from scipy.spatial import cKDTree

    pts = segments.reshape(-1, 2)
    parent = np.arange(len(pts))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in cKDTree(pts).query_pairs(tol):
        a, b = root(i), root(j)
        if a != b:
            parent[max(a, b)] = min(a, b)
    reps = np.array([root(i) for i in range(len(pts))])
    return pts[reps].reshape(segments.shape)


def _read_watertight(path: str | Path, unit: str, inside: str) -> Any:
    """The trimesh of a watertight mesh file; ValueError naming the problem (unknown unit,
    unreadable file, no triangles, open edges: `inside` says what has no inside then)."""
    import trimesh

    if unit not in UNITS_M:
        raise ValueError(f"unit = {unit!r}; allowed: {', '.join(UNITS_M)}")
    p = Path(path)
    try:
        mesh: Any = trimesh.load(p, force="mesh")
    except (OSError, ValueError) as err:
        raise ValueError(f"cannot read the mesh file {p}: {err}") from None
    if len(mesh.faces) == 0:
        raise ValueError(f"{p} holds no triangles")
    if not mesh.is_watertight:
        raise ValueError(f"{p} is not watertight (open edges): {inside} has no inside; close the mesh")
    return mesh


def load_closed_mesh(path: str | Path, unit: str = "mm") -> tuple[np.ndarray, np.ndarray]:
    """(vertices in metres (n, 3), faces (m, 3)) of a watertight mesh file; ValueError naming the
    problem (unknown unit, unreadable file, no triangles, open edges) otherwise."""
    mesh = _read_watertight(path, unit, "it")
    return np.asarray(mesh.vertices, float) * UNITS_M[unit], np.asarray(mesh.faces, np.int64)


def mesh_outlines(
    path: str | Path, *, axisymmetric: bool, unit: str = "mm"
) -> list[tuple[np.ndarray, list[np.ndarray]]]:
    """The mesh's section as polygons, each (exterior (n, 2), [holes]) in metres: (x, y) at z = 0,
    or (z, r >= 0) in a half-plane through the z axis when `axisymmetric`. Raises ValueError
    naming the problem (unreadable file, open mesh, empty section)."""
    import trimesh
    from shapely.geometry import LineString, box
    from shapely.ops import polygonize, unary_union

    p = Path(path)
    mesh = _read_watertight(p, unit, "its section")
    # a half-plane through the axis at a small angle, so it passes through no vertex of a mesh
    # revolved in equal steps from phi = 0 (its section radius differs by 1 - cos(1e-7) ~ 5e-15)
    phi = 1e-7 if axisymmetric else 0.0
    normal = (math.sin(phi), -math.cos(phi), 0.0) if axisymmetric else (0.0, 0.0, 1.0)
    segs = trimesh.intersections.mesh_plane(mesh, plane_normal=normal, plane_origin=(0.0, 0.0, 0.0))
    if len(segs) == 0:
        where = "a half-plane through its z axis" if axisymmetric else "the plane z = 0"
        raise ValueError(f"{p}: the mesh does not meet {where}; place the part there (the scene's section)")
    if axisymmetric:  # in-plane coordinates (z, r): r along (cos phi, sin phi, 0)
        uv = np.stack([segs[..., 2], segs[..., 0] * math.cos(phi) + segs[..., 1] * math.sin(phi)], axis=-1)
    else:
        uv = segs[..., :2]
    uv = _weld(np.round(uv, _ROUND), _WELD * float(np.ptp(np.asarray(mesh.vertices))))
    polys = list(polygonize([LineString(s) for s in uv if not np.array_equal(s[0], s[1])]))
    shape = unary_union(polys)
    if axisymmetric:
        shape = shape.intersection(box(-1e12, 0.0, 1e12, 1e12))
    out = []
    for part in getattr(shape, "geoms", [shape]):
        if part.is_empty or part.area <= 0:
            continue
        k = UNITS_M[unit]
        out.append((np.asarray(part.exterior.coords)[:-1] * k, [np.asarray(h.coords)[:-1] * k for h in part.interiors]))
    if not out:
        raise ValueError(f"{p}: the section has no area")
    return out
