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
import os
import platform
import sys
import time
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
from ..scene.model import BuiltScene, Scene, SceneError, SceneTooLargeError, load_scene, parse_scene, shape3d
from ..scene.schema import ARRAY_SECTIONS, SECTIONS
from ..solver.loop import Result, simulate
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
    centre = tuple(float(v) / g.dx_m for v in t["centre_m"])
    axis = tuple(float(v) for v in (t["axis"] or (1.0, 0.0, 0.0)))
    solids = [shape3d(p, f"objects[{i}]", o) for i, o in enumerate(scene.objects)]
    obstacle = None if not solids else solids[0] if len(solids) == 1 else Union3D(tuple(solids))
    radius_m = 0.5 * t["diameter_m"] if t["diameter_m"] is not None else None
    meta: dict[str, Any] = {"diameter_m": t["diameter_m"], "file": p}
    if radius_m is not None:
        meta["radius_cells"] = radius_m / g.dx_m
    objs = scene.objects
    if len(objs) == 1 and objs[0]["shape"] == "halfspace":
        o = objs[0]
        point = tuple(float(v) / g.dx_m for v in o["point_m"])
        n = np.asarray(o["normal"], float)
        meta.update(
            wall_point_cells=point,
            wall_normal=tuple(float(v) for v in n / np.linalg.norm(n)),
            angle_deg=math.degrees(math.atan2(abs(n[1]), -n[0])),
            distance_cells=point[0] - centre[0],
            rasterise=scene.medium["rasterise"],
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


@dataclass
class SceneRun3D:
    """A finished 3-D scene run: the scene, what it built, the result, the A-scans of its
    receiving transducers ({name: (t_s, a_scan)}) and the summary."""

    scene: Scene
    built: BuiltScene
    result: Result
    a_scans: dict
    summary: dict

    @property
    def grid(self) -> Grid:
        return self.built.grid


def _peak_memory_bytes() -> dict:
    """The process's peak memory: the accelerator's peak bytes in use where JAX reports them,
    and the host's peak resident set (ru_maxrss) always."""
    import resource

    import jax

    out: dict[str, Any] = {"host_peak_rss_bytes": int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024}
    d = jax.devices()[0]
    if d.platform != "cpu":
        stats = d.memory_stats() or {}
        if "peak_bytes_in_use" in stats:
            out["device_peak_bytes"] = int(stats["peak_bytes_in_use"])
    return out


def run_scene3d(
    scene: Scene, *, available_bytes: int | None = None, mlups: float | None = None, quiet: bool = False
) -> SceneRun3D:
    """Build and run a 3-D scene: the estimate (memory, and time from the measured throughput or
    `mlups`) is printed to stderr before the run (unless `quiet`) and kept in the summary; a run
    that would not fit in `available_bytes` (default: this machine's available memory) is refused
    with `SceneTooLargeError`. Returns the run with the A-scans of the receiving transducers."""
    import equinox as eqx
    import jax

    from .. import __version__
    from ..observe.analytic3d import lattice_wavenumber_3d
    from ..solver.estimate import RunTooLargeError, check_fits, estimate_run, features_of, format_estimate
    from ..solver.loop import check_result, run
    from ..solver.stepper import Stepper

    if scene.kind.ndim != 3:
        raise SceneError(f'{scene.path}: [grid.kind] = {scene.grid["kind"]!r}; run_scene3d runs kind = "3d" scenes')
    t0 = time.perf_counter()
    built = scene.build(available_bytes=available_bytes)
    grid, n_steps = built.grid, built.n_steps
    stepper = Stepper.build(grid, built.medium, built.sources, built.sensors, built.edges)
    shape = tuple(grid.shape)
    feats = features_of(stepper, n_steps, mlups=mlups)
    nbytes, secs = estimate_run(shape, n_steps, grid.dtype, feats)
    line = format_estimate(shape, n_steps, nbytes, secs)
    if not quiet:
        print(line, file=sys.stderr, flush=True)
    try:
        check_fits(shape, n_steps, nbytes, available=available_bytes, seconds=secs)
    except RunTooLargeError as err:
        raise SceneTooLargeError(f"{scene.path}: [grid] {' '.join(str(err).split())}") from None
    build_s = time.perf_counter() - t0

    t1 = time.perf_counter()
    if not quiet:
        print("compiling the 3-D time loop (seconds; cached for the next run) ...", file=sys.stderr, flush=True)

    def whole_run(st):
        return check_result(run(st, n_steps), st)

    jitted: Any = eqx.filter_jit(whole_run)
    compiled = jitted.lower(stepper).compile()
    compile_s = time.perf_counter() - t1
    if not quiet:
        print(f"compiled in {compile_s:.1f} s; running {n_steps} steps ...", file=sys.stderr, flush=True)
    t2 = time.perf_counter()
    result = compiled(stepper)
    jax.block_until_ready(result.peak_history)
    run_s = time.perf_counter() - t2
    wall = time.perf_counter() - t1
    memory = _peak_memory_bytes()

    a_scans = {}
    t_s = np.arange(1, n_steps + 1) * grid.dt_s
    probes = np.asarray(result.probes) if result.probes is not None else np.zeros((n_steps, 0))
    receivers = {}
    for r in built.receivers:
        src = built.sources[r.source]
        lags = src.lags_s if bool(jnp.any(src.lags_s != 0)) else None
        a = np.asarray(received_signal(probes[:, r.start : r.stop], src.weights, lags, grid.dt_s))
        a_scans[r.name] = (t_s, a)
        gated = np.abs(a[r.gate_start_step :]) if r.gate_start_step < n_steps else np.zeros(1)
        k = int(np.argmax(gated))
        receivers[r.name] = {
            "cells": r.stop - r.start,
            "gate_start_step": r.gate_start_step,
            "gate_start_s": r.gate_start_step * grid.dt_s,
            "echo_peak": float(gated[k]),
            "echo_peak_s": (r.gate_start_step + k + 1) * grid.dt_s,
            "transmit_peak": float(np.abs(a[: max(1, r.gate_start_step)]).max()),
            "units": "Pa x cell weights (the weighted sum of the pressure over the transducer's cells)",
        }

    dist_cells = min(grid.courant * n_steps, math.sqrt(sum(n * n for n in shape)))
    omega = grid.omega
    k0 = omega / grid.courant
    k_axis, k_diag = (float(lattice_wavenumber_3d(omega, grid.courant, d)) for d in ((1, 0, 0), (1, 1, 1)))
    perr = max(abs(k_axis - k0), abs(k_diag - k0)) * dist_cells
    edges = built.edges
    summary = {
        "difflattice_version": __version__,
        "scene": scene.path,
        "grid": grid.describe(),
        "medium": {
            "boundary_model": built.medium.boundary_model,
            "homogeneous": built.medium.is_homogeneous,
            "absorption_db_per_m": built.medium.absorption_db_per_m,
        },
        "edges": {s: getattr(edges, s) for s in ("x_lo", "x_hi", "y_lo", "y_hi", "z_lo", "z_hi")}
        | {"thickness_cells": edges.thickness_cells},
        "estimate": {
            "printed": line,
            "memory_bytes": nbytes,
            "time_s": secs,
            "mlups_assumed": feats.mlups if feats.mlups is not None else "measured (solver.estimate.measure_mlups)",
        },
        "run": {
            "n_steps": n_steps,
            "duration_s": n_steps * grid.dt_s,
            "build_s": build_s,
            "wall_time_s": wall,
            "compile_s": compile_s,
            "note": "wall_time_s: the time loop including its compilation (compile_s); mlups over wall_time_s, "
            "mlups_excl_compile over the run alone",
            "mlups": math.prod(shape) * n_steps / wall / 1e6,
            "mlups_excl_compile": math.prod(shape) * n_steps / run_s / 1e6,
            "device": str(jax.devices()[0]),
            "machine": platform.machine(),
            "load_average": list(os.getloadavg()),
        },
        "memory": memory,
        "stability": {
            "finite": bool(np.all(np.isfinite(np.asarray(result.peak_history)))),
            "peak_pa": float(np.max(np.asarray(result.peak_history))),
            "final_peak_pa": float(np.asarray(result.peak_history)[-1]),
        },
        "receivers": receivers,
        "accuracy": {
            "farthest_distance_m": dist_cells * grid.dx_m,
            "expected_phase_error_periods": perr / (2 * math.pi),
            "note": "worst of the axis and diagonal directions, from the 3-D lattice's dispersion relation "
            "(analytic3d); above ~0.05 periods arrival times at that distance are not trustworthy: raise "
            "cells_per_wavelength",
        },
    }
    return SceneRun3D(scene, built, result, a_scans, summary)


def _plane_label(axis: int, index: int, dx_m: float) -> tuple[str, tuple[str, str]]:
    names = tuple(n for i, n in enumerate("xyz") if i != axis)
    return f"{names[0]}-{names[1]} at {'xyz'[axis]} = {index * dx_m * 1e3:.1f} mm", (names[0], names[1])


def write_outputs3d(sr: SceneRun3D, out_dir: str | Path, *, data_format: str = "npz") -> dict:
    """Write a 3-D run's outputs into `out_dir`; returns the paths:

    - a_scan.csv (a header row, then t_s and one column per receiving transducer,
      `<name>_pa_x_weight`: the weighted sum of the pressure over its cells, Pa x cell weights,
      not a pressure) and a_scan.json (the same with the echo window), a_scan.png;
    - peak_slices.png: the peak level (dB re its maximum) on the orthogonal planes of
      `[sensors] snapshot_slices_m` (default: through the transducer's centre), transducer cells
      in cyan and rigid obstacles outlined; field_slices.png: the pressure there at the last
      step where the field is not empty (the last snapshot that holds a wave, when the wave has
      left the window by the end);
    - mip_z.png, mip_y.png: maximum-intensity projections of the peak level along z (seen from
      above) and y (from the side); probes.png: the `[sensors] probes_m` pressures;
    - sensors.npz (probe series, A-scans, the peak-level, RMS and arrival volumes where recorded,
      snapshot planes) or, with `data_format` "netcdf", sensors.nc (the same with coordinates in
      m and s and units as attributes); probes.csv (t_s, probe_<i>_pa) where probes were given;
      summary.json.
    """
    from .. import plots
    from . import datafiles

    datafiles.check_format(data_format)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    g, res, built = sr.grid, sr.result, sr.built
    files: dict[str, Any] = {}
    arrays: dict[str, np.ndarray] = {"peak_history_pa": np.asarray(res.peak_history)}
    if res.probes is not None:
        arrays["probes_pa"] = np.asarray(res.probes)
        arrays["probe_cells"] = np.asarray(built.sensors.probes)
    if sr.a_scans:
        names = list(sr.a_scans)
        t = next(iter(sr.a_scans.values()))[0]
        cols = np.stack([sr.a_scans[n][1] for n in names], axis=1)
        table = {"t_s": t} | {datafiles.column_name(n, "pa_x_weight"): sr.a_scans[n][1] for n in names}
        files["a_scan_csv"] = str(datafiles.write_csv(out / "a_scan.csv", table))
        doc = {
            "dt_s": g.dt_s,
            "t_s": t.tolist(),
            "a_scan": {n: sr.a_scans[n][1].tolist() for n in names},
            "receivers": sr.summary["receivers"],
        }
        (out / "a_scan.json").write_text(json.dumps(doc))
        files["a_scan_json"] = str(out / "a_scan.json")
        fig = plots.time_series_plot(t, cols, names, ylabel=A_SCAN_LABEL)
        files["a_scan_png"] = str(plots.save(fig, out / "a_scan.png"))
        for n in names:
            arrays[f"a_scan_{n}"] = sr.a_scans[n][1]
    n_user = min((r.start for r in built.receivers), default=built.sensors.n_probes)
    if res.probes is not None and n_user > 0:  # the [sensors] probes_m points (before the receivers' cells)
        t = (np.arange(res.probes.shape[0]) + 1) * g.dt_s
        user = np.asarray(res.probes)[:, :n_user]
        fig = plots.time_series_plot(t, user, [f"probe {i}" for i in range(n_user)])
        files["probes"] = str(plots.save(fig, out / "probes.png"))
        cols_p = {"t_s": t} | {f"probe_{i}_pa": user[:, i] for i in range(n_user)}
        files["probes_csv"] = str(datafiles.write_csv(out / "probes.csv", cols_p))
    planes = built.sensors.snapshot_planes(tuple(g.shape)) or ()
    src_cells = [np.asarray(s.cells_array) for s in built.sources]
    rigid = None if built.medium.rigid is None else np.asarray(built.medium.rigid)
    marks, outlines = {}, {}

    def plane(a3, axis, index):
        return np.take(a3, index, axis=axis)

    for axis, index in planes:
        label, _ = _plane_label(axis, index, g.dx_m)
        keep = [i for i in range(3) if i != axis]
        marks[label] = [c[:, keep] for c in src_cells]
        if rigid is not None:
            outlines[label] = plane(rigid, axis, index)
    if res.p_rms is not None:
        arrays["p_rms_pa"] = np.asarray(res.p_rms)
    if res.arrival is not None:
        arrays["arrival_step"] = np.asarray(res.arrival)
    if res.p_max is not None:
        pmax = np.asarray(res.p_max)
        arrays["p_max_pa"] = pmax
        peak = {}
        for axis, index in planes:
            label, axes = _plane_label(axis, index, g.dx_m)
            peak[label] = (axes, plane(pmax, axis, index))
        fig = plots.slices_3d(
            peak, g.dx_m, floor_db=-40.0, marks=marks, outlines=outlines, title="peak level (dB re max)"
        )
        files["peak_slices"] = str(plots.save(fig, out / "peak_slices.png"))
        for axis in (2, 1):
            fig = plots.max_intensity_projection(pmax, g.dx_m, axis=axis, floor_db=-40.0)
            files[f"mip_{'xyz'[axis]}"] = str(plots.save(fig, out / f"mip_{'xyz'[axis]}.png"))
    n_steps = sr.summary["run"]["n_steps"]
    step, field_planes = _last_field_planes(sr, planes)
    note = "" if step == n_steps else f", the last snapshot that holds a wave (the run ends at step {n_steps})"
    fig = plots.slices_3d(
        field_planes,
        g.dx_m,
        marks=marks,
        outlines=outlines,
        title=f"pressure at step {step} ({step * g.dt_s * 1e6:.0f} µs){note}",
    )
    files["field_slices"] = str(plots.save(fig, out / "field_slices.png"))
    if res.snapshots is not None:
        snaps = res.snapshots if isinstance(res.snapshots, tuple) else (res.snapshots,)
        for (axis, index), s in zip(planes, snaps):
            arrays[f"snapshots_{'xyz'[axis]}{index}_pa"] = np.asarray(s)
        arrays["snapshot_steps"] = np.asarray(res.snapshot_steps)
    if data_format == "netcdf":
        files["sensors"] = str(datafiles.netcdf_3d(sr, arrays, out / "sensors.nc"))
    else:
        np.savez_compressed(out / "sensors.npz", allow_pickle=False, **arrays)
        files["sensors"] = str(out / "sensors.npz")
    sr.summary["files"] = files
    (out / "summary.json").write_text(json.dumps(sr.summary, indent=2, default=_json_default))
    files["summary"] = str(out / "summary.json")
    return files


A_SCAN_LABEL = "weighted sum over the face (Pa x cell weight)"
"""The A-scan's quantity: the receiving transducer's weighted sum of the pressure over its cells
(`received_signal`), in Pa times the (dimensionless) cell weights; not a pressure."""

EMPTY_FIELD = 1e-3
"""A field slice whose largest |p| is below this fraction of the run's peak counts as empty."""


def _last_field_planes(sr: SceneRun3D, planes) -> tuple[int, dict]:
    """The field on the snapshot planes at the last step where it is not empty: the last step of
    the run, or, where the wave has left the window by then (below `EMPTY_FIELD` x the run's
    peak), the last recorded snapshot above that. Returns (step, {label: (axes, 2-D array)})."""
    g, res = sr.grid, sr.result
    n_steps = sr.summary["run"]["n_steps"]
    final = np.asarray(res.final.pressure)
    labels = [_plane_label(axis, index, g.dx_m) for axis, index in planes]
    final_planes = {lab: (axes, np.take(final, index, axis=axis)) for (lab, axes), (axis, index) in zip(labels, planes)}
    peak = float(sr.summary["stability"]["peak_pa"]) or 1.0
    level = max((float(np.abs(a).max()) for _, a in final_planes.values()), default=0.0)
    if level >= EMPTY_FIELD * peak or res.snapshots is None or res.snapshot_steps is None:
        return n_steps, final_planes
    snaps = [np.asarray(s) for s in (res.snapshots if isinstance(res.snapshots, tuple) else (res.snapshots,))]
    steps = np.asarray(res.snapshot_steps).reshape(-1)
    for k in range(len(steps) - 1, -1, -1):
        if max(float(np.abs(s[k]).max()) for s in snaps) >= EMPTY_FIELD * peak:
            return int(steps[k]), {lab: (axes, s[k]) for (lab, axes), s in zip(labels, snaps)}
    return n_steps, final_planes


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
