"""The 3-D scene build: grid, edges, disc transducers and sensors first, then the memory estimate
(a run that does not fit is refused before any grid-sized array exists), then the medium maps.
`Scene.build` calls it for a 3-D grid (the plane and rz builds live with the scene)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from .common import (
    _NO_CELLS,
    _SIDES_3D,
    BuiltScene,
    Receiver,
    _fail,
    _n_steps,
    _points,
    _signal,
    _vector,
)
from .media import _make_grid, _materials, _medium
from .objects import _rings_3d, _slice_planes, _union3d, shape3d
from .schema import DiscTransducer

if TYPE_CHECKING:
    from .model import Scene


def build_volume(self: Scene, available_bytes: int | None) -> BuiltScene:
    """The 3-D lattice: grid, edges, sources and sensors first, then the memory estimate
    (refused before any grid-sized array exists), then the medium maps."""
    from ..lattice import geometry3d as g3
    from ..lattice.coefficients import Edges

    p = self.path
    med = self.medium
    bg, mats = _materials(self)
    grid = _make_grid(self, mats)
    if self.farfield is not None:
        _fail(
            p,
            "farfield",
            "is for 2d and rz scenes; on a 3d grid record probes (or use observe.farfield3d from Python)",
        )
    o = self.output
    if o.show_steps or o.show_times_s:
        _fail(
            p,
            "output.show_steps",
            "field moments are for 2d and rz scenes; on a 3d grid use [sensors] snapshot_every_steps "
            "(slices every that many steps)",
        )

    ed = self.edges
    if ed.r_hi is not None:
        _fail(p, "edges.r_hi", "is for rz grids; a 3d grid has x_lo, x_hi, y_lo, y_hi, z_lo, z_hi")
    try:
        sides: dict[str, Any] = {s: (getattr(ed, s) or ed.kind) for s in _SIDES_3D}
        edges = Edges(**sides, thickness_cells=ed.thickness_cells)
        edges = edges.for_rank(3)
        edges.check_kind(grid.kind)
    except ValueError as err:
        _fail(p, "edges", str(err))
    n_steps = _n_steps(self, grid)

    # sources (small: the disc's cells) and sensors before anything grid-sized
    sources = _sources_3d(self, grid)
    sensors, receivers, n_cols, planes = _sensors_3d(self, grid, sources)
    s = self.sensors

    # the estimate, before the medium maps (the largest arrays a build makes) exist
    shape = tuple(grid.shape)
    n_snap = 0 if s.snapshot_every_steps is None else -(-n_steps // min(s.snapshot_every_steps, n_steps))
    nbytes = self._check_fits(
        grid,
        n_steps,
        available_bytes,
        pml=edges.uses_pml,
        sponge="sponge" in edges.kinds(),
        heterogeneous=bool(self.objects),
        soft=any(m.kind == "soft" for m in mats[1:]) or med.boundary_model == "speed_zero",
        absorption=med.absorption_db_per_m > 0,
        air_absorption=self.air_conditions() is not None,
        n_probes=n_cols,
        snapshot_cells=sum(math.prod(shape) // shape[a] for a, _ in planes),
        n_snapshots=n_snap,
        field_stats=int(s.p_max) + int(s.p_rms) + int(s.arrival_threshold_pa is not None),
    )

    occupancies = []
    for i, ob in enumerate(self.objects):
        solid = shape3d(p, f"objects[{i}]", ob)
        try:
            occupancies.append(g3.rasterise3d(solid, grid, med.rasterise))
        except ValueError as e:
            _fail(p, "medium.rasterise", str(e))
    medium = _medium(self, grid, bg, mats, occupancies, [], _union3d)
    return BuiltScene(
        grid,
        medium,
        tuple(sources),
        sensors,
        edges,
        n_steps,
        None,
        0,
        [],
        self.render_every(grid),
        tuple(receivers),
        int(nbytes),
    )


def _sources_3d(self: Scene, grid) -> list:
    """The 3-D scene's disc transducers (each checked, errors naming its key)."""
    from ..solver.sources import disc_transducer_3d

    p = self.path
    if not self.transducers:
        _fail(p, "transducers", "a scene needs at least one [[transducers]] entry")
    sources = []
    for i, t in enumerate(self.transducers):
        where = f"transducers[{i}]"
        if not isinstance(t, DiscTransducer):
            _fail(p, f"{where}.type", f'= {t.type!r} is a 2d transducer: a 3d grid takes type = "disc"')
        if t.baffle is not None and t.baffle != "none":
            _fail(
                p,
                f"{where}.baffle",
                f"= {t.baffle!r}: a 3d disc is a bare source; give a baffle as an object (e.g. a box "
                'behind the face) and baffle = "none"',
            )
        injection = t.injection or "soft"
        centre = _vector(p, f"{where}.centre_m", t.centre_m)
        axis = _vector(p, f"{where}.axis", t.axis if t.axis is not None else [1.0, 0.0, 0.0])
        rings, diameter = _rings_3d(self, where, t)
        sig = _signal(p, where, t, grid)
        try:
            sources.append(
                disc_transducer_3d(
                    grid, centre, axis, diameter_m=diameter, rings=rings, signal=sig, injection=injection
                )
            )
        except (ValueError, TypeError) as err:
            _fail(p, where, str(err))

    return sources


def _sensors_3d(self: Scene, grid, sources: list) -> tuple:
    """(sensors, receivers, number of recorded columns, snapshot planes) of a 3-D scene: the
    probes, then each receiving transducer's cells (its A-scan)."""
    from ..solver.sensors import Sensors, probe_cells

    p = self.path
    s = self.sensors
    columns = [probe_cells(grid, _points(p, "sensors.probes_m", s.probes_m, 3))] if s.probes_m else []
    n_cols = sum(len(c) for c in columns)
    receivers = []
    for i, (t, src) in enumerate(zip(self.transducers, sources)):
        if not isinstance(t, DiscTransducer) or not t.receive:
            if isinstance(t, DiscTransducer) and t.gate_start_s is not None:
                _fail(p, f"transducers[{i}].gate_start_s", "needs receive = true (the A-scan it gates)")
            continue
        cells = np.asarray(src.cells_array)
        gate = 0 if t.gate_start_s is None else int(round(grid.s_to_steps(t.gate_start_s)))
        receivers.append(Receiver(t.name, i, n_cols, n_cols + len(cells), gate))
        columns.append(cells)
        n_cols += len(cells)
    planes = _slice_planes(self, grid, sources)
    try:
        sensors = Sensors(
            probes=np.concatenate(columns) if columns else _NO_CELLS,
            p_max=s.p_max,
            p_rms=s.p_rms,
            arrival_threshold_pa=s.arrival_threshold_pa,
            snapshot_every=s.snapshot_every_steps,
            snapshot_slices=planes,
        )
        sensors.check_inside(grid)
    except ValueError as err:
        _fail(p, "sensors", str(err))

    return sensors, receivers, n_cols, planes
