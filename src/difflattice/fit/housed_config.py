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

A measured wavefront (a near-field phase scan) is fitted jointly with the lobe where `[data]`
names one, with the keys of the ordinary fit configs (`fit.config`): `wave` (a capture file or a
plain table with a units header), `wave_z_m` (the scan line's distance in front of the can's
front face), `wave_mask_m`, and `[solver] wave_sigma_deg`. `load_housed_wave` reads it.
`lobe_mask_deg` leaves angle ranges of the record's table out of the fit (`housed_lobe`).

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
from .config import lobe_mask_setting, wave_mask_setting

HOUSED_FAMILIES = (
    "flat",
    "recessed",
    "opening",
    "cone",
    "bending",
    "profile",
)  # fit.housed.FAMILIES (not imported: no JAX here)


@dataclass(frozen=True)
class HousedDataSection(Section):
    """What is fitted: a datasheet record (data/datasheets/README.md) with a digitised directivity table."""

    SECTION: ClassVar[str] = "data"
    datasheet: str = setting(
        kind="str",
        doc="datasheet record (TOML, data/datasheets/README.md), relative to the config file",
        fix="give the path of a record with a [table] (a digitised directivity)",
    )
    lobe_mask_deg: tuple = lobe_mask_setting(
        "angle ranges [lo, hi] of the record's table left out of the fit (inclusive), e.g. [[60, 90]]"
    )
    wave: str | None = setting(
        None,
        kind="str",
        doc="wavefront file, fitted with the lobe: capture (`difflattice capture wave`), or plain table with a "
        "units header (e.g. x_mm,phase_deg), relative to the config file",
        fix="give the path relative to the config file",
    )
    wave_z_m: float | None = setting(
        None,
        kind="number",
        gt=0,
        le=10,
        unit="m",
        doc="distance of the wavefront's scan line in front of the can's front face (the face the fit puts): "
        "required for a plain table; with a capture file it must agree with its z",
        fix="give the scan line's distance in front of the front face in metres, e.g. 0.01",
    )
    wave_mask_m: tuple = wave_mask_setting(
        "positions x ranges [lo, hi] of the wavefront left out of the fit (inclusive)"
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
        doc="ladder (flat, recessed, opening, cone, bending, profile compared by AIC/BIC, the simplest adequate "
        "chosen) or one family",
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
class HousedSolverSection(Section):
    """The wavefront's uncertainty (as `[solver]` of the ordinary fit configs); only with `[data] wave`."""

    SECTION: ClassVar[str] = "solver"
    wave_sigma_deg: float = setting(
        1.0,
        kind="number",
        ge=0.001,
        le=90,
        unit="deg",
        doc="1-sigma of the measured phase, used as given (the rig reports phases in mdeg)",
        fix="give the phase noise of the mean of the bursts, e.g. 0.3 deg / sqrt(n_avg)",
    )


@dataclass(frozen=True)
class HousedOutputSection(Section):
    """Where the report goes."""

    SECTION: ClassVar[str] = "output"
    dir: str = setting("out/fits/housed", kind="str", doc="output directory (report.json, report.md)")


SECTIONS = (HousedDataSection, HousedModelSection, HousingSection, HousedSolverSection, HousedOutputSection)


@dataclass(frozen=True)
class HousedConfig:
    """A checked housed-fit config; `path` is the file (data paths are relative to its folder)."""

    data: HousedDataSection
    model: HousedModelSection
    housing: HousingSection
    output: HousedOutputSection
    solver: HousedSolverSection = HousedSolverSection()
    path: Path | None = None

    @property
    def base(self) -> Path:
        return self.path.resolve().parent if self.path is not None else Path.cwd()

    @property
    def datasheet_path(self) -> Path:
        return self.base / self.data.datasheet

    def error(self, key: str, problem: str) -> ConfigError:
        """A one-line `ConfigError` about `[key]` of this config's file."""
        return ConfigError(message(self.path, key, None, problem))


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
    allowed = ("data", "model", "solver", "output")
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
        solver=parse_section(HousedSolverSection, raw.get("solver"), file=path),
        path=path,
    )
    d = cfg.data
    if d.wave is None:
        for key, given in (
            ("data.wave_z_m", d.wave_z_m is not None),
            ("data.wave_mask_m", bool(d.wave_mask_m)),
            ("solver.wave_sigma_deg", "wave_sigma_deg" in (raw.get("solver") or {})),
        ):
            if given:
                raise cfg.error(key, 'is given but there is no wavefront; fix: remove it or give [data] wave = "..."')
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


def load_housed_wave(cfg: HousedConfig, frequency_hz: float) -> tuple[Any, tuple[str, ...]]:
    """The wavefront `[data] wave` names, as `fit.data.WaveData` (or None without one), and notes
    for the report. A capture file carries its frequency (it must be the datasheet record's
    `frequency_hz`) and z (it must agree with `wave_z_m` where that is given); a plain table takes
    z from `wave_z_m` (required). Phases are the rig's lag behind the drive (`fit.data`); sigma is
    `[solver] wave_sigma_deg`. Raises `ConfigError` naming the key for a missing or unreadable
    file, a lobe capture given as the wave, disagreeing frequency or z, or fewer than 3 points."""
    import math

    import numpy as np

    from ..capture.errors import CaptureFileError
    from ..capture.files import WaveCapture, is_capture_file, load_capture, load_wave_table
    from ..config import show
    from .data import wave_from_capture, wave_from_table

    d = cfg.data
    if d.wave is None:
        return None, ()
    p = Path(d.wave).expanduser()
    p = p if p.is_absolute() else cfg.base / p
    if not p.is_file():
        where = "not a file" if p.exists() else "not found"
        raise cfg.error(
            "data.wave", f"= {show(d.wave)}: {where} ({p}); fix: paths are relative to the config file's folder"
        )
    sigma = cfg.solver.wave_sigma_deg
    notes: list[str] = []
    try:
        if is_capture_file(p):
            cap = load_capture(p, allow_incomplete=True)
            if not isinstance(cap, WaveCapture):
                raise cfg.error(
                    "data.wave",
                    f"= {show(d.wave)} is a {cap.kind} capture (its header says kind: {cap.kind}); "
                    "fix: give a wavefront capture (the lobe comes from the datasheet record)",
                )
            f_cap = float(cap.metadata["freq_hz"])
            if abs(f_cap - frequency_hz) > 0.5:
                raise cfg.error(
                    "data.wave",
                    f"= {show(d.wave)} was captured at {f_cap:g} Hz but the datasheet record is at "
                    f"{frequency_hz:g} Hz; fix: fit a wavefront of the record's frequency",
                )
            if len(cap.seq) < 3:
                raise cfg.error("data.wave", f"= {show(d.wave)} holds only {len(cap.seq)} points; a fit needs >= 3")
            z_cap = float(np.median(cap.z_m))
            if d.wave_z_m is not None and abs(d.wave_z_m - z_cap) > 1e-4:
                raise cfg.error(
                    "data.wave_z_m",
                    f"= {show(d.wave_z_m)} m but {p.name} says z = {z_cap:g} m; fix: correct it or "
                    "leave it out (a capture carries its own)",
                )
            wave = wave_from_capture(cap, sigma_deg=sigma)
            if not cap.complete:
                notes.append(f"{p.name}: incomplete capture, fitted the {len(cap.seq)} points present")
        else:
            table = load_wave_table(p)
            if d.wave_z_m is None:
                raise cfg.error(
                    "data.wave_z_m",
                    f"is required: {p.name} is a plain table without metadata; fix: give the scan "
                    "line's distance in front of the front face in m",
                )
            wave = wave_from_table(
                table, frequency_hz=frequency_hz, z_m=d.wave_z_m, temperature_c=math.nan, sigma_deg=sigma
            )  # the housed fit's sound speed is [model] speed_of_sound_m_s; the table carries no temperature
    except CaptureFileError as e:
        raise cfg.error("data.wave", f"= {show(d.wave)} cannot be used: {e}") from None
    except ValueError as e:  # WaveData's own checks (non-finite phases, < 3 points)
        raise cfg.error("data.wave", f"= {show(d.wave)} cannot be used: {e}") from None
    notes.append(
        f"{p.name}: wavefront, {len(wave.x_m)} points at {wave.z_m:g} m in front of the front face, sigma {sigma:g} deg"
    )
    from .loading import masked_wave

    wave, note = masked_wave(cfg, wave, p.name)
    if note:
        notes.append(note)
    return wave, tuple(notes)


def housed_lobe(cfg: HousedConfig, sheet) -> tuple[Any, tuple[str, ...]]:
    """The record's lobe (`fit.datasheet.Datasheet.lobe`) less the angles `[data] lobe_mask_deg`
    leaves out, and a note for the report. ConfigError if the mask leaves fewer than 3 points;
    a ConfigWarning if it leaves out none."""
    from ..config import show
    from .data import mask_lobe
    from .loading import checked_mask

    lobe = sheet.lobe()  # refuses a record without a table, naming the fix
    ranges = cfg.data.lobe_mask_deg
    if not ranges:
        return lobe, ()
    n_out = checked_mask(
        cfg,
        "data.lobe_mask_deg",
        ranges,
        lobe.angle_deg,
        points="lobe points",
        none=f"angle of the table ({lobe.angle_deg.min():g}..{lobe.angle_deg.max():g} deg)",
    )
    return mask_lobe(lobe, ranges), (f"lobe_mask_deg {show(ranges)} left out {n_out} of {len(lobe.angle_deg)} angles",)
