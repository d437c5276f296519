"""What every part of a scene's build shares: the scene errors (naming the file, the key and the
fix), the side names, and small readers of keys (points, vectors, materials, signals, run length)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple, NoReturn

import numpy as np

from .schema import ConfigError, fail, parse_table

if TYPE_CHECKING:
    from ..lattice.coefficients import Edges
    from ..lattice.grid import Grid
    from ..lattice.medium import Material, Medium
    from ..observe.farfield_base import FarFieldSurface
    from ..solver.sensors import Sensors
    from ..solver.sources import PointSources, Signal
    from .model import Scene
    from .schema import TransducerSection


class Receiver(NamedTuple):
    """A transducer that also receives (`receive = true`): its A-scan is
    `solver.sensors.received_signal` of the probe columns `start:stop` (its cells) with its
    weights and lags. `gate_start_step`: the echo window's first step (0: none given)."""

    name: str
    source: int
    start: int
    stop: int
    gate_start_step: int


class BuiltScene(NamedTuple):
    """What `Scene.build()` gives: the solver's objects plus what the scene asks to observe.

    - `grid`, `medium`, `sources`, `sensors`, `edges`, `n_steps`: the arguments of `simulate`;
    - `contour`: the far-field surface of the grid's kind (None when the scene has no `[farfield]`);
    - `farfield_source`: index of the transducer whose lobe is computed;
    - `show_steps`: steps at which field images are wanted; `render_every`: render stride, cells;
    - `receivers` (3d): the transducers whose received signal (A-scan) is recorded;
    - `estimate_bytes` (3d): the run's memory estimate, checked against the available memory
      before the medium maps were built (None on 2d and rz grids).
    """

    grid: Grid
    medium: Medium
    sources: tuple[PointSources, ...]
    sensors: Sensors
    edges: Edges
    n_steps: int
    contour: FarFieldSurface | None
    farfield_source: int
    show_steps: list[int]
    render_every: int
    receivers: tuple[Receiver, ...] = ()
    estimate_bytes: int | None = None


class SceneError(ConfigError):
    """A scene file that cannot be used: the message names the file, the key and the fix."""


def _fail(path, key, msg) -> NoReturn:
    fail(path, key, msg, SceneError)


def _parse_table(path, section: str, table, where: str):
    """One table of the scene file as its typed section (`schema.parse_table`), errors as
    `SceneError`."""
    return parse_table(path, section, table, where, SceneError)


class SceneTooLargeError(SceneError):
    """A scene (any lattice kind) whose run would not fit in the available memory; the message
    gives the estimate (`solver.estimate`) and the fix. Raised before any grid-sized array is
    built."""


_SIDES_2D = ("x_lo", "x_hi", "y_lo", "y_hi")


_NO_CELLS = np.zeros((0, 2), np.int32)


_SIDES_3D = _SIDES_2D + ("z_lo", "z_hi")


_TRANSDUCER_KEYS_3D = ("axis", "ring_edges_m", "fit_report", "gate_start_s")
"""Keys of a disc transducer that only a 3-D grid uses."""


def _signal(path, where: str, t: TransducerSection, grid: Grid) -> Signal:
    from ..solver.sources import ContinuousWave, ToneBurst

    f = t.frequency_hz or grid.frequency_hz
    try:
        if t.signal == "burst":
            return ToneBurst(f, t.cycles, t.window, t.amplitude_pa)
        return ContinuousWave(f, t.ramp_cycles, t.amplitude_pa)
    except (ValueError, TypeError) as err:
        _fail(path, where, str(err))


def _n_steps(scene: Scene, grid: Grid) -> int:
    p, r = scene.path, scene.run
    if (r.n_steps is None) == (r.duration_s is None):
        _fail(p, "run", "give exactly one of n_steps or duration_s (s)")
    n_steps = r.n_steps if r.n_steps is not None else int(math.ceil(grid.s_to_steps(r.duration_s)))
    if n_steps < 1:
        _fail(p, "run", f"n_steps = {n_steps} must be >= 1")
    return n_steps


def _points(path, key: str, points, ndim: int) -> np.ndarray:
    """Points [[x, y(, z)], ...] in metres as an (n, ndim) array, each checked for its length."""
    for j, pt in enumerate(points):
        if not isinstance(pt, (list, tuple)) or len(pt) != ndim:
            _fail(path, f"{key}[{j}]", f"= {pt!r}: give {ndim} coordinates in metres")
    try:
        return np.asarray(points, dtype=float).reshape(-1, ndim)
    except (TypeError, ValueError) as e:
        _fail(path, key, f"not numbers: {e}")


def _vector(path, key: str, v) -> tuple[float, float, float]:
    if v is None or len(v) != 3:
        _fail(path, key, f"= {v!r}: give 3 numbers [x, y, z]")
    return (float(v[0]), float(v[1]), float(v[2]))


def _material(path, key, name, lookup) -> Material:
    try:
        return lookup(name)
    except ValueError as e:
        _fail(path, key, str(e))
