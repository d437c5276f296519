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
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from ..lattice.coefficients import Edges
    from ..lattice.grid import Grid
    from ..lattice.medium import Medium
    from ..observe.farfield import BoxContour
    from ..observe.farfield_rz import CylinderSurface
    from ..solver.sensors import Sensors
    from ..solver.sources import PointSources

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


def _fail(path, key, msg):
    fail(path, key, msg, SceneError)


def _validate_table(path, section: str, table: dict, where: str) -> dict:
    return validate_section(path, section, table, where, SceneError)


class BuiltScene(NamedTuple):
    """What `Scene.build()` gives: the solver's objects plus what the scene asks to observe.

    - `grid`, `medium`, `sources`, `sensors`, `edges`, `n_steps`: the arguments of `simulate`;
    - `contour`: the far-field contour (None when the scene has no `[farfield]`);
    - `farfield_source`: index of the transducer whose lobe is computed;
    - `show_steps`: steps at which field images are wanted; `render_every`: render stride, cells.
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

    # ---------------------------------------------------------------------------------------
    def build(self) -> BuiltScene:
        """Build the solver's objects (`BuiltScene`) for `simulate`."""
        from ..lattice import geometry as geo
        from ..lattice.coefficients import Edges
        from ..lattice.grid import make_grid
        from ..lattice.medium import Medium, air, material, warn_if_under_resolved
        from ..observe.farfield import box_around
        from ..observe.farfield_rz import cylinder_around
        from ..solver.sensors import Sensors, probe_cells
        from ..solver.sources import ContinuousWave, ToneBurst, disc_housing, disc_transducer, line_transducer

        p = self.path
        med = self.medium
        bg = (
            air(med["temperature_c"])
            if med["background"] == "air"
            else _material(p, "medium.background", med["background"], material)
        )
        if bg.kind != "fluid":
            _fail(p, "medium.background", f"must be a fluid material, got {bg.name} ({bg.kind})")
        mats = [bg] + [
            _material(p, f"objects[{i}].material", o["material"], material) for i, o in enumerate(self.objects)
        ]
        if med["boundary_model"] == "speed_zero":
            for i, m in enumerate(mats[1 : 1 + len(self.objects)]):
                given = "material" in (self.raw.get("objects", [{}] * len(self.objects))[i] or {})
                if m.kind == "fluid" or (given and m.kind == "rigid"):
                    warnings.warn(
                        f"{p}: [objects[{i}].material] = {m.name!r} is ignored under "
                        f'boundary_model = "speed_zero": every object is a speed-zero '
                        f"(pressure-release, R = -1) region, its speed "
                        f"{'and density ' if m.kind == 'fluid' else ''}not used. Use "
                        f'material = "soft" to say so, or boundary_model = "conservative" to '
                        f"simulate {m.name!r}.",
                        UserWarning,
                        stacklevel=2,
                    )
            mats = [bg]
        c_max = max(m.speed_m_s for m in mats if m.kind == "fluid")
        g = self.grid
        if (g["size_m"] is None) == (g["shape"] is None):
            _fail(p, "grid", "give exactly one of size_m = [width, height] (m) or shape = [nx, ny] (cells)")
        try:
            grid = make_grid(
                frequency_hz=g["frequency_hz"],
                cells_per_wavelength=g["cells_per_wavelength"],
                c_max_m_s=c_max,
                shape=tuple(g["shape"]) if g["shape"] else None,
                size_m=tuple(g["size_m"]) if g["size_m"] else None,
                courant=g["courant"],
                dtype=g["dtype"],
                kind=g["kind"],
            )
        except ValueError as e:
            _fail(p, "grid", str(e))
        rz = grid.kind == "rz"

        # every simulated fluid must be resolved: the cell is sized for the fastest one
        fastest = max((m for m in mats if m.kind == "fluid"), key=lambda m: m.speed_m_s).name
        seen = set()
        for m in mats:
            if m.kind == "fluid" and m.name not in seen:
                seen.add(m.name)
                warn_if_under_resolved(m.name, m.speed_m_s, grid.frequency_hz, grid.dx_m, fastest=fastest)

        # medium maps
        rigid, soft = [], []
        speed = np.full(grid.shape, bg.speed_m_s)
        rho = np.full(grid.shape, bg.density_kg_m3)
        fluid_objects = False
        for i, (o, m) in enumerate(
            zip(self.objects, mats[1:] if med["boundary_model"] != "speed_zero" else [None] * len(self.objects))
        ):
            shape = _shape(p, f"objects[{i}]", o, geo)
            try:
                occ = np.asarray(geo.rasterise(shape, grid, med["rasterise"]))
            except ValueError as e:
                _fail(p, "medium.rasterise", str(e))
            if med["boundary_model"] == "speed_zero" or m.kind == "soft":
                soft.append(occ)
            elif m.kind == "rigid":
                rigid.append(occ)
            else:
                fluid_objects = True
                speed = speed * (1 - occ) + m.speed_m_s * occ
                rho = rho * (1 - occ) + m.density_kg_m3 * occ
        dt = grid.jnp_dtype
        import jax.numpy as jnp

        for i, t in enumerate(self.transducers):
            if t["type"] == "disc" and rz and t["baffle"] != "rigid" and t["diameter_m"] is not None:
                try:
                    rigid.append(
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

        def union(occs):
            return None if not occs else jnp.asarray(np.asarray(geo.union_occupancy(occs)), dt)

        try:
            medium = Medium(
                sound_speed_m_s=jnp.asarray(speed, dt) if fluid_objects else bg.speed_m_s,
                density_kg_m3=jnp.asarray(rho, dt) if fluid_objects else bg.density_kg_m3,
                rigid=union(rigid),
                soft=union(soft),
                boundary_model=med["boundary_model"],
                absorption_db_per_m=float(med["absorption_db_per_m"]),
            )
        except ValueError as e:
            _fail(p, "medium", str(e))

        e = self.edges
        try:
            if rz:
                for side in ("x_lo", "x_hi", "y_lo", "y_hi"):
                    if e[side] is not None:
                        _fail(
                            p,
                            f"edges.{side}",
                            "on an rz grid name the sides z_lo, z_hi and r_hi (the axis needs no edge)",
                        )
                edges = Edges.axisymmetric(
                    **{s: (e[s] or e["kind"]) for s in ("z_lo", "z_hi", "r_hi")}, thickness_cells=e["thickness_cells"]
                )
            else:
                for side in ("z_lo", "z_hi", "r_hi"):
                    if e[side] is not None:
                        _fail(
                            p,
                            f"edges.{side}",
                            'is for rz grids ([grid] kind = "rz"); a 2d grid has x_lo, x_hi, y_lo, y_hi',
                        )
                edges = Edges(
                    **{s: (e[s] or e["kind"]) for s in ("x_lo", "x_hi", "y_lo", "y_hi")},
                    thickness_cells=e["thickness_cells"],
                )
            edges.check_kind(grid.kind)
        except ValueError as err:
            _fail(p, "edges", str(err))

        sources = []
        if not self.transducers:
            _fail(p, "transducers", "a scene needs at least one [[transducers]] entry")
        for i, t in enumerate(self.transducers):
            where = f"transducers[{i}]"
            f = t["frequency_hz"] or grid.frequency_hz
            try:
                if t["signal"] == "burst":
                    sig = ToneBurst(f, t["cycles"], t["window"], t["amplitude_pa"])
                elif t["signal"] == "cw":
                    sig = ContinuousWave(f, t["ramp_cycles"], t["amplitude_pa"])
                else:
                    _fail(p, f"{where}.signal", f"= {t['signal']!r}; allowed: burst, cw")
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
                    sources.append(
                        line_transducer(
                            grid,
                            tuple(t["centre_m"]),
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

        s = self.sensors
        probes = probe_cells(grid, s["probes_m"]) if s["probes_m"] else np.zeros((0, 2), int)
        contour = None
        phasor_cells = np.zeros((0, 2), int)
        ff_index = 0
        if self.farfield is not None:
            ff = self.farfield
            names = [t["name"] for t in self.transducers]
            if ff["transducer"] is not None:
                if ff["transducer"] not in names:
                    _fail(p, "farfield.transducer", f"= {ff['transducer']!r}; known: {', '.join(names)}")
                ff_index = names.index(ff["transducer"])
            if rz:
                baffled = self.transducers[ff_index]["baffle"] == "rigid"
                contour = cylinder_around(sources[ff_index].cells_array, ff["gap_cells"], baffled=baffled)
            else:
                contour = box_around(sources[ff_index].cells_array, ff["gap_cells"])
            L = edges.thickness_cells if edges.kinds() & {"pml", "sponge"} else 0
            try:
                contour.check_inside(grid, margin=L)
            except ValueError as err:
                _fail(p, "farfield.gap_cells", str(err))
            phasor_cells = contour.cells
        try:
            sensors = Sensors(
                probes=probes,
                phasor_cells=phasor_cells,
                p_max=s["p_max"],
                p_rms=s["p_rms"],
                arrival_threshold_pa=s["arrival_threshold_pa"],
                snapshot_every=s["snapshot_every_steps"],
            )
            sensors.check_inside(grid)
        except ValueError as err:
            _fail(p, "sensors", str(err))

        r = self.run
        if (r["n_steps"] is None) == (r["duration_s"] is None):
            _fail(p, "run", "give exactly one of n_steps or duration_s (s)")
        n_steps = r["n_steps"] if r["n_steps"] is not None else int(math.ceil(grid.s_to_steps(r["duration_s"])))
        if n_steps < 1:
            _fail(p, "run", f"n_steps = {n_steps} must be >= 1")
        if r["checkpoint"] not in ("none", "sqrt"):
            _fail(p, "run.checkpoint", f"= {r['checkpoint']!r}; allowed: none, sqrt")
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


def _material(path, key, name, lookup):
    try:
        return lookup(name)
    except ValueError as e:
        _fail(path, key, str(e))


def _shape(path, where, o: dict, geo):
    kind = o["shape"]
    need = {
        "segment": ("a_m", "b_m", "thickness_m"),
        "box": ("lo_m", "hi_m"),
        "circle": ("centre_m", "radius_m"),
        "polygon": ("vertices_m",),
        "polyline": ("points_m", "thickness_m"),
    }
    if kind not in need:
        _fail(path, f"{where}.shape", f"= {kind!r}; allowed: {', '.join(need)}")
    for k in need[kind]:
        if o.get(k) is None:
            _fail(path, f"{where}.{k}", f"is required for shape = {kind!r}")
    a = lambda k: np.asarray(o[k], dtype=float)
    try:
        s = {
            "segment": lambda: geo.Segment(a("a_m"), a("b_m"), a("thickness_m")),
            "box": lambda: geo.Box(a("lo_m"), a("hi_m")),
            "circle": lambda: geo.Circle(a("centre_m"), a("radius_m")),
            "polygon": lambda: geo.Polygon(a("vertices_m")),
            "polyline": lambda: geo.Polyline(a("points_m"), a("thickness_m")),
        }[kind]()
    except Exception as e:  # malformed coordinates
        _fail(path, where, f"bad {kind} parameters: {e}")
    if o.get("cut"):
        cut = _validate_table(path, "objects", o["cut"], f"{where}.cut")
        s = geo.Difference(s, _shape(path, f"{where}.cut", cut, geo))
    return s


def parse_scene(data: dict, path: str = "<scene>") -> Scene:
    """Validate a scene given as a dict (e.g. parsed TOML)."""
    allowed = set(SCHEMA)
    for key in data:
        if key not in allowed:
            _fail(path, key, f"unknown section; allowed: {', '.join(SCHEMA)}")
    if "grid" not in data:
        _fail(path, "grid", "section is required (frequency_hz, size_m or shape, ...)")
    sec = {}
    for name in SCHEMA:
        if name in ARRAY_SECTIONS:
            items = data.get(name, [])
            if not isinstance(items, list):
                _fail(path, name, f"must be an array of tables ([[{name}]]), got {type(items).__name__}")
            sec[name] = [_validate_table(path, name, t, f"{name}[{i}]") for i, t in enumerate(items)]
        elif name == "farfield":
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
