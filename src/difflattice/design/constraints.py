"""Constraints a maker has, as optimiser bounds and penalties, checked again on the exported part.

`MakerConstraints` states them on the part as printed (millimetres on the part, not on the
design's centre lines):

- `max_length_m`: the part's extent along the beam axis;
- `max_mouth_diameter_m`: the part's outer extent across the axis (the outside of the walls);
- `min_wall_m`: the thinnest wall;
- `can_diameter_m` (+ `can_clearance_m` either side): the transducer's can, which the throat
  must hold: the throat is fixed at can + 2 x clearance (a horn's throat is no longer free);
- `max_overhang_deg`: the steepest down-facing surface, from the vertical, when the part is
  printed with its z axis up (the axis of a revolved part, throat or vertex down; the extrusion
  axis of a 2-D part, whose walls are then vertical);
- no self-intersection (always): each wall outline a simple polygon, walls disjoint.

`limits_for` turns them into the design's box bounds (conservatively: the outer extents are
bounded by the centre-line parameters plus the largest wall; e.g. the horn's axial extent is at
most length + 1.5 wall). What a box cannot express is a penalty added to the loss
(`penalty`): the horn of revolution's steepest wall slope against the overhang angle, the
reflector's depth against the length. `part_report` measures every constraint on the exported
mesh and its outlines (independently of the parameters) and says for each whether the part meets
it and whether the optimiser's bound or penalty is active (the design sits on it).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any, overload

import jax.numpy as jnp
import numpy as np

from .shapes import HornLimits, HornParams, ReflectorLimits, ReflectorParams

PENALTY_WEIGHT = 1.0
"""Loss per (deg or mm over the limit)^2 of a penalty constraint."""

ACTIVE_FRACTION = 1e-3
"""A bound is active when the parameter lies within this fraction of its range from it (the
sigmoid that keeps it inside has saturated); a penalty when its value is within this fraction of
the limit or over it."""


@dataclass(frozen=True)
class MakerConstraints:
    """A maker's limits on the printed part (metres, degrees); None = not constrained."""

    max_length_m: float | None = None
    max_mouth_diameter_m: float | None = None
    min_wall_m: float | None = None
    can_diameter_m: float | None = None
    can_clearance_m: float = 0.0
    max_overhang_deg: float | None = None
    tolerance_m: float = 1e-5

    def __post_init__(self):
        for k in ("max_length_m", "max_mouth_diameter_m", "min_wall_m", "can_diameter_m"):
            v = getattr(self, k)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise ValueError(f"{k} = {v}: give a positive length in metres (or leave it out)")
        if not (self.can_clearance_m >= 0):
            raise ValueError(f"can_clearance_m = {self.can_clearance_m}: give a length >= 0 m")
        if self.max_overhang_deg is not None and not (0 < self.max_overhang_deg <= 90):
            raise ValueError(f"max_overhang_deg = {self.max_overhang_deg}: give an angle in (0, 90] deg")

    def as_dict(self) -> dict:
        return asdict(self)


def _tighter(limits, **upper) -> dict:
    """Field updates that lower the named upper bounds (never raise them)."""
    return {k: min(getattr(limits, k), v) for k, v in upper.items() if v is not None}


@overload
def limits_for(c: MakerConstraints, base: HornLimits) -> HornLimits: ...
@overload
def limits_for(c: MakerConstraints, base: ReflectorLimits) -> ReflectorLimits: ...
def limits_for(c: MakerConstraints, base: HornLimits | ReflectorLimits) -> HornLimits | ReflectorLimits:
    """The design's box bounds `base` tightened by the constraints (ValueError if none is left)."""
    wall_min = max(base.wall_min_m, c.min_wall_m) if c.min_wall_m is not None else base.wall_min_m
    if wall_min > base.wall_max_m:
        raise ValueError(
            f"min_wall_m = {c.min_wall_m} m exceeds the design's largest wall ({base.wall_max_m} m): "
            "raise wall_max_m or lower min_wall_m"
        )
    w = base.wall_max_m
    if isinstance(base, HornLimits):
        upd = _tighter(
            base,
            length_max_m=None if c.max_length_m is None else c.max_length_m - 1.5 * w,
            mouth_max_m=None if c.max_mouth_diameter_m is None else c.max_mouth_diameter_m - 2 * w,
        )
        if c.can_diameter_m is not None:
            throat = c.can_diameter_m + 2 * c.can_clearance_m
            upd["throat_min_m"] = upd["throat_max_m"] = throat
        new = {**asdict_limits(base), **upd, "wall_min_m": wall_min}
        _check_room(new, ("throat_min_m", "mouth_max_m"), ("length_min_m", "length_max_m"))
        return HornLimits(**new)
    upd = _tighter(base, aperture_max_m=None if c.max_mouth_diameter_m is None else c.max_mouth_diameter_m - 2 * w)
    new = {**asdict_limits(base), **upd, "wall_min_m": wall_min}
    _check_room(new, ("aperture_min_m", "aperture_max_m"))
    return ReflectorLimits(**new)


def asdict_limits(limits) -> dict:
    return {k: getattr(limits, k) for k in type(limits).__dataclass_fields__}


def _check_room(new: dict, *pairs) -> None:
    for lo, hi in pairs:
        if new[lo] > new[hi]:
            raise ValueError(
                f"the constraints leave no admissible design: {lo} = {new[lo] * 1e3:.2f} mm > {hi} = "
                f"{new[hi] * 1e3:.2f} mm (loosen the maximum length / mouth diameter, or fit a smaller can)"
            )


# -- penalties (what a box bound cannot express) --------------------------------------------------
def penalty_values(c: MakerConstraints, params, *, ring_metric: bool) -> dict:
    """Differentiable (value, limit) pairs of the penalty constraints: the horn of revolution's
    steepest wall angle from the axis (deg; printed axis-up it is the outer face's overhang), the
    reflector's axial extent (m; sag + wall, as `limits_for` bounds the horn's)."""
    out = {}
    if isinstance(params, HornParams) and ring_metric and c.max_overhang_deg is not None:
        out["overhang_deg"] = (max_wall_angle_deg(params), c.max_overhang_deg)
    if isinstance(params, ReflectorParams) and c.max_length_m is not None:
        sag = params.aperture_m**2 / (16 * params.focal_m)
        out["length_m"] = (sag + 2 * params.wall_m, c.max_length_m)
    return out


def max_wall_angle_deg(p: HornParams):
    """Steepest angle of the horn's inner profile from the axis, degrees (sampled as the walls are)."""
    from ..lattice.geometry import flare_slope

    u = jnp.linspace(0.0, 1.0, 65)
    slope = 0.5 * (p.mouth_m - p.throat_m) * flare_slope(u, p.flare) / p.length_m
    return jnp.degrees(jnp.arctan(jnp.max(slope)))


def penalty(c: MakerConstraints | None, params, *, ring_metric: bool):
    """Sum of PENALTY_WEIGHT x (excess in deg or mm)^2 over the penalty constraints (0 inside)."""
    if c is None:
        return 0.0
    total: Any = 0.0
    for name, (v, lim) in penalty_values(c, params, ring_metric=ring_metric).items():
        scale = 1e3 if name.endswith("_m") else 1.0
        total = total + PENALTY_WEIGHT * (scale * jnp.maximum(v - lim, 0.0)) ** 2
    return total


# -- the part as exported -------------------------------------------------------------------------
def _min_wall(outline_m: np.ndarray) -> float:
    """Thickness of the thinnest section of a wall outline: twice the largest erosion radius that
    leaves it one connected piece (a neck thinner than that would split it), by bisection."""
    from shapely.geometry import Polygon

    poly = Polygon(outline_m)
    lo, hi = 0.0, 0.5 * math.sqrt(poly.area)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        e = poly.buffer(-mid, quad_segs=8)
        if not e.is_empty and e.geom_type == "Polygon":
            lo = mid
        else:
            hi = mid
    return 2 * lo


def _overhang(mesh, bed_m: float) -> tuple[float, float]:
    """Steepest down-facing face from the vertical (deg) and the share of the part's area steeper
    than 45 deg, z up, ignoring faces within `bed_m` of the lowest point (the part's foot)."""
    v = np.asarray(mesh.vertices, float) * 1e-3
    f = np.asarray(mesh.faces)
    n = np.asarray(mesh.face_normals, float)
    area = np.asarray(mesh.area_faces, float)
    z_top = v[f][:, :, 2].max(1)
    keep = (n[:, 2] < 0) & (z_top > v[:, 2].min() + bed_m)
    ang = np.degrees(np.arcsin(np.clip(-n[:, 2], 0.0, 1.0)))
    if not keep.any():
        return 0.0, 0.0
    return float(ang[keep].max()), float(area[keep & (ang > 45.0)].sum() / area.sum())


def part_report(problem, params, mesh, outlines: list[np.ndarray], c: MakerConstraints | None) -> list[dict]:
    """Each constraint measured on the part (`mesh` in mm, `outlines` in m as exported): its limit,
    the part's value, whether the part meets it (within `tolerance_m`) and whether the optimiser's
    bound / penalty is active. Rows also for the bounds every design keeps (no self-intersection)."""
    from shapely.geometry import Polygon

    c = c or MakerConstraints()
    rz = problem.lattice.ring_metric
    tol = c.tolerance_m
    lim = problem.limits
    b = np.asarray(mesh.bounds, float) * 1e-3
    v = np.asarray(mesh.vertices, float) * 1e-3
    axial = b[1, 2] - b[0, 2] if rz else b[1, 0] - b[0, 0]
    across = 2 * float(np.hypot(v[:, 0], v[:, 1]).max()) if rz else b[1, 1] - b[0, 1]
    d = params.as_dict()

    def at(name, hi: bool = True) -> bool:
        lo_v, hi_v = _param_range(lim, name, d)
        span = max(hi_v - lo_v, 1e-30)
        return bool((hi_v - d[name] if hi else d[name] - lo_v) <= ACTIVE_FRACTION * span)

    rows = []

    def row(name, limit, value, upper: bool, active, how: str):
        ok = limit is None or (value <= limit + tol if upper else value >= limit - tol)
        rows.append(
            {
                "constraint": name,
                "limit": limit,
                "part": float(value),
                "kind": "max" if upper else "min",
                "satisfied": bool(ok),
                "active": active,
                "enforced_by": how,
            }
        )

    horn = isinstance(params, HornParams)
    pen = {k: (float(a), b_) for k, (a, b_) in penalty_values(c, params, ring_metric=rz).items()}
    if horn:
        row("length_m", c.max_length_m, axial, True, at("length_m"), "bound on length_m")
        row("mouth_diameter_m", c.max_mouth_diameter_m, across, True, at("mouth_m"), "bound on mouth_m")
    else:
        a_len = pen.get("length_m")
        row(
            "length_m",
            c.max_length_m,
            axial,
            True,
            None if a_len is None else bool(a_len[0] >= a_len[1] * (1 - ACTIVE_FRACTION)),
            "penalty on sag + wall",
        )
        row("mouth_diameter_m", c.max_mouth_diameter_m, across, True, at("aperture_m"), "bound on aperture_m")
    polys = [Polygon(o) for o in outlines]
    row(
        "min_wall_m",
        c.min_wall_m,
        min(_min_wall(o) for o in outlines),
        False,
        at("wall_m", hi=False),
        "bound on wall_m",
    )
    if horn:
        if rz:
            bore = 2 * float(np.min(np.concatenate([o[:, 1] for o in outlines])))
        else:
            bore = float(min(p.distance(q) for i, p in enumerate(polys) for q in polys[i + 1 :]))
        can = None if c.can_diameter_m is None else c.can_diameter_m
        row("throat_bore_m", can, bore, False, "fixed" if can is not None else None, "throat fixed at can + clearance")
    simple = all(p.is_valid and p.exterior.is_simple for p in polys)
    overlap = sum(p.intersection(q).area for i, p in enumerate(polys) for q in polys[i + 1 :])
    rows.append(
        {
            "constraint": "no_self_intersection",
            "limit": 0.0,
            "part": float(overlap),
            "kind": "max",
            "satisfied": bool(simple and overlap <= tol * tol),
            "active": False,
            "enforced_by": "by construction (monotone profile, inner faces >= throat apart)"
            if horn
            else "by construction (one wall)",
        }
    )
    worst, share = _overhang(mesh, float(d["wall_m"]))
    o_pen = pen.get("overhang_deg")
    row(
        "overhang_deg",
        c.max_overhang_deg,
        worst,
        True,
        None if o_pen is None else bool(o_pen[0] >= o_pen[1] * (1 - ACTIVE_FRACTION)),
        _overhang_how(o_pen is not None, rz, horn),
    )
    rows[-1]["area_fraction_over_45deg"] = share
    return rows


def _overhang_how(penalised: bool, rz: bool, horn: bool) -> str:
    if penalised:
        return "penalty on the steepest wall angle"
    if not rz:
        return "checked only (a 2-D part prints standing on its end: its walls are vertical)"
    if horn:
        return "checked only (no overhang limit declared)"
    return "checked only (a dish is flat near its vertex in any orientation: print it with supports)"


def _param_range(lim, name: str, d: dict) -> tuple[float, float]:
    if name == "mouth_m":
        return d["throat_m"], lim.mouth_max_m
    stem = name[:-2]  # length_m -> length
    return getattr(lim, f"{stem}_min_m"), getattr(lim, f"{stem}_max_m")


def constraints_line(rows: list[dict]) -> str:
    """One console line: each constrained quantity, its part value / limit, and its state."""
    parts = []
    for r in rows:
        if r["limit"] is None:
            continue
        unit, s = ("deg", 1.0) if r["constraint"].endswith("_deg") else ("mm", 1e3)
        state = "VIOLATED" if not r["satisfied"] else ("active" if r["active"] else "inactive")
        name = r["constraint"].rsplit("_", 1)[0]
        if r["constraint"] == "no_self_intersection":
            parts.append(f"no self-intersection ({'ok' if r['satisfied'] else 'VIOLATED'})")
            continue
        op = "<=" if r["kind"] == "max" else ">="
        parts.append(f"{name} {r['part'] * s:.2f} {op} {r['limit'] * s:.2f} {unit} ({state})")
    ok = all(r["satisfied"] for r in rows)
    return "constraints: " + "; ".join(parts) + ("; all satisfied" if ok else "; NOT ALL SATISFIED")


def with_can(c: MakerConstraints, diameter_m: float | None, clearance_m: float = 0.0) -> MakerConstraints:
    return c if diameter_m is None else replace(c, can_diameter_m=diameter_m, can_clearance_m=clearance_m)


def project(limits: HornLimits | ReflectorLimits, p):
    """`p` with each parameter clipped into `limits` (a start design moved inside tightened bounds)."""
    d = p.as_dict()
    if isinstance(limits, HornLimits):
        d["throat_m"] = min(max(d["throat_m"], limits.throat_min_m), limits.throat_max_m)
        d["mouth_m"] = min(max(d["mouth_m"], d["throat_m"]), limits.mouth_max_m)
        d["length_m"] = min(max(d["length_m"], limits.length_min_m), limits.length_max_m)
        d["flare"] = min(max(d["flare"], -limits.flare_max), limits.flare_max)
    else:
        d["focal_m"] = min(max(d["focal_m"], limits.focal_min_m), limits.focal_max_m)
        d["aperture_m"] = min(max(d["aperture_m"], limits.aperture_min_m), limits.aperture_max_m)
    d["wall_m"] = min(max(d["wall_m"], limits.wall_min_m), limits.wall_max_m)
    return type(p)(**d)
