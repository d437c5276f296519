"""Reproducible fits: a TOML config (data files, model, solver, output) run by one command.

    difflattice fit fitting/polaroid.toml

The report records package versions, the git commit and SHA-256 hashes of the config and data,
so a re-run can be checked against it (`tests/fit/test_reproducible.py` re-runs a config and
compares the numbers).
"""

from __future__ import annotations

import hashlib
import json
import math
import platform
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

from ..scene.schema import NUM, REQUIRED, ConfigError, schema_markdown, validate_table

SCHEMA = {
    "data": {
        "lobe": (str, None, "lobe capture file (CSV from `difflattice capture lobe`), relative to the config"),
        "wave": (str, None, "wavefront capture file (CSV from `difflattice capture wave`)"),
    },
    "model": {
        "line_length_m": (NUM, REQUIRED, "length of the modelled line of source cells, m (>= the largest diameter to try)"),
        "diameter_m": (NUM, None, "initial active diameter, m (default: a scan)"),
        "cells_per_wavelength": (NUM, 20.0, "lattice resolution of the transfer simulation"),
        "weights": (str, "smooth", "uniform, free, symmetric or smooth"),
        "lags": (str, "smooth", "uniform, free, symmetric or smooth"),
        "n_basis": (int, 4, "number of smooth basis functions per profile"),
        "symmetric": (bool, True, "smooth profiles use even polynomials only"),
        "fit_diameter": (bool, True, "fit the active diameter"),
        "lobe_range_m": (NUM, None, "range at which the lobe is modelled, m (default: the file's range_m; "
                                    "use e.g. 1000 for data that are a Fraunhofer pattern)"),
    },
    "solver": {
        "name": (str, "levenberg_marquardt", "levenberg_marquardt, dogleg, gauss_newton or bfgs"),
        "max_steps": (int, 200, "iteration limit"),
        "rtol": (NUM, 1e-7, "relative tolerance"),
        "atol": (NUM, 1e-7, "absolute tolerance"),
        "floor_db": (NUM, 40.0, "lobe residual floor below the measured peak, dB"),
        "lobe_weight": (NUM, 1.0, "weight of the lobe residuals"),
        "wave_weight": (NUM, 1.0, "weight of the wavefront residuals"),
        "wave_sigma_deg": (NUM, 1.0, "1-sigma of the measured phase, deg"),
    },
    "output": {
        "dir": (str, "out/fit", "report directory, relative to the working directory"),
        "field_image": (bool, True, "simulate and render the fitted transducer's field"),
    },
}


def load_config(path: str | Path) -> dict:
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except OSError as e:
        raise ConfigError(f"{path}: cannot read the fit config ({e.strerror})") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: not valid TOML: {e}") from None
    for k in data:
        if k not in SCHEMA:
            raise ConfigError(f"{path}: [{k}] unknown section; allowed: {', '.join(SCHEMA)}")
    cfg = {s: validate_table(path, SCHEMA[s], data.get(s, {}), s) for s in SCHEMA}
    if not cfg["data"]["lobe"] and not cfg["data"]["wave"]:
        raise ConfigError(f"{path}: [data] give a lobe file, a wave file or both")
    cfg["_path"] = str(path)
    cfg["_base"] = path.resolve().parent
    return cfg


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def provenance(config_path: Path | None, data_paths: list[Path]) -> dict:
    import equinox
    import jax
    import optimistix

    from .. import __version__

    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5,
                                cwd=Path(__file__).parent).stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        commit = None
    return {
        "difflattice": __version__,
        "versions": {"python": sys.version.split()[0], "jax": jax.__version__, "equinox": equinox.__version__,
                     "optimistix": optimistix.__version__, "numpy": np.__version__},
        "git_commit": commit,
        "machine": platform.machine(),
        "device": str(jax.devices()[0]),
        "config_sha256": _sha256(config_path) if config_path else None,
        "data_sha256": {str(p): _sha256(p) for p in data_paths},
        "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }


def run_fit(cfg: dict, *, out: str | Path | None = None, quick: bool = False, verbose: bool = True) -> dict:
    """Run a validated config; returns the report dict (also written to the output dir)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from ..capture.files import load_capture
    from .data import lobe_from_capture, wave_from_capture
    from .model import ModelSpec
    from .report import write_report
    from .solve import FitOptions, fit
    from .transfer import free_field_transfer

    base = cfg["_base"]
    paths = []
    lobe = wave = None
    if cfg["data"]["lobe"]:
        p = base / cfg["data"]["lobe"]
        paths.append(p)
        lobe = lobe_from_capture(load_capture(p))
    if cfg["data"]["wave"]:
        p = base / cfg["data"]["wave"]
        paths.append(p)
        wave = wave_from_capture(load_capture(p), sigma_deg=cfg["solver"]["wave_sigma_deg"])
    freqs = {d.frequency_hz for d in (lobe, wave) if d is not None}
    if len(freqs) > 1:
        raise ConfigError(f"{cfg['_path']}: [data] the files were captured at different frequencies {sorted(freqs)} Hz")
    f = freqs.pop()
    temps = [d.temperature_c for d in (lobe, wave) if d is not None]
    t_c = float(np.mean(temps))
    c = 331.3 * math.sqrt(1 + t_c / 273.15)
    m = cfg["model"]
    ppw = 12.0 if quick else m["cells_per_wavelength"]
    dx = c / (f * ppw)
    n_cells = int(round(m["line_length_m"] / dx))
    t0 = time.perf_counter()
    transfer = free_field_transfer(
        frequency_hz=f, c_m_s=c, n_cells=n_cells, cells_per_wavelength=ppw,
        lobe_angle_deg=None if lobe is None else lobe.angle_deg, lobe_range_m=None if lobe is None else (m["lobe_range_m"] or lobe.range_m),
        wave_x_m=None if wave is None else wave.x_m, wave_z_m=None if wave is None else wave.z_m,
    )
    t_transfer = time.perf_counter() - t0
    s = cfg["solver"]
    try:
        spec = ModelSpec(n_cells=n_cells, dx_m=dx, frequency_hz=f, weights=m["weights"], lags=m["lags"], n_basis=m["n_basis"],
                         symmetric=m["symmetric"], fit_diameter=m["fit_diameter"], diameter_m=m["diameter_m"])
        opts = FitOptions(solver=s["name"], rtol=s["rtol"], atol=s["atol"], max_steps=s["max_steps"], floor_db=s["floor_db"],
                          lobe_weight=s["lobe_weight"], wave_weight=s["wave_weight"])
    except ValueError as e:
        raise ConfigError(f"{cfg['_path']}: {e}") from None
    fitted = fit(spec, transfer, lobe, wave, opts, progress=verbose)
    uspec = ModelSpec(n_cells=n_cells, dx_m=dx, frequency_hz=f, weights="uniform", lags="uniform", fit_diameter=False,
                      diameter_m=m["diameter_m"] or m["line_length_m"])
    uniform = fit(uspec, transfer, lobe, wave, opts)
    prov = provenance(Path(cfg["_path"]) if cfg.get("_path") and Path(cfg["_path"]).exists() else None, paths)
    prov["timing_s"] = {"transfer_simulation": t_transfer, "fit": fitted.wall_time_s, "total_to_fit": t_transfer + fitted.wall_time_s}
    prov["quick"] = quick
    prov["temperature_c"] = t_c
    prov["speed_of_sound_m_s"] = c
    out_dir = Path(out) if out is not None else Path(cfg["output"]["dir"])
    rep = write_report(out_dir, fitted, uniform, transfer, lobe, wave, provenance=prov,
                       field_image=cfg["output"]["field_image"] and not quick)
    if verbose:
        _print_summary(rep, out_dir)
    return rep


def _print_summary(rep: dict, out_dir: Path) -> None:
    f = rep["fit"]
    if not f["converged"]:
        print("!" * 72 + f"\n!! FIT DID NOT CONVERGE: {f['result_code']} after {f['n_steps']} steps\n" + "!" * 72)
    for w in f["warnings"]:
        print(f"warning: {w}")
    p = f["parameters"]
    rms = ", ".join(f"{k} {v:.3g}" for k, v in f["rms"].items() if "normalised" not in k and "all_points" not in k)
    t = rep["provenance"]["timing_s"]
    print(f"fit: {f['result_code']} in {f['n_steps']} steps; D = {p['diameter_m'] * 1e3:.2f} ± {p['diameter_stderr_m'] * 1e3:.2f} mm; "
          f"RMS {rms}; chi2_red {f['chi2_reduced']:.3g}; transfer {t['transfer_simulation']:.1f} s + fit {t['fit']:.1f} s")
    print(f"report: {out_dir / 'report.md'}")


def run_fit_config(path: str | Path, *, out=None, quick: bool = False) -> int:
    cfg = load_config(path)
    rep = run_fit(cfg, out=out, quick=quick)
    return 0 if rep["fit"]["converged"] else 3


def config_markdown() -> str:
    return schema_markdown(SCHEMA)
