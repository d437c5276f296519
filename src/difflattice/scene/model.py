"""Scene files (TOML): a documented, validated description of a whole simulation.

`load_scene(path)` reads and validates a file into a `Scene`: a frozen spec of typed sections
(SI units), the transducers and objects tagged unions whose `type` / `shape` picks the class;
`Scene.build()` turns it into the simulator's objects (grid, medium, sources, sensors, edges).
Every key, its unit, default and allowed values are declared once in `scene/schema.py` (typed
sections of `difflattice.config`; docs/scene-files.md is generated from them); an unknown key, a
key of another transducer type or object shape, a wrong type or a value out of range raises
`SceneError` naming the file, the key and the fix.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from ..lattice.coefficients import Edges
    from ..lattice.grid import Grid
    from ..lattice.kinds import LatticeKind
    from ..observe.farfield_base import FarFieldSurface
    from ..solver.sources import PointSources

from .common import (
    _NO_CELLS,
    _SIDES_2D,
    _TRANSDUCER_KEYS_3D,
    BuiltScene,
    SceneError,
    SceneTooLargeError,
    _fail,
    _n_steps,
    _parse_table,
    _points,
    _signal,
)
from .common import Receiver as Receiver  # re-exported: callers import it from here
from .media import _make_grid, _materials, _medium
from .objects import _shape
from .objects import shape3d as shape3d  # re-exported: callers import it from here
from .schema import (
    ARRAY_SECTIONS,
    OPTIONAL_SECTIONS,
    SECTIONS,
    AirSection,
    DiscTransducer,
    EdgesSection,
    FarfieldSection,
    GridSection,
    MediumSection,
    Object,
    OutputSection,
    RunSection,
    SensorsSection,
    Transducer,
)
from .schema import schema_markdown as _schema_markdown

# Every key, its type, default, unit and allowed values: declared once in scene/schema.py
# (SECTIONS).
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


@dataclass(frozen=True)
class Scene:
    """A validated scene (SI units): one typed section per table of the file (`scene.schema`),
    `transducers` and `objects` as tuples of the classes their `type` / `shape` names, `air` and
    `farfield` None when the file leaves them out. Frozen: derive another scene with
    `at_resolution`, `scaled` or `dataclasses.replace`. `path` names the file in messages."""

    path: str
    grid: GridSection
    medium: MediumSection = MediumSection()
    edges: EdgesSection = EdgesSection()
    transducers: tuple[Transducer, ...] = ()
    objects: tuple[Object, ...] = ()
    sensors: SensorsSection = SensorsSection()
    farfield: FarfieldSection | None = None
    run: RunSection = RunSection()
    output: OutputSection = OutputSection()
    air: AirSection | None = None  # None: dry air at [medium] temperature_c, lossless

    def air_conditions(self):
        """The scene's `AirConditions` when `[air]` asks for absorption, else None."""
        if self.air is None or not self.air.absorption:
            return None
        from ..lattice.medium import AirConditions

        a = self.air
        return AirConditions(a.temperature_c, a.humidity_pct, a.pressure_pa)

    def describe_air(self) -> str:
        """One line naming the air the scene simulates (printed by `difflattice simulate`)."""
        from .. import air as air_model

        f = self.grid.frequency_hz
        if self.air is None:
            if self.medium.background != "air":
                return f"background: {self.medium.background} (no air)"
            line = air_model.describe(self.medium.air_temperature_c, 0.0)
            return line + ", lossless (no [air] section: dry air, no absorption)"
        a = self.air
        line = air_model.describe(a.temperature_c, a.humidity_pct, a.pressure_pa, f)
        return line + ("" if a.absorption else " -- not simulated ([air] absorption = false)")

    def as_dict(self) -> dict:
        """The scene as plain TOML-able tables (every key with its value, defaults included; keys
        left None dropped): what a scene file holding exactly this scene would say."""
        from ..config import as_dict

        out: dict[str, Any] = {}
        for name in SECTIONS:
            v = getattr(self, name)
            if v is not None and not (name in ARRAY_SECTIONS and not v):
                out[name] = as_dict(v)
        return out

    # ---------------------------------------------------------------------------------------
    def at_resolution(self, cells_per_wavelength: float) -> Scene:
        """This scene at `cells_per_wavelength` (cell and step counts scale, metres and seconds
        stay: `scene.resolution`), its sections checked again."""
        from .resolution import scene_at

        return scene_at(self, cells_per_wavelength)

    def scaled(self, scale: float) -> Scene:
        """This scene with a grid `scale` times as fine (`scene.resolution.scaled_scene`)."""
        from .resolution import scaled_scene

        return scaled_scene(self, scale)

    @property
    def kind(self) -> LatticeKind:
        """The scene's lattice kind (`[grid] kind`)."""
        from ..lattice.kinds import as_kind

        return as_kind(self.grid.kind)

    def build(self, *, available_bytes: int | None = None) -> BuiltScene:
        """Build the solver's objects (`BuiltScene`) for `simulate`. Every scene is first
        estimated (`solver.estimate`) and refused (`SceneTooLargeError`) when its run would not
        fit in `available_bytes` (default: the memory available on this machine), before any
        grid-sized array exists. Each lattice kind imports only its own pieces (a 2-D scene builds
        nothing 3-D, and vice versa)."""
        if self.kind.ndim == 3:
            from .volume import build_volume

            return build_volume(self, available_bytes)
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
        """The 2-D and r-z lattices: grid (estimated before any grid-sized array), objects and
        housings, medium, edges, sources, the far-field surface and the sensors."""
        from ..lattice import geometry as geo
        from ..solver.sensors import Sensors, probe_cells

        p = self.path
        med = self.medium
        bg, mats = _materials(self)
        grid = _make_grid(self, mats)
        ed, s = self.edges, self.sensors
        self._check_fits(  # before the objects' and media's grid-sized arrays
            grid,
            _n_steps(self, grid),
            available_bytes,
            pml="pml" in {getattr(ed, k) for k in ("kind", *_SIDES_2D, "z_lo", "z_hi", "r_hi")},
            heterogeneous=bool(self.objects),
            n_probes=len(s.probes_m or ()),
            field_stats=int(s.p_max) + int(s.p_rms) + int(s.arrival_threshold_pa is not None),
        )
        for i, t in enumerate(self.transducers):
            if not isinstance(t, DiscTransducer):
                continue
            for k in _TRANSDUCER_KEYS_3D:
                if getattr(t, k) is not None:
                    _fail(p, f"transducers[{i}].{k}", f'is for 3d grids ([grid] kind = "3d"), not {grid.kind}')
            if t.receive:
                _fail(p, f"transducers[{i}].receive", f"is implemented for 3d grids, not {grid.kind}")
        if self.sensors.snapshot_slices_m is not None:
            _fail(p, "sensors.snapshot_slices_m", f"is for 3d grids (a {grid.kind} snapshot is the whole field)")

        occupancies = []
        for i, o in enumerate(self.objects):
            shape = _shape(p, f"objects[{i}]", o, geo, grid.kind.ring_metric)
            try:
                occupancies.append(np.asarray(geo.rasterise(shape, grid, med.rasterise)))
            except ValueError as e:
                _fail(p, "medium.rasterise", str(e))
        housings = self._housings(grid)
        medium = _medium(self, grid, bg, mats, occupancies, housings, lambda occs: geo.union_occupancy(occs))
        edges = self._plane_edges(grid)
        sources = self._plane_sources(grid, edges)
        probes = probe_cells(grid, _points(p, "sensors.probes_m", s.probes_m, 2)) if s.probes_m else None
        contour, phasor_cells, ff_index = self._farfield_surface(grid, edges, sources, [*occupancies, *housings])
        try:
            sensors = Sensors(
                probes=probes if probes is not None else _NO_CELLS,
                phasor_cells=phasor_cells if phasor_cells is not None else _NO_CELLS,
                p_max=s.p_max,
                p_rms=s.p_rms,
                arrival_threshold_pa=s.arrival_threshold_pa,
                snapshot_every=s.snapshot_every_steps,
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

    def _housings(self, grid: Grid) -> list[np.ndarray]:
        """Occupancies of the rz discs' housings (a can or an open ring; none for a rigid baffle)."""
        from ..solver.sources import disc_housing

        p, rz = self.path, grid.kind.ring_metric
        housings = []
        for i, t in enumerate(self.transducers):
            if (
                isinstance(t, DiscTransducer)
                and rz
                and t.rz_baffle() != "rigid"
                and t.diameter_m is not None
                and not t.soft_rings
            ):
                try:
                    housings.append(
                        np.asarray(
                            disc_housing(
                                grid,
                                radius_m=t.diameter_m / 2,
                                z_m=t.centre_m[0],
                                baffle=t.rz_baffle(),
                                depth_m=t.can_depth_m,
                                wall_m=t.can_wall_m,
                            )
                        )
                    )
                except ValueError as err:
                    _fail(p, f"transducers[{i}]", str(err))
        return housings

    def _plane_edges(self, grid: Grid) -> Edges:
        """The window's edges of a plane or rz scene, checked against the lattice kind."""
        from ..lattice.coefficients import Edges

        p, ed, rz = self.path, self.edges, grid.kind.has_axis_edge
        try:
            if rz:
                for side in _SIDES_2D:
                    if getattr(ed, side) is not None:
                        _fail(
                            p,
                            f"edges.{side}",
                            "on an rz grid name the sides z_lo, z_hi and r_hi (the axis needs no edge)",
                        )
                sides: dict[str, Any] = {s: (getattr(ed, s) or ed.kind) for s in ("z_lo", "z_hi", "r_hi")}
                edges = Edges.axisymmetric(
                    **sides,
                    thickness_cells=ed.thickness_cells,
                )
            else:
                for side in ("z_lo", "z_hi", "r_hi"):
                    if getattr(ed, side) is not None:
                        _fail(
                            p,
                            f"edges.{side}",
                            'is for rz and 3d grids ([grid] kind = "rz" or "3d"); a 2d grid has x_lo, x_hi, y_lo, y_hi',
                        )
                sides = {s: (getattr(ed, s) or ed.kind) for s in _SIDES_2D}
                edges = Edges(
                    **sides,
                    thickness_cells=ed.thickness_cells,
                )
            edges.check_kind(grid.kind)
        except ValueError as err:
            _fail(p, "edges", str(err))

        return edges

    def _plane_sources(self, grid: Grid, edges: Edges) -> list[PointSources]:
        """The transducers of a plane (line) or rz (disc) scene."""
        p, rz = self.path, grid.kind.ring_metric
        sources = []
        if not self.transducers:
            _fail(p, "transducers", "a scene needs at least one [[transducers]] entry")
        for i, t in enumerate(self.transducers):
            where = f"transducers[{i}]"
            sig = _signal(p, where, t, grid)
            try:
                if isinstance(t, DiscTransducer) != bool(rz):
                    _fail(
                        p,
                        f"{where}.type",
                        f"= {t.type!r} does not fit a {grid.kind} grid: use type = "
                        f"{'disc' if rz else 'line'} (or [grid] kind = {'2d' if rz else 'rz'})",
                    )
                if isinstance(t, DiscTransducer):
                    sources.append(_rz_disc(p, where, t, grid, edges, sig))
                else:
                    sources.append(_line(p, where, t, grid, sig))
            except (ValueError, TypeError) as err:
                _fail(p, where, str(err))

        return sources

    def _farfield_surface(
        self, grid: Grid, edges: Edges, sources, solids_occupancy
    ) -> tuple[FarFieldSurface | None, np.ndarray | None, int]:
        """The far-field surface (`[farfield]`, the kind's own: `observe.surfaces`): it encloses
        the transducer and every object, or the scene is refused with the reason; returns
        (surface, its phasor cells, transducer index)."""
        from ..observe.surfaces import surface_around

        p = self.path
        contour: FarFieldSurface | None = None
        phasor_cells = None
        ff_index = 0
        if self.farfield is not None:
            ff = self.farfield
            names = [t.name for t in self.transducers]
            if ff.transducer is not None:
                if ff.transducer not in names:
                    _fail(p, "farfield.transducer", f"= {ff.transducer!r}; known: {', '.join(names)}")
                ff_index = names.index(ff.transducer)
            # the surface encloses the transducer and every object (a surface through an object
            # would integrate a field that is not free space: a wrong lobe), or the scene is refused
            solids = [np.argwhere(np.asarray(o) > 0) for o in solids_occupancy]
            t = self.transducers[ff_index]
            # a disc on the rigid baffle (the low window face of axis 0) needs no surface there
            on_baffle = isinstance(t, DiscTransducer) and t.rz_baffle() == "rigid"
            baffle = f"{grid.kind.axis_names[0]}_lo" if on_baffle else None
            L = edges.thickness_cells if edges.kinds() & {"pml", "sponge"} else 0
            try:
                contour = surface_around(
                    grid, sources[ff_index].cells_array, ff.gap_cells, objects=solids, baffle=baffle, margin=L
                )
            except ValueError as err:
                why = (
                    f"the far-field surface encloses the transducer and the {len(solids)} object(s) "
                    f"{ff.gap_cells} cells out (so that it crosses no object), and then: {err}. Fix: a larger "
                    "window ([grid] size_m or shape), a smaller gap_cells, or no [farfield] (record probes)"
                    if solids
                    else str(err)
                )
                _fail(p, "farfield.gap_cells", why)
            phasor_cells = contour.cells
        return contour, phasor_cells, ff_index

    # ---------------------------------------------------------------------------------------
    # ---------------------------------------------------------------------------------------
    def show_steps(self, grid, n_steps: int) -> list[int]:
        """The steps of `[output] show_steps` and `show_times_s` (nearest step), sorted, unique;
        each must lie in 1..n_steps."""
        o = self.output
        steps = []
        for i, v in enumerate(o.show_steps):
            if isinstance(v, bool) or not isinstance(v, int):
                _fail(self.path, f"output.show_steps[{i}]", f"= {v!r} must be a whole number of steps")
            steps.append(v)
        for i, v in enumerate(o.show_times_s):
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
            return render_stride(grid.cells_per_wavelength, self.output.render_every_cells)
        except ValueError as e:
            _fail(self.path, "output.render_every_cells", str(e))


# ------------------------------------------------------------------------------------------
# pieces shared by the lattice kinds


# ------------------------------------------------------------------------------------------
# 2-D shapes


# ------------------------------------------------------------------------------------------
# 3-D shapes, discs and slices


def parse_scene(data: dict, path: str = "<scene>") -> Scene:
    """Validate a scene given as a dict (e.g. parsed TOML) into a `Scene`: each table checked
    against its section's declaration (an array's tables against the class their `type` /
    `shape` names); raises `SceneError` naming the file, the table, the key and the fix."""
    if not isinstance(data, dict):
        _fail(path, "scene", f"must be a table of sections, got {type(data).__name__}")
    for key in data:
        if key not in SECTIONS:
            _fail(path, key, f"unknown section; allowed: {', '.join(SECTIONS)}")
    if "grid" not in data:
        _fail(path, "grid", "section is required (frequency_hz, size_m or shape, ...)")
    sec: dict[str, Any] = {}
    for name in SECTIONS:
        if name in ARRAY_SECTIONS:
            items = data.get(name, [])
            if not isinstance(items, list):
                _fail(path, name, f"must be an array of tables ([[{name}]]), got {type(items).__name__}")
            sec[name] = tuple(_parse_table(path, name, t, f"{name}[{i}]") for i, t in enumerate(items))
        elif name in OPTIONAL_SECTIONS:
            sec[name] = _parse_table(path, name, data[name], name) if name in data else None
        else:
            sec[name] = _parse_table(path, name, data.get(name, {}), name)
    return Scene(path=str(path), **sec)


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


def _line(p, where: str, t, grid: Grid, sig) -> PointSources:
    """A plane scene's line transducer."""
    from ..solver.sources import line_transducer

    if len(t.centre_m) != 2:
        _fail(p, f"{where}.centre_m", f"= {list(t.centre_m)}: give [x_m, y_m] on a 2d grid")
    return line_transducer(
        grid,
        (t.centre_m[0], t.centre_m[1]),
        n_cells=t.n_cells,
        diameter_m=t.diameter_m,
        direction_deg=t.direction_deg,
        signal=sig,
        weights=t.weights,
        lags_s=t.lags_s,
        injection=t.injection,
    )


def _rz_disc(p, where: str, t: DiscTransducer, grid: Grid, edges: Edges, sig) -> PointSources:
    """An rz scene's disc: the velocity piston in its baffle, or (`injection = "soft"`) the
    transparent soft ring disc."""
    from ..solver.sources import disc_transducer

    if t.rz_baffle() == "rigid" and edges.x_lo != "rigid":
        _fail(
            p,
            f"{where}.baffle",
            f"= 'rigid' needs the rigid baffle plane: set [edges] z_lo = "
            f'"rigid" (now {edges.x_lo!r}), or baffle = "none" / "can" for an unbaffled disc',
        )
    if t.diameter_m is None:
        _fail(p, f"{where}.diameter_m", "is required for a disc (its diameter, m)")
    if len(t.centre_m) != 2 or t.centre_m[1] != 0:
        _fail(p, f"{where}.centre_m", f"= {list(t.centre_m)}: a disc sits on the axis, give [z_m, 0]")
    if t.injection == "hard":
        _fail(
            p,
            f"{where}.injection",
            '= "hard" is not an rz disc: leave injection out (the velocity piston) or give "soft" (a transparent '
            'ring disc, with baffle = "none")',
        )
    if t.soft_rings:
        if t.rz_baffle() != "none":
            _fail(p, f"{where}.injection", '= "soft" is a transparent ring disc (no housing): give baffle = "none"')
        return _soft_ring_disc(grid, t.diameter_m / 2, t.centre_m[0], sig)
    return disc_transducer(
        grid,
        radius_m=t.diameter_m / 2,
        z_m=t.centre_m[0],
        signal=sig,
        weights=t.weights,
        lags_s=t.lags_s,
        baffle=t.rz_baffle(),
    )


def _soft_ring_disc(grid: Grid, radius_m: float, z_m: float, signal) -> PointSources:
    """Soft (pressure-adding) ring sources in the row whose cell centre is nearest `z_m`, one per
    ring the radius touches, each weighted by the ring's covered face fraction (`ring_fractions`):
    transparent, radiating both ways, as the design problems' rz disc (`design.problem`)."""
    import jax.numpy as jnp

    from ..solver.sources import PointSources, ring_fractions

    row = int(round(z_m / grid.dx_m - 0.5))
    n = max(1, math.ceil(radius_m / grid.dx_m - 1e-9))
    cells = np.stack([np.full(n, row), np.arange(n)], 1)
    w = ring_fractions(jnp.asarray(radius_m / grid.dx_m, grid.jnp_dtype), n).astype(grid.jnp_dtype)
    return PointSources(cells=cells, signal=signal, weights=w, lags_s=jnp.zeros(n, grid.jnp_dtype), injection="soft")
