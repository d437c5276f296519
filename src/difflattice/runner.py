"""Run a scene end to end: simulate with a progress bar, derive observables, write outputs.

The CLI's `simulate` is a thin layer over `run_scene` + `write_outputs`.
"""

from __future__ import annotations

import json
import math
import platform
import time
from dataclasses import dataclass
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import __version__
from .analytic import phase_error_rad
from .farfield import far_field, level_db
from .observables import lobe_metrics
from .scene import Scene
from .solver import INSTABILITY_MESSAGE, Result, Stepper, run


@dataclass
class SceneRun:
    scene: Scene
    grid: object
    stepper: Stepper
    result: Result
    summary: dict
    lobe: tuple[np.ndarray, np.ndarray] | None
    snapshots: list
    snapshot_steps: list


def run_chunked(stepper: Stepper, n_steps: int, *, segments: int = 20, progress: bool = True, checkpoint=None):
    """Run in `segments` compiled pieces so a progress bar can update between them (the kernel
    itself is untouched). Returns (result of the last piece with merged probes, snapshots, steps,
    compile+first-segment time)."""
    from tqdm import tqdm

    seg = max(1, math.ceil(n_steps / segments))
    if stepper.sensors.snapshot_every:
        k = stepper.sensors.snapshot_every
        seg = max(k, (seg // k) * k)
    runner = eqx.filter_jit(lambda st, s, n: run(s, n, state=st, checkpoint=checkpoint))
    state = stepper.init()
    probes, snaps, snap_steps, peaks = [], [], [], []
    done = 0
    first_time = None
    bar = tqdm(total=n_steps, unit="step", disable=not progress, desc="simulate")
    while done < n_steps:
        n = min(seg, n_steps - done)
        t0 = time.perf_counter()
        res = runner(state, stepper, n)
        jax.block_until_ready(res.peak_history)
        if first_time is None:
            first_time = time.perf_counter() - t0
        state = res.final
        if res.probes is not None:
            probes.append(np.asarray(res.probes))
        if res.snapshots is not None:
            snaps += list(np.asarray(res.snapshots))
            snap_steps += [done + s for s in res.chunk_steps]
        peaks.append(np.asarray(res.peak_history))
        done += n
        bar.update(n)
        if not np.all(np.isfinite(peaks[-1])):
            bar.close()
            raise FloatingPointError(f"{INSTABILITY_MESSAGE} (detected by step {done})")
    bar.close()
    import dataclasses

    # the merged record covers all n_steps: probes and peaks concatenated, RMS over the whole run
    merged = dataclasses.replace(
        res,
        probes=np.concatenate(probes) if probes else None,
        peak_history=np.concatenate(peaks),
        p_rms=None if res.final.p_sq is None else np.sqrt(np.asarray(res.final.p_sq) / n_steps),
        n_steps=n_steps,
    )
    return merged, snaps, snap_steps, first_time


def run_scene(scene: Scene, *, progress: bool = True) -> SceneRun:
    grid, medium, sources, sensors, edges, n_steps, extras = scene.build()
    if grid.dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    stepper = Stepper.build(grid, medium, sources, sensors, edges)
    checkpoint = None if scene.run["checkpoint"] == "none" else "sqrt"
    t0 = time.perf_counter()
    result, snaps, snap_steps, first = run_chunked(stepper, n_steps, progress=progress, checkpoint=checkpoint)
    wall = time.perf_counter() - t0
    nx, ny = grid.shape
    dist_cells = min(grid.courant * n_steps, math.hypot(nx, ny))
    dist_wl = dist_cells / grid.cells_per_wavelength
    perr = phase_error_rad(grid.cells_per_wavelength, grid.courant, dist_wl)
    summary = {
        "difflattice_version": __version__,
        "scene": scene.path,
        "grid": {
            "shape": list(grid.shape), "dx_m": grid.dx_m, "dt_s": grid.dt_s,
            "size_m": list(grid.size_m), "frequency_hz": grid.frequency_hz,
            "cells_per_wavelength": grid.cells_per_wavelength, "courant": grid.courant,
            "steps_per_period": grid.steps_per_period, "dtype": grid.dtype,
        },
        "medium": {"boundary_model": medium.boundary_model, "homogeneous": medium.is_homogeneous,
                   "absorption_db_per_m": medium.absorption_db_per_m},
        "edges": {s: getattr(edges, s) for s in ("x_lo", "x_hi", "y_lo", "y_hi")} | {"thickness_cells": edges.thickness_cells},
        "run": {
            "n_steps": n_steps, "duration_s": n_steps * grid.dt_s, "wall_time_s": wall,
            "first_segment_incl_compile_s": first,
            "mlups": nx * ny * n_steps / wall / 1e6,
            "device": str(jax.devices()[0]), "machine": platform.machine(),
        },
        "stability": {
            "finite": bool(np.all(np.isfinite(result.peak_history))),
            "peak_pa": float(np.max(result.peak_history)),
            "final_peak_pa": float(result.peak_history[-1]),
        },
        "accuracy": {
            "farthest_distance_m": dist_cells * grid.dx_m,
            "farthest_distance_wavelengths": dist_wl,
            "expected_phase_error_rad": perr,
            "expected_phase_error_periods": perr / (2 * math.pi),
            "note": "worst direction, from the discrete dispersion relation; above ~0.05 periods "
                    "arrival times and interference patterns at that distance are not trustworthy: "
                    "raise cells_per_wavelength",
        },
    }
    lobe = None
    contour = extras["contour"]
    if contour is not None:
        ff = scene.farfield
        a0, a1, da = ff["angles_deg"]
        angles = np.arange(a0, a1 + da / 2, da)
        src = sources[extras["farfield_source"]]
        centre = tuple(src.cells_array.mean(0))
        p = far_field(result.phasors, contour, grid, angles, ff["range_m"], centre)
        lv = np.asarray(level_db(p, floor_db=-100))
        lobe = (angles, lv)
        summary["farfield"] = {"range_m": ff["range_m"], **lobe_metrics(angles, lv)}
    return SceneRun(scene, grid, stepper, result, summary, lobe, snaps, snap_steps)


def write_outputs(sr: SceneRun, out_dir: str | Path, *, animate: bool = True) -> dict:
    """Write summary.json, sensors.npz and images (PNG, GIF) into `out_dir`; returns the paths."""
    from . import plots

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    g = sr.grid
    res = sr.result
    st = sr.stepper
    files = {}
    arrays = {"peak_history_pa": np.asarray(res.peak_history), "final_field_pa": np.asarray(res.final.pressure)}
    if res.probes is not None:
        arrays["probes_pa"] = np.asarray(res.probes)
        arrays["probe_cells"] = np.asarray(st.sensors.probes)
    if res.p_max is not None:
        arrays["p_max_pa"] = np.asarray(res.p_max)
    if res.p_rms is not None:
        arrays["p_rms_pa"] = np.asarray(res.p_rms)
    if res.arrival is not None:
        arrays["arrival_step"] = np.asarray(res.arrival)
    if sr.lobe is not None:
        arrays["lobe_angle_deg"], arrays["lobe_level_db"] = sr.lobe
    np.savez_compressed(out / "sensors.npz", **arrays)
    files["sensors"] = str(out / "sensors.npz")

    lat = st.lattice
    obst = None
    if lat.keep is not None:
        obst = 1 - np.asarray(lat.keep)
    elif lat.bx is not None:
        obst = _closed_cells(lat)
    src_cells = [s.cells_array for s in st.sources]
    fig = plots.field_image(res.final.pressure, g.dx_m, step=res.n_steps if not sr.snapshot_steps else sr.summary["run"]["n_steps"],
                            dt_s=g.dt_s, obstacles=obst, sources=src_cells)
    files["field"] = str(plots.save(fig, out / "field.png"))
    if res.p_max is not None:
        files["peak_level"] = str(plots.save(plots.level_image(res.p_max, g.dx_m, sources=src_cells), out / "peak_level.png"))
    if sr.lobe is not None:
        a, lv = sr.lobe
        files["lobe"] = str(plots.save(plots.lobe_plots(a, {"model": lv}), out / "lobe.png"))
    if res.probes is not None and len(st.sensors.probes):
        t = (np.arange(len(res.probes)) + 1) * g.dt_s
        fig = plots.time_series_plot(t, res.probes, [f"probe {i}" for i in range(len(st.sensors.probes))])
        files["probes"] = str(plots.save(fig, out / "probes.png"))
    if sr.snapshots:
        for k, (f, s) in enumerate(zip(sr.snapshots, sr.snapshot_steps)):
            plots.save(plots.field_image(f, g.dx_m, step=s, dt_s=g.dt_s, obstacles=obst, sources=src_cells), out / "frames" / f"frame_{k:04d}.png")
        files["frames"] = str(out / "frames")
        if animate:
            files["animation"] = str(plots.animate(sr.snapshots, sr.snapshot_steps, g.dx_m, g.dt_s, out / "animation.gif", obstacles=obst, sources=src_cells))
    sr.summary["files"] = files
    (out / "summary.json").write_text(json.dumps(sr.summary, indent=2, default=_json_default))
    files["summary"] = str(out / "summary.json")
    return files


def _closed_cells(lat) -> np.ndarray:
    """Cells whose faces are all closed (rigid obstacles in the conservative form)."""
    bx, by = np.asarray(lat.bx), np.asarray(lat.by)
    closed = (bx[:-1] == 0) & (bx[1:] == 0) & (by[:, :-1] == 0) & (by[:, 1:] == 0)
    return closed.astype(float)


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
