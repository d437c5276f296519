"""Fit configs of housed transducers (`fit.housed`): a datasheet record, the can's outline and
which families to fit, run by `difflattice fit` like any fit config.

    [data]
    datasheet = "../data/datasheets/some_device.toml"   # a record with a digitised [table]

    [model]
    model = "housed"
    family = "ladder"            # or one of flat, recessed, opening, profile

    [model.housing]              # the outline drawing, metres
    outer_diameter_m = 0.016
    length_m = 0.012

A config is recognised by `model = "housed"` (`is_housed_config`); `load_housed_config` checks it
into a `HousedConfig` with one-line `ConfigError`s naming the key, and docs/housed.md's key tables
are generated from the declarations below. No JAX here.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from ..config import ConfigError, Section, message, parse_section, setting

HOUSED_FAMILIES = ("flat", "recessed", "opening", "profile")  # fit.housed.FAMILIES (not imported: no JAX here)


@dataclass(frozen=True)
class HousedDataSection(Section):
    """What is fitted: a datasheet record (data/datasheets/README.md) with a digitised directivity table."""

    SECTION: ClassVar[str] = "data"
    datasheet: str = setting(
        kind="str",
        doc="datasheet record (TOML, data/datasheets/README.md), relative to the config file",
        fix="give the path of a record with a [table] (a digitised directivity)",
    )


@dataclass(frozen=True)
class HousedModelSection(Section):
    """The housed model (`fit.housed`): which families, the lattice resolution and initial geometry."""

    SECTION: ClassVar[str] = "model"
    model: str = setting(kind="str", choices=("housed",), doc='"housed": a transducer in its can (fit.housed)')
    family: str = setting(
        "ladder",
        kind="str",
        choices=("ladder", *HOUSED_FAMILIES),
        doc="ladder (flat, recessed, opening, profile compared by AIC/BIC, the simplest adequate chosen) or one family",
        fix='use "ladder" or one of ' + ", ".join(HOUSED_FAMILIES),
    )
    cells_per_wavelength: float = setting(
        16.0,
        kind="number",
        ge=6,
        le=64,
        unit="cells/λ",
        doc="lattice resolution of the fit (16: the lobe of a 9 mm piston 3 mm deep within 0.1 dB of 32)",
        fix="use 12-24",
    )
    resolution_cells_per_wavelength: float | None = setting(
        20.0,
        kind="number",
        ge=6,
        le=64,
        unit="cells/λ",
        doc="the chosen fit is repeated at this resolution and the shifts are added to its errors",
        fix="use 1.25-1.5 x cells_per_wavelength",
    )
    speed_of_sound_m_s: float = setting(
        343.2, kind="number", gt=200, le=400, unit="m/s", doc="speed of sound in the air of the measurement"
    )
    diaphragm_m: float | None = setting(
        None,
        kind="number",
        gt=0,
        unit="m",
        doc="initial diaphragm diameter (default: the baffled piston of the data's -6 dB angle)",
    )
    recess_m: float | None = setting(
        None, kind="number", ge=0, unit="m", doc="initial recess of the diaphragm behind the front face"
    )
    opening_m: float | None = setting(
        None, kind="number", gt=0, unit="m", doc="initial diameter of the front plate's opening"
    )
    fixed: tuple = setting(
        [],
        kind="list",
        items="str",
        choices=("diaphragm", "recess", "opening"),
        doc="geometry held at its given value (diaphragm_m, recess_m, opening_m), e.g. an opening from the outline",
        fix='give e.g. ["opening"] with opening_m',
    )


@dataclass(frozen=True)
class HousingSection(Section):
    """The can from the datasheet's outline drawing: nothing fitted is larger than it."""

    SECTION: ClassVar[str] = "model.housing"
    outer_diameter_m: float = setting(
        kind="number", gt=0, le=1, unit="m", doc="outer diameter of the can", fix="read it off the outline drawing"
    )
    length_m: float = setting(
        kind="number",
        gt=0,
        le=1,
        unit="m",
        doc="length of the can, back to front face (without pins)",
        fix="read it off the outline drawing",
    )
    wall_m: float = setting(
        0.5e-3, kind="number", ge=0, le=0.1, unit="m", doc="wall of the bore (bore = outer diameter less two walls)"
    )
    plate_m: float = setting(
        1.0e-3,
        kind="number",
        gt=0,
        le=0.1,
        unit="m",
        doc="front plate thickness (family opening; >= 2 lattice cells)",
    )
    back: str = setting(
        "closed",
        kind="str",
        choices=("closed", "open"),
        doc="the can's back: closed (solid behind the diaphragm) or open (a tube: the diaphragm's rear radiates)",
    )
    front: str = setting(
        "free",
        kind="str",
        choices=("free", "flange"),
        doc="the can's front: free (a can in free air) or flange (the front face continues as an infinite rigid "
        "baffle: the can set in a wall or panel; back must be closed)",
        fix='use "free", or "flange" for a unit mounted flush in a panel',
    )


@dataclass(frozen=True)
class HousedOutputSection(Section):
    """Where the report goes."""

    SECTION: ClassVar[str] = "output"
    dir: str = setting("out/fits/housed", kind="str", doc="output directory (report.json, report.md)")


SECTIONS = (HousedDataSection, HousedModelSection, HousingSection, HousedOutputSection)


@dataclass(frozen=True)
class HousedConfig:
    """A checked housed-fit config; `path` is the file (data paths are relative to its folder)."""

    data: HousedDataSection
    model: HousedModelSection
    housing: HousingSection
    output: HousedOutputSection
    path: Path | None = None

    @property
    def base(self) -> Path:
        return self.path.resolve().parent if self.path is not None else Path.cwd()

    @property
    def datasheet_path(self) -> Path:
        return self.base / self.data.datasheet


def is_housed_config(path: str | Path) -> bool:
    """Whether the TOML file at `path` is a housed-fit config (`[model] model = "housed"`)."""
    try:
        raw = tomllib.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return False  # the ordinary loader reports it
    model = raw.get("model")
    return isinstance(model, dict) and model.get("model") == "housed"


def housed_config_from_dict(raw: dict[str, Any], *, path: str | Path | None = None) -> HousedConfig:
    """Check a parsed housed-fit config."""
    path = None if path is None else Path(path)
    allowed = ("data", "model", "output")
    for k in raw:
        if k not in allowed:
            raise ConfigError(message(path, k, None, f"unknown section; allowed: {', '.join(allowed)}"))
    model = dict(raw.get("model") or {})
    housing = model.pop("housing", None)
    if housing is None:
        raise ConfigError(
            message(
                path, "model.housing", None, "is required: the can's outer_diameter_m and length_m (outline drawing)"
            )
        )
    if "data" not in raw:
        raise ConfigError(message(path, "data", None, 'section is required: give datasheet = "..."'))
    cfg = HousedConfig(
        data=parse_section(HousedDataSection, raw["data"], file=path),
        model=parse_section(HousedModelSection, model, file=path),
        housing=parse_section(HousingSection, housing, file=path),
        output=parse_section(HousedOutputSection, raw.get("output"), file=path),
        path=path,
    )
    h = cfg.housing
    if h.front == "flange" and h.back == "open":
        raise ConfigError(
            message(
                path, "model.housing.front", None, '= "flange" needs back = "closed" (a baffled can has no rear field)'
            )
        )
    if h.wall_m * 2 >= h.outer_diameter_m:
        raise ConfigError(
            message(
                path, "model.housing.wall_m", None, f"= {h.wall_m} m leaves no bore in a {h.outer_diameter_m} m can"
            )
        )
    return cfg


def load_housed_config(path: str | Path) -> HousedConfig:
    """Read and check a housed-fit config file (TOML)."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise ConfigError(f"{path}: cannot read the fit config ({e}); fix: check the path and the TOML") from None
    return housed_config_from_dict(raw, path=path)


def housed_config_markdown() -> str:
    """The housed-fit config's key tables (docs/housed.md)."""
    from ..config import markdown_tables

    return markdown_tables(SECTIONS)
