"""Geometry: parametrised shapes as signed distance functions (SDF), rasterised hard or smooth.

Shapes take their parameters in metres as arrays, so gradients reach them. Rasterisation gives an
occupancy in [0, 1] per cell: "hard" is 1 inside and 0 outside; "smooth" ramps over one cell
across the boundary, ``smoothstep(clip(0.5 - sdf / dx, 0, 1))`` (an estimate of the covered area
fraction with a continuous derivative), so occupancy is differentiable in the shape parameters
and Taylor tests see no kinks.

**Gradients under `jax.jit`.** Every min, max, clip and hypot on the way from a shape parameter to
the occupancy is written as a `jnp.where` select on a comparison (`_min2`, `_max2`, `_clip`,
`_norm`, `_min_axis0`), never as `jnp.minimum` / `jnp.maximum` / `jnp.clip` / `jnp.min` /
`jnp.hypot`. JAX differentiates those by *equality* of an operand with the op's result
(``eq(x, max(x, y))``); compiled by XLA on a CPU with FMA, the operand is recomputed in another
fusion with a different contraction (``a - t b`` as one fused multiply-add in one place and a
rounded product in the other), the equality fails by one ulp in many cells and their gradient is
silently dropped (`--xla_cpu_max_isa=SSE4_2`, no FMA, hides it). Shape gradients of a cone and a
dish on an rz grid came out 0.56x to -4x the true value under `jit` (eager was right, and so were
NumPy coordinates, which XLA folds differently; tests/core/test_rz_geometry_jit_gradient.py). A
select keeps the comparison's boolean as the residual, so a one-ulp difference can only move a
cell across an exact tie, where either side's derivative is a valid one.

The paper's scenes are built from these primitives in `scenes.py`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .grid import Grid


def _min2(a, b):
    """min(a, b) differentiated by a select (see the module docstring: not `jnp.minimum`)."""
    return jnp.where(a <= b, a, b)


def _max2(a, b):
    """max(a, b) differentiated by a select (not `jnp.maximum`)."""
    return jnp.where(a >= b, a, b)


def _clip(x, lo, hi):
    """clip(x, lo, hi) differentiated by selects (not `jnp.clip`): gradient 1 inside, 0 outside."""
    return jnp.where(x < lo, lo, jnp.where(x > hi, hi, x))


def _norm(x, y):
    """sqrt(x^2 + y^2) with gradient 0 (not NaN) at the origin (not `jnp.hypot`, whose max/min
    pair loses gradients under jit). Lengths here are metres, far from overflow."""
    s = x * x + y * y
    pos = s > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, s, 1.0)), 0.0)


def _min_axis0(d):
    """Minimum over axis 0 as a gather at the argmin (not `jnp.min`): the gradient goes to the
    nearest piece only, whatever the rounding of the other pieces."""
    i = jnp.argmin(d, axis=0)
    return jnp.take_along_axis(d, i[None], axis=0)[0]


class Shape(eqx.Module):
    """Base class: `sdf(x, y)` with coordinates in metres, negative inside."""

    def sdf(self, x, y):  # pragma: no cover - abstract
        raise NotImplementedError


class Circle(Shape):
    """A disc of `radius_m` around `centre_m` (x, y), metres."""

    centre_m: Float[Array, 2]
    radius_m: Float[Array, ""]

    def sdf(self, x, y):
        c = jnp.asarray(self.centre_m)
        return _norm(x - c[0], y - c[1]) - self.radius_m


class Segment(Shape):
    """A wall: the segment from `a_m` to `b_m` thickened to `thickness_m` (round ends)."""

    a_m: Float[Array, 2]
    b_m: Float[Array, 2]
    thickness_m: Float[Array, ""]

    def sdf(self, x, y):
        return _segment_distance(x, y, jnp.asarray(self.a_m), jnp.asarray(self.b_m)) - 0.5 * self.thickness_m


class Box(Shape):
    """An axis-aligned rectangle from `lo_m` (x, y) to `hi_m`."""

    lo_m: Float[Array, 2]
    hi_m: Float[Array, 2]

    def sdf(self, x, y):
        lo, hi = jnp.asarray(self.lo_m), jnp.asarray(self.hi_m)
        c, h = 0.5 * (lo + hi), 0.5 * (hi - lo)
        qx, qy = jnp.abs(x - c[0]) - h[0], jnp.abs(y - c[1]) - h[1]
        outside = _norm(_max2(qx, 0.0), _max2(qy, 0.0))
        return outside + _min2(_max2(qx, qy), 0.0)


class Polygon(Shape):
    """A closed polygon with vertices (n, 2) in metres (either orientation)."""

    vertices_m: Float[Array, "n 2"]

    def sdf(self, x, y):
        v = jnp.asarray(self.vertices_m)
        a, b = v, jnp.roll(v, -1, axis=0)
        d = _min_axis0(jnp.stack([_segment_distance(x, y, a[i], b[i]) for i in range(v.shape[0])]))
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
        d = _min_axis0(jnp.stack([_segment_distance(x, y, p[i], p[i + 1]) for i in range(p.shape[0] - 1)]))
        return d - 0.5 * self.thickness_m


class Union(Shape):
    """The union of `shapes` (minimum of their signed distances)."""

    shapes: tuple[Shape, ...]

    def sdf(self, x, y):
        return _min_axis0(jnp.stack([s.sdf(x, y) for s in self.shapes]))


class Difference(Shape):
    """`base` with `cut` removed."""

    base: Shape
    cut: Shape

    def sdf(self, x, y):
        return _max2(self.base.sdf(x, y), -self.cut.sdf(x, y))


def _segment_distance(x, y, a, b):
    abx, aby = b[0] - a[0], b[1] - a[1]
    apx, apy = x - a[0], y - a[1]
    t = _clip((apx * abx + apy * aby) / (abx * abx + aby * aby + 1e-30), 0.0, 1.0)
    return _norm(apx - t * abx, apy - t * aby)


def rasterise(
    shape: Shape, grid: Grid, mode: Literal["hard", "smooth"] = "smooth", *, ramp_cells: float = 1.0
) -> Float[Array, "nx ny"]:
    """Occupancy of `shape` per cell (1 inside). "smooth" ramps over `ramp_cells` cells across the
    boundary: a wider ramp averages the sub-cell position of a wall over more cells (a smoother
    design objective, at the price of a blurrier wall)."""
    if not ramp_cells > 0:
        raise ValueError(f"ramp_cells = {ramp_cells} must be > 0")
    nx, ny = grid.shape
    dt = grid.jnp_dtype
    o = grid.origin_cells  # cell centres: 0 on a 2-D grid, 1/2 (from the axis and z = 0) on an rz grid
    x = ((jnp.arange(nx, dtype=dt) + o) * grid.dx_m)[:, None] * jnp.ones((1, ny), dt)
    y = ((jnp.arange(ny, dtype=dt) + o) * grid.dx_m)[None, :] * jnp.ones((nx, 1), dt)
    d = shape.sdf(x, y) / (grid.dx_m * ramp_cells)
    if mode == "hard":
        return (d < 0).astype(dt)
    if mode == "smooth":
        u = _clip(0.5 - d, 0.0, 1.0)
        return (u * u * (3 - 2 * u)).astype(dt)
    raise ValueError(f"rasterise mode = {mode!r}; allowed: 'hard', 'smooth'")


def union_occupancy(occupancies: Sequence[Array]) -> Array:
    """Combine occupancies (probabilistic union, differentiable)."""
    free = jnp.asarray(1.0)
    for o in occupancies:
        free = free * (1 - o)
    return 1 - free


# ------------------------------------------------------------------------------------------
# Design shapes: a flared horn and a parabolic mirror, smooth in every parameter.


def flare_profile(u, flare):
    """Normalised horn profile f(u) on u in [0, 1]: f(0) = 0, f(1) = 1, monotone for any `flare`.

    ``f = expm1(flare u) / expm1(flare)``: flare = 0 is the cone (f = u), flare > 0 an
    exponential (tractrix-like) horn that opens fastest at the mouth, flare < 0 one that opens
    fastest at the throat. Near flare = 0 a series keeps value and gradient finite."""
    m = jnp.asarray(flare)
    small = jnp.abs(m) < 1e-4
    ms = jnp.where(small, 1.0, m)
    exact = jnp.expm1(ms * u) / jnp.expm1(ms)
    series = u + 0.5 * m * u * (u - 1) + m * m * u * (u - 1) * (2 * u - 1) / 12
    return jnp.where(small, series, exact)


def flare_slope(u, flare):
    """df/du of `flare_profile` (for the wall normals)."""
    m = jnp.asarray(flare)
    small = jnp.abs(m) < 1e-4
    ms = jnp.where(small, 1.0, m)
    exact = ms * jnp.exp(ms * u) / jnp.expm1(ms)
    series = 1 + 0.5 * m * (2 * u - 1) + m * m * (6 * u * u - 6 * u + 1) / 12
    return jnp.where(small, series, exact)


def polyline_distance(x, y, points):
    """Distance from (x, y) to an open chain of segments through `points` (n, 2), vectorised over
    the segments (one broadcast instead of a Python loop: fast to compile and differentiate)."""
    p = jnp.asarray(points)
    a, b = p[:-1], p[1:]
    ax, ay = a[:, 0].reshape((-1,) + (1,) * jnp.ndim(x)), a[:, 1].reshape((-1,) + (1,) * jnp.ndim(x))
    bx, by = b[:, 0].reshape(ax.shape), b[:, 1].reshape(ax.shape)
    abx, aby = bx - ax, by - ay
    apx, apy = jnp.expand_dims(x, 0) - ax, jnp.expand_dims(y, 0) - ay  # (segments, *grid)
    t = _clip((apx * abx + apy * aby) / (abx * abx + aby * aby + 1e-30), 0.0, 1.0)
    return _min_axis0(_norm(apx - t * abx, apy - t * aby))


class HornWalls(Shape):
    """Two walls of a 2-D horn (a slot in the plane) along +x from the throat centre `throat_centre_m`.

    The inner faces follow y = ±w(x)/2 with w = throat + (mouth - throat) f(x / length) (see
    `flare_profile`), so the opening grows monotonically from `throat_m` to `mouth_m` over
    `length_m`; each wall is `wall_m` thick (its centre line is offset along the local normal, so
    the inner face is the profile at the sample points). `n_points` (static) samples per wall.
    """

    throat_centre_m: Float[Array, 2]
    throat_m: Float[Array, ""]
    mouth_m: Float[Array, ""]
    length_m: Float[Array, ""]
    wall_m: Float[Array, ""]
    flare: Float[Array, ""]
    n_points: int = eqx.field(static=True, default=17)

    def centre_lines(self):
        """(upper, lower) wall centre lines, each (n_points, 2) in metres."""
        c = jnp.asarray(self.throat_centre_m)
        u = jnp.linspace(0.0, 1.0, self.n_points)
        half = 0.5 * self.throat_m + 0.5 * (self.mouth_m - self.throat_m) * flare_profile(u, self.flare)
        slope = 0.5 * (self.mouth_m - self.throat_m) * flare_slope(u, self.flare) / self.length_m  # dy/dx
        norm = jnp.sqrt(1 + slope * slope)
        x = c[0] + u * self.length_m - 0.5 * self.wall_m * slope / norm
        dy = half + 0.5 * self.wall_m / norm
        upper = jnp.stack([x, c[1] + dy], axis=1)
        lower = jnp.stack([x, c[1] - dy], axis=1)
        return upper, lower

    def walls(self) -> tuple[Polyline, Polyline]:
        up, lo = self.centre_lines()
        t = jnp.asarray(self.wall_m)
        return Polyline(up, t), Polyline(lo, t)

    def sdf(self, x, y):
        up, lo = self.centre_lines()
        d = _min2(polyline_distance(x, y, up), polyline_distance(x, y, lo))
        return d - 0.5 * self.wall_m


class ParabolicMirror(Shape):
    """A parabolic reflector with its focus at `focus_m`, opening towards +x.

    The reflecting face is x = x_f - f + y^2 / (4 f) for |y - y_f| <= aperture / 2 (f =
    `focal_m`, vertex f behind the focus); the wall, `wall_m` thick, lies behind the face (centre
    line offset along the normal). `n_points` (static) samples of the face.
    """

    focus_m: Float[Array, 2]
    focal_m: Float[Array, ""]
    aperture_m: Float[Array, ""]
    wall_m: Float[Array, ""]
    n_points: int = eqx.field(static=True, default=33)

    def centre_line(self):
        """The wall's centre line, (n_points, 2) in metres."""
        c = jnp.asarray(self.focus_m)
        s = jnp.linspace(-0.5, 0.5, self.n_points) * self.aperture_m
        x = c[0] - self.focal_m + s * s / (4 * self.focal_m)
        slope = s / (2 * self.focal_m)  # dx/dy of the face
        norm = jnp.sqrt(1 + slope * slope)
        # behind the face: direction -(1, -slope) / norm
        return jnp.stack([x - 0.5 * self.wall_m / norm, c[1] + s + 0.5 * self.wall_m * slope / norm], axis=1)

    def wall(self) -> Polyline:
        return Polyline(self.centre_line(), jnp.asarray(self.wall_m))

    def sdf(self, x, y):
        return polyline_distance(x, y, self.centre_line()) - 0.5 * self.wall_m
