"""A design's walls as parts to print or mill: watertight STL meshes in millimetres and a CSV of
their outlines.

Each wall is the set of points within half its thickness of its centre line (the shape the
lattice rasterised: `lattice.geometry.Polyline`), outlined with `shapely` (round caps and joins,
as the signed distance has). A plane (2-D) design describes a slot: each wall outline is
extruded by `depth_m` along the third axis. An axisymmetric (rz) design describes a body of
revolution: the outline, clipped to r >= 0, is revolved about the axis in `segments` steps.
Meshes are built and written with `trimesh`; `check_watertight` checks them independently
(every edge shared by exactly two faces in opposite directions, positive volume).

Coordinates: the design's own (x, y) in the plane, or (z, r) revolved to x = r cos(phi),
y = r sin(phi), z = z; all in millimetres in the files.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .problem import DesignProblem

MM_PER_M = 1e3


def wall_outlines(problem: DesignProblem, params) -> list[np.ndarray]:
    """Closed outlines (n, 2) in metres of the design's walls (for rz: clipped to r >= 0), each
    counter-clockwise without the repeated first point."""
    from shapely.geometry import LineString, box

    shape = params.shape(problem.anchor_m)
    walls = shape.walls() if hasattr(shape, "walls") else (shape.wall(),)
    out = []
    for w in walls:
        poly = LineString(np.asarray(w.points_m, float)).buffer(0.5 * float(w.thickness_m), quad_segs=8)
        if problem.lattice.ring_metric:
            poly = poly.intersection(box(-1e3, 0.0, 1e3, 1e3))
        for part in getattr(poly, "geoms", [poly]):
            if part.is_empty or part.area <= 0:
                continue
            ring = part.exterior
            xy = np.asarray(ring.coords)[:-1]
            if not ring.is_ccw:
                xy = xy[::-1]
            out.append(xy)
    return out


def revolve(outline_m: np.ndarray, segments: int = 128):
    """The body of revolution of a closed (z, r) outline (r >= 0) about the z axis, as a
    `trimesh.Trimesh` in millimetres. Vertices on the axis are shared by every segment, so a
    profile touching the axis still closes."""
    import trimesh

    zr = np.asarray(outline_m, float) * MM_PER_M
    zr[:, 1] = np.maximum(zr[:, 1], 0.0)
    phi = 2 * math.pi * np.arange(segments) / segments
    verts: list[tuple[float, float, float]] = []
    index: dict[tuple[int, int], int] = {}

    def vid(i: int, k: int) -> int:
        key = (i, 0) if zr[i, 1] == 0.0 else (i, k % segments)
        if key not in index:
            z, r = zr[i]
            index[key] = len(verts)
            verts.append((r * math.cos(phi[key[1]]), r * math.sin(phi[key[1]]), z))
        return index[key]

    faces = []
    n = len(zr)
    for i in range(n):
        j = (i + 1) % n
        if zr[i, 1] == 0.0 and zr[j, 1] == 0.0:
            continue  # an edge on the axis sweeps nothing
        for k in range(segments):
            a, b, c, d = vid(i, k), vid(j, k), vid(j, k + 1), vid(i, k + 1)
            for tri in ((a, b, c), (a, c, d)):
                if len(set(tri)) == 3:
                    faces.append(tri)
    mesh = trimesh.Trimesh(np.asarray(verts), np.asarray(faces), process=False)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def extrude(outline_m: np.ndarray, depth_m: float):
    """A plane outline (x, y) extruded by `depth_m` along z (from -depth/2 to depth/2), as a
    `trimesh.Trimesh` in millimetres."""
    import trimesh
    from shapely.geometry import Polygon

    mesh = trimesh.creation.extrude_polygon(Polygon(np.asarray(outline_m, float) * MM_PER_M), depth_m * MM_PER_M)
    mesh.apply_translation((0.0, 0.0, -0.5 * depth_m * MM_PER_M))
    return mesh


def part_mesh(problem: DesignProblem, params, *, depth_m: float | None = None, segments: int = 128):
    """The design's walls as one mesh in millimetres (one watertight body per wall): revolved on
    an rz design, extruded by `depth_m` (default: the transducer's width) on a plane one."""
    import trimesh

    outlines = wall_outlines(problem, params)
    if not outlines:
        raise ValueError("the design has no walls to export")
    if problem.lattice.ring_metric:
        bodies = [revolve(o, segments) for o in outlines]
    else:
        depth = problem.n_cells * problem.grid.dx_m if depth_m is None else float(depth_m)
        if not depth > 0:
            raise ValueError(f"depth_m = {depth_m}: the slot's depth must be > 0 m")
        bodies = [extrude(o, depth) for o in outlines]
    return trimesh.util.concatenate(bodies)


def check_watertight(mesh) -> dict:
    """Independent checks of a triangle mesh: every undirected edge in exactly two faces, each
    directed edge once (consistent orientation), and the signed volume (divergence theorem)
    positive. Returns the counts and the volume (mesh units^3)."""
    f = np.asarray(mesh.faces)
    v = np.asarray(mesh.vertices, float)
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    und = np.sort(directed, axis=1)
    _, und_counts = np.unique(und, axis=0, return_counts=True)
    _, dir_counts = np.unique(directed, axis=0, return_counts=True)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    volume = float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)
    return {
        "edges_not_in_two_faces": int(np.sum(und_counts != 2)),
        "directed_edges_repeated": int(np.sum(dir_counts != 1)),
        "volume": volume,
        "watertight": bool(np.all(und_counts == 2) and np.all(dir_counts == 1) and volume > 0),
    }


def write_parts(problem: DesignProblem, params, out_dir: str | Path, *, name: str | None = None, **kwargs) -> dict:
    """Write `<name>.stl` (millimetres) and `<name>_profile.csv` (the wall outlines, one row per
    vertex: wall index and coordinates in mm) into `out_dir`; returns their paths and the mesh
    checks, and the maker constraints measured on the part (`constraints.part_report`). Refuses
    (ValueError) a mesh that fails `check_watertight`."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    name = name or problem.kind
    mesh = part_mesh(problem, params, **kwargs)
    checks = check_watertight(mesh)
    if not checks["watertight"]:
        raise ValueError(f"the exported {name} mesh is not watertight: {checks}")
    stl = out / f"{name}.stl"
    mesh.export(stl)
    cols = ("z_mm", "r_mm") if problem.lattice.ring_metric else ("x_mm", "y_mm")
    rows = [f"wall,{cols[0]},{cols[1]}"]
    for i, o in enumerate(wall_outlines(problem, params)):
        rows += [f"{i},{p[0] * MM_PER_M:.6f},{p[1] * MM_PER_M:.6f}" for p in o]
    csv = out / f"{name}_profile.csv"
    csv.write_text("\n".join(rows) + "\n")
    bounds = np.asarray(mesh.bounds, float)
    from .constraints import part_report

    report = part_report(problem, params, mesh, wall_outlines(problem, params), problem.constraints)
    return {"stl": str(stl), "profile_csv": str(csv), "bounds_mm": bounds.tolist(), **checks, "constraints": report}


def read_profile(path: str | Path) -> list[np.ndarray]:
    """The wall outlines of a `<name>_profile.csv`, in metres (as `wall_outlines` returns them)."""
    lines = Path(path).read_text().splitlines()[1:]
    walls: dict[int, list[tuple[float, float]]] = {}
    for ln in lines:
        i, a, b = ln.split(",")
        walls.setdefault(int(i), []).append((float(a) / MM_PER_M, float(b) / MM_PER_M))
    return [np.asarray(walls[k]) for k in sorted(walls)]
