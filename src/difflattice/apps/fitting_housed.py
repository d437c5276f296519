"""`difflattice fit` for a housed-transducer config (`fit.housed_config`): load the datasheet
record (and a measured wavefront, where `[data] wave` names one: fitted jointly with the lobe),
fit the family ladder (or one family) by gradient through the rz lattice, and write
report.json and report.md: the families side by side, the chosen one and why, its geometry beside
the can's outline, and the provenance of the data (the record's source, the files' SHA-256)."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any, cast

from ..config import ConfigError
from ..fit.housed_config import HousedConfig, housed_lobe, load_housed_config, load_housed_wave


def _family_rows(ladder) -> list[dict]:
    """The families' summaries, each with its lobe residual per angle (model - data, dB)."""
    out = []
    for row, f in zip(ladder.table(), ladder.fits.values(), strict=True):
        row = {k: (v if not isinstance(v, float) or math.isfinite(v) else str(v)) for k, v in row.items()}
        row["residual_db"] = [float(v) for v in f.residual_db]
        out.append(row)
    return out


def _not_converged_line(ladder) -> str:
    """A line naming the families whose fit stopped at its iteration limit (the table's values and
    errors for them are where it stopped, not a minimum)."""
    names = [name for name, f in ladder.fits.items() if not f.converged]
    if not names:
        return ""
    return (
        f"\nNot converged (stopped at the iteration limit; their rows are where they stopped, not minima): "
        f"{', '.join(names)}.\n"
    )


def run_housed(cfg: HousedConfig, *, out: str | Path | None = None, quick: bool = False, verbose: bool = True) -> dict:
    """Run a checked housed-fit config; returns the report dict (also written as report.json and
    report.md in the output dir). `quick`: 12 cells per wavelength and no resolution term."""
    import warnings

    import jax

    if not jax.config.read("jax_enable_x64"):  # the CLI sets it (`apps.jaxconfig.configure`)
        warnings.warn(
            "run_housed: JAX runs in float32 (jax_enable_x64 is off); housed fits run the lattice in float64: "
            "call jax.config.update('jax_enable_x64', True) at start-up",
            RuntimeWarning,
            stacklevel=2,
        )
    from ..fit.datasheet import load_datasheet
    from ..fit.housed import HousedSpec, Housing
    from ..fit.ladder import Ladder, choose_family, family_ladder, fit_housed
    from ..fit.verdict import EXIT_CONSISTENT, EXIT_INADEQUATE, EXIT_NOT_CONVERGED, GOODNESS_P_MIN
    from .provenance import provenance

    sheet = load_datasheet(cfg.datasheet_path)
    lobe, lobe_notes = housed_lobe(cfg, sheet)  # refuses a record without a table, naming the fix
    wave, wave_notes = load_housed_wave(cfg, sheet.frequency_hz)
    wave_path = None if cfg.data.wave is None else cfg.base / Path(cfg.data.wave).expanduser()
    table = sheet.table or {}
    h, m = cfg.housing, cfg.model
    housing = Housing(
        outer_diameter_m=h.outer_diameter_m,
        length_m=h.length_m,
        wall_m=h.wall_m,
        plate_m=h.plate_m,
        back=cast(Any, h.back),
        front=cast(Any, h.front),
    )
    cpw = 12.0 if quick else m.cells_per_wavelength
    res_cpw = None if quick else m.resolution_cells_per_wavelength
    spec = HousedSpec(
        housing=housing,
        frequency_hz=sheet.frequency_hz,
        c_m_s=m.speed_of_sound_m_s,
        cells_per_wavelength=cpw,
        family="flat" if m.family == "ladder" else m.family,
        diaphragm_m=m.diaphragm_m,
        recess_m=m.recess_m,
        opening_m=m.opening_m,
        fixed=tuple(m.fixed),
    )
    t0 = time.perf_counter()
    try:
        if m.family == "ladder":
            ladder = family_ladder(spec, lobe, wave=wave, resolution_cpw=res_cpw)
        else:
            f = fit_housed(spec, lobe, wave=wave, resolution_cpw=res_cpw)
            chosen, reason = choose_family({m.family: f})
            ladder = Ladder({m.family: f}, chosen, reason)
    except ValueError as e:
        if wave is not None and str(e).startswith("wave_z_m"):  # `HousedForward`: the line meets the can
            raise ConfigError(f"{cfg.path}: [data.wave_z_m] {e}") from None
        raise
    wall_s = time.perf_counter() - t0
    best = ladder.fits[ladder.chosen]
    p = best.goodness.get("joint" if wave is not None else "lobe", {}).get("p", 0.0)
    if not best.converged or best.ill_conditioned:
        code = EXIT_NOT_CONVERGED
    elif p < GOODNESS_P_MIN:
        code = EXIT_INADEQUATE
    else:
        code = EXIT_CONSISTENT
    out_dir = (
        Path(out) if out is not None else Path(cfg.output.dir)
    )  # as `apps.fitting`: relative to the working directory
    out_dir.mkdir(parents=True, exist_ok=True)
    rep = {
        "device": sheet.part,
        "datasheet": {"path": str(sheet.path), "source": sheet.source, "table_method": table["method"]},
        "housing_outline_mm": {
            "outer_diameter": 1e3 * h.outer_diameter_m,
            "length": 1e3 * h.length_m,
            "bore": 1e3 * (h.outer_diameter_m - 2 * h.wall_m),
        },
        "housing_front": h.front,
        "lobe_notes": list(lobe_notes),
        "wavefront": None
        if wave is None
        else {
            "path": str(wave_path),
            "points": len(wave.x_m),
            "z_m": wave.z_m,
            "sigma_deg": cfg.solver.wave_sigma_deg,
            "notes": list(wave_notes),
            "rms_deg": best.rms_wave_deg,
            "residual_deg": None if best.wave_residual_deg is None else [float(v) for v in best.wave_residual_deg],
        },
        "goodness": best.goodness,
        "chosen_lobe": {  # the chosen family's lobe against the data, per angle
            "angle_deg": [float(v) for v in lobe.angle_deg],
            "data_db": [float(v) for v in lobe.level_db],
            "model_db": [float(v) for v in best.model_db],
            "residual_db": [float(v) for v in best.residual_db],
        },
        "families": _family_rows(ladder),
        "chosen": ladder.chosen,
        "reason": ladder.reason,
        "chosen_errors_statistical": best.errors_statistical,
        "chosen_errors_resolution": best.errors_resolution,
        "exit_code": code,
        "cells_per_wavelength": cpw,
        "resolution_cells_per_wavelength": res_cpw,
        "wall_time_s": wall_s,
        "provenance": provenance(cfg.path, [sheet.path] + ([wave_path] if wave_path is not None else [])),
    }
    (out_dir / "report.json").write_text(json.dumps(rep, indent=2, default=str))
    o = rep["housing_outline_mm"]
    md = (
        f"# Housed fit: {sheet.part}\n\nData: {sheet.source['document']}, {sheet.source['revision']}, "
        f"{sheet.source['location']} (digitised: {table['method']}, sigma {table['sigma_db']} dB)"
        + "".join(f"; {n}" for n in lobe_notes)
        + ".\n\n"
        f"Outline: can {o['outer_diameter']:.2f} mm across, {o['length']:.2f} mm long, bore {o['bore']:.2f} mm.\n\n"
        + (
            ""
            if wave is None
            else f"Wavefront (fitted with the lobe): {'; '.join(wave_notes)}. Chosen family: wavefront RMS "
            f"{best.rms_wave_deg:.3g} deg, joint chi-square probability {p:.3g}.\n\n"
        )
        + ladder.markdown()
        + _not_converged_line(ladder)
        + f"\nExit code {code} ({cpw:g} cells per wavelength).\n"
    )
    (out_dir / "report.md").write_text(md)
    if verbose:
        print(md)
    return rep


def run_housed_config(path: str | Path, *, out=None, quick: bool = False) -> int:
    """`difflattice fit` of a housed config: exit code as `fit.verdict` (0, 3 or 4)."""
    rep = run_housed(load_housed_config(path), out=out, quick=quick)
    return int(rep["exit_code"])
