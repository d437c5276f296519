"""A scene at another resolution: cell and step counts scale, metres and seconds stay
(`scaled_scene` by a factor, `scene_at` for a target cells-per-wavelength; `Scene.scaled` and
`Scene.at_resolution` call them). Works on the typed spec (`dataclasses.replace`), each changed
section checked again. Per-cell weights and lags of a line (and per-ring ones of an rz disc,
whose rings are one cell wide) are resampled; a 3-D disc's per-ring weights and lags are kept
(its rings are in metres)."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from .common import SceneError

if TYPE_CHECKING:
    from .model import Scene


def _c_max(scene: Scene) -> float:
    """Speed of the fastest fluid of a scene, m/s (what the grid is scaled to): the background
    at `[medium]`'s temperature and every fluid object (none under speed_zero)."""
    from ..lattice.medium import air, material

    med = scene.medium
    bg = air(med.air_temperature_c) if med.background == "air" else material(med.background)
    speeds = [bg.speed_m_s]
    if med.boundary_model != "speed_zero":
        for o in scene.objects:
            m = material(o.material_name)
            if m.kind == "fluid":
                speeds.append(m.speed_m_s)
    return max(speeds)


def _resample(values, n: int) -> list[float]:
    v = np.asarray(values, dtype=float)
    if len(v) == n:
        return v.tolist()
    if len(v) == 1:
        return [float(v[0])] * n
    return np.interp(np.linspace(0, 1, n), np.linspace(0, 1, len(v)), v).tolist()


def scaled_scene(scene: Scene, scale: float) -> Scene:
    """`scene` with the grid `scale` times as fine (physical sizes kept).

    cells_per_wavelength, a grid shape in cells, a line's n_cells, per-cell weights and lags
    (resampled along the line; per ring of an rz disc), edge thickness, far-field gap, snapshot
    interval, show_steps and n_steps all scale; sizes and positions in metres, duration_s and
    show_times_s stay. scale = 1 returns the scene itself."""
    if not scale > 0:
        raise ValueError(f"scale = {scale} must be > 0")
    if scale == 1:
        return scene

    def sc(n, lo=1):
        return max(lo, int(round(n * scale)))

    g = scene.grid
    grid = replace(
        g,
        cells_per_wavelength=g.cells_per_wavelength * scale,
        shape=None if g.shape is None else tuple(sc(n, 3) for n in g.shape),
    )
    dx = _c_max(scene) / (grid.frequency_hz * grid.cells_per_wavelength)
    volume = scene.kind.ndim == 3
    transducers = []
    for t in scene.transducers:
        n_cells = getattr(t, "n_cells", None)
        if n_cells is not None:
            n = sc(n_cells)
            t = replace(t, n_cells=n)
        elif t.diameter_m is not None:
            n = max(1, int(round(t.diameter_m / dx)))
        else:
            n = None
        if n is not None and not volume:
            per_cell: dict[str, Any] = {
                k: _resample(getattr(t, k), n) for k in ("weights", "lags_s") if getattr(t, k) is not None
            }
            t = replace(t, **per_cell) if per_cell else t
        transducers.append(t)
    s, o, r = scene.sensors, scene.output, scene.run
    return replace(
        scene,
        grid=grid,
        edges=replace(scene.edges, thickness_cells=sc(scene.edges.thickness_cells, 4)),
        transducers=tuple(transducers),
        output=replace(o, show_steps=tuple(sc(v) for v in o.show_steps)) if o.show_steps else o,
        sensors=s if s.snapshot_every_steps is None else replace(s, snapshot_every_steps=sc(s.snapshot_every_steps)),
        farfield=None if scene.farfield is None else replace(scene.farfield, gap_cells=sc(scene.farfield.gap_cells)),
        run=r if r.n_steps is None else replace(r, n_steps=sc(r.n_steps)),
    )


def scene_at(scene: Scene, cells_per_wavelength: float) -> Scene:
    """`scene` at `cells_per_wavelength` (`scaled_scene` by the ratio to its own resolution; the
    resolution then set exactly)."""
    if not cells_per_wavelength > 0:
        raise SceneError(f"cells_per_wavelength = {cells_per_wavelength}: give a resolution > 0")
    out = scaled_scene(scene, cells_per_wavelength / scene.grid.cells_per_wavelength)
    return replace(out, grid=replace(out.grid, cells_per_wavelength=float(cells_per_wavelength)))
