"""3-D geometry: parametrised solids as signed distance functions (SDF), rasterised hard or smooth.

The 3-D counterpart of `geometry.py`, with the same conventions: parameters in metres as arrays
(gradients reach them), `sdf(x, y, z)` negative inside, and `rasterise3d` giving an occupancy in
[0, 1] per cell: "hard" is 1 inside and 0 outside; "smooth" ramps over `ramp_cells` cells across the
boundary, ``smoothstep(clip(0.5 - sdf / (dx ramp), 0, 1))`` (an estimate of the covered volume
fraction with a continuous derivative: the cut-cell occupancy the conservative lattice reads as
the cell's solid fraction).

Orientations are given by unit-free direction vectors (normalised inside, so any length works)
or, for boxes, by three angles in degrees (yaw about z, then pitch about the new y, then roll
about the new x: ``R = Rz(yaw) Ry(pitch) Rx(roll)`` maps box axes to grid axes).

Solids: `Sphere`, `Cylinder` (finite, capped, any axis), `OrientedBox`, `HalfSpace` (everything
behind a plane), `Slab` (a plate of given thickness at any orientation), and the combinators
`Union3D`, `Intersection3D`, `Difference3D`; and `MeshSolid`, the inside of a closed triangle mesh
(inside by ray parity, distance exact near the surface; not differentiable). SDFs of combinations are exact outside unions and
bounds elsewhere (min/max), which is all the one-cell smooth ramp needs near the surface.
"""

from __future__ import annotations

import functools
from typing import Literal

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float


class Shape3D(eqx.Module):
    """Base class: `sdf(x, y, z)` with coordinates in metres (broadcastable arrays), negative inside."""

    def sdf(self, x, y, z):  # pragma: no cover - abstract
        raise NotImplementedError


def _unit(v):
    v = jnp.asarray(v)
    return v / jnp.sqrt(jnp.sum(v * v))


def rotation_matrix(angles_deg) -> Array:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` from (yaw, pitch, roll) in degrees (differentiable)."""
    a = jnp.deg2rad(jnp.asarray(angles_deg))
    cy, sy = jnp.cos(a[0]), jnp.sin(a[0])
    cp, sp = jnp.cos(a[1]), jnp.sin(a[1])
    cr, sr = jnp.cos(a[2]), jnp.sin(a[2])
    one, zero = jnp.ones_like(cy), jnp.zeros_like(cy)
    Rz = jnp.stack([jnp.stack([cy, -sy, zero]), jnp.stack([sy, cy, zero]), jnp.stack([zero, zero, one])])
    Ry = jnp.stack([jnp.stack([cp, zero, sp]), jnp.stack([zero, one, zero]), jnp.stack([-sp, zero, cp])])
    Rx = jnp.stack([jnp.stack([one, zero, zero]), jnp.stack([zero, cr, -sr]), jnp.stack([zero, sr, cr])])
    return Rz @ Ry @ Rx


def _dot(v, x, y, z):
    return v[0] * x + v[1] * y + v[2] * z


def _safe_norm(*parts):
    """sqrt(sum of squares) with a finite gradient at 0."""
    s = functools.reduce(lambda a, b: a + b, [p * p for p in parts])
    pos = s > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, s, 1.0)), 0.0)


class Sphere(Shape3D):
    """A ball of `radius_m` around `centre_m` (x, y, z), metres."""

    centre_m: Float[Array, 3]
    radius_m: Float[Array, ""]

    def sdf(self, x, y, z):
        c = jnp.asarray(self.centre_m)
        return _safe_norm(x - c[0], y - c[1], z - c[2]) - self.radius_m


class Cylinder(Shape3D):
    """A finite (capped) circular cylinder: axis through `centre_m` along `axis` (any length),
    `radius_m`, total `length_m` (metres). A post is a long vertical cylinder."""

    centre_m: Float[Array, 3]
    axis: Float[Array, 3]
    radius_m: Float[Array, ""]
    length_m: Float[Array, ""]

    def sdf(self, x, y, z):
        c = jnp.asarray(self.centre_m)
        a = _unit(self.axis)
        dx, dy, dz = x - c[0], y - c[1], z - c[2]
        t = _dot(a, dx, dy, dz)
        radial = _safe_norm(dx - t * a[0], dy - t * a[1], dz - t * a[2]) - self.radius_m
        axial = jnp.abs(t) - 0.5 * self.length_m
        outside = _safe_norm(jnp.maximum(radial, 0), jnp.maximum(axial, 0))
        return outside + jnp.minimum(jnp.maximum(radial, axial), 0)


class OrientedBox(Shape3D):
    """A rectangular box of edge lengths `size_m` (along its own x, y, z) centred at `centre_m`,
    rotated by `angles_deg` = (yaw, pitch, roll) in degrees (see `rotation_matrix`)."""

    centre_m: Float[Array, 3]
    size_m: Float[Array, 3]
    angles_deg: Float[Array, 3] = eqx.field(default_factory=lambda: jnp.zeros(3))

    def sdf(self, x, y, z):
        c = jnp.asarray(self.centre_m)
        R = rotation_matrix(self.angles_deg)
        h = 0.5 * jnp.asarray(self.size_m)
        dx, dy, dz = x - c[0], y - c[1], z - c[2]
        # box-frame coordinates: R^T d
        q = [jnp.abs(_dot(R[:, i], dx, dy, dz)) - h[i] for i in range(3)]
        outside = _safe_norm(*(jnp.maximum(qi, 0) for qi in q))
        return outside + jnp.minimum(jnp.maximum(jnp.maximum(q[0], q[1]), q[2]), 0)


class HalfSpace(Shape3D):
    """Everything behind the plane through `point_m` whose outward normal is `normal` (the solid
    side is opposite to the normal): ``sdf = (x - point) . n``."""

    point_m: Float[Array, 3]
    normal: Float[Array, 3]

    def sdf(self, x, y, z):
        p = jnp.asarray(self.point_m)
        n = _unit(self.normal)
        return _dot(n, x - p[0], y - p[1], z - p[2])


class Slab(Shape3D):
    """A plate of `thickness_m` centred on the plane through `point_m` with normal `normal`
    (unbounded in-plane: cut it with `Intersection3D` for a finite panel)."""

    point_m: Float[Array, 3]
    normal: Float[Array, 3]
    thickness_m: Float[Array, ""]

    def sdf(self, x, y, z):
        p = jnp.asarray(self.point_m)
        n = _unit(self.normal)
        return jnp.abs(_dot(n, x - p[0], y - p[1], z - p[2])) - 0.5 * self.thickness_m


class Union3D(Shape3D):
    """The union of `shapes` (minimum of their signed distances)."""

    shapes: tuple[Shape3D, ...]

    def sdf(self, x, y, z):
        return functools.reduce(jnp.minimum, [s.sdf(x, y, z) for s in self.shapes])


class Intersection3D(Shape3D):
    """The intersection of `shapes` (maximum of their signed distances)."""

    shapes: tuple[Shape3D, ...]

    def sdf(self, x, y, z):
        return functools.reduce(jnp.maximum, [s.sdf(x, y, z) for s in self.shapes])


class Difference3D(Shape3D):
    """`base` with `cut` removed."""

    base: Shape3D
    cut: Shape3D

    def sdf(self, x, y, z):
        return jnp.maximum(self.base.sdf(x, y, z), -self.cut.sdf(x, y, z))


def cell_coordinates_m(grid) -> tuple[Array, Array, Array]:
    """Cell-centre coordinates of a 3-D grid as broadcastable arrays (nx,1,1), (1,ny,1), (1,1,nz)
    in metres (cell (0, 0, 0) at the origin)."""
    shape = tuple(grid.shape)
    if len(shape) != 3:
        raise ValueError(f"rasterise3d needs a 3-D grid (shape (nx, ny, nz)), got shape {shape}")
    nx, ny, nz = shape
    dt = grid.jnp_dtype
    h = grid.dx_m
    return (
        (jnp.arange(nx, dtype=dt) * h)[:, None, None],
        (jnp.arange(ny, dtype=dt) * h)[None, :, None],
        (jnp.arange(nz, dtype=dt) * h)[None, None, :],
    )


def rasterise3d(
    shape: Shape3D, grid, mode: Literal["hard", "smooth"] = "smooth", *, ramp_cells: float = 1.0
) -> Float[Array, "nx ny nz"]:
    """Occupancy of `shape` per cell of a 3-D `grid` (1 inside), hard or smooth (see the module
    docstring; the same convention as `geometry.rasterise`)."""
    if not ramp_cells > 0:
        raise ValueError(f"ramp_cells = {ramp_cells} must be > 0")
    if mode not in ("hard", "smooth"):
        raise ValueError(f"rasterise mode = {mode!r}; allowed: 'hard', 'smooth'")
    x, y, z = cell_coordinates_m(grid)
    dt = grid.jnp_dtype
    d = shape.sdf(x, y, z) / (grid.dx_m * ramp_cells)
    d = jnp.broadcast_to(d, tuple(grid.shape))
    if mode == "hard":
        return (d < 0).astype(dt)
    u = jnp.clip(0.5 - d, 0.0, 1.0)
    return (u * u * (3 - 2 * u)).astype(dt)


# ------------------------------------------------------------------------------------------
# Solids from triangle meshes (STL, OBJ, ... read in the scene layer): inside by ray parity,
# distance exact within a band around the surface.


def _segment_distance_np(p, a, b):
    """Distance from points p (n, 3) to the segment a-b (NumPy)."""
    ab = b - a
    t = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def point_triangle_distance(p, a, b, c):
    """Distance from points p (n, 3) to the triangle abc: the distance to its plane where the
    foot of the perpendicular lies inside it, else to the nearest of its three edges."""
    edges = np.minimum(
        np.minimum(_segment_distance_np(p, a, b), _segment_distance_np(p, b, c)), _segment_distance_np(p, c, a)
    )
    n = np.cross(b - a, c - a)
    nn = float(np.linalg.norm(n))
    if nn == 0.0:  # a degenerate (sliver) triangle is its edges
        return edges
    n = n / nn
    h = (p - a) @ n
    q = p - h[:, None] * n
    inside = (np.cross(b - a, q - a) @ n >= 0) & (np.cross(c - b, q - b) @ n >= 0) & (np.cross(a - c, q - c) @ n >= 0)
    return np.where(inside, np.abs(h), edges)


def _axes(x, y, z) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The 1-D axes of `cell_coordinates_m`'s broadcastable (nx,1,1), (1,ny,1), (1,1,nz) arrays."""
    xs, ys, zs = (np.asarray(v, float) for v in (x, y, z))
    if not (
        xs.ndim == ys.ndim == zs.ndim == 3
        and xs.shape[1:] == (1, 1)
        and ys.shape[::2] == (1, 1)
        and zs.shape[:2] == (1, 1)
    ):
        raise ValueError("MeshSolid.sdf takes the grid's axes as cell_coordinates_m gives them (rasterise3d)")
    return xs[:, 0, 0], ys[0, :, 0], zs[0, 0, :]


def _span(axis: np.ndarray, lo: float, hi: float) -> slice:
    return slice(int(np.searchsorted(axis, lo, "left")), int(np.searchsorted(axis, hi, "right")))


class MeshSolid(Shape3D):
    """The inside of a closed triangle mesh (vertices in metres, faces as vertex indices; fixed:
    no gradient reaches it). `sdf` on a grid's axes: a cell is inside when a ray from it along
    -z crosses the surface an odd number of times (columns offset by 1e-7 cell so that no ray
    meets an edge exactly); its distance is the exact distance to the nearest triangle within
    `band_cells` cells of the surface and `band_cells` cells beyond (enough for the smooth
    ramp of `rasterise3d`, which reads only |sdf| < ramp / 2). Give a watertight mesh (the scene
    layer checks): the parity of an open one is meaningless."""

    vertices_m: np.ndarray  # NumPy leaves: read on the host, never traced
    faces: np.ndarray
    band_cells: float = eqx.field(static=True, default=4.0)

    def sdf(self, x, y, z):
        xs, ys, zs = _axes(x, y, z)
        h = float(xs[1] - xs[0]) if len(xs) > 1 else float(ys[1] - ys[0])
        band = self.band_cells * h
        tri = np.asarray(self.vertices_m, float)[np.asarray(self.faces)]
        inside = self._parity(tri, xs, ys, zs, h)
        dist = np.full(inside.shape, band)
        for a, b, c in tri:
            lo, hi = np.minimum(np.minimum(a, b), c) - band, np.maximum(np.maximum(a, b), c) + band
            si, sj, sk = _span(xs, lo[0], hi[0]), _span(ys, lo[1], hi[1]), _span(zs, lo[2], hi[2])
            X, Y, Z = np.meshgrid(xs[si], ys[sj], zs[sk], indexing="ij")
            if X.size == 0:
                continue
            pts = np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1)
            n = np.cross(b - a, c - a)
            nn = float(np.linalg.norm(n))
            near = np.abs((pts - a) @ (n / nn)) <= band if nn > 0 else np.ones(len(pts), bool)
            sub = dist[si, sj, sk].ravel()
            sub[near] = np.minimum(sub[near], point_triangle_distance(pts[near], a, b, c))
            dist[si, sj, sk] = sub.reshape(X.shape)
        return jnp.asarray(np.where(inside, -dist, dist))

    @staticmethod
    def _parity(tri, xs, ys, zs, h) -> np.ndarray:
        """Inside mask by the parity of surface crossings below each cell along its z column."""
        counts = np.zeros((len(xs), len(ys), len(zs) + 1), np.int32)
        ox, oy = 1e-7 * h * np.sqrt(2.0), 1e-7 * h * np.sqrt(3.0)
        for a, b, c in tri:
            lo, hi = np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)
            si, sj = _span(xs + ox, lo[0], hi[0]), _span(ys + oy, lo[1], hi[1])
            X, Y = np.meshgrid(xs[si] + ox, ys[sj] + oy, indexing="ij")
            if X.size == 0:
                continue
            det = (b[1] - c[1]) * (a[0] - c[0]) + (c[0] - b[0]) * (a[1] - c[1])
            if det == 0.0:  # parallel to z: no ray crosses it
                continue
            w0 = ((b[1] - c[1]) * (X - c[0]) + (c[0] - b[0]) * (Y - c[1])) / det
            w1 = ((c[1] - a[1]) * (X - c[0]) + (a[0] - c[0]) * (Y - c[1])) / det
            w2 = 1.0 - w0 - w1
            hit = (w0 >= 0) & (w1 >= 0) & (w2 >= 0)
            if not hit.any():
                continue
            zc = w0 * a[2] + w1 * b[2] + w2 * c[2]
            i, j = np.nonzero(hit)
            k = np.searchsorted(zs, zc[hit], "right")  # cells k, k+1, ... lie above the crossing
            np.add.at(counts, (i + si.start, j + sj.start, k), 1)
        return (np.cumsum(counts, axis=2)[:, :, : len(zs)] % 2) == 1
