"""Geometry: parametrised shapes as signed distance functions (SDF), rasterised hard or smooth.

Shapes take their parameters in metres as arrays, so gradients reach them. Rasterisation gives an
occupancy in [0, 1] per cell: "hard" is 1 inside and 0 outside; "smooth" ramps over one cell
across the boundary, ``smoothstep(clip(0.5 - sdf / dx, 0, 1))`` (an estimate of the covered area
fraction with a continuous derivative), so occupancy is differentiable in the shape parameters
and Taylor tests see no kinks.

The paper's scenes are built from these primitives in `scenes.py`.
"""

from __future__ import annotations

from typing import Literal, Sequence

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .grid import Grid


class Shape(eqx.Module):
    """Base class: `sdf(x, y)` with coordinates in metres, negative inside."""

    def sdf(self, x, y):  # pragma: no cover - abstract
        raise NotImplementedError


class Circle(Shape):
    """A disc of `radius_m` around `centre_m` (x, y), metres."""

    centre_m: Float[Array, "2"]
    radius_m: Float[Array, ""]

    def sdf(self, x, y):
        c = jnp.asarray(self.centre_m)
        return jnp.hypot(x - c[0], y - c[1]) - self.radius_m


class Segment(Shape):
    """A wall: the segment from `a_m` to `b_m` thickened to `thickness_m` (round ends)."""

    a_m: Float[Array, "2"]
    b_m: Float[Array, "2"]
    thickness_m: Float[Array, ""]

    def sdf(self, x, y):
        return _segment_distance(x, y, jnp.asarray(self.a_m), jnp.asarray(self.b_m)) - 0.5 * self.thickness_m


class Box(Shape):
    """An axis-aligned rectangle from `lo_m` (x, y) to `hi_m`."""

    lo_m: Float[Array, "2"]
    hi_m: Float[Array, "2"]

    def sdf(self, x, y):
        lo, hi = jnp.asarray(self.lo_m), jnp.asarray(self.hi_m)
        c, h = 0.5 * (lo + hi), 0.5 * (hi - lo)
        qx, qy = jnp.abs(x - c[0]) - h[0], jnp.abs(y - c[1]) - h[1]
        outside = jnp.hypot(jnp.maximum(qx, 0), jnp.maximum(qy, 0))
        return outside + jnp.minimum(jnp.maximum(qx, qy), 0)


class Polygon(Shape):
    """A closed polygon with vertices (n, 2) in metres (either orientation)."""

    vertices_m: Float[Array, "n 2"]

    def sdf(self, x, y):
        v = jnp.asarray(self.vertices_m)
        a, b = v, jnp.roll(v, -1, axis=0)
        d = jnp.min(
            jnp.stack([_segment_distance(x, y, a[i], b[i]) for i in range(v.shape[0])]), axis=0
        )
        # even-odd rule for inside
        inside = jnp.zeros(jnp.shape(x), bool)
        for i in range(v.shape[0]):
            (x1, y1), (x2, y2) = a[i], b[i]
            cond = (y1 > y) != (y2 > y)
            xcross = x1 + (y - y1) * (x2 - x1) / jnp.where(y2 == y1, 1e-30, y2 - y1)
            inside = inside ^ (cond & (x < xcross))
        return jnp.where(inside, -d, d)


class Polyline(Shape):
    """An open chain of walls through points (n, 2), thickness `thickness_m`."""

    points_m: Float[Array, "n 2"]
    thickness_m: Float[Array, ""]

    def sdf(self, x, y):
        p = jnp.asarray(self.points_m)
        d = jnp.min(jnp.stack([_segment_distance(x, y, p[i], p[i + 1]) for i in range(p.shape[0] - 1)]), axis=0)
        return d - 0.5 * self.thickness_m


class Union(Shape):
    """The union of `shapes` (minimum of their signed distances)."""

    shapes: tuple[Shape, ...]

    def sdf(self, x, y):
        return jnp.min(jnp.stack([s.sdf(x, y) for s in self.shapes]), axis=0)


class Difference(Shape):
    """`base` with `cut` removed."""

    base: Shape
    cut: Shape

    def sdf(self, x, y):
        return jnp.maximum(self.base.sdf(x, y), -self.cut.sdf(x, y))


def _segment_distance(x, y, a, b):
    abx, aby = b[0] - a[0], b[1] - a[1]
    apx, apy = x - a[0], y - a[1]
    t = jnp.clip((apx * abx + apy * aby) / (abx * abx + aby * aby + 1e-30), 0.0, 1.0)
    return jnp.hypot(apx - t * abx, apy - t * aby)


def rasterise(
    shape: Shape, grid: Grid, mode: Literal["hard", "smooth"] = "smooth"
) -> Float[Array, "nx ny"]:
    """Occupancy of `shape` per cell (1 inside)."""
    nx, ny = grid.shape
    dt = grid.jnp_dtype
    x = (jnp.arange(nx, dtype=dt) * grid.dx_m)[:, None] * jnp.ones((1, ny), dt)
    y = (jnp.arange(ny, dtype=dt) * grid.dx_m)[None, :] * jnp.ones((nx, 1), dt)
    d = shape.sdf(x, y) / grid.dx_m
    if mode == "hard":
        return (d < 0).astype(dt)
    if mode == "smooth":
        u = jnp.clip(0.5 - d, 0.0, 1.0)
        return (u * u * (3 - 2 * u)).astype(dt)
    raise ValueError(f"rasterise mode = {mode!r}; allowed: 'hard', 'smooth'")


def union_occupancy(occupancies: Sequence[Array]) -> Array:
    """Combine occupancies (probabilistic union, differentiable)."""
    free = 1.0
    for o in occupancies:
        free = free * (1 - o)
    return 1 - free
