"""The scene file format's keys, declared once in the typed configuration layer
(`difflattice.config`): one frozen dataclass per section, and per transducer type and object
shape (the tagged unions `TRANSDUCER`, on `type`, and `OBJECT`, on `shape`: each class declares
only its own keys, the shared ones in a common base). Validation (`parse_table`) and the docs
tables (`schema_markdown`, docs/scene-files.md) are generated from these declarations.

Checks that need the simulator's objects (materials, stability limit, edge and boundary kinds,
shapes) stay where those objects are built (`scene.model.Scene.build`), so their messages come
from the one place that knows the rule.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Literal, NoReturn

from ..config import REQUIRED, ConfigError, Section, markdown_table, parse_section, setting, specs
from ..config.unions import TaggedUnion

__all__ = [
    "ARRAY_SECTIONS",
    "OBJECT",
    "SECTIONS",
    "TRANSDUCER",
    "ConfigError",
    "DiscTransducer",
    "LineTransducer",
    "Object",
    "Transducer",
    "fail",
    "parse_table",
    "schema_markdown",
]


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
    dtype: Literal["float32", "float64"] = setting(
        "float32", kind="str", choices=("float32", "float64"), doc="float32 or float64"
    )
    stencil: Literal["standard", "isotropic", "wide"] | None = setting(
        None,
        kind="str",
        choices=("standard", "isotropic", "wide"),
        doc="spatial stencil: standard (the paper's 5-point; 3d: 7-point), isotropic (2d and rz: the 9-point "
        "form whose phase speed is the same in every direction, so a disc's near-field maxima and minima sit in "
        "place; courant up to sqrt(3)/2 = 0.866 for one density without obstacles, else up to 1/sqrt(2); 3d: the "
        "19-point form, 1.3 % phase-speed error at 6 cells/wavelength in every direction against the 7-point's "
        "3.4 %, courant up to sqrt(3)/2, default 0.86) or wide (3d only: the 19-point form plus the second "
        "neighbours along the axes, 25 points, 0.24 % at 6 cells/wavelength in every direction, courant up to "
        "1/sqrt(2.79) = 0.599, default 0.595); next to obstacles the 3d stencils' limits are checked on the "
        "operator's measured spectrum. Default: wide on 3d grids, isotropic on rz grids in air (no objects, "
        "discs in a rigid baffle: the native kernels run it there), standard on 2d grids (the paper's) and rz "
        "with objects",
    )


@dataclass(frozen=True)
class MediumSection(Section):
    """What fills the window and how object boundaries are modelled."""

    SECTION: ClassVar[str] = "medium"
    background: str = setting("air", kind="str", doc="material filling the window (see Materials)")
    temperature_c: float | None = setting(
        None,
        kind="number",
        gt=-273.15,
        unit="degC",
        doc="air temperature (speed of sound of air; default 20 degC; with an [air] section give it there)",
    )
    boundary_model: Literal["conservative", "paper", "speed_zero"] = setting(
        "conservative",
        kind="str",
        choices=("conservative", "paper", "speed_zero"),
        doc="conservative, paper or speed_zero",
    )
    absorption_db_per_m: float = setting(
        0.0, kind="number", ge=0, unit="dB/m", doc="air absorption at the drive frequency (f^2 law)"
    )
    rasterise: Literal["hard", "smooth"] = setting(
        "hard", kind="str", choices=("hard", "smooth"), doc="hard or smooth object edges"
    )

    @property
    def air_temperature_c(self) -> float:
        """The background air's temperature (`temperature_c`, default 20 degC)."""
        return 20.0 if self.temperature_c is None else self.temperature_c


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


# ------------------------------------------------------------------------------------------
# transducers: a tagged union on `type`


@dataclass(frozen=True)
class TransducerSection(Section):
    """The keys of every transducer (`[[transducers]]`, one table each); `type` picks the rest."""

    SECTION: ClassVar[str] = "transducers"
    type: str = setting("line", kind="str", choices=("line", "disc"), doc="line or disc")
    name: str = setting("transducer", kind="str", doc="label")
    centre_m: tuple = setting(
        kind="list", items="number", unit="m", doc="[x, y] of the face centre (rz: [z, 0]; 3d: [x, y, z])"
    )
    signal: str = setting("burst", kind="str", choices=("burst", "cw"), doc="burst or cw")
    frequency_hz: float | None = setting(
        None, kind="number", gt=0, unit="Hz", doc="drive frequency (default: the grid's)"
    )
    cycles: float = setting(5.0, kind="number", gt=0, unit="cycles", doc="burst length")
    window: Literal["hann", "rect"] = setting(
        "hann", kind="str", choices=("hann", "rect"), doc="burst window: hann or rect"
    )
    ramp_cycles: float = setting(3.0, kind="number", ge=0, unit="cycles", doc="cw switch-on ramp")
    amplitude_pa: float = setting(1.0, kind="number", unit="Pa", doc="source amplitude")


@dataclass(frozen=True)
class LineTransducer(TransducerSection):
    """A line of source cells (`type = "line"`, the default; 2d grids)."""

    type: str = setting("line", kind="str", choices=("line",), doc="line: a line of cells (2d grids)")
    n_cells: int | None = setting(None, kind="int", ge=1, doc="number of source cells (or give diameter_m)")
    diameter_m: float | None = setting(
        None, kind="number", gt=0, unit="m", doc="active length (n_cells = diameter / cell size)"
    )
    direction_deg: float = setting(0.0, kind="number", unit="deg", doc="facing direction (0 = +x, 90 = +y)")
    injection: Literal["soft", "hard"] = setting(
        "soft", kind="str", choices=("soft", "hard"), doc="soft (add to P) or hard (set P)"
    )
    weights: tuple | None = setting(None, kind="list", items="number", doc="amplitude weight per cell (n_cells values)")
    lags_s: tuple | None = setting(None, kind="list", items="number", unit="s", doc="delay per cell (n_cells values)")


@dataclass(frozen=True)
class DiscTransducer(TransducerSection):
    """A disc (`type = "disc"`): on rz grids rings of cells round the axis, on 3d grids a flat disc
    at any position and orientation, its cells weighted by the area they hold."""

    type: str = setting("disc", kind="str", choices=("disc",), doc="disc: rz and 3d grids")
    diameter_m: float | None = setting(
        None, kind="number", gt=0, unit="m", doc="diameter (3d: or give ring_edges_m or fit_report)"
    )
    axis: tuple | None = setting(
        None,
        kind="list",
        items="number",
        doc="3d: the direction its face points to, [x, y, z] (any length; default [1, 0, 0])",
    )
    baffle: Literal["rigid", "none", "can"] | None = setting(
        None,
        kind="str",
        choices=("rigid", "none", "can"),
        doc="rz: rigid (the default: an infinite baffle, the face on the rigid z_lo side, z = 0), none (a bare "
        'disc) or can (a rigid can of depth can_depth_m behind the face); a 3d disc is bare (baffle = "none": '
        "give a baffle as an object)",
    )
    can_depth_m: float | None = setting(None, kind="number", gt=0, unit="m", doc="baffle = can: its depth")
    can_wall_m: float = setting(0.0, kind="number", ge=0, unit="m", doc="baffle = can: wall thickness")
    injection: Literal["soft", "hard"] | None = setting(
        None,
        kind="str",
        choices=("soft", "hard"),
        doc="rz: leave out for the velocity piston, or soft (with baffle = none) for a transparent disc of soft "
        "ring sources (the design problems' source); 3d: soft (add to P, the default) or hard (set P)",
    )
    weights: tuple | None = setting(
        None,
        kind="list",
        items="number",
        doc="amplitude weight per ring (rz: rings one cell wide; 3d: the rings of ring_edges_m)",
    )
    lags_s: tuple | None = setting(None, kind="list", items="number", unit="s", doc="delay per ring, as weights")
    ring_edges_m: tuple | None = setting(
        None,
        kind="list",
        items="any",
        unit="m",
        doc="3d: inner and outer radius of each ring, [[r0, r1], ...] (with weights and lags_s per ring)",
    )
    fit_report: str | None = setting(
        None,
        kind="str",
        doc="3d: take the rings (edges, weights, lags) and the diameter from a disc fit's report.json "
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

    def rz_baffle(self) -> Literal["rigid", "none", "can"]:
        """The housing of this disc on an rz grid (`baffle`, default rigid)."""
        return self.baffle or "rigid"

    @property
    def soft_rings(self) -> bool:
        """An rz disc given `injection = "soft"`: a transparent disc of soft ring sources (the design
        problems' source model) instead of the default velocity piston."""
        return self.injection == "soft"


Transducer = LineTransducer | DiscTransducer
"""One `[[transducers]]` table: the class its `type` names."""
TRANSDUCER = TaggedUnion("transducers", "type", (LineTransducer, DiscTransducer), default="line", noun="transducer")
"""The transducer union: `type` (default line) picks the class."""


# ------------------------------------------------------------------------------------------
# objects: a tagged union on `shape`


@dataclass(frozen=True)
class ObjectSection(Section):
    """The keys of every object (`[[objects]]`, one table each): a shape and its material."""

    SECTION: ClassVar[str] = "objects"
    shape: str = setting(
        kind="str",
        choices=(
            "segment",
            "box",
            "circle",
            "polygon",
            "polyline",
            "mesh",
            "sphere",
            "cylinder",
            "halfspace",
            "slab",
            "union",
            "intersection",
        ),
        doc="2d/rz: segment, box, circle, polygon, polyline or mesh; 3d: box, sphere, cylinder, halfspace, slab, "
        "union, intersection or mesh",
    )
    material: str | None = setting(None, kind="str", doc="material name (rigid, the default; soft, pine, ...)")
    name: str | None = setting(None, kind="str", doc="label (3d pulse-echo runs: the echo table's surface name)")
    cut: Any = setting(
        None, kind="table", union=lambda: OBJECT, doc="a shape (an object table) removed from this one, e.g. a gap"
    )

    @property
    def material_name(self) -> str:
        """The material (`material`, default rigid)."""
        return self.material or "rigid"


def _shape_tag(tag: str, doc: str) -> Any:
    return setting(tag, kind="str", choices=(tag,), doc=doc)


_GEOMETRY_FIX = "give it as the shape's table in docs/scene-files.md says"


def _vec(doc: str, unit: str = "m", required: bool = False, **kw) -> Any:
    return setting(
        REQUIRED if required else None, kind="list", items="number", unit=unit, doc=doc, fix=_GEOMETRY_FIX, **kw
    )


def _num(doc: str, required: bool = True) -> Any:
    return setting(REQUIRED if required else None, kind="number", gt=0, unit="m", doc=doc, fix=_GEOMETRY_FIX)


@dataclass(frozen=True)
class SegmentObject(ObjectSection):
    """A straight wall of a thickness (2d, rz)."""

    shape: str = _shape_tag("segment", "segment (2d, rz)")
    a_m: tuple = _vec("start [x, y]", required=True)
    b_m: tuple = _vec("end [x, y]", required=True)
    thickness_m: float = _num("wall thickness")


@dataclass(frozen=True)
class BoxObject(ObjectSection):
    """A box: by its corners lo_m and hi_m (2d, rz, 3d), or on 3d grids by centre_m and size_m,
    turned by angles_deg."""

    shape: str = _shape_tag("box", "box (2d, rz, 3d)")
    lo_m: tuple | None = _vec("lower corner [x, y] (3d: [x, y, z])")
    hi_m: tuple | None = _vec("upper corner [x, y] (3d: [x, y, z])")
    centre_m: tuple | None = _vec("3d: centre [x, y, z] (with size_m)")
    size_m: tuple | None = _vec("3d: edge lengths [x, y, z] (with centre_m)", gt=0)
    angles_deg: tuple | None = _vec(
        "3d: [yaw about z, pitch about the new y, roll about the new x] (default [0, 0, 0])", unit="deg"
    )


@dataclass(frozen=True)
class CircleObject(ObjectSection):
    """A disc of the plane (2d, rz: a torus or a disc round the axis)."""

    shape: str = _shape_tag("circle", "circle (2d, rz)")
    centre_m: tuple = _vec("centre [x, y]", required=True)
    radius_m: float = _num("radius")


@dataclass(frozen=True)
class PolygonObject(ObjectSection):
    """A closed polygon (2d, rz)."""

    shape: str = _shape_tag("polygon", "polygon (2d, rz)")
    vertices_m: tuple = setting(kind="list", items="any", unit="m", doc="vertices [[x, y], ...]")


@dataclass(frozen=True)
class PolylineObject(ObjectSection):
    """A wall of a thickness along a broken line (2d, rz)."""

    shape: str = _shape_tag("polyline", "polyline (2d, rz)")
    points_m: tuple = setting(kind="list", items="any", unit="m", doc="points [[x, y], ...]")
    thickness_m: float = _num("wall thickness")


@dataclass(frozen=True)
class MeshObject(ObjectSection):
    """A closed mesh file (STL, OBJ, ...): 2d takes its section at z = 0, rz its section through the
    z axis (a body of revolution's profile), 3d the whole solid in grid coordinates (inside by ray
    parity, exact distance near the surface)."""

    shape: str = _shape_tag("mesh", "mesh (2d, rz, 3d)")
    file: str = setting(kind="str", doc="the mesh file, relative to the scene file")
    unit: str = setting("mm", kind="str", choices=("mm", "m", "um", "cm", "in"), doc="the file's length unit")


@dataclass(frozen=True)
class SphereObject(ObjectSection):
    """A ball (3d)."""

    shape: str = _shape_tag("sphere", "sphere (3d)")
    centre_m: tuple = _vec("centre [x, y, z]", required=True)
    radius_m: float = _num("radius")


@dataclass(frozen=True)
class CylinderObject(ObjectSection):
    """A cylinder with capped ends (3d)."""

    shape: str = _shape_tag("cylinder", "cylinder (3d)")
    centre_m: tuple = _vec("centre [x, y, z]", required=True)
    axis: tuple = _vec("axis direction [x, y, z] (any length)", unit="", required=True)
    radius_m: float = _num("radius")
    length_m: float = _num("length")


@dataclass(frozen=True)
class HalfspaceObject(ObjectSection):
    """Everything on one side of a plane (3d): solid opposite to its normal."""

    shape: str = _shape_tag("halfspace", "halfspace (3d)")
    point_m: tuple = _vec("a point [x, y, z] of its plane", required=True)
    normal: tuple = _vec("plane normal [x, y, z] (the solid lies opposite to it)", unit="", required=True)


@dataclass(frozen=True)
class SlabObject(ObjectSection):
    """A plate of a thickness (3d)."""

    shape: str = _shape_tag("slab", "slab (3d)")
    point_m: tuple = _vec("a point [x, y, z] of its mid-plane", required=True)
    normal: tuple = _vec("plane normal [x, y, z]", unit="", required=True)
    thickness_m: float = _num("thickness")


@dataclass(frozen=True)
class UnionObject(ObjectSection):
    """The union of shapes (3d)."""

    shape: str = _shape_tag("union", "union (3d)")
    parts: tuple = setting(kind="list", items="table", union=lambda: OBJECT, doc="the shapes, inline object tables")


@dataclass(frozen=True)
class IntersectionObject(ObjectSection):
    """The intersection of shapes (3d)."""

    shape: str = _shape_tag("intersection", "intersection (3d)")
    parts: tuple = setting(kind="list", items="table", union=lambda: OBJECT, doc="the shapes, inline object tables")


Object = (
    SegmentObject
    | BoxObject
    | CircleObject
    | PolygonObject
    | PolylineObject
    | MeshObject
    | SphereObject
    | CylinderObject
    | HalfspaceObject
    | SlabObject
    | UnionObject
    | IntersectionObject
)
"""One `[[objects]]` table: the class its `shape` names."""
OBJECT: TaggedUnion = TaggedUnion(
    "objects",
    "shape",
    (
        SegmentObject,
        BoxObject,
        CircleObject,
        PolygonObject,
        PolylineObject,
        MeshObject,
        SphereObject,
        CylinderObject,
        HalfspaceObject,
        SlabObject,
        UnionObject,
        IntersectionObject,
    ),
    noun="object",
)
"""The object union: `shape` (required) picks the class."""


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


SECTIONS: dict[str, type | TaggedUnion] = {
    "grid": GridSection,
    "medium": MediumSection,
    "air": AirSection,
    "edges": EdgesSection,
    "transducers": TRANSDUCER,
    "objects": OBJECT,
    "sensors": SensorsSection,
    "farfield": FarfieldSection,
    "run": RunSection,
    "output": OutputSection,
}
"""Scene file sections in file order: name -> declared section class (or, for the arrays of
tables, the tagged union whose `type` / `shape` picks the class)."""
ARRAY_SECTIONS = ("transducers", "objects")
"""Sections written as arrays of tables (`[[transducers]]`)."""
OPTIONAL_SECTIONS = ("air", "farfield")
"""Sections that are None when the file leaves them out (the others take their defaults)."""


def parse_table(path, section: str, table: Any, where: str, error: type[ConfigError] = ConfigError) -> Any:
    """One table of a scene file as its typed section (an array's table: the class its tag names).
    Raises `error` (one line: file, key, value, allowed, fix)."""
    decl = SECTIONS[section]
    try:
        if isinstance(decl, TaggedUnion):
            return decl.parse(table, file=path, where=where)
        return parse_section(decl, table, file=path, where=where)
    except ConfigError as e:
        if isinstance(e, error):
            raise
        raise error(str(e)) from None


def fail(path, key, msg, error: type[ConfigError] = ConfigError) -> NoReturn:
    """Raise `error` for `[key]` of the file at `path`."""
    raise error(f"{path}: [{key}] {msg}")


def schema_markdown() -> str:
    """The scene-file reference as Markdown tables (docs/scene-files.md), from the declarations:
    one table per section, and per transducer type and object shape (its own keys; the keys every
    transducer or object has in one table before them)."""
    out = []
    for name, decl in SECTIONS.items():
        if isinstance(decl, TaggedUnion):
            base = decl.variants[0].__mro__[1]
            tags = ", ".join(f"`{t}`" for t in decl.classes)
            common = markdown_table(base, heading=f"`[[{name}]]`").rstrip("\n")
            dflt = f' (default `"{decl.default}"`)' if decl.default else ""
            out.append(
                common.replace(
                    "| key |",
                    f"`{decl.tag}`{dflt} picks the {decl.noun}'s kind: {tags}; each has the keys of this table "
                    f"and its own, below. A key of another kind is refused, naming the kinds it belongs to.\n\n| key |",
                    1,
                )
                + "\n"
            )
            shared = {s.name for s in specs(base)} - {decl.tag}
            for tag, cls in decl.classes.items():
                out.append(markdown_table(cls, heading=f'`[[{name}]]` {decl.tag} = "{tag}"', level=4, skip=shared))
        else:
            head = f"`[{name}]`"
            out.append(markdown_table(decl, heading=head))
    return "\n".join(out)
