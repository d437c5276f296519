"""Scene files (TOML): a documented, validated description of a whole simulation.

`load_scene(path)` reads and validates a file into a `Scene` (plain data, SI units);
`Scene.build()` turns it into the simulator's objects (grid, medium, sources, sensors, edges).
Every key, its unit, default and allowed values are declared once in `scene/schema.py` (typed
sections of `difflattice.config`; docs/scene-files.md is generated from them); an unknown key, a
wrong type or a value out of range raises `SceneError` naming the file, the key and what is
allowed.
"""

from __future__ import annotations

import math
import tomllib
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, NoReturn

import numpy as np

if TYPE_CHECKING:
    from ..lattice.coefficients import Edges
    from ..lattice.geometry3d import Shape3D
    from ..lattice.grid import Grid, StencilKind
    from ..lattice.kinds import LatticeKind
    from ..lattice.medium import Material, Medium
    from ..observe.farfield import BoxContour
    from ..observe.farfield_rz import CylinderSurface
    from ..solver.sensors import Sensors
    from ..solver.sources import PointSources, Signal

from .schema import ARRAY_SECTIONS, SCHEMA, ConfigError, fail, validate_section
from .schema import schema_markdown as _schema_markdown


class SceneError(ConfigError):
    """A scene file that cannot be used: the message names the file, the key and the fix."""


# Every key, its type, default, unit and allowed values: declared once in scene/schema.py
# (SECTIONS); SCHEMA is a plain view of those declarations.
ANIMATION_KINDS = ("gif", "mp4", "none")

PAPER_RENDER_EVERY = 3
"""The paper rendered every third cell of its 20-cells-per-wavelength grid (6.7 pixels per
wavelength)."""
MIN_PIXELS_PER_WAVELENGTH = 20 / PAPER_RENDER_EVERY


def render_stride(cells_per_wavelength: float, override: int | None = None) -> int:
    """Render every n-th cell: the paper's 3 at 20 cells per wavelength, never fewer than
    `MIN_PIXELS_PER_WAVELENGTH` (6.7) rendered pixels per wavelength (so every cell below
    13.3 cells per wavelength, where a fixed stride of 3 would alias the wave). `override`
    (cells, >= 1) replaces the automatic choice."""
    if override is not None:
        if isinstance(override, bool) or not isinstance(override, (int, np.integer)) or override < 1:
            raise ValueError(f"render stride = {override!r}: give a whole number of cells >= 1")
        return int(override)
    if not cells_per_wavelength > 0:
        raise ValueError(f"cells_per_wavelength = {cells_per_wavelength} must be > 0")
    return max(1, int(cells_per_wavelength / MIN_PIXELS_PER_WAVELENGTH + 1e-9))


def _fail(path, key, msg) -> NoReturn:
    fail(path, key, msg, SceneError)


def _validate_table(path, section: str, table: dict, where: str) -> dict:
    return validate_section(path, section, table, where, SceneError)


class SceneTooLargeError(SceneError):
    """A scene (any lattice kind) whose run would not fit in the available memory; the message
    gives the estimate (`solver.estimate`) and the fix. Raised before any grid-sized array is
    built."""


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
    - `contour`: the far-field contour (None when the scene has no `[farfield]`; always on 3d);
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
    contour: BoxContour | CylinderSurface | None
    farfield_source: int
    show_steps: list[int]
    render_every: int
    receivers: tuple[Receiver, ...] = ()
    estimate_bytes: int | None = None


_SIDES_2D = ("x_lo", "x_hi", "y_lo", "y_hi")
_NO_CELLS = np.zeros((0, 2), np.int32)
_SIDES_3D = _SIDES_2D + ("z_lo", "z_hi")
_TRANSDUCER_KEYS_3D = ("axis", "ring_edges_m", "fit_report", "gate_start_s")
_OBJECT_KEYS_3D = ("size_m", "angles_deg", "axis", "length_m", "point_m", "normal", "parts")


@dataclass
class Scene:
    """A validated scene (SI units). Sections mirror the file; see `SCHEMA`."""

    path: str
    grid: dict
    medium: dict
    edges: dict
    transducers: list[dict]
    objects: list[dict]
    sensors: dict
    farfield: dict | None
    run: dict
    output: dict = field(default_factory=dict)
    raw: dict = field(default_factory=dict)
    air: dict | None = None  # the optional [air] section (None: dry air at [medium] temperature_c, lossless)

    def air_conditions(self):
        """The scene's `AirConditions` when `[air]` asks for absorption, else None."""
        if self.air is None or not self.air["absorption"]:
            return None
        from ..lattice.medium import AirConditions

        a = self.air
        return AirConditions(a["temperature_c"], a["humidity_pct"], a["pressure_pa"])

    def describe_air(self) -> str:
        """One line naming the air the scene simulates (printed by `difflattice simulate`)."""
        from .. import air as air_model

        f = self.grid["frequency_hz"]
        if self.air is None:
            if self.medium["background"] != "air":
                return f"background: {self.medium['background']} (no air)"
            line = air_model.describe(self.medium["temperature_c"], 0.0)
            return line + ", lossless (no [air] section: dry air, no absorption)"
        a = self.air
        line = air_model.describe(a["temperature_c"], a["humidity_pct"], a["pressure_pa"], f)
        return line + ("" if a["absorption"] else " -- not simulated ([air] absorption = false)")

    # ---------------------------------------------------------------------------------------
    @property
    def kind(self) -> LatticeKind:
        """The scene's lattice kind (`[grid] kind`)."""
        from ..lattice.kinds import as_kind

        return as_kind(self.grid["kind"])

    def build(self, *, available_bytes: int | None = None) -> BuiltScene:
        """Build the solver's objects (`BuiltScene`) for `simulate`. Every scene is first
        estimated (`solver.estimate`) and refused (`SceneTooLargeError`) when its run would not
        fit in `available_bytes` (default: the memory available on this machine), before any
        grid-sized array exists. Each lattice kind imports only its own pieces (a 2-D scene builds
        nothing 3-D, and vice versa)."""
        if self.kind.ndim == 3:
            return self._build_3d(available_bytes)
        return self._build_plane(available_bytes)

    def _check_fits(self, grid: Grid, n_steps: int, available_bytes: int | None, **features) -> int:
        """Refuse (`SceneTooLargeError`, naming the estimate and the fix) a run whose memory
        estimate does not fit; `features` are `solver.estimate.RunFeatures` fields. Returns the
        estimate in bytes."""
        from ..solver.estimate import RunFeatures, RunTooLargeError, check_fits, memory_breakdown

        shape = tuple(grid.shape)
        nbytes = sum(memory_breakdown(shape, n_steps, grid.dtype, RunFeatures(**features)).values())
        try:
            check_fits(shape, n_steps, nbytes, available=available_bytes)
        except RunTooLargeError as err:
            raise SceneTooLargeError(f"{self.path}: [grid] {' '.join(str(err).split())}") from None
        return nbytes

    def _build_plane(self, available_bytes: int | None = None) -> BuiltScene:
        """The 2-D and r-z lattices."""
        from ..lattice import geometry as geo
        from ..lattice.coefficients import Edges
        from ..observe.farfield import box_around
        from ..observe.farfield_rz import cylinder_around
        from ..solver.sensors import Sensors, probe_cells
        from ..solver.sources import disc_housing, disc_transducer, line_transducer

        p = self.path
        med = self.medium
        bg, mats = _materials(self)
        grid = _make_grid(self, mats)
        ed, s = self.edges, self.sensors
        self._check_fits(  # before the objects' and media's grid-sized arrays
            grid,
            _n_steps(self, grid),
            available_bytes,
            pml="pml" in {ed[k] for k in ("kind", *_SIDES_2D, "z_lo", "z_hi", "r_hi")},
            heterogeneous=bool(self.objects),
            n_probes=len(s["probes_m"] or ()),
            field_stats=int(s["p_max"]) + int(s["p_rms"]) + int(s["arrival_threshold_pa"] is not None),
        )
        rz = grid.kind.ring_metric
        for i, t in enumerate(self.transducers):
            for k in _TRANSDUCER_KEYS_3D:
                if t[k] is not None:
                    _fail(p, f"transducers[{i}].{k}", f'is for 3d grids ([grid] kind = "3d"), not {grid.kind}')
            if t["receive"]:
                _fail(p, f"transducers[{i}].receive", f"is implemented for 3d grids, not {grid.kind}")
        if self.sensors["snapshot_slices_m"] is not None:
            _fail(p, "sensors.snapshot_slices_m", f"is for 3d grids (a {grid.kind} snapshot is the whole field)")

        occupancies = []
        for i, o in enumerate(self.objects):
            shape = _shape(p, f"objects[{i}]", o, geo, grid.kind.ring_metric)
            try:
                occupancies.append(np.asarray(geo.rasterise(shape, grid, med["rasterise"])))
            except ValueError as e:
                _fail(p, "medium.rasterise", str(e))
        housings = []
        for i, t in enumerate(self.transducers):
            if t["type"] == "disc" and rz and t["baffle"] != "rigid" and t["diameter_m"] is not None:
                try:
                    housings.append(
                        np.asarray(
                            disc_housing(
                                grid,
                                radius_m=t["diameter_m"] / 2,
                                z_m=t["centre_m"][0],
                                baffle=t["baffle"],
                                depth_m=t["can_depth_m"],
                                wall_m=t["can_wall_m"],
                            )
                        )
                    )
                except ValueError as err:
                    _fail(p, f"transducers[{i}]", str(err))
        medium = _medium(self, grid, bg, mats, occupancies, housings, lambda occs: geo.union_occupancy(occs))

        try:
            if rz:
                for side in _SIDES_2D:
                    if ed[side] is not None:
                        _fail(
                            p,
                            f"edges.{side}",
                            "on an rz grid name the sides z_lo, z_hi and r_hi (the axis needs no edge)",
                        )
                edges = Edges.axisymmetric(
                    **{s: (ed[s] or ed["kind"]) for s in ("z_lo", "z_hi", "r_hi")},
                    thickness_cells=ed["thickness_cells"],
                )
            else:
                for side in ("z_lo", "z_hi", "r_hi"):
                    if ed[side] is not None:
                        _fail(
                            p,
                            f"edges.{side}",
                            'is for rz and 3d grids ([grid] kind = "rz" or "3d"); a 2d grid has x_lo, x_hi, y_lo, y_hi',
                        )
                edges = Edges(
                    **{s: (ed[s] or ed["kind"]) for s in _SIDES_2D},
                    thickness_cells=ed["thickness_cells"],
                )
            edges.check_kind(grid.kind)
        except ValueError as err:
            _fail(p, "edges", str(err))

        sources = []
        if not self.transducers:
            _fail(p, "transducers", "a scene needs at least one [[transducers]] entry")
        for i, t in enumerate(self.transducers):
            where = f"transducers[{i}]"
            sig = _signal(p, where, t, grid)
            try:
                if (t["type"] == "disc") != rz:
                    _fail(
                        p,
                        f"{where}.type",
                        f"= {t['type']!r} does not fit a {grid.kind} grid: use type = "
                        f"{'disc' if rz else 'line'} (or [grid] kind = {'2d' if rz else 'rz'})",
                    )
                if rz:
                    if t["baffle"] == "rigid" and edges.x_lo != "rigid":
                        _fail(
                            p,
                            f"{where}.baffle",
                            f"= 'rigid' needs the rigid baffle plane: set [edges] z_lo = "
                            f'"rigid" (now {edges.x_lo!r}), or baffle = "none" / "can" for an unbaffled disc',
                        )
                    if t["diameter_m"] is None:
                        _fail(p, f"{where}.diameter_m", "is required for a disc (its diameter, m)")
                    if len(t["centre_m"]) != 2 or t["centre_m"][1] != 0:
                        _fail(
                            p, f"{where}.centre_m", f"= {list(t['centre_m'])}: a disc sits on the axis, give [z_m, 0]"
                        )
                    sources.append(
                        disc_transducer(
                            grid,
                            radius_m=t["diameter_m"] / 2,
                            z_m=t["centre_m"][0],
                            signal=sig,
                            weights=t["weights"],
                            lags_s=t["lags_s"],
                            baffle=t["baffle"],
                        )
                    )
                else:
                    if len(t["centre_m"]) != 2:
                        _fail(p, f"{where}.centre_m", f"= {list(t['centre_m'])}: give [x_m, y_m] on a 2d grid")
                    sources.append(
                        line_transducer(
                            grid,
                            (t["centre_m"][0], t["centre_m"][1]),
                            n_cells=t["n_cells"],
                            diameter_m=t["diameter_m"],
                            direction_deg=t["direction_deg"],
                            signal=sig,
                            weights=t["weights"],
                            lags_s=t["lags_s"],
                            injection=t["injection"],
                        )
                    )
            except (ValueError, TypeError) as err:
                _fail(p, where, str(err))

        probes = probe_cells(grid, _points(p, "sensors.probes_m", s["probes_m"], 2)) if s["probes_m"] else None
        contour: BoxContour | CylinderSurface | None = None
        phasor_cells = None
        ff_index = 0
        if self.farfield is not None:
            ff = self.farfield
            names = [t["name"] for t in self.transducers]
            if ff["transducer"] is not None:
                if ff["transducer"] not in names:
                    _fail(p, "farfield.transducer", f"= {ff['transducer']!r}; known: {', '.join(names)}")
                ff_index = names.index(ff["transducer"])
            # the surface encloses the transducer and every object (a surface through an object
            # would integrate a field that is not free space: a wrong lobe), or the scene is refused
            solids = [np.argwhere(np.asarray(o) > 0) for o in (*occupancies, *housings)]
            enclosed = np.concatenate([np.asarray(sources[ff_index].cells_array).reshape(-1, 2), *solids])
            if rz:
                baffled = self.transducers[ff_index]["baffle"] == "rigid"
                cyl = cylinder_around(enclosed, ff["gap_cells"], baffled=baffled)
                contour, phasor_cells = cyl, cyl.cells
                check = cyl.check_inside
            else:
                box = box_around(enclosed, ff["gap_cells"])
                contour, phasor_cells = box, box.cells
                check = box.check_inside
            L = edges.thickness_cells if edges.kinds() & {"pml", "sponge"} else 0
            try:
                check(grid, margin=L)
            except ValueError as err:
                why = (
                    f"the far-field surface encloses the transducer and the {len(solids)} object(s) "
                    f"{ff['gap_cells']} cells out (so that it crosses no object), and then: {err}. Fix: a larger "
                    "window ([grid] size_m or shape), a smaller gap_cells, or no [farfield] (record probes)"
                    if solids
                    else str(err)
                )
                _fail(p, "farfield.gap_cells", why)
        try:
            sensors = Sensors(
                probes=probes if probes is not None else _NO_CELLS,
                phasor_cells=phasor_cells if phasor_cells is not None else _NO_CELLS,
                p_max=s["p_max"],
                p_rms=s["p_rms"],
                arrival_threshold_pa=s["arrival_threshold_pa"],
                snapshot_every=s["snapshot_every_steps"],
            )
            sensors.check_inside(grid)
        except ValueError as err:
            _fail(p, "sensors", str(err))

        n_steps = _n_steps(self, grid)
        return BuiltScene(
            grid,
            medium,
            tuple(sources),
            sensors,
            edges,
            n_steps,
            contour,
            ff_index,
            self.show_steps(grid, n_steps),
            self.render_every(grid),
        )

    # ---------------------------------------------------------------------------------------
    def _build_3d(self, available_bytes: int | None) -> BuiltScene:
        """The 3-D lattice: grid, edges, sources and sensors first, then the memory estimate
        (refused before any grid-sized array exists), then the medium maps."""
        from ..lattice import geometry3d as g3
        from ..lattice.coefficients import Edges
        from ..solver.sensors import Sensors, probe_cells
        from ..solver.sources import disc_transducer_3d

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
        if o["show_steps"] or o["show_times_s"]:
            _fail(
                p,
                "output.show_steps",
                "field moments are for 2d and rz scenes; on a 3d grid use [sensors] snapshot_every_steps "
                "(slices every that many steps)",
            )

        ed = self.edges
        if ed["r_hi"] is not None:
            _fail(p, "edges.r_hi", "is for rz grids; a 3d grid has x_lo, x_hi, y_lo, y_hi, z_lo, z_hi")
        try:
            edges = Edges(
                **{s: (ed[s] or ed["kind"]) for s in _SIDES_3D}, thickness_cells=ed["thickness_cells"]
            ).for_rank(3)
            edges.check_kind(grid.kind)
        except ValueError as err:
            _fail(p, "edges", str(err))
        n_steps = _n_steps(self, grid)

        # sources (small: the disc's cells) and sensors before anything grid-sized
        if not self.transducers:
            _fail(p, "transducers", "a scene needs at least one [[transducers]] entry")
        sources = []
        for i, t in enumerate(self.transducers):
            where = f"transducers[{i}]"
            if t["type"] != "disc":
                _fail(p, f"{where}.type", f'= {t["type"]!r} is a 2d transducer: a 3d grid takes type = "disc"')
            raw = _raw_item(self.raw, "transducers", i)
            if "baffle" in raw and t["baffle"] != "none":
                _fail(
                    p,
                    f"{where}.baffle",
                    f"= {t['baffle']!r}: a 3d disc is a bare source; give a baffle as an object (e.g. a box "
                    'behind the face) and baffle = "none"',
                )
            if t["injection"] not in ("soft", "hard"):
                _fail(p, f"{where}.injection", f"= {t['injection']!r}; allowed: soft, hard")
            centre = _vector(p, f"{where}.centre_m", t["centre_m"])
            axis = _vector(p, f"{where}.axis", t["axis"] if t["axis"] is not None else [1.0, 0.0, 0.0])
            rings, diameter = _rings_3d(self, where, t)
            sig = _signal(p, where, t, grid)
            try:
                sources.append(
                    disc_transducer_3d(
                        grid, centre, axis, diameter_m=diameter, rings=rings, signal=sig, injection=t["injection"]
                    )
                )
            except (ValueError, TypeError) as err:
                _fail(p, where, str(err))

        s = self.sensors
        columns = [probe_cells(grid, _points(p, "sensors.probes_m", s["probes_m"], 3))] if s["probes_m"] else []
        n_cols = sum(len(c) for c in columns)
        receivers = []
        for i, (t, src) in enumerate(zip(self.transducers, sources)):
            if not t["receive"]:
                if t["gate_start_s"] is not None:
                    _fail(p, f"transducers[{i}].gate_start_s", "needs receive = true (the A-scan it gates)")
                continue
            cells = np.asarray(src.cells_array)
            gate = 0 if t["gate_start_s"] is None else int(round(grid.s_to_steps(t["gate_start_s"])))
            receivers.append(Receiver(t["name"], i, n_cols, n_cols + len(cells), gate))
            columns.append(cells)
            n_cols += len(cells)
        planes = _slice_planes(self, grid, sources)
        try:
            sensors = Sensors(
                probes=np.concatenate(columns) if columns else _NO_CELLS,
                p_max=s["p_max"],
                p_rms=s["p_rms"],
                arrival_threshold_pa=s["arrival_threshold_pa"],
                snapshot_every=s["snapshot_every_steps"],
                snapshot_slices=planes,
            )
            sensors.check_inside(grid)
        except ValueError as err:
            _fail(p, "sensors", str(err))

        # the estimate, before the medium maps (the largest arrays a build makes) exist
        shape = tuple(grid.shape)
        n_snap = 0 if s["snapshot_every_steps"] is None else -(-n_steps // min(s["snapshot_every_steps"], n_steps))
        nbytes = self._check_fits(
            grid,
            n_steps,
            available_bytes,
            pml=edges.uses_pml,
            heterogeneous=bool(self.objects),
            soft=any(m.kind == "soft" for m in mats[1:]) or med["boundary_model"] == "speed_zero",
            absorption=med["absorption_db_per_m"] > 0,
            air_absorption=self.air_conditions() is not None,
            n_probes=n_cols,
            snapshot_cells=sum(math.prod(shape) // shape[a] for a, _ in planes),
            n_snapshots=n_snap,
            field_stats=int(s["p_max"]) + int(s["p_rms"]) + int(s["arrival_threshold_pa"] is not None),
        )

        occupancies = []
        for i, ob in enumerate(self.objects):
            solid = shape3d(p, f"objects[{i}]", ob)
            try:
                occupancies.append(g3.rasterise3d(solid, grid, med["rasterise"]))
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

    # ---------------------------------------------------------------------------------------
    def show_steps(self, grid, n_steps: int) -> list[int]:
        """The steps of `[output] show_steps` and `show_times_s` (nearest step), sorted, unique;
        each must lie in 1..n_steps."""
        o = self.output
        steps = []
        for i, v in enumerate(o["show_steps"]):
            if isinstance(v, bool) or not isinstance(v, int):
                _fail(self.path, f"output.show_steps[{i}]", f"= {v!r} must be a whole number of steps")
            steps.append(v)
        for i, v in enumerate(o["show_times_s"]):
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                _fail(self.path, f"output.show_times_s[{i}]", f"= {v!r} must be a time in seconds")
            steps.append(int(round(grid.s_to_steps(float(v)))))
        for s in steps:
            if not 1 <= s <= n_steps:
                t_s = s * grid.dt_s
                _fail(
                    self.path,
                    "output",
                    f"moment at step {s} ({t_s * 1e6:.1f} µs) lies outside the run "
                    f"(steps 1..{n_steps}, up to {n_steps * grid.dt_s * 1e6:.1f} µs)",
                )
        return sorted(set(steps))

    def render_every(self, grid) -> int:
        """Render stride in cells: `[output] render_every_cells`, else `plots.render_stride`."""
        try:
            return render_stride(grid.cells_per_wavelength, self.output["render_every_cells"])
        except ValueError as e:
            _fail(self.path, "output.render_every_cells", str(e))


# ------------------------------------------------------------------------------------------
# pieces shared by the lattice kinds


def _materials(scene: Scene) -> tuple[Material, list[Material]]:
    """(background, [background, one material per object]); under speed_zero only the background
    (every object is a speed-zero region), warning about materials that are then ignored."""
    from ..lattice.medium import air, material

    p, med = scene.path, scene.medium
    if scene.air is not None:
        if med["background"] != "air":
            _fail(p, "air", f"describes the air, but [medium] background = {med['background']!r}: remove [air]")
        if "temperature_c" in scene.raw.get("medium", {}):
            _fail(p, "medium.temperature_c", "is given twice: [air] temperature_c sets it; remove this one")
        a = scene.air
        bg = air(a["temperature_c"], a["pressure_pa"], a["humidity_pct"])
    elif med["background"] == "air":
        bg = air(med["temperature_c"])
    else:
        bg = _material(p, "medium.background", med["background"], material)
    if bg.kind != "fluid":
        _fail(p, "medium.background", f"must be a fluid material, got {bg.name} ({bg.kind})")
    mats = [bg] + [_material(p, f"objects[{i}].material", o["material"], material) for i, o in enumerate(scene.objects)]
    if med["boundary_model"] == "speed_zero":
        for i, m in enumerate(mats[1:]):
            given = "material" in _raw_item(scene.raw, "objects", i)
            if m.kind == "fluid" or (given and m.kind == "rigid"):
                warnings.warn(
                    f"{p}: [objects[{i}].material] = {m.name!r} is ignored under "
                    f'boundary_model = "speed_zero": every object is a speed-zero '
                    f"(pressure-release, R = -1) region, its speed "
                    f"{'and density ' if m.kind == 'fluid' else ''}not used. Use "
                    f'material = "soft" to say so, or boundary_model = "conservative" to '
                    f"simulate {m.name!r}.",
                    UserWarning,
                    stacklevel=3,
                )
        mats = [bg]
    return bg, mats


def _make_grid(scene: Scene, mats: list[Material]) -> Grid:
    """The grid, its cell sized for the fastest simulated fluid; the courant default and limit of
    the lattice kind (refused above it naming `[grid.courant]`); warns for every under-resolved
    fluid."""
    from ..lattice.grid import make_grid
    from ..lattice.medium import warn_if_under_resolved

    p, g = scene.path, scene.grid
    kind = scene.kind
    ndim = kind.ndim
    if (g["size_m"] is None) == (g["shape"] is None):
        axes = ", ".join(kind.axis_names)
        _fail(p, "grid", f"give exactly one of size_m = [{axes}] (m) or shape = [{axes}] (cells)")
    for key in ("size_m", "shape"):
        if g[key] is not None and len(g[key]) != ndim:
            _fail(p, f"grid.{key}", f"= {list(g[key])}: a {kind} grid needs {ndim} entries")
        for i, v in enumerate(g[key] or ()):
            if not v > 0:
                _fail(p, f"grid.{key}", f"= {list(g[key])}: entry {i} ({kind.axis_names[i]}) must be > 0")
    if g["size_m"] is not None:  # each size must span cells at this resolution (make_grid would clamp it)
        dx = None
        try:
            fastest_c = max(m.speed_m_s for m in mats if m.kind == "fluid")
            dx = fastest_c / (g["frequency_hz"] * g["cells_per_wavelength"])
        except ValueError:
            pass
        if dx is not None:
            small = [s for s in g["size_m"] if round(s / dx) < 3]
            if small:
                _fail(
                    p,
                    "grid.size_m",
                    f"= {list(g['size_m'])} m: {small[0]:g} m is fewer than 3 cells of {dx * 1e3:.3g} mm at this "
                    "resolution; give each size in metres, at least a few wavelengths plus the edge layers",
                )
    default = kind.default_courant
    courant = default if g["courant"] is None else float(g["courant"])
    air_cond = scene.air_conditions()
    # rz scenes in air (no objects, no housing, one fluid) default to the isotropic stencil: the
    # near field in place, on the native kernels; with obstacles the standard one (the native
    # kernels run the isotropic stencil on uniform faces only)
    in_air = not scene.objects and all(
        t.get("type") != "disc" or t.get("baffle", "rigid") == "rigid" for t in scene.transducers
    )
    stencil: StencilKind = g["stencil"] or ("isotropic" if kind.ring_metric and in_air else "standard")
    try:
        kind.check_stencil(stencil)
    except ValueError as err:
        _fail(p, "grid.stencil", str(err))
    limit = kind.stability_limit(stencil)
    if air_cond is not None:  # absorption stiffens the step: its own, lower limit (docs/air.md)
        from ..lattice.coefficients import absorbing_courant

        fast = max(m.speed_m_s for m in mats if m.kind == "fluid")
        c_air = absorbing_courant(g["frequency_hz"], g["cells_per_wavelength"], fast, air_cond, kind, stencil)
        if g["courant"] is None:
            courant = min(courant, c_air)
        elif courant > c_air / 0.9999:
            _fail(
                p,
                "grid.courant",
                f"= {courant:g} cells/step exceeds the limit with air absorption, {c_air / 0.9999:.5f} (the "
                f"relaxation and viscous terms stiffen the step): leave courant out (then {c_air:.5f}) or set "
                "it lower, or [air] absorption = false",
            )
    if courant > limit:
        _fail(
            p,
            "grid.courant",
            f"= {courant:g} cells/step exceeds the {kind.label} stability limit {kind.limit_formula(stencil)} = "
            f"{limit:.4f} (the leapfrog would grow without bound): set courant = {default} (the default) or less",
        )
    fluids = [m for m in mats if m.kind == "fluid"]
    fastest = max(fluids, key=lambda m: m.speed_m_s)
    try:
        grid = make_grid(
            frequency_hz=g["frequency_hz"],
            cells_per_wavelength=g["cells_per_wavelength"],
            c_max_m_s=fastest.speed_m_s,
            shape=tuple(g["shape"]) if g["shape"] else None,
            size_m=tuple(g["size_m"]) if g["size_m"] else None,
            courant=courant,
            dtype=g["dtype"],
            kind=kind,
            stencil=stencil,
        )
    except ValueError as e:
        _fail(p, "grid", str(e))
    # every simulated fluid must be resolved: the cell is sized for the fastest one
    seen = set()
    for m in fluids:
        if m.name not in seen:
            seen.add(m.name)
            warn_if_under_resolved(m.name, m.speed_m_s, grid.frequency_hz, grid.dx_m, fastest=fastest.name)
    return grid


def _medium(scene: Scene, grid: Grid, bg: Material, mats: list[Material], occupancies, extra_rigid, union) -> Medium:
    """The `Medium`: each object's occupancy goes to the rigid or soft map or, for a fluid
    material, into the speed and density maps; `union` combines several occupancies."""
    import jax.numpy as jnp

    from ..lattice.medium import Medium

    p, med = scene.path, scene.medium
    speed_zero = med["boundary_model"] == "speed_zero"
    rigid, soft = list(extra_rigid), []
    speed = np.full(grid.shape, bg.speed_m_s)
    rho = np.full(grid.shape, bg.density_kg_m3)
    fluid_objects = False
    for i, occ in enumerate(occupancies):
        m = None if speed_zero else mats[1 + i]
        if m is None or m.kind == "soft":
            soft.append(occ)
        elif m.kind == "rigid":
            rigid.append(occ)
        else:
            fluid_objects = True
            o = np.asarray(occ)
            speed = speed * (1 - o) + m.speed_m_s * o
            rho = rho * (1 - o) + m.density_kg_m3 * o
    dt = grid.jnp_dtype

    def combined(occs):
        return None if not occs else jnp.asarray(union(occs), dt)

    try:
        return Medium(
            sound_speed_m_s=jnp.asarray(speed, dt) if fluid_objects else bg.speed_m_s,
            density_kg_m3=jnp.asarray(rho, dt) if fluid_objects else bg.density_kg_m3,
            rigid=combined(rigid),
            soft=combined(soft),
            boundary_model=med["boundary_model"],
            absorption_db_per_m=float(med["absorption_db_per_m"]),
            air=scene.air_conditions(),
        )
    except ValueError as e:
        _fail(p, "medium", str(e))


def _union3d(occs):
    """Union of 3-D occupancies: one is kept as it is (bitwise), several combine as
    1 - prod(1 - o) (the 2-D `union_occupancy`, without its no-op for a single one)."""
    if len(occs) == 1:
        return occs[0]
    free = 1 - occs[0]
    for o in occs[1:]:
        free = free * (1 - o)
    return 1 - free


def _signal(path, where: str, t: dict, grid: Grid) -> Signal:
    from ..solver.sources import ContinuousWave, ToneBurst

    f = t["frequency_hz"] or grid.frequency_hz
    try:
        if t["signal"] == "burst":
            return ToneBurst(f, t["cycles"], t["window"], t["amplitude_pa"])
        return ContinuousWave(f, t["ramp_cycles"], t["amplitude_pa"])
    except (ValueError, TypeError) as err:
        _fail(path, where, str(err))


def _n_steps(scene: Scene, grid: Grid) -> int:
    p, r = scene.path, scene.run
    if (r["n_steps"] is None) == (r["duration_s"] is None):
        _fail(p, "run", "give exactly one of n_steps or duration_s (s)")
    n_steps = r["n_steps"] if r["n_steps"] is not None else int(math.ceil(grid.s_to_steps(r["duration_s"])))
    if n_steps < 1:
        _fail(p, "run", f"n_steps = {n_steps} must be >= 1")
    return n_steps


def _raw_item(raw: dict, section: str, i: int) -> dict:
    items = raw.get(section) or []
    item = items[i] if i < len(items) else {}
    return item if isinstance(item, dict) else {}


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


# ------------------------------------------------------------------------------------------
# 2-D shapes


def _mesh_shape(path, where, o: dict, geo, axisymmetric: bool):
    """A mesh file's section (`scene.meshes`) as a union of polygons (holes cut out)."""
    from .meshes import mesh_outlines

    f = Path(o["file"])
    f = f if f.is_absolute() else Path(str(path)).parent / f
    try:
        polys = mesh_outlines(f, axisymmetric=axisymmetric, unit=o["unit"])
    except ValueError as err:
        _fail(path, f"{where}.file", str(err))
    shapes = []
    for outer, holes in polys:
        s = geo.Polygon(outer)
        for h in holes:
            s = geo.Difference(s, geo.Polygon(h))
        shapes.append(s)
    return shapes[0] if len(shapes) == 1 else geo.Union(tuple(shapes))


def _shape(path, where, o: dict, geo, axisymmetric: bool = False):
    kind = o["shape"]
    need = {
        "segment": ("a_m", "b_m", "thickness_m"),
        "box": ("lo_m", "hi_m"),
        "circle": ("centre_m", "radius_m"),
        "polygon": ("vertices_m",),
        "polyline": ("points_m", "thickness_m"),
        "mesh": ("file",),
    }
    if kind not in need:
        extra = ' (3-D shapes need [grid] kind = "3d")' if kind in _SHAPES_3D else ""
        _fail(path, f"{where}.shape", f"= {kind!r}; allowed: {', '.join(need)}{extra}")
    for k in _OBJECT_KEYS_3D:
        if o.get(k) is not None:
            _fail(path, f"{where}.{k}", 'is for 3d objects ([grid] kind = "3d")')
    for k in need[kind]:
        if o.get(k) is None:
            _fail(path, f"{where}.{k}", f"is required for shape = {kind!r}")

    def a(k):
        return np.asarray(o[k], dtype=float)

    try:
        s = {
            "segment": lambda: geo.Segment(a("a_m"), a("b_m"), a("thickness_m")),
            "box": lambda: geo.Box(a("lo_m"), a("hi_m")),
            "circle": lambda: geo.Circle(a("centre_m"), a("radius_m")),
            "polygon": lambda: geo.Polygon(a("vertices_m")),
            "polyline": lambda: geo.Polyline(a("points_m"), a("thickness_m")),
            "mesh": lambda: _mesh_shape(path, where, o, geo, axisymmetric),
        }[kind]()
    except SceneError:
        raise
    except Exception as e:  # malformed coordinates
        _fail(path, where, f"bad {kind} parameters: {e}")
    if o.get("cut"):
        cut = _validate_table(path, "objects", o["cut"], f"{where}.cut")
        s = geo.Difference(s, _shape(path, f"{where}.cut", cut, geo, axisymmetric))
    return s


# ------------------------------------------------------------------------------------------
# 3-D shapes, discs and slices

_SHAPES_3D = {
    "box": (),
    "sphere": ("centre_m", "radius_m"),
    "cylinder": ("centre_m", "axis", "radius_m", "length_m"),
    "halfspace": ("point_m", "normal"),
    "slab": ("point_m", "normal", "thickness_m"),
    "union": ("parts",),
    "intersection": ("parts",),
}
_VECTORS_3D = ("centre_m", "size_m", "angles_deg", "axis", "point_m", "normal", "lo_m", "hi_m")


def shape3d(path, where: str, o: dict):
    """The `lattice.geometry3d` solid of a validated `[[objects]]` table on a 3-D grid (box by
    lo_m/hi_m or centre_m/size_m/angles_deg, sphere, cylinder, halfspace, slab, union and
    intersection of `parts`, each with an optional `cut`); parameters as float arrays."""
    import jax.numpy as jnp

    from ..lattice import geometry3d as g3

    kind = o["shape"]
    if kind not in _SHAPES_3D:
        _fail(path, f"{where}.shape", f"= {kind!r}; allowed on a 3d grid: {', '.join(_SHAPES_3D)}")
    need = _SHAPES_3D[kind]
    if kind == "box":
        need = ("lo_m", "hi_m") if o.get("centre_m") is None and o.get("size_m") is None else ("centre_m", "size_m")
    for k in need:
        if o.get(k) is None:
            extra = " (or centre_m and size_m)" if k in ("lo_m", "hi_m") else ""
            _fail(path, f"{where}.{k}", f"is required for shape = {kind!r}{extra}")
    for k in _VECTORS_3D:
        if o.get(k) is not None:
            _vector(path, f"{where}.{k}", o[k])
    for k in ("a_m", "b_m", "vertices_m", "points_m"):
        if o.get(k) is not None:
            _fail(path, f"{where}.{k}", "is for 2d objects; see the 3d shapes' keys in docs/scene-files.md")

    def a(k):
        return jnp.asarray(o[k], dtype=float)

    s: Shape3D
    if kind == "box":
        if "lo_m" in need:
            lo, hi = np.asarray(o["lo_m"], float), np.asarray(o["hi_m"], float)
            if np.any(hi <= lo):
                _fail(path, f"{where}.hi_m", f"= {list(o['hi_m'])} must exceed lo_m = {list(o['lo_m'])} on every axis")
            s = g3.OrientedBox(jnp.asarray(0.5 * (lo + hi)), jnp.asarray(hi - lo))
        else:
            angles = o["angles_deg"] if o.get("angles_deg") is not None else [0.0, 0.0, 0.0]
            s = g3.OrientedBox(a("centre_m"), a("size_m"), jnp.asarray(angles, dtype=float))
    elif kind == "sphere":
        s = g3.Sphere(a("centre_m"), a("radius_m"))
    elif kind == "cylinder":
        s = g3.Cylinder(a("centre_m"), a("axis"), a("radius_m"), a("length_m"))
    elif kind == "halfspace":
        s = g3.HalfSpace(a("point_m"), a("normal"))
    elif kind == "slab":
        s = g3.Slab(a("point_m"), a("normal"), a("thickness_m"))
    else:
        parts = o["parts"]
        if not isinstance(parts, (list, tuple)) or not parts:
            _fail(path, f"{where}.parts", 'give a list of inline tables, e.g. [{ shape = "halfspace", ... }, ...]')
        solids = []
        for j, part in enumerate(parts):
            w = f"{where}.parts[{j}]"
            if not isinstance(part, dict):
                _fail(path, w, f"= {part!r} must be an inline table {{ shape = ..., ... }}")
            solids.append(shape3d(path, w, _validate_table(path, "objects", part, w)))
        s = g3.Union3D(tuple(solids)) if kind == "union" else g3.Intersection3D(tuple(solids))
    if o.get("cut"):
        w = f"{where}.cut"
        s = g3.Difference3D(s, shape3d(path, w, _validate_table(path, "objects", o["cut"], w)))
    return s


def _rings_3d(scene: Scene, where: str, t: dict) -> tuple[dict | None, float | None]:
    """(rings dict for `disc_transducer_3d` or None, diameter in m or None) of a 3-D disc: from
    `fit_report` (`rings_from_fit_report`), or `ring_edges_m` with per-ring weights and lags."""
    from ..solver.sources import rings_from_fit_report

    p = scene.path
    diameter = t["diameter_m"]
    if t["fit_report"] is not None:
        if t["ring_edges_m"] is not None or t["weights"] is not None or t["lags_s"] is not None:
            _fail(p, f"{where}.fit_report", "gives the rings: leave out ring_edges_m, weights and lags_s")
        report = Path(p).parent / t["fit_report"]
        try:
            rings = rings_from_fit_report(report)
        except OSError as e:
            _fail(p, f"{where}.fit_report", f"= {t['fit_report']!r}: cannot read {report} ({e.strerror})")
        except (ValueError, KeyError) as e:
            _fail(p, f"{where}.fit_report", f"= {t['fit_report']!r}: {e}")
        d = rings.pop("diameter_m", None)
        return rings, diameter if diameter is not None else d
    if t["ring_edges_m"] is not None:
        if t["weights"] is None:
            _fail(p, f"{where}.weights", "is required with ring_edges_m (one weight per ring)")
        edges = t["ring_edges_m"]
        if not all(isinstance(e, (list, tuple)) and len(e) == 2 for e in edges):
            _fail(p, f"{where}.ring_edges_m", "give [[inner, outer], ...] radii in metres, one pair per ring")
        rings = {"ring_edges_m": [list(e) for e in edges], "weights": list(t["weights"])}
        if t["lags_s"] is not None:
            rings["lags_s"] = list(t["lags_s"])
        return rings, diameter
    if t["weights"] is not None or t["lags_s"] is not None:
        _fail(
            p,
            f"{where}.weights",
            "a 3d disc's weights and lags_s are per ring: give ring_edges_m = [[r0, r1], ...] with them",
        )
    if diameter is None:
        _fail(p, f"{where}.diameter_m", "is required for a disc (its diameter, m), or give ring_edges_m or fit_report")
    return None, diameter


def _slice_planes(scene: Scene, grid: Grid, sources) -> tuple[tuple[int, int], ...]:
    """The (axis, index) planes of `[sensors] snapshot_slices_m`, default the three planes
    through the first transducer's centre (the cell nearest its mean cell)."""
    sl = scene.sensors["snapshot_slices_m"]
    if sl is None:
        c = np.rint(np.asarray(sources[0].cells_array, float).mean(axis=0)).astype(int)
        return tuple((a, int(c[a])) for a in range(3))
    planes = []
    for j, item in enumerate(sl):
        key = f"sensors.snapshot_slices_m[{j}]"
        if not (isinstance(item, (list, tuple)) and len(item) == 2 and item[0] in ("x", "y", "z")):
            _fail(scene.path, key, f'= {item!r}: give ["x", position_m] (axis x, y or z and a position in metres)')
        if isinstance(item[1], bool) or not isinstance(item[1], (int, float)):
            _fail(scene.path, key, f"= {item!r}: the position must be a number of metres")
        a = "xyz".index(item[0])
        i = int(round(float(item[1]) / grid.dx_m))
        if not 0 <= i < grid.shape[a]:
            _fail(scene.path, key, f"= {item!r} lies outside the grid (0 .. {grid.size_m[a]:.4g} m along {item[0]})")
        planes.append((a, i))
    if not planes:
        _fail(scene.path, "sensors.snapshot_slices_m", "is empty: give at least one plane, or leave it out")
    return tuple(planes)


def parse_scene(data: dict, path: str = "<scene>") -> Scene:
    """Validate a scene given as a dict (e.g. parsed TOML)."""
    allowed = set(SCHEMA)
    for key in data:
        if key not in allowed:
            _fail(path, key, f"unknown section; allowed: {', '.join(SCHEMA)}")
    if "grid" not in data:
        _fail(path, "grid", "section is required (frequency_hz, size_m or shape, ...)")
    sec: dict[str, Any] = {}
    for name in SCHEMA:
        if name in ARRAY_SECTIONS:
            items = data.get(name, [])
            if not isinstance(items, list):
                _fail(path, name, f"must be an array of tables ([[{name}]]), got {type(items).__name__}")
            sec[name] = [_validate_table(path, name, t, f"{name}[{i}]") for i, t in enumerate(items)]
        elif name in ("farfield", "air"):  # optional sections
            sec[name] = _validate_table(path, name, data[name], name) if name in data else None
        else:
            sec[name] = _validate_table(path, name, data.get(name, {}), name)
    return Scene(path=str(path), raw=data, **sec)


def load_scene(path: str | Path) -> Scene:
    """Read and validate a TOML scene file."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise SceneError(f"{path}: cannot read the scene file ({e.strerror})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{path}: not valid TOML: {e}") from None
    return parse_scene(data, str(path))


def schema_markdown() -> str:
    """The scene-file reference as Markdown tables (used to write docs/scene-files.md)."""
    return _schema_markdown()
