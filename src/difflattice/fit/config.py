"""Reproducible fits: a typed TOML config (data, model, solver, uncertainty, output) run by one command.

    .venv/bin/difflattice fit fitting/polaroid_like.toml

`load_config(path)` reads and checks a file into a `FitConfig` (frozen, typed; its sections are
declared once below, and docs/fitting.md's key tables are generated from the declarations);
every impossible value is a one-line `ConfigError` naming the file, the key, the value, what is
allowed and the fix, and legal but unwise values give a `ConfigWarning`. `run_fit(cfg)` loads the
data (`load_fit_data`: capture files, complete or not, or a plain lobe table; masks; checks
against the config), simulates the transfer, fits and writes the report. The report records
package versions, the git commit and SHA-256 hashes of the config and data, so a re-run can be
checked against it.

Precision is the caller's choice: `run_fit` never changes JAX's configuration. The fit needs
float64 (`jax.config.update("jax_enable_x64", True)` at start-up, as the command line does
through `difflattice.apps.jaxconfig.configure()`); it warns when float64 is off.
"""

from __future__ import annotations

import dataclasses
import hashlib
import platform
import subprocess
import sys
import time
import tomllib
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, cast

import numpy as np

from ..config import ConfigError, ConfigWarning, Section, message, parse_section, setting, show, specs

PROFILES = ("uniform", "free", "symmetric", "smooth")  # fit.model.PROFILES (not imported: no JAX here)
DISC_PROFILES = (*PROFILES, "rim_taper")  # fit.disc.DISC_PROFILES; a disc takes "symmetric" as "free"
SOLVERS = ("levenberg_marquardt", "dogleg", "gauss_newton", "bfgs")  # fit.solve.SOLVERS
LOSSES = ("l2", "huber", "cauchy")
BAFFLES = ("rigid", "none", "can")  # solver.sources.BAFFLES (not imported: no JAX here)
MIN_FIT_CELLS_PER_WAVELENGTH = 8.0
"""Below this a fit's transfer simulation carries a phase error large enough to bias the fitted
parameters (docs/accuracy.md); it is allowed, with a warning."""


@dataclass(frozen=True)
class DataSection(Section):
    """What is fitted. Paths are relative to the config file. A lobe file is a capture file
    (`difflattice capture lobe`) or a plain two-column table whose header names the units
    (angle_deg | angle_rad, level_db | level_linear | level_pa | level_v), e.g. a
    digitised datasheet beam pattern; a plain table carries no metadata, so `frequency_hz`,
    `range_m`, `temperature_c` and `lobe_sigma_db` must then be given here. An incomplete capture
    (a gap of missing points) is fitted with the points it holds, and the report says so."""

    SECTION: ClassVar[str] = "data"
    lobe: str | None = setting(
        None,
        kind="str",
        doc="lobe file: capture, or plain table with a units header (e.g. angle_deg,level_db)",
        fix="give the path relative to the config file",
    )
    wave: str | None = setting(
        None,
        kind="str",
        doc="wavefront file: capture (`difflattice capture wave`), or plain table with a units header (e.g. x_mm,phase_deg)",
        fix="give the path relative to the config file",
    )
    lobe_mask_deg: tuple = setting(
        [],
        kind="list",
        items="range",
        ge=-180,
        le=180,
        unit="deg",
        doc="angle ranges [lo, hi] left out of the fit (inclusive), e.g. [[-90, -60], [60, 90]]",
        fix="give [[lo, hi], ...] in degrees with lo < hi",
    )
    wave_mask_m: tuple = setting(
        [],
        kind="list",
        items="range",
        unit="m",
        doc="positions x ranges [lo, hi] left out of the fit (inclusive)",
        fix="give [[lo, hi], ...] in metres with lo < hi",
    )
    frequency_hz: float | None = setting(
        None,
        kind="number",
        gt=0,
        le=10e6,
        unit="Hz",
        doc="drive frequency: required for a plain table; with capture files it must agree with their header",
        fix="give the drive frequency in Hz",
    )
    range_m: float | None = setting(
        None,
        kind="number",
        gt=0,
        le=1000,
        unit="m",
        doc="microphone range of a plain lobe table; with a capture file it must agree with its header",
        fix="give the range of the measurement in metres",
    )
    temperature_c: float | None = setting(
        None,
        kind="number",
        ge=-40,
        le=60,
        unit="degC",
        doc="air temperature: required for a plain table; with capture files it replaces the temperature they record (the report says so)",
        fix="give the air temperature in degrees Celsius",
    )
    wave_z_m: float | None = setting(
        None,
        kind="number",
        gt=0,
        le=10,
        unit="m",
        doc="distance of a plain wavefront table's scan line from the face: required for a plain table; with a capture file it must agree with its z",
        fix="give the scan line's distance from the face in metres, e.g. 0.0165",
    )
    lobe_sigma_db: float | None = setting(
        None,
        kind="number",
        gt=0,
        le=20,
        unit="dB",
        doc="1-sigma of the lobe levels: required for a plain table; with a capture file, a floor on the sigma from the burst-to-burst sd (default 0.05 dB)",
        fix="give the uncertainty of the levels in dB, e.g. 0.5 for a digitised datasheet",
    )


@dataclass(frozen=True)
class ModelSection(Section):
    """The transducer model: a line of source cells (2-D lattice) or a disc of ring source cells
    (axisymmetric lattice, `fit.disc`), with weight and lag profiles and an active diameter
    (docs/fitting.md, "How it works")."""

    SECTION: ClassVar[str] = "model"
    model: str = setting(
        "line",
        kind="str",
        choices=("line", "disc"),
        doc="model family: line (a 2-D line of cells); disc (a circular transducer: a disc of ring cells on the "
        "axisymmetric lattice, lobe and wavefront exact at the data's range)",
        fix='use model = "disc" for a circular transducer, "line" for the 2-D line model',
    )
    line_length_m: float = setting(
        kind="number",
        gt=0,
        le=10,
        unit="m",
        doc='the modelled face: the length of the line of source cells, or for model = "disc" the diameter of '
        "the modelled disc (>= the largest diameter to try)",
        fix="give the length of the transducer face plus a margin, e.g. 0.04",
    )
    diameter_m: float | None = setting(
        None,
        kind="number",
        gt=0,
        unit="m",
        doc="active diameter: the fixed value when fit_diameter = false, else the initial value (default: a scan over 0.5-0.98 x line_length_m)",
        fix="give the active diameter in metres, <= line_length_m",
    )
    cells_per_wavelength: float = setting(
        20.0,
        kind="number",
        ge=4,
        le=200,
        unit="cells/λ",
        doc="lattice resolution of the transfer simulation (a fit should use >= 8)",
        fix="use 20 (the default); below 4 the lattice cannot carry the wave",
        warn=(
            (
                lambda v: v < MIN_FIT_CELLS_PER_WAVELENGTH,
                "= {value} cells per wavelength is coarse for a fit: the transfer's phase error biases the "
                f"fitted parameters; use >= {MIN_FIT_CELLS_PER_WAVELENGTH:g} (20 is the default)",
            ),
        ),
    )
    weights: str = setting(
        "smooth",
        kind="str",
        choices=DISC_PROFILES,
        doc='weight profile across the face (rim_taper: model = "disc" only; for a disc, symmetric = free)',
        fix="choose one of the profile families",
    )
    lags: str = setting(
        "smooth",
        kind="str",
        choices=DISC_PROFILES,
        doc='lag profile across the face (rim_taper: model = "disc" only; for a disc, symmetric = free)',
        fix="choose one of the profile families",
    )
    n_basis: int = setting(
        4, kind="int", ge=1, le=16, doc="number of smooth basis functions (Chebyshev) per profile", fix="use 2-6"
    )
    symmetric: bool = setting(True, kind="bool", doc="smooth profiles use even polynomials only (a symmetric aperture)")
    fit_diameter: bool = setting(True, kind="bool", doc="fit the active diameter")
    lobe_range_m: float | None = setting(
        None,
        kind="number",
        gt=0,
        le=1e6,
        unit="m",
        doc="range at which the lobe is modelled (default: the data's range; e.g. 1000 for data that are a Fraunhofer pattern)",
        fix="give a range in metres, > 0",
    )
    baffle: str = setting(
        "rigid",
        kind="str",
        choices=BAFFLES,
        doc='model = "disc": what surrounds the face: rigid (an infinite rigid baffle in the face plane), none '
        "(a bare disc: the modelled face on a rigid disc one cell thick, in free space) or can (the face flush "
        "with the front of a closed rigid can, can_depth_m deep, can_wall_m wall)",
        fix='use "rigid" (a transducer in a large panel), "none" (a bare transducer) or "can" (in its housing)',
    )
    can_depth_m: float | None = setting(
        None,
        kind="number",
        gt=0,
        le=10,
        unit="m",
        doc='baffle = "can": depth of the housing behind the face (required)',
        fix="give the housing's depth in metres, e.g. 0.02",
    )
    can_wall_m: float = setting(
        0.0,
        kind="number",
        ge=0,
        le=10,
        unit="m",
        doc='baffle = "can": wall thickness of the housing around the modelled face (line_length_m across)',
        fix="give the wall thickness in metres, >= 0",
    )
    stencil: str = setting(
        "standard",
        kind="str",
        choices=("standard", "isotropic"),
        doc="model = \"disc\": the r-z lattice's stencil for the ring transfers: standard (the paper's 5-point "
        "stencil) or isotropic (9-point Mehrstellen: near-field extrema in place on the lattice itself). The "
        "transfers carry the field from a surface one cell round the disc with the exact wavenumber, so the "
        "lattice's dispersion hardly enters; measured on the 38.4 mm piston at 20 cells per wavelength the "
        "standard stencil fits as well (chi2_red 0.44 against 0.94, same diameter to 0.0002 mm)",
        fix='use "standard" (default) or "isotropic"',
    )


@dataclass(frozen=True)
class SolverSection(Section):
    """How the least-squares problem is solved (optimistix) and how the residuals are weighted."""

    SECTION: ClassVar[str] = "solver"
    name: str = setting(
        "levenberg_marquardt",
        kind="str",
        choices=SOLVERS,
        doc="optimistix solver",
        fix="levenberg_marquardt is the robust default",
    )
    max_steps: int = setting(200, kind="int", ge=1, le=100_000, doc="iteration limit per stage", fix="use e.g. 200")
    rtol: float = setting(1e-7, kind="number", gt=0, lt=1, doc="relative tolerance of the optimistix solver")
    atol: float = setting(1e-7, kind="number", gt=0, doc="absolute tolerance of the optimistix solver")
    rtol_cost: float = setting(
        1e-6,
        kind="number",
        gt=0,
        lt=1,
        doc="convergence: relative change of the cost over the last accepted steps below which the fit has converged",
    )
    rtol_step: float = setting(
        0.05,
        kind="number",
        gt=0,
        le=100,
        unit="SE",
        doc="convergence: the last step, in the parameters' standard errors, below which the fit has converged",
    )
    loss: str = setting(
        "l2",
        kind="str",
        choices=LOSSES,
        doc="residual loss: l2 (least squares), huber or cauchy (robust against outliers)",
    )
    loss_scale: float = setting(
        3.0,
        kind="number",
        gt=0,
        le=100,
        unit="sigma",
        doc="scale of the robust loss in units of each point's 1-sigma: residuals beyond it count less",
    )
    floor_db: float = setting(
        40.0,
        kind="number",
        gt=0,
        le=200,
        unit="dB",
        doc="lobe residual floor below the measured peak (deep nulls count as the floor)",
        fix="use a few dB less than the data's dynamic range, e.g. 40",
    )
    lobe_weight: float = setting(1.0, kind="number", ge=0, le=1e6, doc="weight of the lobe residuals")
    wave_weight: float = setting(1.0, kind="number", ge=0, le=1e6, doc="weight of the wavefront residuals")
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
class UncertaintySection(Section):
    """The systematic part of the error budget: a refit at a second resolution (discretisation
    error) and refits with other model families (model inadequacy)."""

    SECTION: ClassVar[str] = "uncertainty"
    second_cells_per_wavelength: float | None = setting(
        None,
        kind="number",
        ge=4,
        le=200,
        unit="cells/λ",
        doc="resolution of the refit that measures the discretisation error (default: the fit's choice)",
        fix="give a resolution different from [model] cells_per_wavelength, e.g. 1.5 x",
    )
    model_families: tuple = setting(
        [],
        kind="list",
        items="str",
        choices=PROFILES,
        doc="profile families (weights and lags) refitted to measure the model-inadequacy spread",
        fix='list profile families, e.g. ["smooth", "symmetric"]',
    )


@dataclass(frozen=True)
class OutputSection(Section):
    """Where the report goes."""

    SECTION: ClassVar[str] = "output"
    dir: str = setting("out/fit", kind="str", doc="report directory, relative to the working directory")
    field_image: bool = setting(True, kind="bool", doc="simulate and render the fitted transducer's field")


@dataclass(frozen=True)
class AirSection(Section):
    """The air of the measurement (optional section; issue 34). Each key left out comes from the
    capture files' metadata (temperature: the mean of the recorded temperatures; humidity_pct,
    pressure_hpa from the header), else dry air at 101325 Pa (the emulator's air); the report's provenance says
    which (`fit_air`). Sets the speed of sound of the fit (humid air, `difflattice.air`)."""

    SECTION: ClassVar[str] = "air"
    temperature_c: float | None = setting(
        None, kind="number", ge=-40, le=60, unit="degC", doc="air temperature (default: the capture's)"
    )
    humidity_pct: float | None = setting(
        None, kind="number", ge=0, le=100, unit="%", doc="relative humidity (default: the capture's, else 0: dry)"
    )
    pressure_pa: float | None = setting(
        None, kind="number", ge=30000, le=120000, unit="Pa", doc="static pressure (default: the capture's, else 101325)"
    )


def fit_air(cfg: FitConfig, data: FitData) -> dict[str, Any]:
    """The air a fit uses: {temperature_c, humidity_pct, pressure_pa, speed_of_sound_m_s, source},
    `source` naming, per key, where it came from ([air], [data], a capture file's header, default)."""
    from ..air import speed_of_sound_m_s
    from ..capture.files import is_capture_file, load_capture

    a = cfg.air
    if a.temperature_c is not None and cfg.data.temperature_c is not None:
        raise cfg.error("air.temperature_c", "is given twice ([data] temperature_c too): keep one")
    meta: dict[str, Any] = {}
    for path in data.paths:
        if is_capture_file(path):
            m = load_capture(path, allow_incomplete=True).metadata
            meta.update({k: m[k] for k in ("humidity_pct", "pressure_hpa") if m.get(k) is not None})
    src: dict[str, str] = {}
    t = a.temperature_c if a.temperature_c is not None else data.temperature_c
    src["temperature_c"] = "[air]" if a.temperature_c is not None else "capture or [data]"
    if a.humidity_pct is not None:
        h, src["humidity_pct"] = a.humidity_pct, "[air]"
    elif "humidity_pct" in meta:
        h, src["humidity_pct"] = float(meta["humidity_pct"]), "capture file"
    else:
        h, src["humidity_pct"] = 0.0, "default: dry (no [air] humidity_pct, none in the capture)"
    if a.pressure_pa is not None:
        p, src["pressure_pa"] = a.pressure_pa, "[air]"
    elif "pressure_hpa" in meta:
        p, src["pressure_pa"] = 100.0 * float(meta["pressure_hpa"]), "capture file"
    else:
        p, src["pressure_pa"] = 101325.0, "default (no [air] pressure_pa, none in the capture)"
    c = speed_of_sound_m_s(t, h, p)
    return {"temperature_c": t, "humidity_pct": h, "pressure_pa": p, "speed_of_sound_m_s": c, "source": src}


SECTIONS = (DataSection, ModelSection, SolverSection, UncertaintySection, OutputSection, AirSection)


@dataclass(frozen=True)
class FitConfig:
    """A checked fit configuration: the sections of the file and the file itself (`path`, None
    for a config built in Python; data paths are relative to its folder, else to the working
    directory). Cross-checks between keys run on construction."""

    data: DataSection
    model: ModelSection
    solver: SolverSection = field(default_factory=SolverSection)
    uncertainty: UncertaintySection = field(default_factory=UncertaintySection)
    output: OutputSection = field(default_factory=OutputSection)
    path: Path | None = None
    air: AirSection = field(default_factory=AirSection)

    @property
    def base(self) -> Path:
        """The folder data paths are relative to."""
        return self.path.resolve().parent if self.path is not None else Path.cwd()

    def error(self, key: str, problem: str) -> ConfigError:
        """A one-line `ConfigError` about `[key]` of this config's file."""
        return ConfigError(message(self.path, key, None, problem))

    def __post_init__(self) -> None:
        d, m, s, u = self.data, self.model, self.solver, self.uncertainty
        if d.lobe is None and d.wave is None:
            raise self.error(
                "data", 'nothing to fit: give lobe = "...", wave = "..." or both (paths relative to the config file)'
            )
        if m.diameter_m is not None:
            if m.diameter_m > m.line_length_m or (m.fit_diameter and m.diameter_m >= m.line_length_m):
                rel = "<" if m.fit_diameter else "<="
                raise self.error(
                    "model.diameter_m",
                    f"= {show(m.diameter_m)} m must be {rel} line_length_m = "
                    f"{show(m.line_length_m)} m (the active aperture lies on the modelled line); fix: "
                    "lengthen line_length_m or correct diameter_m",
                )
        for key in ("weights", "lags"):
            if m.model != "disc" and getattr(m, key) not in PROFILES:
                raise self.error(
                    f"model.{key}",
                    f"= {show(getattr(m, key))} is a profile of the disc model only; fix: use one of "
                    f'{", ".join(PROFILES)}, or model = "disc"',
                )
        if m.model != "disc" and (m.baffle != "rigid" or m.can_depth_m is not None or m.can_wall_m != 0):
            raise self.error(
                "model.baffle",
                f'= {show(m.baffle)} (with can_depth_m / can_wall_m) is for model = "disc" only: the line model '
                'is a line of cells in free space; fix: remove them or use model = "disc"',
            )
        if m.model != "disc" and m.stencil != "standard":
            raise self.error(
                "model.stencil",
                f'= {show(m.stencil)} is for model = "disc" only: the line model\'s transfers run the standard '
                'stencil; fix: remove stencil or set model = "disc"',
            )
        if m.baffle == "can" and m.can_depth_m is None:
            raise self.error(
                "model.can_depth_m",
                'is required with baffle = "can" (the housing\'s depth behind the face, m); fix: give e.g. '
                'can_depth_m = 0.02, or baffle = "none"',
            )
        if m.baffle != "can" and (m.can_depth_m is not None or m.can_wall_m != 0):
            raise self.error(
                "model.can_depth_m",
                f'and can_wall_m are for baffle = "can", not {show(m.baffle)}; fix: remove them or set baffle = "can"',
            )
        if d.lobe_mask_deg and d.lobe is None:
            raise self.error(
                "data.lobe_mask_deg", 'is given but there is no lobe file; fix: remove it or give lobe = "..."'
            )
        if d.wave_mask_m and d.wave is None:
            raise self.error(
                "data.wave_mask_m", 'is given but there is no wave file; fix: remove it or give wave = "..."'
            )
        weighted = (d.lobe is not None and s.lobe_weight > 0) or (d.wave is not None and s.wave_weight > 0)
        if not weighted:
            raise self.error(
                "solver",
                f"nothing to fit: lobe_weight = {show(s.lobe_weight)}, wave_weight = "
                f"{show(s.wave_weight)} leave no given data with a positive weight; fix: give the data a weight > 0",
            )
        if u.second_cells_per_wavelength is not None and u.second_cells_per_wavelength == m.cells_per_wavelength:
            raise self.error(
                "uncertainty.second_cells_per_wavelength",
                f"= {show(u.second_cells_per_wavelength)} equals [model] cells_per_wavelength: the refit "
                "would measure nothing; fix: give another resolution, e.g. 1.5 x",
            )


def load_config(path: str | Path) -> FitConfig:
    """Read and check a fit config file (TOML). Raises `ConfigError` (one line) for anything that
    cannot be used; issues `ConfigWarning` for legal but unwise values."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise ConfigError(f"{path}: cannot read the fit config ({e.strerror}); fix: check the path") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a text file; a fit config is TOML") from None
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: not valid TOML: {' '.join(str(e).split())}") from None
    return config_from_dict(raw, path=path)


def config_from_dict(raw: dict[str, Any], *, path: str | Path | None = None) -> FitConfig:
    """Check a parsed config (as `tomllib` returns it) into a `FitConfig`."""
    path = None if path is None else Path(path)
    names = {c.SECTION: c for c in SECTIONS}
    for k in raw:
        if k not in names:
            raise ConfigError(message(path, k, None, f"unknown section; allowed: {', '.join(names)}"))
    for required in ("data", "model"):
        if required not in raw:
            what = "the data files (lobe, wave)" if required == "data" else "at least line_length_m"
            raise ConfigError(message(path, required, None, f"section is required: give [{required}] with {what}"))
    sections = {k: parse_section(c, raw.get(k), file=path) for k, c in names.items()}
    return FitConfig(**sections, path=path)


# --------------------------------------------------------------------------------------------
# Data
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FitData:
    """The data a config names, loaded and checked: lobe and wave (or None), the files read, and
    notes on what was done with them (incomplete captures, masks, overrides) for the report."""

    lobe: Any
    wave: Any
    paths: tuple[Path, ...]
    notes: tuple[str, ...]
    frequency_hz: float
    temperature_c: float


def _resolve(cfg: FitConfig, key: str, value: str | None) -> Path:
    assert value is not None
    p = Path(value).expanduser()
    p = p if p.is_absolute() else cfg.base / p
    if not p.is_file():
        where = "not a file" if p.exists() else "not found"
        raise cfg.error(key, f"= {show(value)}: {where} ({p}); fix: paths are relative to the config file's folder")
    return p


def _capture(cfg: FitConfig, key: str, value: str | None, p: Path, notes: list[str]):
    from ..capture.errors import CaptureFileError
    from ..capture.files import describe_seqs, load_capture

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # incompleteness is reported below, once
            cap = load_capture(p, allow_incomplete=True)
    except CaptureFileError as e:
        raise cfg.error(key, f"= {show(value)} cannot be used: {e}") from None
    kind = key.split(".")[1]
    if cap.kind != kind:
        other = "wave" if kind == "lobe" else "lobe"
        raise cfg.error(
            key,
            f"= {show(value)} is a {cap.kind} capture (its header says kind: {cap.kind}); "
            f"fix: give it as {other} = {show(value)}",
        )
    n, total = len(cap.seq), cap.metadata["n_points"]
    if n == 0:
        raise cfg.error(
            key,
            f"= {show(value)} holds no points (0 of {total}); fix: capture the scan (re-run the "
            "capture command to continue it)",
        )
    if not cap.complete:
        notes.append(
            f"{p.name}: incomplete capture, fitted the {n} of {total} points present "
            f"(seq {describe_seqs(cap.missing)} missing); re-run the capture command to complete it"
        )
    return cap


def _check_agrees(
    cfg: FitConfig, key: str, given: float | None, actual: float, what: str, tol: float, unit: str
) -> None:
    if given is not None and abs(given - actual) > tol:
        raise cfg.error(
            key,
            f"= {show(given)} {unit} but {what} says {actual:g} {unit}; fix: correct it or leave it "
            "out (capture files carry their own)",
        )


def _lobe_data(cfg: FitConfig, notes: list[str]):
    from ..capture.errors import CaptureFileError
    from ..capture.files import is_capture_file, load_lobe_table
    from .data import lobe_from_capture, lobe_from_table

    d = cfg.data
    p = _resolve(cfg, "data.lobe", d.lobe)
    try:
        capture = is_capture_file(p)
    except CaptureFileError as e:
        raise cfg.error("data.lobe", f"= {show(d.lobe)} cannot be read: {e}") from None
    if capture:
        cap = _capture(cfg, "data.lobe", d.lobe, p, notes)
        _check_agrees(cfg, "data.frequency_hz", d.frequency_hz, cap.metadata["freq_hz"], p.name, 0.5, "Hz")
        _check_agrees(
            cfg, "data.range_m", d.range_m, cap.metadata["range_m"], p.name, 1e-6 + 1e-3 * cap.metadata["range_m"], "m"
        )
        if len(cap.seq) < 3:
            raise cfg.error("data.lobe", f"= {show(d.lobe)} holds only {len(cap.seq)} points; a fit needs >= 3")
        return lobe_from_capture(cap, min_sigma_db=d.lobe_sigma_db or 0.05), p, True
    try:
        table = load_lobe_table(p)
    except CaptureFileError as e:
        raise cfg.error(
            "data.lobe", f"= {show(d.lobe)} is neither a capture file nor a plain lobe table with a units header: {e}"
        ) from None
    for k, what in (
        ("frequency_hz", "the drive frequency in Hz"),
        ("range_m", "the measurement range in m"),
        ("temperature_c", "the air temperature in degC"),
        ("lobe_sigma_db", "the 1-sigma of the levels in dB"),
    ):
        if getattr(d, k) is None:
            raise cfg.error(f"data.{k}", f"is required: {p.name} is a plain table without metadata; fix: give {what}")
    assert d.frequency_hz is not None and d.range_m is not None  # checked just above
    assert d.temperature_c is not None and d.lobe_sigma_db is not None
    notes.append(
        f"{p.name}: plain lobe table ({len(table.angle_deg)} points), with frequency {d.frequency_hz:g} Hz, "
        f"range {d.range_m:g} m, {d.temperature_c:g} degC and sigma {d.lobe_sigma_db:g} dB from the config; columns {' and '.join(table.units)}"
    )
    return (
        lobe_from_table(
            table,
            frequency_hz=d.frequency_hz,
            range_m=d.range_m,
            temperature_c=d.temperature_c,
            sigma_db=d.lobe_sigma_db,
        ),
        p,
        False,
    )


def _wave_table(cfg: FitConfig, p: Path, notes: list[str]):
    """A plain wavefront table with a units header, with the metadata the config gives."""
    from ..capture.errors import CaptureFileError
    from ..capture.files import load_wave_table
    from .data import wave_from_table

    d = cfg.data
    try:
        table = load_wave_table(p)
    except CaptureFileError as e:
        raise cfg.error(
            "data.wave",
            f"= {show(d.wave)} is neither a capture file nor a plain wavefront table with a units header: {e}",
        ) from None
    for k, what in (
        ("frequency_hz", "the drive frequency in Hz"),
        ("temperature_c", "the air temperature in degC"),
        ("wave_z_m", "the scan line's distance from the face in m"),
    ):
        if getattr(d, k) is None:
            raise cfg.error(f"data.{k}", f"is required: {p.name} is a plain table without metadata; fix: give {what}")
    assert d.frequency_hz is not None and d.temperature_c is not None and d.wave_z_m is not None
    notes.append(
        f"{p.name}: plain wavefront table ({len(table.x_m)} points), with frequency {d.frequency_hz:g} Hz, "
        f"z {d.wave_z_m:g} m, {d.temperature_c:g} degC and sigma {cfg.solver.wave_sigma_deg:g} deg from the config; "
        f"columns {' and '.join(table.units)}"
    )
    wave = wave_from_table(
        table,
        frequency_hz=d.frequency_hz,
        z_m=d.wave_z_m,
        temperature_c=d.temperature_c,
        sigma_deg=cfg.solver.wave_sigma_deg,
    )
    return wave, p


def _wave_data(cfg: FitConfig, notes: list[str]):
    from ..capture.errors import CaptureFileError
    from ..capture.files import is_capture_file
    from .data import wave_from_capture

    d = cfg.data
    p = _resolve(cfg, "data.wave", d.wave)
    try:
        capture = is_capture_file(p)
    except CaptureFileError as e:
        raise cfg.error("data.wave", f"= {show(d.wave)} cannot be read: {e}") from None
    if not capture:
        return _wave_table(cfg, p, notes)
    cap = _capture(cfg, "data.wave", d.wave, p, notes)
    if d.wave_z_m is not None and len(cap.z_m):
        _check_agrees(cfg, "data.wave_z_m", d.wave_z_m, float(np.median(cap.z_m)), p.name, 1e-4, "m")
    _check_agrees(cfg, "data.frequency_hz", d.frequency_hz, cap.metadata["freq_hz"], p.name, 0.5, "Hz")
    if len(cap.seq) < 3:
        raise cfg.error("data.wave", f"= {show(d.wave)} holds only {len(cap.seq)} points; a fit needs >= 3")
    return wave_from_capture(cap, sigma_deg=cfg.solver.wave_sigma_deg), p


def load_fit_data(cfg: FitConfig) -> FitData:
    """Load and check the data `cfg` names. Raises `ConfigError` naming the key for a missing or
    unreadable file, a wave capture given as lobe (or the reverse), a plain table without the
    metadata it needs, disagreeing frequencies or ranges, no points, or a mask that leaves fewer
    than 3; issues `ConfigWarning` for a mask that excludes nothing, a floor below the data's
    dynamic range and a one-sided scan fitted with an asymmetric model."""
    from .data import mask_counts, mask_lobe, mask_wave

    d = cfg.data
    notes: list[str] = []
    paths: list[Path] = []
    lobe = wave = None
    if d.lobe is not None:
        lobe, p, is_capture = _lobe_data(cfg, notes)
        paths.append(p)
        if d.lobe_mask_deg:
            n_out = mask_counts(lobe.angle_deg, d.lobe_mask_deg)
            left = len(lobe.angle_deg) - n_out
            if left < 3:
                raise cfg.error(
                    "data.lobe_mask_deg",
                    f"= {show(d.lobe_mask_deg)} leaves {left} of "
                    f"{len(lobe.angle_deg)} lobe points; a fit needs >= 3; fix: narrow the ranges",
                )
            if n_out == 0:
                warnings.warn(
                    message(
                        cfg.path,
                        "data.lobe_mask_deg",
                        None,
                        f"= {show(d.lobe_mask_deg)} excludes no "
                        f"point of {p.name} (angles {lobe.angle_deg.min():g}..{lobe.angle_deg.max():g} deg)",
                    ),
                    ConfigWarning,
                    stacklevel=2,
                )
            lobe = mask_lobe(lobe, d.lobe_mask_deg)
            notes.append(f"{p.name}: lobe_mask_deg {show(d.lobe_mask_deg)} left out {n_out} points")
        if d.temperature_c is not None and is_capture:
            notes.append(
                f"{p.name}: temperature {d.temperature_c:g} degC from the config replaces the "
                f"capture's {lobe.temperature_c:.2f} degC"
            )
            lobe = dataclasses.replace(lobe, temperature_c=d.temperature_c)
    if d.wave is not None:
        wave, p = _wave_data(cfg, notes)
        paths.append(p)
        if d.wave_mask_m:
            n_out = mask_counts(wave.x_m, d.wave_mask_m)
            left = len(wave.x_m) - n_out
            if left < 3:
                raise cfg.error(
                    "data.wave_mask_m",
                    f"= {show(d.wave_mask_m)} leaves {left} of {len(wave.x_m)} "
                    "wavefront points; a fit needs >= 3; fix: narrow the ranges",
                )
            if n_out == 0:
                warnings.warn(
                    message(
                        cfg.path,
                        "data.wave_mask_m",
                        None,
                        f"= {show(d.wave_mask_m)} excludes no "
                        f"point of {p.name} (x {wave.x_m.min():g}..{wave.x_m.max():g} m)",
                    ),
                    ConfigWarning,
                    stacklevel=2,
                )
            wave = mask_wave(wave, d.wave_mask_m)
            notes.append(f"{p.name}: wave_mask_m {show(d.wave_mask_m)} left out {n_out} points")
        if d.temperature_c is not None:
            notes.append(
                f"{p.name}: temperature {d.temperature_c:g} degC from the config replaces the "
                f"capture's {wave.temperature_c:.2f} degC"
            )
            wave = dataclasses.replace(wave, temperature_c=d.temperature_c)
    freqs = sorted({x.frequency_hz for x in (lobe, wave) if x is not None})
    if len(freqs) > 1:
        raise cfg.error(
            "data",
            f"the lobe and wave files were captured at different frequencies {freqs} Hz; "
            "fix: fit data of one drive frequency",
        )
    temps = [x.temperature_c for x in (lobe, wave) if x is not None]
    _unwise_data_warnings(cfg, lobe, wave)
    return FitData(
        lobe=lobe,
        wave=wave,
        paths=tuple(paths),
        notes=tuple(notes),
        frequency_hz=freqs[0],
        temperature_c=float(np.mean(temps)),
    )


def _symmetric_model(m: ModelSection) -> bool:
    if m.model == "disc":  # symmetric about its axis by construction
        return True
    return all(p in ("uniform", "symmetric") or (p == "smooth" and m.symmetric) for p in (m.weights, m.lags))


def _unwise_data_warnings(cfg: FitConfig, lobe, wave) -> None:
    from .data import floor_limited_level_db, one_sided

    if lobe is not None:
        bottom = floor_limited_level_db(lobe)
        span = None if bottom is None else float(np.max(lobe.level_db)) - bottom
        if span is not None and cfg.solver.floor_db > span:
            warnings.warn(
                message(
                    cfg.path,
                    "solver.floor_db",
                    None,
                    f"= {show(cfg.solver.floor_db)} dB reaches below the data's dynamic range ({span:.1f} dB "
                    "from the peak to the noise floor or clipped bottom of the lobe data): the nulls "
                    f"there are fitted at face value; use floor_db <= {max(span - 3, 1):.0f}",
                ),
                ConfigWarning,
                stacklevel=3,
            )
    sides = [
        v
        for v in ((lobe.angle_deg if lobe is not None else None), (wave.x_m if wave is not None else None))
        if v is not None
    ]
    if sides and all(one_sided(v) for v in sides) and not _symmetric_model(cfg.model):
        warnings.warn(
            message(
                cfg.path,
                "model",
                None,
                "the data cover one side of the axis only, but the model is not symmetric (weights = "
                f"{show(cfg.model.weights)}, lags = {show(cfg.model.lags)}, symmetric = "
                f"{show(cfg.model.symmetric)}): its other half is not determined; use symmetric profiles",
            ),
            ConfigWarning,
            stacklevel=3,
        )


# --------------------------------------------------------------------------------------------
# Running
# --------------------------------------------------------------------------------------------


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def provenance(config_path: Path | None, data_paths: list[Path] | tuple[Path, ...]) -> dict:
    """Package versions, git commit, machine, device and SHA-256 of the config and data files."""
    import equinox
    import jax
    import optimistix

    from .. import __version__

    try:
        commit = (
            subprocess.run(
                ["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5, cwd=Path(__file__).parent
            ).stdout.strip()
            or None
        )
    except (OSError, subprocess.SubprocessError):
        commit = None
    return {
        "difflattice": __version__,
        "versions": {
            "python": sys.version.split()[0],
            "jax": jax.__version__,
            "equinox": equinox.__version__,
            "optimistix": optimistix.__version__,
            "numpy": np.__version__,
        },
        "git_commit": commit,
        "machine": platform.machine(),
        "device": str(jax.devices()[0]),
        "config_sha256": _sha256(config_path) if config_path else None,
        "data_sha256": {str(p): _sha256(p) for p in data_paths},
        "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }


def fit_options(cfg: FitConfig):
    """The solver's `FitOptions` for `cfg`. The robust-loss and convergence keys are passed on
    where this version's `FitOptions` accepts them; a non-default value it does not accept gives
    a `ConfigWarning`."""
    from .solve import FitOptions

    s = cfg.solver
    kw: dict[str, Any] = dict(
        solver=s.name,
        rtol=s.rtol,
        atol=s.atol,
        max_steps=s.max_steps,
        floor_db=s.floor_db,
        lobe_weight=s.lobe_weight,
        wave_weight=s.wave_weight,
    )
    accepted = {f.name for f in dataclasses.fields(FitOptions)}
    newer = {"loss": s.loss, "loss_scale": s.loss_scale, "rtol_cost": s.rtol_cost, "rtol_step": s.rtol_step}
    defaults = {sp.name: sp.default for sp in specs(SolverSection)}
    for k, v in newer.items():
        if k in accepted:
            kw[k] = v
        elif v != defaults[k]:
            warnings.warn(
                message(
                    cfg.path, f"solver.{k}", None, f"= {show(v)} is ignored: this version's solver does not support it"
                ),
                ConfigWarning,
                stacklevel=2,
            )
    try:
        return FitOptions(**kw)
    except ValueError as e:
        raise cfg.error("solver", str(e)) from None


def _warn_unused_uncertainty(cfg: FitConfig) -> None:
    """[uncertainty] is declared for the error budget (`fit.uncertainty`); where this version has
    no such module, a key that is set is said to be unused rather than silently ignored."""
    import importlib.util

    u = cfg.uncertainty
    given = {
        k: v
        for k, v in (
            ("second_cells_per_wavelength", u.second_cells_per_wavelength),
            ("model_families", u.model_families),
        )
        if v not in (None, ())
    }
    if given and importlib.util.find_spec("difflattice.fit.uncertainty") is None:
        for k, v in given.items():
            warnings.warn(
                message(
                    cfg.path,
                    f"uncertainty.{k}",
                    None,
                    f"= {show(v)} is not used: this version has no uncertainty budget (fit.uncertainty)",
                ),
                ConfigWarning,
                stacklevel=3,
            )


def _fit_line(cfg: FitConfig, lobe, wave, f: float, c: float, ppw: float, opts, verbose: bool, prefetch):
    """The line model's transfer, fit and untuned uniform fit: (fitted, uniform, transfer,
    make_transfer(cells_per_wavelength), transfer time in s). `prefetch`: a resolution (cells per
    wavelength) whose transfer the error budget will ask for, simulated beside the fit (or None)."""
    from .model import ModelSpec
    from .solve import fit
    from .transfer import free_field_transfer

    m = cfg.model
    dx = c / (f * ppw)
    n_cells = int(round(m.line_length_m / dx))
    if n_cells < 3:
        raise cfg.error(
            "model.line_length_m",
            f"= {show(m.line_length_m)} m is {n_cells} cells at {ppw:g} cells per "
            f"wavelength ({dx * 1e3:.2f} mm); the line needs >= 3 cells; fix: give the face length in metres",
        )

    def simulate_transfer(cpw: float):
        return free_field_transfer(
            frequency_hz=f,
            c_m_s=c,
            n_cells=int(round(m.line_length_m / (c / (f * cpw)))),
            cells_per_wavelength=cpw,
            lobe_angle_deg=None if lobe is None else lobe.angle_deg,
            lobe_range_m=None if lobe is None else (m.lobe_range_m or lobe.range_m),
            wave_x_m=None if wave is None else wave.x_m,
            wave_z_m=None if wave is None else wave.z_m,
        )

    t0 = time.perf_counter()
    transfer = simulate_transfer(ppw)
    t_transfer = time.perf_counter() - t0
    make_transfer = _Prefetched(simulate_transfer, prefetch)
    try:
        spec = ModelSpec(
            n_cells=n_cells,
            dx_m=dx,
            frequency_hz=f,
            weights=cast(Any, m.weights),  # checked against PROFILES by the declaration
            lags=cast(Any, m.lags),
            n_basis=m.n_basis,
            symmetric=m.symmetric,
            fit_diameter=m.fit_diameter,
            diameter_m=m.diameter_m,
        )
    except ValueError as e:
        raise cfg.error("model", str(e)) from None
    # a given diameter is the start of a fitted one (no scan over diameters)
    params0 = spec.init_params() if (m.fit_diameter and m.diameter_m is not None) else None
    fitted = fit(spec, transfer, lobe, wave, opts, progress=verbose, params0=params0, multistart=True)
    uspec = ModelSpec(
        n_cells=n_cells,
        dx_m=dx,
        frequency_hz=f,
        weights="uniform",
        lags="uniform",
        fit_diameter=False,
        diameter_m=m.diameter_m or m.line_length_m,
    )
    uniform = fit(uspec, transfer, lobe, wave, opts)
    return fitted, uniform, transfer, make_transfer, t_transfer


class _Prefetched:
    """`make_transfer` with the transfer at one resolution (`cells_per_wavelength`; None: none)
    simulated in a background thread from now on: the error budget's second resolution runs while
    the main fit traces its programs (one core each; the native kernels and XLA release the GIL).
    A call for that resolution waits for the thread and returns its result (or raises its error)."""

    def __init__(self, make, cells_per_wavelength: float | None):
        import concurrent.futures

        self.make = make
        self.cpw = cells_per_wavelength
        self.future = None
        if cells_per_wavelength is not None:
            pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="difflattice-prefetch")
            self.future = pool.submit(make, cells_per_wavelength)
            pool.shutdown(wait=False)

    def __call__(self, cells_per_wavelength: float):
        if self.future is not None and cells_per_wavelength == self.cpw:
            return self.future.result()
        return self.make(cells_per_wavelength)


def _fit_disc(cfg: FitConfig, lobe, wave, f: float, c: float, ppw: float, opts, verbose: bool, prefetch):
    """The disc model's (`fit.disc`) transfer on the axisymmetric lattice, fit and untuned uniform
    piston fit, as `_fit_line`; `line_length_m` is the modelled disc's diameter."""
    from .solve import fit
    from .transfer_disc import disc_setup

    m = cfg.model
    t0 = time.perf_counter()
    try:
        setup = disc_setup(
            frequency_hz=f,
            c_m_s=c,
            face_diameter_m=m.line_length_m,
            cells_per_wavelength=ppw,
            lobe=lobe,
            wave=wave,
            lobe_range_m=m.lobe_range_m,
            weights=m.weights,
            lags=m.lags,
            n_basis=m.n_basis,
            fit_diameter=m.fit_diameter,
            diameter_m=m.diameter_m,
            baffle=m.baffle,
            can_depth_m=m.can_depth_m,
            can_wall_m=m.can_wall_m,
            stencil=cast(Any, m.stencil),  # checked against the choices by the declaration
        )
    except ValueError as e:
        raise cfg.error("model", str(e)) from None
    t_transfer = time.perf_counter() - t0
    make_transfer = _Prefetched(setup.make_transfer, prefetch)
    spec, transfer = setup.spec, cast(Any, setup.transfer)  # a DiscTransfer: the interface of a Transfer
    params0 = spec.init_params() if (m.fit_diameter and m.diameter_m is not None) else None
    fitted = fit(spec, transfer, lobe, wave, opts, progress=verbose, params0=params0, multistart=True)
    uniform = fit(setup.uniform_spec, transfer, lobe, wave, opts)
    return fitted, uniform, transfer, make_transfer, t_transfer


def run_fit(cfg: FitConfig, *, out: str | Path | None = None, quick: bool = False, verbose: bool = True) -> dict:
    """Run a checked config; returns the report dict (also written to the output dir).

    Data problems are `ConfigError`s naming the key (see `load_fit_data`). Uses the JAX precision
    the caller set (float64 expected; see the module docstring)."""
    import jax

    if not jax.config.read("jax_enable_x64"):
        warnings.warn(
            "run_fit: JAX runs in float32 (jax_enable_x64 is off); fits expect float64: call "
            "jax.config.update('jax_enable_x64', True) at start-up",
            RuntimeWarning,
            stacklevel=2,
        )
    from .report import start_figures, write_report

    data = load_fit_data(cfg)
    lobe, wave, f = data.lobe, data.wave, data.frequency_hz
    air_used = fit_air(cfg, data)
    c = air_used["speed_of_sound_m_s"]
    if verbose:
        print(
            f"air: {air_used['temperature_c']:.2f} degC, {air_used['humidity_pct']:g} % RH, "
            f"{air_used['pressure_pa']:.0f} Pa -> c = {c:.2f} m/s (from {air_used['source']})"
        )
    m = cfg.model
    ppw = 12.0 if quick else m.cells_per_wavelength
    opts = fit_options(cfg)
    _warn_unused_uncertainty(cfg)
    fit_model = _fit_disc if m.model == "disc" else _fit_line
    # the error budget's second resolution (as `error_budget` picks it), simulated beside the fit
    from .uncertainty import error_budget, second_resolution

    m2 = second_resolution(ppw, None if quick else cfg.uncertainty.second_cells_per_wavelength)
    fitted, uniform, transfer, make_transfer, t_transfer = fit_model(cfg, lobe, wave, f, c, ppw, opts, verbose, m2)
    fitted.warnings[:0] = [f"data: {n}" for n in data.notes]
    out_dir = Path(out) if out is not None else Path(cfg.output.dir)
    # the figures that do not need the error budget are drawn in a worker process meanwhile
    field_image = cfg.output.field_image and not quick  # a line on the 2-D lattice, a disc on the rz lattice
    figures = start_figures(out_dir, fitted, uniform, transfer, lobe, wave, field_image=field_image)
    # error budget (fit.uncertainty): refits at a second resolution and with other model families
    t1 = time.perf_counter()
    try:
        budget = error_budget(
            fitted,
            transfer,
            lobe,
            wave,
            opts,
            make_transfer=make_transfer,
            second_cells_per_wavelength=None if quick else cfg.uncertainty.second_cells_per_wavelength,
            model_families=list(cfg.uncertainty.model_families) or None,
            progress=verbose,
        )
    except BaseException:
        figures.close()
        raise
    t_budget = time.perf_counter() - t1
    prov = provenance(cfg.path if cfg.path is not None and cfg.path.exists() else None, data.paths)
    prov["timing_s"] = {
        "transfer_simulation": t_transfer,
        "fit": fitted.wall_time_s,
        "total_to_fit": t_transfer + fitted.wall_time_s,
        "error_budget": t_budget,
    }
    prov["quick"] = quick
    prov["temperature_c"] = data.temperature_c
    prov["speed_of_sound_m_s"] = c
    prov["air"] = air_used
    prov["data_notes"] = list(data.notes)
    rep = write_report(
        out_dir,
        fitted,
        uniform,
        transfer,
        lobe,
        wave,
        provenance=prov,
        field_image=field_image,
        budget=budget,
        figures=figures,
    )
    if verbose:
        _print_summary(rep, out_dir)
    return rep


def _print_summary(rep: dict, out_dir: Path) -> None:
    f = rep["fit"]
    verdict = f["outcome"]
    if verdict["outcome"] != "consistent":
        print("!" * 72 + f"\n!! {verdict['line']}\n" + "!" * 72)
    for w in f["warnings"]:
        print(f"warning: {w}")
    p = f["parameters"]
    units = {"lobe_db": "dB", "wave_phase_deg": "deg"}
    rms = ", ".join(
        f"{k} {v:.3g} {units.get(k, '')}".rstrip()
        for k, v in f["rms"].items()
        if "normalised" not in k and "all_points" not in k
    )
    t = rep["provenance"]["timing_s"]
    d = next((e for e in rep.get("budget", {}).get("scalars", []) if e["name"] == "diameter_mm"), None)
    dtxt = (
        f"{p['diameter_m'] * 1e3:.3f} (fixed)"
        if d is None
        else f"{d['limit']} ({d['status']})"
        if d["status"] == "at_bound"
        else f"{d['value']:.3f} ({d['status']}: {d['note']})"
        if d["status"] != "determined"
        else f"{d['value']:.4g} ± {d['stat']:.2g} (stat) ± {d['systematic']:.2g} (sys) = ± {d['total']:.2g}"
    )
    print(
        f"fit: {f['result_code']} in {f['n_steps']} steps; D = {dtxt} mm; RMS {rms}; {_chi2_text(f)}; "
        f"transfer {t['transfer_simulation']:.1f} s + fit {t['fit']:.1f} s + error budget {t.get('error_budget', 0):.1f} s"
    )
    for u in rep.get("budget", {}).get("undetermined", []):
        print(f"not determined by the data: {u}")
    print(f"report: {out_dir / 'report.md'}")
    print(f"{verdict['outcome'].replace('_', ' ')} (exit {verdict['exit_code']}): {verdict['line']}")


def _chi2_text(f: dict) -> str:
    """'chi2_red 0.98 (p 0.61; lobe 1.0, wave 0.93)': per measured datum, joint and per data set."""
    g = f.get("goodness") or {}
    j = g.get("joint")
    if j is None:
        return f"chi2_red {f['chi2_reduced']:.3g}"
    sets = ", ".join(f"{k} {g[k]['chi2_reduced']:.3g}" for k in ("lobe", "wave") if k in g)
    return f"chi2_red {j['chi2_reduced']:.3g} (p {j['p']:.2g}; {sets})"


def run_fit_config(path: str | Path, *, out=None, quick: bool = False) -> int:
    """`difflattice fit`: load, run, report; exit code 0 (converged and consistent with the data),
    3 (did not converge) or 4 (converged, but the model does not describe the data): see
    `fit.verdict`."""
    cfg = load_config(path)
    rep = run_fit(cfg, out=out, quick=quick)
    return int(rep["fit"]["outcome"]["exit_code"])


def config_markdown() -> str:
    """The fit config's key tables (docs/fitting.md), generated from the declarations above."""
    from ..config import markdown_tables

    return markdown_tables(SECTIONS)
