"""Reproducible fits: a typed TOML config (data, model, solver, uncertainty, output) run by one command.

    .venv/bin/difflattice fit fitting/polaroid_like.toml

`load_config(path)` reads and checks a file into a `FitConfig` (frozen, typed; its sections are
declared once below, and docs/fitting.md's key tables are generated from the declarations);
every impossible value is a one-line `ConfigError` naming the file, the key, the value, what is
allowed and the fix, and legal but unwise values give a `ConfigWarning`. `fit.loading.load_fit_data`
loads a config's data (capture files, complete or not, or plain tables; masks; checks against the
config); `apps.fitting.run_fit(cfg)` runs the whole fit (transfer, stages, error budget, report
with provenance: package versions, the git commit and SHA-256 hashes of the config and data).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from ..config import ConfigError, Section, message, parse_section, setting, show

PROFILES = ("uniform", "free", "symmetric", "smooth")  # fit.model.PROFILES (not imported: no JAX here)
DISC_PROFILES = (*PROFILES, "rim_taper")  # fit.disc.DISC_PROFILES; a disc takes "symmetric" as "free"
SOLVERS = ("levenberg_marquardt", "dogleg", "gauss_newton", "bfgs")  # fit.solve.SOLVERS
LOSSES = ("l2", "huber", "cauchy")
BAFFLES = ("rigid", "none", "can")  # solver.sources.BAFFLES (not imported: no JAX here)
MIN_FIT_CELLS_PER_WAVELENGTH = 8.0
"""Below this a fit's transfer simulation carries a phase error large enough to bias the fitted
parameters (docs/accuracy.md); it is allowed, with a warning."""


def lobe_mask_setting(doc: str) -> Any:
    """The `[data] lobe_mask_deg` declaration (angle ranges left out of a fit), with its `doc`:
    one declaration for the fit configs and the housed ones."""
    return setting(
        [],
        kind="list",
        items="range",
        ge=-180,
        le=180,
        unit="deg",
        doc=doc,
        fix="give [[lo, hi], ...] in degrees with lo < hi",
    )


def wave_mask_setting(doc: str) -> Any:
    """The `[data] wave_mask_m` declaration (wavefront position ranges left out of a fit)."""
    return setting([], kind="list", items="range", unit="m", doc=doc, fix="give [[lo, hi], ...] in metres with lo < hi")


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
    lobe_mask_deg: tuple = lobe_mask_setting(
        "angle ranges [lo, hi] left out of the fit (inclusive), e.g. [[-90, -60], [60, 90]]"
    )
    wave_mask_m: tuple = wave_mask_setting("positions x ranges [lo, hi] left out of the fit (inclusive)")
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


# --------------------------------------------------------------------------------------------
# Running
# --------------------------------------------------------------------------------------------


def config_markdown() -> str:
    """The fit config's key tables (docs/fitting.md), generated from the declarations above."""
    from ..config import markdown_tables

    return markdown_tables(SECTIONS)
