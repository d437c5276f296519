"""3-D pulse-echo scenes (issue 16): a circular transducer facing a wall at an incidence angle, a
concave right-angle corner, a vertical post; each run gives the A-scan the transducer receives.

Each scene is a function returning a `Scene3D` (grid, medium, source, receiver sensors, edges,
step count and the geometry a reference needs); `pulse_echo` runs it (printing the memory and
time estimate first, refusing a run that would not fit) and returns the A-scan: by reciprocity,
the weighted sum over the transducer's source cells of the pressure recorded there
(`sensors.received_signal`). Scene files (`data/scenes/*3d*.toml`) describe the same scenes; see
`load_scene3d` for the fields this module reads from them (and `scene_to_toml`, which writes them).

Conventions: the transducer sits on the grid's x axis side facing +x; angles are in degrees, a
wall's incidence angle is the angle between the transducer axis and the wall normal, turned in the
x-y plane. Lattice units inside, SI at the API.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import jax.numpy as jnp
import numpy as np

from ..lattice.coefficients import Edges
from ..lattice.geometry3d import Cylinder, HalfSpace, Intersection3D, Shape3D, Union3D, rasterise3d
from ..lattice.grid import Grid, make_grid
from ..lattice.medium import Medium
from ..solver.loop import simulate
from ..solver.sensors import Sensors, received_signal
from ..solver.sources import PointSources, ToneBurst, disc_transducer_3d

AIR_M_S = 343.0
AIR_KG_M3 = 1.2


@dataclass(frozen=True)
class Scene3D:
    """A 3-D pulse-echo scene, ready to run (`pulse_echo`)."""

    name: str
    grid: Grid
    medium: Medium
    source: PointSources
    edges: Edges
    n_steps: int
    obstacle: Shape3D
    transducer_centre_cells: tuple[float, float, float]
    transducer_axis: tuple[float, float, float]
    gate_start_step: int  # the echo window starts here (after the transmit ring-down)
    meta: dict = field(default_factory=dict)

    @property
    def sensors(self) -> Sensors:
        return Sensors(probes=self.source.cells_array)


def _transducer(grid: Grid, centre_cells, diameter_m: float, cycles: float, rings=None) -> PointSources:
    centre_m = tuple(float(c) * grid.dx_m for c in centre_cells)
    return disc_transducer_3d(
        grid, centre_m, (1.0, 0.0, 0.0), diameter_m=diameter_m, rings=rings, signal=ToneBurst(grid.frequency_hz, cycles)
    )


def _grid(frequency_hz, cells_per_wavelength, shape, dtype) -> Grid:
    return make_grid(
        frequency_hz=frequency_hz,
        cells_per_wavelength=cells_per_wavelength,
        c_max_m_s=AIR_M_S,
        shape=shape,
        kind="3d",
        dtype=dtype,
    )


def _layout(dx_m, diameter_m, distance_m, pml, extra_x=0.0, lateral=None):
    """(shape, transducer centre in cells, distance in cells) of a box holding the transducer, the
    obstacle at `distance_m` and `pml` absorbing cells on every side."""
    a = 0.5 * diameter_m / dx_m
    d = distance_m / dx_m
    lat = lateral if lateral is not None else 2 * a + 16
    n_lat = int(math.ceil(2 * (lat / 2 + 4) + 2 * pml))
    x0 = pml + 6
    nx = int(math.ceil(x0 + d + extra_x + 8 + pml))
    c = (x0, 0.5 * (n_lat - 1), 0.5 * (n_lat - 1))
    return (nx, n_lat, n_lat), c, d


def wall_scene(
    angle_deg: float = 0.0,
    *,
    distance_m: float = 0.0257,
    diameter_m: float = 8.6e-3,
    frequency_hz: float = 40e3,
    cells_per_wavelength: float = 20.0,
    cycles: float = 3.0,
    pml_cells: int = 12,
    lateral_m: float | None = None,
    rasterise: Literal["hard", "smooth"] = "smooth",
    dtype: Literal["float32", "float64"] = "float32",
    rings: dict | None = None,
) -> Scene3D:
    """A rigid plane wall `distance_m` in front of a disc transducer (along its axis), its normal
    turned by `angle_deg` from the axis in the x-y plane (0 = normal incidence). The wall fills
    the half-space behind the plane, into the absorbing layers."""
    dx = AIR_M_S / (frequency_hz * cells_per_wavelength)
    a = 0.5 * diameter_m / dx
    d = distance_m / dx
    t = math.radians(angle_deg)
    lat = (
        (lateral_m / dx)
        if lateral_m is not None
        else 2 * (a + d * math.sin(t) + 0.6 * math.sqrt(d * cells_per_wavelength)) + 8
    )
    shape, c, d = _layout(dx, diameter_m, distance_m, pml_cells, extra_x=0.5 * lat * math.tan(t), lateral=lat)
    grid = _grid(frequency_hz, cells_per_wavelength, shape, dtype)
    normal = (-math.cos(t), math.sin(t), 0.0)  # outward normal of the solid (pointing back at the transducer)
    point = (c[0] + d, c[1], c[2])
    wall = HalfSpace(jnp.asarray(point) * dx, jnp.asarray(normal))
    occ = rasterise3d(wall, grid, rasterise)
    src = _transducer(grid, c, diameter_m, cycles, rings)
    n_steps = _steps(grid, 2 * d + 2 * a * math.sin(2 * t) + 4 * a * a / (4 * d), cycles)
    return Scene3D(
        f"wall_{angle_deg:g}deg",
        grid,
        Medium(AIR_M_S, AIR_KG_M3, rigid=occ),
        src,
        Edges.all("pml", thickness_cells=pml_cells),
        n_steps,
        wall,
        c,
        (1.0, 0.0, 0.0),
        _gate(grid, 2 * (d - a * math.sin(t)) - 2 * a * math.tan(t), cycles, a),
        {
            "wall_point_cells": point,
            "wall_normal": normal,
            "angle_deg": angle_deg,
            "distance_cells": d,
            "radius_cells": a,
            "diameter_m": diameter_m,
            "rasterise": rasterise,
        },
    )


def corner_scene(
    *,
    distance_m: float = 0.0257,
    diameter_m: float = 8.6e-3,
    frequency_hz: float = 40e3,
    cells_per_wavelength: float = 20.0,
    cycles: float = 3.0,
    pml_cells: int = 12,
    dtype: Literal["float32", "float64"] = "float32",
) -> Scene3D:
    """A concave right-angle corner (two rigid walls meeting along a vertical edge, parallel to z)
    whose edge lies `distance_m` ahead on the transducer axis, the axis bisecting the corner: the
    corner returns the beam towards the transducer like a mirror at normal incidence (the paper's
    Fig. 6 in 3-D)."""
    dx = AIR_M_S / (frequency_hz * cells_per_wavelength)
    a = 0.5 * diameter_m / dx
    d = distance_m / dx
    lat = 2 * (a + 0.5 * d) + 8
    shape, c, d = _layout(dx, diameter_m, distance_m, pml_cells, extra_x=0.0, lateral=lat)
    grid = _grid(frequency_hz, cells_per_wavelength, shape, dtype)
    apex = jnp.asarray((c[0] + d, c[1], c[2])) * dx
    s = 1 / math.sqrt(2)
    # the solid is everything beyond either wall: the union of the half-spaces behind them (their
    # intersection would be a convex wedge pointing at the transducer)
    corner = Union3D((HalfSpace(apex, jnp.asarray((-s, s, 0.0))), HalfSpace(apex, jnp.asarray((-s, -s, 0.0)))))
    occ = rasterise3d(corner, grid, "smooth")
    src = _transducer(grid, c, diameter_m, cycles)
    n_steps = _steps(grid, 2 * d + 2 * a, cycles)
    return Scene3D(
        "corner",
        grid,
        Medium(AIR_M_S, AIR_KG_M3, rigid=occ),
        src,
        Edges.all("pml", thickness_cells=pml_cells),
        n_steps,
        corner,
        c,
        (1.0, 0.0, 0.0),
        _gate(grid, math.sqrt(2) * d - 2 * a, cycles, a),
        {"apex_cells": (c[0] + d, c[1], c[2]), "distance_cells": d, "radius_cells": a, "diameter_m": diameter_m},
    )


def post_scene(
    *,
    distance_m: float = 0.0257,
    post_diameter_m: float = 4.3e-3,
    diameter_m: float = 8.6e-3,
    frequency_hz: float = 40e3,
    cells_per_wavelength: float = 20.0,
    cycles: float = 3.0,
    pml_cells: int = 12,
    dtype: Literal["float32", "float64"] = "float32",
) -> Scene3D:
    """A vertical rigid post (a cylinder along z through the whole grid, `post_diameter_m` wide)
    whose axis crosses the transducer axis `distance_m` ahead: a 2-D cut would make it an
    infinite wall; in 3-D its echo spreads in the horizontal plane."""
    dx = AIR_M_S / (frequency_hz * cells_per_wavelength)
    a = 0.5 * diameter_m / dx
    rp = 0.5 * post_diameter_m / dx
    shape, c, d = _layout(dx, diameter_m, distance_m + post_diameter_m, pml_cells)
    d = distance_m / dx
    grid = _grid(frequency_hz, cells_per_wavelength, shape, dtype)
    centre = jnp.asarray((c[0] + d + rp, c[1], c[2])) * dx
    post = Cylinder(centre, jnp.asarray((0.0, 0.0, 1.0)), jnp.asarray(rp * dx), jnp.asarray(4.0 * shape[2] * dx))
    occ = rasterise3d(post, grid, "smooth")
    src = _transducer(grid, c, diameter_m, cycles)
    n_steps = _steps(grid, 2 * d + 2 * a, cycles)
    return Scene3D(
        "post",
        grid,
        Medium(AIR_M_S, AIR_KG_M3, rigid=occ),
        src,
        Edges.all("pml", thickness_cells=pml_cells),
        n_steps,
        post,
        c,
        (1.0, 0.0, 0.0),
        _gate(grid, 2 * d - 2 * a, cycles, a),
        {
            "post_axis_cells": (c[0] + d + rp, c[1]),
            "post_radius_cells": rp,
            "distance_cells": d,
            "radius_cells": a,
            "diameter_m": diameter_m,
        },
    )


def _steps(grid: Grid, path_cells: float, cycles: float) -> int:
    """Steps until an echo over `path_cells` has fully arrived (plus two periods)."""
    return int(math.ceil(path_cells / grid.courant + (cycles + 2) * grid.steps_per_period))


def _gate(grid: Grid, earliest_path_cells: float, cycles: float, radius_cells: float = 0.0) -> int:
    """First step of the echo window: a period before the earliest echo, but not before the
    transmit has ended and its ring-down (the rim wave crossing the face) has left the face."""
    transmit = cycles * grid.steps_per_period + 2 * radius_cells / grid.courant
    return int(max(transmit, earliest_path_cells / grid.courant - grid.steps_per_period))


def pulse_echo(scene: Scene3D, *, preflight: Literal["print", "check", "off"] = "print"):
    """Run `scene` and return (t_s (n_steps,), a_scan (n_steps,) in Pa x cell weights): the
    transducer's received signal over the whole run (use `scene.gate_start_step` to cut away the
    transmit). `preflight` (see `simulate`): "print" prints the memory and time estimate first,
    "check" only refuses a run that would not fit, "off" does neither."""
    res = simulate(
        scene.grid,
        scene.medium,
        scene.source,
        scene.sensors,
        n_steps=scene.n_steps,
        edges=scene.edges,
        preflight=preflight,
    )
    src = scene.source
    lags = src.lags_s if bool(jnp.any(src.lags_s != 0)) else None
    a_scan = received_signal(res.probes, src.weights, lags, scene.grid.dt_s)
    t = np.arange(1, scene.n_steps + 1) * scene.grid.dt_s
    return t, np.asarray(a_scan)


def image_source_reference(scene: Scene3D, t_steps=None) -> np.ndarray:
    """The wall echo of a `wall_scene` by the image source (continuum, `analytic3d`), on steps
    `t_steps` (default 1 .. n_steps), in the A-scan's units."""
    from ..observe.analytic3d import image_source_echo

    if "wall_normal" not in scene.meta:
        raise ValueError(f"scene {scene.name!r} has no plane wall: the image source applies to wall_scene only")
    g = scene.grid
    src = scene.source
    t = np.arange(1, scene.n_steps + 1) if t_steps is None else np.asarray(t_steps, float)
    sig = src.signal
    return image_source_echo(
        src.cells_array.astype(float),
        np.asarray(src.weights),
        np.asarray(src.lags_s) / g.dt_s,
        scene.meta["wall_point_cells"],
        scene.meta["wall_normal"],
        lambda ts: np.asarray(sig(np.asarray(ts) * g.dt_s)),
        t,
        g.courant,
    )


def echo_metrics(t_steps, a_scan, reference, omega: float, gate_start: int) -> dict:
    """Arrival-time difference (in periods, from the phase of the gated echoes at the drive
    frequency) and level difference (dB, of the gated echoes' envelope peaks) of `a_scan`
    against `reference`."""
    t = np.asarray(t_steps, float)
    m = t >= gate_start
    e, r = np.asarray(a_scan)[m], np.asarray(reference)[m]
    ph = np.exp(1j * omega * t[m])
    E, R = np.sum(e * ph), np.sum(r * ph)
    dphi = float(np.angle(E / R))
    return {
        "arrival_periods": dphi / (2 * math.pi),
        "level_db": 20 * math.log10(abs(E) / abs(R)),
        "peak_db": 20 * math.log10(np.abs(_envelope(e)).max() / np.abs(_envelope(r)).max()),
    }


def _envelope(x):
    n = len(x)
    X = np.fft.fft(x)
    h = np.zeros(n)
    h[0] = 1
    h[1 : (n + 1) // 2] = 2
    if n % 2 == 0:
        h[n // 2] = 1
    return np.abs(np.fft.ifft(X * h))


# ------------------------------------------------------------------------------------------
# scene files (kind = "3d")

_SHAPES = {
    "halfspace": (HalfSpace, ("point_m", "normal")),
    "slab": (None, ("point_m", "normal", "thickness_m")),
    "sphere": (None, ("centre_m", "radius_m")),
    "cylinder": (Cylinder, ("centre_m", "axis", "radius_m", "length_m")),
    "box": (None, ("centre_m", "size_m", "angles_deg")),
    "intersection": (Intersection3D, ("parts",)),
    "union": (None, ("parts",)),
    "difference": (None, ("base", "cut")),
}


def _shape_from_table(t: dict, where: str) -> Shape3D:
    from ..lattice import geometry3d as g3

    kind = t.get("shape")
    if kind not in _SHAPES:
        raise ValueError(f"{where}.shape = {kind!r}; allowed: {', '.join(_SHAPES)}")
    need = _SHAPES[kind][1]
    missing = [k for k in need if k not in t and not (kind == "box" and k == "angles_deg")]
    if missing:
        raise ValueError(f"{where}: shape = {kind!r} needs {', '.join(missing)}")
    arr = lambda k: jnp.asarray(t[k], dtype=float)  # noqa: E731
    if kind == "halfspace":
        return g3.HalfSpace(arr("point_m"), arr("normal"))
    if kind == "slab":
        return g3.Slab(arr("point_m"), arr("normal"), arr("thickness_m"))
    if kind == "sphere":
        return g3.Sphere(arr("centre_m"), arr("radius_m"))
    if kind == "cylinder":
        return g3.Cylinder(arr("centre_m"), arr("axis"), arr("radius_m"), arr("length_m"))
    if kind == "box":
        return g3.OrientedBox(
            arr("centre_m"), arr("size_m"), jnp.asarray(t.get("angles_deg", [0.0, 0.0, 0.0]), dtype=float)
        )
    if kind in ("intersection", "union"):
        parts = tuple(_shape_from_table(p, f"{where}.parts[{i}]") for i, p in enumerate(t["parts"]))
        return g3.Intersection3D(parts) if kind == "intersection" else g3.Union3D(parts)
    return g3.Difference3D(_shape_from_table(t["base"], f"{where}.base"), _shape_from_table(t["cut"], f"{where}.cut"))


def _shape_to_table(s: Shape3D) -> dict:
    from ..lattice import geometry3d as g3

    f = lambda v: [float(x) for x in np.ravel(np.asarray(v))]  # noqa: E731
    if isinstance(s, g3.HalfSpace):
        return {"shape": "halfspace", "point_m": f(s.point_m), "normal": f(s.normal)}
    if isinstance(s, g3.Slab):
        return {"shape": "slab", "point_m": f(s.point_m), "normal": f(s.normal), "thickness_m": float(s.thickness_m)}
    if isinstance(s, g3.Sphere):
        return {"shape": "sphere", "centre_m": f(s.centre_m), "radius_m": float(s.radius_m)}
    if isinstance(s, g3.Cylinder):
        return {
            "shape": "cylinder",
            "centre_m": f(s.centre_m),
            "axis": f(s.axis),
            "radius_m": float(s.radius_m),
            "length_m": float(s.length_m),
        }
    if isinstance(s, g3.OrientedBox):
        return {"shape": "box", "centre_m": f(s.centre_m), "size_m": f(s.size_m), "angles_deg": f(s.angles_deg)}
    if isinstance(s, (g3.Intersection3D, g3.Union3D)):
        return {
            "shape": "intersection" if isinstance(s, g3.Intersection3D) else "union",
            "parts": [_shape_to_table(p) for p in s.shapes],
        }
    if isinstance(s, g3.Difference3D):
        return {"shape": "difference", "base": _shape_to_table(s.base), "cut": _shape_to_table(s.cut)}
    raise ValueError(f"cannot write a {type(s).__name__} to a scene file")


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, str):
        return json_str(v)
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise ValueError(f"cannot write {v!r} to TOML")


def json_str(s: str) -> str:
    import json

    return json.dumps(s)


def scene_to_toml(scene: Scene3D, comment: str = "") -> str:
    """A scene file (kind = "3d") that `load_scene3d` turns back into `scene`."""
    g, src = scene.grid, scene.source
    sig = src.signal
    lines = [f"# {line}" if line else "#" for line in comment.strip().splitlines()] if comment else []
    lines += [
        "[grid]",
        'kind = "3d"',
        f"frequency_hz = {g.frequency_hz!r}",
        f"cells_per_wavelength = {g.cells_per_wavelength!r}",
        f"shape = {_toml_value(list(g.shape))}",
        f"courant = {g.courant!r}",
        f'dtype = "{g.dtype}"',
        "",
        "[medium]",
        f"speed_m_s = {AIR_M_S!r}",
        f"density_kg_m3 = {AIR_KG_M3!r}",
        "",
        "[edges]",
        'kind = "pml"',
        f"thickness_cells = {scene.edges.thickness_cells}",
        "",
        "[[transducers]]",
        'name = "disc"',
        'shape = "disc"',
        f"centre_m = {_toml_value([float(v) * g.dx_m for v in scene.transducer_centre_cells])}",
        f"axis = {_toml_value([float(v) for v in scene.transducer_axis])}",
        f"diameter_m = {scene.meta['diameter_m']!r}",
        'signal = "burst"',
        f"cycles = {float(sig.cycles)!r}",
        "receive = true                  # the A-scan: the weighted sum over its cells (reciprocity)",
        "",
    ]
    rast = scene.meta.get("rasterise", "smooth")
    lines += ["[[objects]]", 'material = "rigid"', f'rasterise = "{rast}"']
    for k, v in _shape_to_table(scene.obstacle).items():
        lines.append(f"{k} = {_toml_value(v)}")
    lines += [
        "",
        "[run]",
        f"name = {json_str(scene.name)}",
        f"n_steps = {scene.n_steps}",
        f"gate_start_step = {scene.gate_start_step}",
        "",
    ]
    return "\n".join(lines)


def load_scene3d(path) -> Scene3D:
    """Read a scene file whose [grid] says kind = "3d" (the format `scene_to_toml` writes:
    [grid] frequency_hz, cells_per_wavelength, shape, courant, dtype; [medium] speed_m_s,
    density_kg_m3; [edges] kind = "pml", thickness_cells; one [[transducers]] of shape "disc"
    (centre_m, axis, diameter_m, optional rings = {ring_edges_m, weights, lags_s}, signal "burst",
    cycles, receive); [[objects]] rigid solids (shape = halfspace | slab | sphere | cylinder |
    box | intersection | union | difference, their parameters in metres, rasterise hard or
    smooth); [run] n_steps, gate_start_step)."""
    import tomllib
    from pathlib import Path

    p = Path(path)
    data = tomllib.loads(p.read_text())
    gsec = data.get("grid", {})
    if gsec.get("kind") != "3d":
        raise ValueError(f'{p}: [grid] kind = {gsec.get("kind")!r}; this loader reads 3-D scenes (kind = "3d")')
    grid = make_grid(
        frequency_hz=gsec["frequency_hz"],
        cells_per_wavelength=gsec["cells_per_wavelength"],
        c_max_m_s=data.get("medium", {}).get("speed_m_s", AIR_M_S),
        shape=tuple(gsec["shape"]),
        kind="3d",
        courant=gsec.get("courant"),
        dtype=gsec.get("dtype", "float32"),
    )
    med = data.get("medium", {})
    trs = data.get("transducers", [])
    if len(trs) != 1 or trs[0].get("shape") != "disc":
        raise ValueError(f'{p}: give exactly one [[transducers]] with shape = "disc"')
    tr = trs[0]
    src = disc_transducer_3d(
        grid,
        tuple(tr["centre_m"]),
        tuple(tr["axis"]),
        diameter_m=tr.get("diameter_m"),
        rings=tr.get("rings"),
        signal=ToneBurst(grid.frequency_hz, float(tr.get("cycles", 5.0))),
    )
    occ = None
    shapes = []
    for i, o in enumerate(data.get("objects", [])):
        if o.get("material", "rigid") != "rigid":
            raise ValueError(f"{p}: objects[{i}].material = {o.get('material')!r}; 3-D scene files hold rigid objects")
        s = _shape_from_table(o, f"objects[{i}]")
        shapes.append(s)
        o_occ = rasterise3d(s, grid, o.get("rasterise", "smooth"))
        occ = o_occ if occ is None else 1 - (1 - occ) * (1 - o_occ)
    edges = Edges.all(
        data.get("edges", {}).get("kind", "pml"), thickness_cells=int(data.get("edges", {}).get("thickness_cells", 12))
    )
    run = data.get("run", {})
    centre_cells = tuple(float(v) / grid.dx_m for v in tr["centre_m"])
    obstacle = shapes[0] if len(shapes) == 1 else Union3D(tuple(shapes))
    return Scene3D(
        run.get("name", p.stem),
        grid,
        Medium(med.get("speed_m_s", AIR_M_S), med.get("density_kg_m3", AIR_KG_M3), rigid=occ),
        src,
        edges,
        int(run["n_steps"]),
        obstacle,
        centre_cells,
        tuple(tr["axis"]),
        int(run.get("gate_start_step", 0)),
        {"diameter_m": tr.get("diameter_m"), "file": str(p)},
    )
