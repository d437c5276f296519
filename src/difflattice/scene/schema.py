"""The scene file format's keys, declared once in the typed configuration layer
(`difflattice.config`): one frozen dataclass per section. Validation (`validate_section`), the
docs tables (`schema_markdown`, docs/scene-files.md) and `SCHEMA` (a plain view for older code)
are all generated from these declarations.

Checks that need the simulator's objects (materials, stability limit, edge and boundary kinds,
shapes) stay where those objects are built (`scene.model.Scene.build`), so their messages come
from the one place that knows the rule.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, NoReturn

from ..config import REQUIRED, ConfigError, Section, markdown_table, parse_section, setting, specs

__all__ = ["ConfigError", "SECTIONS", "SCHEMA", "ARRAY_SECTIONS", "validate_section", "schema_markdown", "fail"]


@dataclass(frozen=True)
class GridSection(Section):
    """The lattice: frequency and resolution set the cell size; give the window as `size_m` or `shape`."""

    SECTION: ClassVar[str] = "grid"
    kind: str = setting(
        "2d",
        kind="str",
        choices=("2d", "rz", "3d"),
        doc="lattice kind: 2d (a plane, the paper's model), rz (axisymmetric: axis 0 = z along the axis, "
        "axis 1 = r; objects are bodies of revolution, transducers are discs) or 3d (a volume of cubic "
        "cells: 3-D solids, disc transducers at any position and orientation)",
    )
    frequency_hz: float = setting(kind="number", gt=0, unit="Hz", doc="drive frequency the scales are built for")
    cells_per_wavelength: float = setting(
        20.0, kind="number", gt=0, unit="cells/λ", doc="cells per wavelength in the fastest medium"
    )
    size_m: tuple | None = setting(
        None,
        kind="list",
        items="number",
        gt=0,
        unit="m",
        doc="[width, height] of the window (rz: [z length, radius]; 3d: [x, y, z] sizes; or give shape)",
    )
    shape: tuple | None = setting(
        None,
        kind="list",
        items="int",
        ge=1,
        unit="cells",
        doc="[nx, ny] cells (rz: [nz, nr]; 3d: [nx, ny, nz]; or give size_m)",
    )
    courant: float | None = setting(
        None,
        kind="number",
        gt=0,
        doc="fastest medium's speed in cells/step (default 0.707 in 2d and rz, at most 1/sqrt(2) = 0.7071; "
        "0.577 in 3d, at most 1/sqrt(3) = 0.5774)",
    )
    dtype: str = setting("float32", kind="str", doc="float32 or float64")
    stencil: str | None = setting(
        None,
        kind="str",
        choices=("standard", "isotropic"),
        doc="spatial stencil: standard (the paper's 5-point; 3d: 7-point) or isotropic (2d and rz: the 9-point "
        "form whose phase speed is the same in every direction, so a disc's near-field maxima and minima sit in "
        "place; courant up to sqrt(3)/2 = 0.866 for one density without obstacles, else up to 1/sqrt(2); 3d: the "
        "19-point form, 1.3 % phase-speed error at 6 cells/wavelength in every direction against the 7-point's "
        "3.1 %, courant up to sqrt(3)/2, with rigid obstacles checked on the operator's measured spectrum, "
        "default courant 0.86). Default: isotropic on rz grids in air (no objects, discs in a rigid baffle: the "
        "native kernels run it there) and on 3d grids, standard on 2d grids (the paper's) and rz with objects",
    )


@dataclass(frozen=True)
class MediumSection(Section):
    """What fills the window and how object boundaries are modelled."""

    SECTION: ClassVar[str] = "medium"
    background: str = setting("air", kind="str", doc="material filling the window (see Materials)")
    temperature_c: float = setting(
        20.0, kind="number", gt=-273.15, unit="degC", doc="air temperature (speed of sound of air)"
    )
    boundary_model: str = setting("conservative", kind="str", doc="conservative, paper or speed_zero")
    absorption_db_per_m: float = setting(
        0.0, kind="number", ge=0, unit="dB/m", doc="air absorption at the drive frequency (f^2 law)"
    )
    rasterise: str = setting("hard", kind="str", doc="hard or smooth object edges")


@dataclass(frozen=True)
class AirSection(Section):
    """The air as it is (optional section): its temperature, humidity and pressure set the speed
    of sound, the density and the absorption (ISO 9613-1's O2 and N2 relaxations and the classical
    term, carried in the time domain at every frequency: docs/air.md). Replaces
    `[medium] temperature_c`; the background must be air."""

    SECTION: ClassVar[str] = "air"
    temperature_c: float = setting(20.0, kind="number", gt=-273.15, unit="degC", doc="air temperature")
    humidity_pct: float = setting(50.0, kind="number", ge=0, le=100, unit="%", doc="relative humidity")
    pressure_pa: float = setting(101325.0, kind="number", gt=0, unit="Pa", doc="static pressure")
    absorption: bool = setting(
        True,
        kind="bool",
        doc="simulate the air's absorption (relaxation memory fields; lowers the default courant by ~0.1 %); "
        "false: lossless air of this speed and density",
    )


@dataclass(frozen=True)
class EdgesSection(Section):
    """The window's edges: one kind on every side, or per side."""

    SECTION: ClassVar[str] = "edges"
    kind: str = setting("pml", kind="str", doc="pml, mur, sponge, rigid or soft on every side")
    x_lo: str | None = setting(None, kind="str", doc="override for the left side")
    x_hi: str | None = setting(None, kind="str", doc="override for the right side")
    y_lo: str | None = setting(None, kind="str", doc="override for the bottom side")
    y_hi: str | None = setting(None, kind="str", doc="override for the top side")
    z_lo: str | None = setting(
        None, kind="str", doc="rz: override for the z = 0 side (rigid: a baffle); 3d: for the low z side"
    )
    z_hi: str | None = setting(None, kind="str", doc="rz: override for the far z side; 3d: for the high z side")
    r_hi: str | None = setting(None, kind="str", doc="rz: override for the outer radius (the axis needs no edge)")
    thickness_cells: int = setting(20, kind="int", ge=1, unit="cells", doc="PML or sponge thickness")


@dataclass(frozen=True)
class TransducerSection(Section):
    """One transducer (`[[transducers]]`, one table each): a line (2d) or a disc (rz, 3d)."""

    SECTION: ClassVar[str] = "transducers"
    name: str = setting("transducer", kind="str", doc="label")
    type: str = setting(
        "line",
        kind="str",
        choices=("line", "disc"),
        doc="line (2d: a line of cells) or disc (rz: rings of cells; 3d: a flat disc at any position and "
        "orientation, its cells weighted by the area they hold)",
    )
    centre_m: tuple = setting(
        kind="list", items="number", unit="m", doc="[x, y] of the face centre (rz: [z, 0]; 3d: [x, y, z])"
    )
    axis: tuple | None = setting(
        None,
        kind="list",
        items="number",
        doc="3d disc: the direction its face points to, [x, y, z] (any length; default [1, 0, 0])",
    )
    baffle: str = setting(
        "rigid",
        kind="str",
        choices=("rigid", "none", "can"),
        doc="rz disc: rigid (infinite baffle: the face on the rigid z_lo side, z = 0), none (a bare disc) or "
        "can (a rigid can of depth can_depth_m behind the face); a 3d disc is bare (give a baffle as an object)",
    )
    can_depth_m: float | None = setting(None, kind="number", gt=0, unit="m", doc="disc with baffle = can: its depth")
    can_wall_m: float = setting(0.0, kind="number", ge=0, unit="m", doc="disc with baffle = can: wall thickness")
    n_cells: int | None = setting(None, kind="int", ge=1, doc="number of source cells (or give diameter_m)")
    diameter_m: float | None = setting(
        None, kind="number", gt=0, unit="m", doc="active diameter (n_cells = diameter / cell size)"
    )
    direction_deg: float = setting(0.0, kind="number", unit="deg", doc="facing direction (0 = +x, 90 = +y)")
    signal: str = setting("burst", kind="str", choices=("burst", "cw"), doc="burst or cw")
    frequency_hz: float | None = setting(
        None, kind="number", gt=0, unit="Hz", doc="drive frequency (default: the grid's)"
    )
    cycles: float = setting(5.0, kind="number", gt=0, unit="cycles", doc="burst length")
    window: str = setting("hann", kind="str", doc="burst window: hann or rect")
    ramp_cycles: float = setting(3.0, kind="number", ge=0, unit="cycles", doc="cw switch-on ramp")
    amplitude_pa: float = setting(1.0, kind="number", unit="Pa", doc="source amplitude")
    injection: str = setting(
        "soft",
        kind="str",
        doc="soft (add to P) or hard (set P); an rz disc given injection = soft (with baffle = none) is a "
        "transparent disc of soft ring sources (the design problems' source) instead of the velocity piston",
    )
    weights: tuple | None = setting(
        None,
        kind="list",
        items="number",
        doc="amplitude weights: per cell of a line (n_cells values), per ring of a disc (rz: rings one cell "
        "wide; 3d: the rings of ring_edges_m)",
    )
    lags_s: tuple | None = setting(
        None, kind="list", items="number", unit="s", doc="delays, per cell (line) or per ring (disc), as weights"
    )
    ring_edges_m: tuple | None = setting(
        None,
        kind="list",
        items="any",
        unit="m",
        doc="3d disc: inner and outer radius of each ring, [[r0, r1], ...] (with weights and lags_s per ring)",
    )
    fit_report: str | None = setting(
        None,
        kind="str",
        doc="3d disc: take the rings (edges, weights, lags) and the diameter from a disc fit's report.json "
        "(path relative to the scene file)",
    )
    receive: bool = setting(
        False,
        kind="bool",
        doc="3d: also record what this transducer receives, the pulse-echo A-scan (reciprocity: the weighted sum "
        "of the pressure over its cells)",
    )
    gate_start_s: float | None = setting(
        None,
        kind="number",
        ge=0,
        unit="s",
        doc="receive: the echo window starts here (before it: the transmit and its ring-down); marks the A-scan",
    )


@dataclass(frozen=True)
class ObjectSection(Section):
    """One object (`[[objects]]`, one table each): a shape and its material."""

    SECTION: ClassVar[str] = "objects"
    shape: str = setting(
        kind="str",
        doc="2d/rz: segment, box, circle, polygon, polyline or mesh; 3d: box, sphere, cylinder, halfspace, slab, "
        "union, intersection or mesh",
    )
    file: str | None = setting(
        None,
        kind="str",
        doc="mesh: a closed mesh file (STL, OBJ, ...) relative to the scene file; 2d takes its section at z = 0, "
        "rz its section through the z axis (a body of revolution's profile), 3d the whole solid in grid "
        "coordinates (inside by ray parity, exact distance near the surface)",
    )
    unit: str = setting("mm", kind="str", choices=("mm", "m", "um", "cm", "in"), doc="mesh: the file's length unit")
    material: str = setting("rigid", kind="str", doc="material name (rigid, soft, pine, ...)")
    name: str | None = setting(None, kind="str", doc="label (3d pulse-echo runs: the echo table's surface name)")
    a_m: tuple | None = setting(None, kind="list", items="number", unit="m", doc="segment start [x, y]")
    b_m: tuple | None = setting(None, kind="list", items="number", unit="m", doc="segment end [x, y]")
    thickness_m: float | None = setting(
        None, kind="number", gt=0, unit="m", doc="wall thickness of segment/polyline (3d: of a slab)"
    )
    lo_m: tuple | None = setting(
        None, kind="list", items="number", unit="m", doc="box lower-left corner [x, y] (3d: [x, y, z])"
    )
    hi_m: tuple | None = setting(
        None, kind="list", items="number", unit="m", doc="box upper-right corner [x, y] (3d: [x, y, z])"
    )
    centre_m: tuple | None = setting(
        None,
        kind="list",
        items="number",
        unit="m",
        doc="circle centre [x, y]; 3d: centre [x, y, z] of a sphere, cylinder or turned box",
    )
    radius_m: float | None = setting(None, kind="number", gt=0, unit="m", doc="circle, sphere or cylinder radius")
    size_m: tuple | None = setting(
        None, kind="list", items="number", gt=0, unit="m", doc="3d box: edge lengths [x, y, z] (with centre_m)"
    )
    angles_deg: tuple | None = setting(
        None,
        kind="list",
        items="number",
        unit="deg",
        doc="3d box: [yaw about z, pitch about the new y, roll about the new x] (default [0, 0, 0])",
    )
    axis: tuple | None = setting(
        None, kind="list", items="number", doc="3d cylinder: axis direction [x, y, z] (any length)"
    )
    length_m: float | None = setting(None, kind="number", gt=0, unit="m", doc="3d cylinder: length (capped ends)")
    point_m: tuple | None = setting(
        None, kind="list", items="number", unit="m", doc="3d halfspace or slab: a point [x, y, z] of its plane"
    )
    normal: tuple | None = setting(
        None,
        kind="list",
        items="number",
        doc="3d halfspace or slab: plane normal [x, y, z] (a halfspace is solid opposite to it)",
    )
    parts: tuple | None = setting(
        None, kind="list", items="any", doc="3d union or intersection: the shapes, inline tables with these keys"
    )
    vertices_m: tuple | None = setting(None, kind="list", items="any", unit="m", doc="polygon vertices [[x, y], ...]")
    points_m: tuple | None = setting(None, kind="list", items="any", unit="m", doc="polyline points [[x, y], ...]")
    cut: dict | None = setting(None, kind="table", doc="a shape (same keys) removed from this one, e.g. a gap")


@dataclass(frozen=True)
class SensorsSection(Section):
    """What is recorded during the run."""

    SECTION: ClassVar[str] = "sensors"
    probes_m: tuple = setting(
        [], kind="list", items="any", unit="m", doc="points [[x, y], ...] recorded every step (3d: [[x, y, z], ...])"
    )
    p_max: bool = setting(True, kind="bool", doc="record the peak |p| map")
    p_rms: bool = setting(False, kind="bool", doc="record the RMS map")
    arrival_threshold_pa: float | None = setting(
        None, kind="number", gt=0, unit="Pa", doc="record first-arrival step where |p| exceeds this"
    )
    snapshot_every_steps: int | None = setting(
        None, kind="int", ge=1, unit="steps", doc="keep the field every that many steps"
    )
    snapshot_slices_m: tuple | None = setting(
        None,
        kind="list",
        items="any",
        unit="m",
        doc='3d: the planes a snapshot keeps, [["x", 0.02], ["z", 0.015]] (axis, position; default: the three '
        "planes through the first transducer's centre)",
    )


@dataclass(frozen=True)
class FarfieldSection(Section):
    """The lobe pattern (optional section): Kirchhoff-Helmholtz transform of a contour round a transducer."""

    SECTION: ClassVar[str] = "farfield"
    range_m: float = setting(1.0, kind="number", gt=0, unit="m", doc="range of the lobe pattern")
    angles_deg: tuple = setting(
        [-90.0, 90.0, 0.5], kind="list", items="number", unit="deg", doc="[start, stop, step] of the lobe angles"
    )
    gap_cells: int = setting(
        4,
        kind="int",
        ge=1,
        unit="cells",
        doc="surface distance from the transducer's cells and every object's (the surface encloses them all)",
    )
    transducer: str | None = setting(
        None, kind="str", doc="name of the transducer whose lobe is computed (default: first)"
    )
    dispersion: str | None = setting(
        None,
        kind="str",
        choices=("lattice", "continuum"),
        doc="wavenumber of the transform: lattice (continues the lattice's own field) or continuum "
        "(k = omega / c, as the design problems use); default: the transform's own (2d: lattice, rz: continuum)",
    )


@dataclass(frozen=True)
class RunSection(Section):
    """How long to run: `n_steps` or `duration_s`."""

    SECTION: ClassVar[str] = "run"
    n_steps: int | None = setting(None, kind="int", ge=1, doc="number of time steps (or give duration_s)")
    duration_s: float | None = setting(None, kind="number", gt=0, unit="s", doc="simulated time")
    checkpoint: str = setting(
        "none", kind="str", choices=("none", "sqrt"), doc="none or sqrt (memory-bounded gradients)"
    )


@dataclass(frozen=True)
class OutputSection(Section):
    """Images written by `difflattice simulate`."""

    SECTION: ClassVar[str] = "output"
    show_steps: tuple = setting(
        [],
        kind="list",
        items="any",
        unit="steps",
        doc="steps at which to save a field image (moment_NNNNNN.png), e.g. [1030, 1300]",
    )
    show_times_s: tuple = setting(
        [], kind="list", items="any", unit="s", doc="times at which to save a field image (rounded to the nearest step)"
    )
    render_every_cells: int | None = setting(
        None,
        kind="int",
        unit="cells",
        doc="render every n-th cell in field images (default: 3 at 20 cells/wavelength, >= 6.7 pixels per wavelength)",
    )
    frames: bool = setting(True, kind="bool", doc="write a PNG per snapshot (frames/frame_NNNN.png)")
    animation: str = setting(
        "gif",
        kind="str",
        choices=("gif", "mp4", "none"),
        doc="animation of the snapshots: gif, mp4 (needs ffmpeg, else gif) or none",
    )


SECTIONS: dict[str, type] = {
    c.SECTION: c
    for c in (
        GridSection,
        MediumSection,
        AirSection,
        EdgesSection,
        TransducerSection,
        ObjectSection,
        SensorsSection,
        FarfieldSection,
        RunSection,
        OutputSection,
    )
}
"""Scene file sections in file order: name -> declared section class."""
ARRAY_SECTIONS = ("transducers", "objects")
"""Sections written as arrays of tables (`[[transducers]]`)."""

_TYPES = {"number": (int, float), "int": int, "bool": bool, "str": str, "list": list, "table": dict}
SCHEMA: dict[str, dict[str, tuple]] = {
    name: {
        s.name: (
            _TYPES[s.kind],
            s.default if s.default is REQUIRED or not isinstance(s.default, tuple) else list(s.default),
            s.doc + (f", {s.unit}" if s.unit else ""),
        )
        for s in specs(cls)
    }
    for name, cls in SECTIONS.items()
}
"""A plain view of the declarations: section -> key -> (type(s), default, description with unit)."""


def _plain(value: Any) -> Any:
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return value


def validate_section(path, section: str, table: Any, where: str, error: type[ConfigError] = ConfigError) -> dict:
    """Check one table of a scene file against its declaration; returns the values with defaults
    filled (lists as lists). Raises `error` (one line: file, key, value, allowed, fix)."""
    cls = SECTIONS[section]
    try:
        obj = parse_section(cls, table, file=path, where=where)
    except ConfigError as e:
        raise error(str(e)) from None
    return {s.name: _plain(getattr(obj, s.name)) for s in specs(cls)}


def fail(path, key, msg, error: type[ConfigError] = ConfigError) -> NoReturn:
    """Raise `error` for `[key]` of the file at `path`."""
    raise error(f"{path}: [{key}] {msg}")


def schema_markdown() -> str:
    """The scene-file reference as Markdown tables (docs/scene-files.md), from the declarations."""
    out = []
    for name, cls in SECTIONS.items():
        head = f"`[[{name}]]`" if name in ARRAY_SECTIONS else f"`[{name}]`"
        out.append(markdown_table(cls, heading=head))
    return "\n".join(out)
