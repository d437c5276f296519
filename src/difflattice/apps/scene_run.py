"""Run a scene end to end: simulate with a progress bar, derive observables, write outputs.

The CLI's `simulate` is a thin layer over `run_scene` + `write_outputs`, one entry for every lattice
kind (3-D runs are `scene3d_run`'s).
"""

from __future__ import annotations

import json
import math
import platform
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from .. import __version__
from ..lattice.grid import Grid
from ..observe.analytic import phase_error_rad
from ..observe.farfield import level_db
from ..observe.observables import lobe_metrics
from ..scene.model import Scene
from ..solver.loop import INSTABILITY_MESSAGE, Result, run_pieces
from ..solver.stepper import Stepper

if TYPE_CHECKING:  # a plane or rz run never imports the 3-D runner
    from .scene3d_run import SceneRun3D


@dataclass
class SceneRun:
    """A finished scene run. `snapshots` are the fields every `snapshot_every_steps`, already
    thinned to every `render_every`-th cell (what the images show; no full-resolution history is
    kept); `moments` maps each `[output]` show step to the full-resolution field at that step."""

    scene: Scene
    grid: Grid
    stepper: Stepper
    result: Result
    summary: dict
    lobe: tuple[np.ndarray, np.ndarray] | None
    snapshots: list
    snapshot_steps: list
    moments: dict = field(default_factory=dict)
    render_every: int = 1


def _piece_ends(n_steps: int, seg: int, snapshot_every: int | None, moments) -> list[int]:
    """Steps at which the chunked run stops: every `seg` steps, at n_steps, at each moment, and
    (after a moment) at the next snapshot step, so that snapshots stay on multiples of
    `snapshot_every`."""
    ends = set(range(seg, n_steps, seg)) | {n_steps}
    for m in moments:
        ends.add(int(m))
        if snapshot_every:
            ends.add(min(n_steps, -(-int(m) // snapshot_every) * snapshot_every))
    return sorted(e for e in ends if 1 <= e <= n_steps)


def run_in_pieces(
    stepper: Stepper,
    n_steps: int,
    *,
    segments: int = 20,
    progress: bool = True,
    checkpoint=None,
    moments=(),
    render_every: int = 1,
):
    """Run in `segments` compiled pieces so a progress bar can update between them (the kernel
    itself is untouched). Pieces also end at each step of `moments`, whose full-resolution fields
    are kept. Snapshots are thinned to every `render_every`-th cell as they arrive.

    While the first piece compiles the bar says so ("simulate (compiling)"): the first run of a
    scene on a machine pauses there for seconds. A piece of a length not seen before includes its
    compilation; the pieces of a length seen before give the throughput without it.

    Returns (result of the last piece with merged probes, snapshots, their steps, timing,
    {moment step: field}); timing holds "first_segment_incl_compile_s", "steady_steps" and
    "steady_s" (the pieces without compilation) and "compile_s" (the rest of the time, less what
    those steps would take at the steady rate; None when no piece length repeated)."""
    from tqdm import tqdm

    if render_every < 1:
        raise ValueError(f"render_every = {render_every} must be >= 1 cell")
    seg = max(1, math.ceil(n_steps / segments))
    k = stepper.sensors.snapshot_every
    if k:
        seg = max(k, (seg // k) * k)
    wanted = set(int(m) for m in moments)
    bad = [m for m in wanted if not 1 <= m <= n_steps]
    if bad:
        raise ValueError(f"moments {sorted(bad)} lie outside steps 1..{n_steps}")
    ends = _piece_ends(n_steps, seg, k, wanted)
    pieces = run_pieces(stepper, ends, checkpoint=checkpoint)  # the solver's piece loop
    probes, snaps, snap_steps, peaks = [], [], [], []
    kept = {}
    done = 0
    first_time = None
    seen: set[int] = set()
    fresh_steps, fresh_s, steady_steps, steady_s = 0, 0.0, 0, 0.0
    bar = tqdm(total=n_steps, unit="step", disable=not progress, desc="simulate (compiling)")
    t0 = time.perf_counter()
    for end, res in zip(ends, pieces):
        n = end - done
        dt = time.perf_counter() - t0
        if first_time is None:
            first_time = dt
            bar.set_description("simulate")
        if n in seen:
            steady_steps, steady_s = steady_steps + n, steady_s + dt
        else:
            seen.add(n)
            fresh_steps, fresh_s = fresh_steps + n, fresh_s + dt
        state = res.final
        if res.probes is not None:
            probes.append(res.probes)
        if k is not None and res.snapshots is not None:  # snapshots are recorded only when `k` is set
            for f, s in zip(np.asarray(res.snapshots), res.chunk_steps):
                step = done + s
                if step % k == 0 or step == n_steps:  # not the extra frame a moment's piece ends with
                    snaps.append(np.array(f[::render_every, ::render_every]))
                    snap_steps.append(step)
        peaks.append(res.peak_history)
        done = end
        if end in wanted:
            kept[end] = np.asarray(state.pressure)
        bar.update(n)
        if not np.all(np.isfinite(peaks[-1])):
            bar.close()
            raise FloatingPointError(f"{INSTABILITY_MESSAGE} (detected by step {done})")
        t0 = time.perf_counter()
    bar.close()
    import dataclasses

    # the merged record covers all n_steps: probes and peaks concatenated, RMS over the whole run
    merged = dataclasses.replace(
        res,
        probes=jnp.concatenate(probes) if probes else None,
        peak_history=jnp.concatenate(peaks),
        p_rms=None if res.final.p_sq is None else jnp.sqrt(res.final.p_sq / n_steps),
        n_steps=n_steps,
    )
    timing = {
        "first_segment_incl_compile_s": first_time,
        "steady_steps": steady_steps,
        "steady_s": steady_s,
        "compile_s": max(0.0, fresh_s - fresh_steps * steady_s / steady_steps) if steady_steps else None,
    }
    return merged, snaps, snap_steps, timing, kept


def run_scene(
    scene: Scene, *, progress: bool = True, available_bytes: int | None = None, mlups: float | None = None
) -> SceneRun | SceneRun3D:
    """Run a scene of any lattice kind: the one entry (`write_outputs` writes what it returns).

    Plane and rz scenes run in pieces (progress bar, field moments, snapshots; `SceneRun`); 3-D
    scenes print their estimate first and run with A-scans of the receiving transducers
    (`scene3d_run.run_scene3d`: `available_bytes` and `mlups` are the estimate's memory limit and
    assumed throughput; `SceneRun3D`). Every scene is estimated before any grid-sized array."""
    if scene.kind.ndim == 3:
        from .scene3d_run import run_scene3d

        return run_scene3d(scene, available_bytes=available_bytes, mlups=mlups, quiet=not progress)
    return _run_plane(scene, progress=progress)


def _run_plane(scene: Scene, *, progress: bool) -> SceneRun:
    """A plane or rz scene's run (see `run_scene`)."""
    built = scene.build()
    grid, medium, sources, sensors, edges, n_steps = built[:6]
    stepper = Stepper.build(grid, medium, sources, sensors, edges)
    checkpoint = None if scene.run.checkpoint == "none" else "sqrt"
    t0 = time.perf_counter()
    every = built.render_every
    result, snaps, snap_steps, timing, moments = run_in_pieces(
        stepper, n_steps, progress=progress, checkpoint=checkpoint, moments=built.show_steps, render_every=every
    )
    wall = time.perf_counter() - t0
    nx, ny = grid.shape
    dist_cells = min(grid.courant * n_steps, math.hypot(nx, ny))
    dist_wl = dist_cells / grid.cells_per_wavelength
    perr = phase_error_rad(grid.cells_per_wavelength, grid.courant, dist_wl, stencil=grid.stencil)
    summary = {
        "difflattice_version": __version__,
        "scene": scene.path,
        "grid": grid.describe(),
        "medium": {
            "boundary_model": medium.boundary_model,
            "homogeneous": medium.is_homogeneous,
            "absorption_db_per_m": medium.absorption_db_per_m,
        },
        "edges": {s: getattr(edges, s) for s in ("x_lo", "x_hi", "y_lo", "y_hi")}
        | {"thickness_cells": edges.thickness_cells},
        "run": {
            "n_steps": n_steps,
            "duration_s": n_steps * grid.dt_s,
            "wall_time_s": wall,
            "first_segment_incl_compile_s": timing["first_segment_incl_compile_s"],
            "compile_s": timing["compile_s"],
            "mlups": nx * ny * n_steps / wall / 1e6,
            "mlups_excl_compile": nx * ny * timing["steady_steps"] / timing["steady_s"] / 1e6
            if timing["steady_s"] > 0
            else None,
            "note": "mlups: over the whole run, compilation included; mlups_excl_compile: over the pieces "
            "that did not compile (compile_s: the rest of the time less those steps at that rate)",
            "device": str(jax.devices()[0]),
            "machine": platform.machine(),
            "backend": result.backend,
            "backend_why_not": dict(result.backend_why_not),
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
    contour, ff = built.contour, scene.farfield
    if contour is not None and ff is not None:  # a contour is built exactly when the scene has [farfield]
        a0, a1, da = ff.angles_deg
        angles = np.arange(a0, a1 + da / 2, da)
        disp = {} if ff.dispersion is None else {"dispersion": ff.dispersion}
        # the kind's surface: angles from axis 0 towards axis 1, at the range from the transducer
        t, src = scene.transducers[built.farfield_source], sources[built.farfield_source]
        centre = contour.lobe_centre_cells(src.cells_array, t.centre_m, grid.dx_m)
        p = contour.far_field(result.phasors, grid, angles, range_m=ff.range_m, centre_cells=centre, **disp)
        lv = np.asarray(level_db(p, floor_db=-100))
        lobe = (angles, lv)
        summary["farfield"] = {"range_m": ff.range_m, "dispersion": ff.dispersion, **lobe_metrics(angles, lv)}
    summary["output"] = {
        "render_every_cells": every,
        "pixels_per_wavelength": grid.cells_per_wavelength / every,
        "show_steps": sorted(moments),
    }
    return SceneRun(scene, grid, stepper, result, summary, lobe, snaps, snap_steps, moments, every)


def _mirror_rz(field):
    """An rz field (nz, nr) as the full meridian section (nz, 2 nr): r < 0 mirrored, axis at the middle."""
    f = np.asarray(field)
    return np.concatenate([f[:, ::-1], f], axis=1)


def write_outputs(
    sr: SceneRun | SceneRun3D,
    out_dir: str | Path,
    *,
    animate: bool = True,
    frames: bool | None = None,
    animation: str | None = None,
    data_format: str = "npz",
) -> dict[str, str | list[str]]:
    """Write summary.json, the sensor data and images into `out_dir`; returns the paths.

    Data: sensors.npz (`data_format` "npz") or sensors.nc ("netcdf": NetCDF-4 for xarray / h5py,
    coordinates in m and s, units as attributes; see `apps.datafiles`), and the CSV tables
    probes.csv (t_s, probe_<i>_pa) and lobe.csv (angle_deg, level_db) where recorded.

    Images: field.png (last step), moment_<step>.png per `[output]` show step, peak_level.png,
    lobe.png, probes.png, and for snapshots frames/frame_NNNN.png (unless `frames` is False) and
    an animation (`animation`: "gif", "mp4" or "none"; `animate=False` is "none"). `frames` and
    `animation` default to the scene's `[output]` section. Field images render every
    `sr.render_every`-th cell. A 3-D run (`SceneRun3D`) writes its own set
    (`scene3d_run.write_outputs3d`: A-scans, echo labels, slices and projections)."""
    if not isinstance(sr, SceneRun):
        from .scene3d_run import write_outputs3d

        return write_outputs3d(sr, out_dir, data_format=data_format)
    from ..scene.model import ANIMATION_KINDS
    from . import datafiles

    datafiles.check_format(data_format)
    if frames is None:
        frames = sr.scene.output.frames
    if animation is None:
        animation = sr.scene.output.animation
    if animation not in ANIMATION_KINDS:
        raise ValueError(f"animation = {animation!r}; allowed: {', '.join(ANIMATION_KINDS)}")
    if not animate:
        animation = "none"
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = _write_data(sr, out, data_format)
    files |= _write_images(sr, out, frames=bool(frames), animation=animation)
    sr.summary["files"] = files
    (out / "summary.json").write_text(json.dumps(sr.summary, indent=2, default=_json_default))
    files["summary"] = str(out / "summary.json")
    return files


def _write_data(sr: SceneRun, out: Path, data_format: str) -> dict[str, str | list[str]]:
    """sensors.npz / sensors.nc and the CSV tables (probes, lobe)."""
    from . import datafiles

    g = sr.grid
    res = sr.result
    st = sr.stepper
    files: dict[str, str | list[str]] = {}
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
    if data_format == "netcdf":
        files["sensors"] = str(datafiles.netcdf_2d(sr, arrays, out / "sensors.nc"))
    else:
        # numpy's stub also matches `**arrays` against `allow_pickle: bool`; every value here is an array
        np.savez_compressed(out / "sensors.npz", **arrays)  # type: ignore[arg-type]
        files["sensors"] = str(out / "sensors.npz")
    if res.probes is not None and len(st.sensors.probes):
        t = (np.arange(len(res.probes)) + 1) * g.dt_s
        cols = {"t_s": t} | {f"probe_{i}_pa": c for i, c in enumerate(np.asarray(res.probes).reshape(len(t), -1).T)}
        files["probes_csv"] = str(datafiles.write_csv(out / "probes.csv", cols))
    if sr.lobe is not None:
        files["lobe_csv"] = str(
            datafiles.write_csv(out / "lobe.csv", {"angle_deg": sr.lobe[0], "level_db": sr.lobe[1]})
        )

    return files


def _write_images(sr: SceneRun, out: Path, *, frames: bool, animation: str) -> dict[str, str | list[str]]:
    """field.png, the moments, peak level, lobe and probe plots, frames and the animation."""
    from .. import plots

    g = sr.grid
    res = sr.result
    st = sr.stepper
    every = sr.render_every
    files: dict[str, str | list[str]] = {}
    obst = obstacle_map(st)
    src_cells = [s.cells_array for s in st.sources]
    mirrored = g.kind.mirrored_view  # rz: show the whole meridian section, r from -R to R
    view = _mirror_rz if mirrored else (lambda f: f)
    size_m = (g.size_m[0], (2 if mirrored else 1) * g.size_m[1])
    labels = g.kind.axis_labels()
    look: dict[str, Any] = {"axis_labels": labels, "origin_m": (0.0, -g.size_m[1] if mirrored else 0.0)}
    if mirrored:
        nr = g.shape[1]
        obst = None if obst is None else _mirror_rz(obst)
        src_cells = [np.concatenate([c[:, :1], nr + c[:, 1:]], axis=1) for c in src_cells] + [
            np.concatenate([c[:, :1], nr - 1 - c[:, 1:]], axis=1) for c in src_cells
        ]
    n_steps = sr.summary["run"]["n_steps"]
    fig = plots.field_image(
        view(res.final.pressure),
        g.dx_m,
        every=every,
        step=n_steps,
        dt_s=g.dt_s,
        obstacles=obst,
        sources=src_cells,
        **look,
    )
    files["field"] = str(plots.save(fig, out / "field.png"))
    if sr.moments:
        moment_files = []
        for step, f in sorted(sr.moments.items()):
            fig = plots.field_image(
                view(f), g.dx_m, every=every, step=step, dt_s=g.dt_s, obstacles=obst, sources=src_cells, **look
            )
            moment_files.append(str(plots.save(fig, out / f"moment_{step:06d}.png")))
        files["moments"] = moment_files
    if res.p_max is not None:
        files["peak_level"] = str(
            plots.save(plots.level_image(view(res.p_max), g.dx_m, sources=src_cells, **look), out / "peak_level.png")
        )
    if sr.lobe is not None:
        a, lv = sr.lobe
        files["lobe"] = str(plots.save(plots.lobe_plots(a, {"model": lv}), out / "lobe.png"))
    if res.probes is not None and len(st.sensors.probes):
        t = (np.arange(len(res.probes)) + 1) * g.dt_s
        fig = plots.time_series_plot(t, res.probes, [f"probe {i}" for i in range(len(st.sensors.probes))])
        files["probes"] = str(plots.save(fig, out / "probes.png"))
    if sr.snapshots:
        # snapshots are already thinned to every `every`-th cell: draw each as one pixel per sample
        if frames:
            for k, (f, s) in enumerate(zip(sr.snapshots, sr.snapshot_steps)):
                plots.save(
                    plots.field_image(
                        view(f),
                        g.dx_m,
                        every=1,
                        step=s,
                        dt_s=g.dt_s,
                        obstacles=obst,
                        sources=src_cells,
                        size_m=size_m,
                        **look,
                    ),
                    out / "frames" / f"frame_{k:04d}.png",
                )
            files["frames"] = str(out / "frames")
        if animation != "none":
            files["animation"] = str(
                plots.animate(
                    [view(f) for f in sr.snapshots],
                    sr.snapshot_steps,
                    g.dx_m,
                    g.dt_s,
                    out / f"animation.{animation}",
                    every=1,
                    obstacles=obst,
                    sources=src_cells,
                    size_m=size_m,
                    **look,
                )
            )
    return files


def obstacle_map(stepper) -> np.ndarray | None:
    """Occupancy of the obstacles (1 inside) for outlines in images, or None."""
    lat = stepper.lattice
    if lat.keep is not None:
        return 1 - np.asarray(lat.keep)
    if lat.bx is not None:
        return _closed_cells(lat)
    return None


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
