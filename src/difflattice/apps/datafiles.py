"""Data files a scene run writes beside its images: CSV tables and a NetCDF file.

CSV: one plain header row of column names that carry their unit (`t_s`, `probe_0_pa`), then
numbers, comma-separated; `pandas.read_csv(path)` reads it as is. NetCDF (`sensors.nc`, HDF5
underneath, written through xarray + h5netcdf): every variable with its dimensions, coordinates
in SI units and `units` / `long_name` attributes, so `xarray.open_dataset` or `h5py.File` show
what each number is.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

NETCDF_HINT = "pip install 'difflattice[netcdf]' (xarray and h5netcdf)"


def write_csv(path: str | Path, columns: dict[str, Any]) -> Path:
    """A CSV table: `columns` maps a column name (with its unit, e.g. "t_s") to a 1-D array;
    all the same length. A plain header row, no comment lines."""
    if not columns:
        raise ValueError(f"{path}: no columns to write")
    names = list(columns)
    bad = [n for n in names if "," in n or '"' in n or "\n" in n]
    if bad:
        raise ValueError(f"{path}: column names {bad} contain a comma, quote or line break")
    data = [np.asarray(columns[n], dtype=float).reshape(-1) for n in names]
    lengths = {len(d) for d in data}
    if len(lengths) != 1:
        raise ValueError(f"{path}: columns of different lengths {[len(d) for d in data]}")
    path = Path(path)
    np.savetxt(path, np.column_stack(data), delimiter=",", header=",".join(names), comments="", fmt="%.9g")
    return path


def column_name(label: str, unit: str) -> str:
    """A CSV column name from a free label and a unit: lower case, spaces and punctuation as
    underscores, the unit last (`column_name("probe 0", "pa")` -> "probe_0_pa")."""
    keep = "".join(c if c.isalnum() else "_" for c in label.strip().lower())
    while "__" in keep:
        keep = keep.replace("__", "_")
    return f"{keep.strip('_')}_{unit}"


def have_netcdf() -> bool:
    """Whether xarray and the h5netcdf engine are installed (`--format netcdf` needs both)."""
    try:
        import h5netcdf  # noqa: F401
        import xarray  # noqa: F401
    except ImportError:
        return False
    return True


def check_format(data_format: str) -> None:
    """Refuse an unknown data format, or netcdf without its packages, before any work."""
    if data_format not in ("npz", "netcdf"):
        raise ValueError(f"data format {data_format!r}; allowed: 'npz', 'netcdf'")
    if data_format == "netcdf" and not have_netcdf():
        raise ModuleNotFoundError(f"--format netcdf needs xarray and h5netcdf: {NETCDF_HINT}")


def write_netcdf(path: str | Path, variables: dict[str, tuple], coords: dict[str, tuple], attrs: dict) -> Path:
    """Write `sensors.nc`: `variables` maps a name to (dims, array, units, long_name); `coords`
    maps a dimension to (array, units, long_name); `attrs` are the file's global attributes
    (numbers and strings). Written by xarray with the h5netcdf engine (NetCDF-4, an HDF5 file)."""
    import xarray as xr

    ds = xr.Dataset(
        {
            name: xr.Variable(dims, np.asarray(a), attrs={"units": units, "long_name": long})
            for name, (dims, a, units, long) in variables.items()
        },
        coords={
            name: xr.Variable((name,), np.asarray(a), attrs={"units": units, "long_name": long})
            for name, (a, units, long) in coords.items()
        },
        attrs={k: v for k, v in attrs.items() if isinstance(v, (int, float, str))},
    )
    path = Path(path)
    ds.to_netcdf(path, engine="h5netcdf")
    return path


def cell_coords(grid, names: str) -> dict[str, tuple]:
    """Cell-centre coordinates, metres, per axis of a field on `grid` (`Grid.coordinates_m`;
    `names`: "xy", "zr" or "xyz", one letter per axis)."""
    return {n: (a, "m", f"{n} of the cell centre") for n, a in zip(names, grid.coordinates_m(), strict=True)}


def netcdf_2d(sr, arrays: dict, path: Path) -> Path:
    """sensors.nc of a 2-D or rz run (`apps.scene_run.SceneRun`): the arrays of sensors.npz with their dimensions,
    coordinates (cell centres in m, time in s, probe positions in m, lobe angles in deg) and units."""
    g = sr.grid
    names = "".join(g.kind.axis_names)
    n_steps = int(sr.summary["run"]["n_steps"])
    coords: dict[str, tuple] = cell_coords(g, names)
    if "probes_pa" in arrays:
        coords["t"] = ((np.arange(len(arrays["probes_pa"])) + 1) * g.dt_s, "s", "time at the end of each step")
    field = (names[0], names[1])
    dims = {
        "peak_history_pa": ("chunk",),
        "final_field_pa": field,
        "p_max_pa": field,
        "p_rms_pa": field,
        "arrival_step": field,
    }
    text = {
        "peak_history_pa": ("Pa", "largest |pressure| in the window at the end of each chunk of steps"),
        "final_field_pa": ("Pa", f"pressure at the last step ({n_steps})"),
        "p_max_pa": ("Pa", "peak |pressure| over the run"),
        "p_rms_pa": ("Pa", "RMS pressure over the run"),
        "arrival_step": ("1", "first step at which |pressure| passed the arrival threshold (-1: never)"),
    }
    variables = {k: (dims[k], arrays[k], *text[k]) for k in dims if k in arrays}
    if "probes_pa" in arrays:
        cells = np.asarray(arrays["probe_cells"], float)
        coords["probe"] = (np.arange(len(cells)), "1", "probe index ([sensors] probes_m order)")
        variables["probes_pa"] = (("t", "probe"), arrays["probes_pa"], "Pa", "pressure at each probe")
        for i, n in enumerate(names):
            pos = (cells[:, i] + g.origin_cells) * g.dx_m
            variables[f"probe_{n}_m"] = (("probe",), pos, "m", f"{n} of the probe's cell centre")
    if "lobe_angle_deg" in arrays:
        coords["angle"] = (arrays["lobe_angle_deg"], "deg", "far-field angle from the source's axis")
        variables["lobe_level_db"] = (("angle",), arrays["lobe_level_db"], "dB", "far-field level re its maximum")
    attrs = {
        "title": f"difflattice scene run: {sr.scene.path}",
        "difflattice_version": sr.summary["difflattice_version"],
        "grid_kind": g.kind,
        "dx_m": g.dx_m,
        "dt_s": g.dt_s,
        "frequency_hz": g.frequency_hz,
        "cells_per_wavelength": g.cells_per_wavelength,
    }
    return write_netcdf(path, variables, coords, attrs)


def netcdf_3d(sr, arrays: dict, path: Path) -> Path:
    """sensors.nc of a 3-D run (`apps.scenes3d.SceneRun3D`): the arrays of sensors.npz with dimensions, coordinates (cell
    centres in m, time in s) and units; snapshot planes as (snapshot step, a, b)."""
    g = sr.grid
    coords: dict[str, tuple] = cell_coords(g, "xyz")
    n_t = len(arrays["probes_pa"]) if "probes_pa" in arrays else int(sr.summary["run"]["n_steps"])
    coords["t"] = ((np.arange(n_t) + 1) * g.dt_s, "s", "time at the end of each step")
    variables: dict[str, tuple] = {
        "peak_history_pa": (
            ("chunk",),
            arrays["peak_history_pa"],
            "Pa",
            "largest |pressure| in the window at the end of each chunk of steps",
        )
    }
    for key, long, unit in (
        ("p_max_pa", "peak |pressure| over the run", "Pa"),
        ("p_rms_pa", "RMS pressure over the run", "Pa"),
        ("arrival_step", "first step at which |pressure| passed the arrival threshold (-1: never)", "1"),
    ):
        if key in arrays:
            variables[key] = (("x", "y", "z"), arrays[key], unit, long)
    if "probes_pa" in arrays:
        cells = np.asarray(arrays["probe_cells"], float)
        coords["probe"] = (np.arange(len(cells)), "1", "probe index (probes_m, then the receivers' cells)")
        variables["probes_pa"] = (("t", "probe"), arrays["probes_pa"], "Pa", "pressure at each probe")
        for i, n in enumerate("xyz"):
            variables[f"probe_{n}_m"] = (("probe",), (cells[:, i] + g.origin_cells) * g.dx_m, "m", f"probe {n}")
    for name in sr.a_scans:
        variables[f"a_scan_{name}"] = (
            ("t",),
            arrays[f"a_scan_{name}"],
            "Pa x cell weight",
            f"A-scan of {name!r}: weighted sum of the pressure over its cells",
        )
    if "snapshot_steps" in arrays:
        coords["snapshot"] = (np.asarray(arrays["snapshot_steps"]) * g.dt_s, "s", "time of each snapshot")
        for key, a in arrays.items():
            if key.startswith("snapshots_"):
                axis = "xyz".index(key[len("snapshots_")])
                a_name, b_name = (n for n in "xyz" if n != "xyz"[axis])
                variables[key] = (("snapshot", a_name, b_name), a, "Pa", f"pressure on the plane {key[10:-3]}")
    attrs = {
        "title": f"difflattice 3-D scene run: {sr.scene.path}",
        "difflattice_version": sr.summary["difflattice_version"],
        "grid_kind": "3d",
        "dx_m": g.dx_m,
        "dt_s": g.dt_s,
        "frequency_hz": g.frequency_hz,
        "cells_per_wavelength": g.cells_per_wavelength,
    }
    return write_netcdf(path, variables, coords, attrs)
