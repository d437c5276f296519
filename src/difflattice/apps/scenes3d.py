"""3-D scenes (issue 16): pulse-echo scenes built through the official scene path, and the run and
outputs of any `[grid] kind = "3d"` scene file.

- The pulse-echo scenes (a disc transducer facing a wall at an incidence angle, a concave
  right-angle corner, a vertical post) are scene tables (`wall_data`, `corner_data`,
  `post_data`: the same dicts the files `data/scenes/*3d*.toml` hold), validated and built by
  `scene.model` like every scene; `wall_scene` etc. return a `Scene3D` (the built scene plus
  the geometry a reference needs), `pulse_echo` runs it and returns the A-scan the transducer
  receives (reciprocity: the weighted sum over its cells of the pressure there,
  `sensors.received_signal`). `load_scene3d` reads a file into a `Scene3D`, `scene_to_toml`
  writes one.
- `run_scene3d` runs any 3-D `Scene` (what `difflattice simulate` does for a 3-D file): the
  memory and time estimate is printed first and a run that would not fit is refused; then
  `write_outputs3d` writes the A-scans (CSV, JSON), the orthogonal slices and the
  maximum-intensity projections of the peak level (PNG) and a summary (JSON) with the estimate,
  the measured time and the peak memory.

Conventions: the pulse-echo transducer faces +x; a wall's incidence angle is the angle between
the transducer axis and the wall normal, turned in the x-y plane. Air is `difflattice.air` at
20 deg C. SI at the API, cells and steps only where a name says so.
"""

from __future__ import annotations

import copy
import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import jax.numpy as jnp
import numpy as np

from ..air import SPEED_OF_SOUND_20C_M_S
from ..lattice.coefficients import Edges
from ..lattice.geometry3d import Shape3D, Union3D
from ..lattice.grid import Grid
from ..lattice.kinds import KINDS
from ..lattice.medium import Medium
from ..scene.model import BuiltScene, Scene, SceneError, load_scene, parse_scene, shape3d
from ..scene.schema import ARRAY_SECTIONS, SECTIONS, HalfspaceObject
from ..solver.loop import simulate
from ..solver.sensors import Sensors, received_signal
from ..solver.sources import PointSources, ring_table

AIR_TEMPERATURE_C = 20.0
"""The pulse-echo scenes' air (`difflattice.air` at this temperature)."""


@dataclass(frozen=True)
class Scene3D:
    """A 3-D pulse-echo scene, ready to run (`pulse_echo`): the built scene's grid, medium,
    transducer, edges and step count, the obstacle as a solid, the transducer's centre (cells)
    and axis, the echo window's first step, and `data`, the scene tables it was built from."""

    name: str
    grid: Grid
    medium: Medium
    source: PointSources
    edges: Edges
    n_steps: int
    obstacle: Shape3D | None
    transducer_centre_cells: tuple[float, float, float]
    transducer_axis: tuple[float, float, float]
    gate_start_step: int  # the echo window starts here (after the transmit ring-down)
    meta: dict = field(default_factory=dict)
    data: dict = field(default_factory=dict)

    @property
    def sensors(self) -> Sensors:
        return Sensors(probes=self.source.cells_array)


def _dx_m(frequency_hz: float, cells_per_wavelength: float) -> float:
    return SPEED_OF_SOUND_20C_M_S / (frequency_hz * cells_per_wavelength)


def _sig(x: float) -> float:
    """`x` to 4 significant digits (times written to scene tables)."""
    return float(f"{x:.4g}")


def _r(v):
    """Lengths and directions to 7 significant digits (a readable file; 0.1 µm at 5 cm)."""
    if isinstance(v, (list, tuple)):
        return [_r(x) for x in v]
    return float(f"{float(v):.7g}")


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


def _steps_per_period(cells_per_wavelength: float, courant: float) -> float:
    return cells_per_wavelength / courant


def _n_steps(cpw: float, courant: float, path_cells: float, cycles: float) -> int:
    """Steps until an echo over `path_cells` has fully arrived (plus two periods)."""
    return int(math.ceil(path_cells / courant + (cycles + 2) * _steps_per_period(cpw, courant)))


def _gate(cpw: float, courant: float, earliest_path_cells: float, cycles: float, radius_cells: float = 0.0) -> int:
    """First step of the echo window: a period before the earliest echo, but not before the
    transmit has ended and its ring-down (the rim wave crossing the face) has left the face."""
    spp = _steps_per_period(cpw, courant)
    transmit = cycles * spp + 2 * radius_cells / courant
    return int(max(transmit, earliest_path_cells / courant - spp))


def _tables(
    *,
    shape,
    centre_cells,
    dx: float,
    frequency_hz: float,
    cells_per_wavelength: float,
    diameter_m: float,
    cycles: float,
    pml_cells: int,
    rasterise: str,
    dtype: str,
    objects: list[dict],
    n_steps: int,
    gate_step: int,
    rings: dict | None = None,
) -> dict:
    """The scene tables of a pulse-echo scene (a disc facing +x that also receives)."""
    from ..lattice.grid import DEFAULT_COURANT_3D

    dt = DEFAULT_COURANT_3D * dx / SPEED_OF_SOUND_20C_M_S
    tr: dict[str, Any] = {
        "name": "disc",
        "type": "disc",
        "centre_m": _r([float(v) * dx for v in centre_cells]),
        "axis": [1.0, 0.0, 0.0],
        "diameter_m": float(diameter_m),
        "signal": "burst",
        "cycles": float(cycles),
        "receive": True,
        "gate_start_s": _sig(gate_step * dt),
    }
    if rings is not None:
        edges, w, lags = ring_table(rings, 0.5 * diameter_m)
        tr.update(ring_edges_m=edges.tolist(), weights=w.tolist(), lags_s=lags.tolist())
    return {
        "grid": {
            "kind": "3d",
            "stencil": "standard",  # the 7-point validation scenes (references: analytic3d's 7-point relation)
            "frequency_hz": float(frequency_hz),
            "cells_per_wavelength": float(cells_per_wavelength),
            "size_m": _r([int(n) * dx for n in shape]),
            "dtype": dtype,
        },
        "medium": {"background": "air", "temperature_c": AIR_TEMPERATURE_C, "rasterise": rasterise},
        "edges": {"kind": "pml", "thickness_cells": int(pml_cells)},
        "transducers": [tr],
        "objects": objects,
        "sensors": {"p_max": True},
        "run": {"duration_s": _sig(n_steps * dt)},
    }


def wall_data(
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
) -> dict:
    """Scene tables of a rigid plane wall `distance_m` in front of a disc transducer (along its
    axis), its normal turned by `angle_deg` from the axis in the x-y plane (0 = normal incidence).
    The wall fills the half-space behind the plane, into the absorbing layers."""
    from ..lattice.grid import DEFAULT_COURANT_3D as C

    cpw = cells_per_wavelength
    dx = _dx_m(frequency_hz, cpw)
    a = 0.5 * diameter_m / dx
    d = distance_m / dx
    t = math.radians(angle_deg)
    lat = (lateral_m / dx) if lateral_m is not None else 2 * (a + d * math.sin(t) + 0.6 * math.sqrt(d * cpw)) + 8
    shape, c, d = _layout(dx, diameter_m, distance_m, pml_cells, extra_x=0.5 * lat * math.tan(t), lateral=lat)
    normal = [-math.cos(t), math.sin(t), 0.0]  # outward normal of the solid (pointing back at the transducer)
    point = [(c[0] + d) * dx, c[1] * dx, c[2] * dx]
    return _tables(
        shape=shape,
        centre_cells=c,
        dx=dx,
        frequency_hz=frequency_hz,
        cells_per_wavelength=cpw,
        diameter_m=diameter_m,
        cycles=cycles,
        pml_cells=pml_cells,
        rasterise=rasterise,
        dtype=dtype,
        objects=[{"shape": "halfspace", "material": "rigid", "point_m": _r(point), "normal": _r(normal)}],
        n_steps=_n_steps(cpw, C, 2 * d + 2 * a * math.sin(2 * t) + 4 * a * a / (4 * d), cycles),
        gate_step=_gate(cpw, C, 2 * (d - a * math.sin(t)) - 2 * a * math.tan(t), cycles, a),
        rings=rings,
    )


def corner_data(
    *,
    distance_m: float = 0.0257,
    diameter_m: float = 8.6e-3,
    frequency_hz: float = 40e3,
    cells_per_wavelength: float = 20.0,
    cycles: float = 3.0,
    pml_cells: int = 12,
    dtype: Literal["float32", "float64"] = "float32",
) -> dict:
    """Scene tables of a concave right-angle corner (two rigid walls meeting along a vertical
    edge, parallel to z) whose edge lies `distance_m` ahead on the transducer axis, the axis
    bisecting the corner: the corner returns the beam towards the transducer like a mirror at
    normal incidence (the paper's Fig. 6 in 3-D). The solid is the union of the half-spaces
    behind the two walls (their intersection would be a convex wedge)."""
    from ..lattice.grid import DEFAULT_COURANT_3D as C

    cpw = cells_per_wavelength
    dx = _dx_m(frequency_hz, cpw)
    a = 0.5 * diameter_m / dx
    d = distance_m / dx
    shape, c, d = _layout(dx, diameter_m, distance_m, pml_cells, extra_x=0.0, lateral=2 * (a + 0.5 * d) + 8)
    apex = [(c[0] + d) * dx, c[1] * dx, c[2] * dx]
    s = 1 / math.sqrt(2)
    parts = [{"shape": "halfspace", "point_m": _r(apex), "normal": _r([-s, sgn * s, 0.0])} for sgn in (1, -1)]
    return _tables(
        shape=shape,
        centre_cells=c,
        dx=dx,
        frequency_hz=frequency_hz,
        cells_per_wavelength=cpw,
        diameter_m=diameter_m,
        cycles=cycles,
        pml_cells=pml_cells,
        rasterise="smooth",
        dtype=dtype,
        objects=[{"shape": "union", "material": "rigid", "parts": parts}],
        n_steps=_n_steps(cpw, C, 2 * d + 2 * a, cycles),
        gate_step=_gate(cpw, C, math.sqrt(2) * d - 2 * a, cycles, a),
    )


def post_data(
    *,
    distance_m: float = 0.0257,
    post_diameter_m: float = 4.3e-3,
    diameter_m: float = 8.6e-3,
    frequency_hz: float = 40e3,
    cells_per_wavelength: float = 20.0,
    cycles: float = 3.0,
    pml_cells: int = 12,
    dtype: Literal["float32", "float64"] = "float32",
) -> dict:
    """Scene tables of a vertical rigid post (a cylinder along z through the whole grid,
    `post_diameter_m` wide) whose axis crosses the transducer axis `distance_m` ahead: a 2-D cut
    would make it an infinite wall; in 3-D its echo spreads in the horizontal plane."""
    from ..lattice.grid import DEFAULT_COURANT_3D as C

    cpw = cells_per_wavelength
    dx = _dx_m(frequency_hz, cpw)
    a = 0.5 * diameter_m / dx
    rp = 0.5 * post_diameter_m / dx
    shape, c, _ = _layout(dx, diameter_m, distance_m + post_diameter_m, pml_cells)
    d = distance_m / dx
    post = {
        "shape": "cylinder",
        "material": "rigid",
        "centre_m": _r([(c[0] + d + rp) * dx, c[1] * dx, c[2] * dx]),
        "axis": [0.0, 0.0, 1.0],
        "radius_m": _r(rp * dx),
        "length_m": _r(4.0 * shape[2] * dx),
    }
    return _tables(
        shape=shape,
        centre_cells=c,
        dx=dx,
        frequency_hz=frequency_hz,
        cells_per_wavelength=cpw,
        diameter_m=diameter_m,
        cycles=cycles,
        pml_cells=pml_cells,
        rasterise="smooth",
        dtype=dtype,
        objects=[post],
        n_steps=_n_steps(cpw, C, 2 * d + 2 * a, cycles),
        gate_step=_gate(cpw, C, 2 * d - 2 * a, cycles, a),
    )


def wall_scene(angle_deg: float = 0.0, **kw) -> Scene3D:
    """The wall scene (`wall_data`'s arguments), built through the scene path."""
    return scene3d_from_data(wall_data(angle_deg, **kw), f"wall_{angle_deg:g}deg")


def corner_scene(**kw) -> Scene3D:
    """The corner scene (`corner_data`'s arguments), built through the scene path."""
    return scene3d_from_data(corner_data(**kw), "corner")


def post_scene(**kw) -> Scene3D:
    """The post scene (`post_data`'s arguments), built through the scene path."""
    return scene3d_from_data(post_data(**kw), "post")


def scene3d_from_data(data: dict, name: str, path: str | None = None) -> Scene3D:
    """Validate and build scene tables of a 3-D pulse-echo scene (one disc transducer with
    `receive = true`) into a `Scene3D`."""
    scene = parse_scene(copy.deepcopy(data), path or f"<{name}>")
    return _scene3d(scene, scene.build(), name, data)


def _scene3d(scene: Scene, built: BuiltScene, name: str, data: dict) -> Scene3D:
    p = scene.path
    if len(built.sources) != 1 or not built.receivers:
        raise SceneError(f"{p}: [transducers] a pulse-echo scene has one disc transducer with receive = true")
    g = built.grid
    t = scene.transducers[0]
    centre = tuple(float(v) / g.dx_m for v in t.centre_m)
    axis = tuple(float(v) for v in (getattr(t, "axis", None) or (1.0, 0.0, 0.0)))
    solids = [shape3d(p, f"objects[{i}]", o) for i, o in enumerate(scene.objects)]
    obstacle = None if not solids else solids[0] if len(solids) == 1 else Union3D(tuple(solids))
    radius_m = 0.5 * t.diameter_m if t.diameter_m is not None else None
    meta: dict[str, Any] = {"diameter_m": t.diameter_m, "file": p}
    if radius_m is not None:
        meta["radius_cells"] = radius_m / g.dx_m
    objs = scene.objects
    if len(objs) == 1 and isinstance(objs[0], HalfspaceObject):
        o = objs[0]
        point = tuple(float(v) / g.dx_m for v in o.point_m)
        n = np.asarray(o.normal, float)
        meta.update(
            wall_point_cells=point,
            wall_normal=tuple(float(v) for v in n / np.linalg.norm(n)),
            angle_deg=math.degrees(math.atan2(abs(n[1]), -n[0])),
            distance_cells=point[0] - centre[0],
            rasterise=scene.medium.rasterise,
        )
    return Scene3D(
        name,
        g,
        built.medium,
        built.sources[0],
        built.edges,
        built.n_steps,
        obstacle,
        (centre[0], centre[1], centre[2]),
        (axis[0], axis[1], axis[2]),
        built.receivers[0].gate_start_step,
        meta,
        data,
    )


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
# scene files


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise ValueError(f"cannot write {v!r} to TOML")


def data_to_toml(data: dict, comment: str = "") -> str:
    """Scene tables as a scene file (sections in the schema's order)."""
    lines = [f"# {line}" if line else "#" for line in comment.strip().splitlines()] if comment else []
    for name in SECTIONS:
        if name not in data:
            continue
        tables = data[name] if name in ARRAY_SECTIONS else [data[name]]
        for t in tables:
            lines.append(f"[[{name}]]" if name in ARRAY_SECTIONS else f"[{name}]")
            lines += [f"{k} = {_toml_value(v)}" for k, v in t.items()]
            lines.append("")
    return "\n".join(lines)


def scene_to_toml(scene: Scene3D, comment: str = "") -> str:
    """The scene file (kind = "3d") that `load_scene3d` turns back into `scene`."""
    return data_to_toml(scene.data, comment)


def load_scene3d(path) -> Scene3D:
    """Read a 3-D pulse-echo scene file (`[grid] kind = "3d"`, one disc transducer with
    `receive = true`) through the scene path into a `Scene3D`."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text())
    except OSError as e:
        raise SceneError(f"{p}: cannot read the scene file ({e.strerror})") from None
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{p}: not valid TOML: {e}") from None
    kind = (data.get("grid") or {}).get("kind")
    if not _is_volume(kind):
        raise SceneError(f'{p}: [grid.kind] = {kind!r}; this loader reads 3-D scenes (kind = "3d")')
    scene = load_scene(p)
    return _scene3d(scene, scene.build(), p.stem, data)


def _is_volume(kind) -> bool:
    """Whether a scene file's raw `[grid] kind` names a 3-D lattice."""
    return isinstance(kind, str) and kind in KINDS and KINDS[kind].ndim == 3


def load_scene_at(path, cells_per_wavelength: float | None = None) -> Scene:
    """Read a scene file (any kind), at `cells_per_wavelength` if given (`Scene.at_resolution`)."""
    scene = load_scene(path)
    return scene if cells_per_wavelength is None else scene.at_resolution(cells_per_wavelength)


# ------------------------------------------------------------------------------------------
# running a 3-D scene file


# the run and its outputs live in `scene3d_run`; re-exported here for existing callers
from .scene3d_run import (  # noqa: E402, F401
    A_SCAN_LABEL,
    EMPTY_FIELD,
    SceneRun3D,
    _last_field_planes,
    run_scene3d,
    write_outputs3d,
)
