"""Running a 3-D scene file and writing its outputs (`difflattice simulate` on a kind = "3d"
scene): the estimate printed before the run, the compiled time loop, the A-scans of the
receiving transducers with their echoes labelled by image-source delays (`echoes3d`), planes,
projections and the summary. Split from `scenes3d` (the pulse-echo scene tables)."""

from __future__ import annotations

import contextlib
import json
import math
import os
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from ..lattice.grid import Grid
from ..scene.model import BuiltScene, Scene, SceneError, SceneTooLargeError
from ..solver.loop import Result
from ..solver.sensors import received_signal


@dataclass
class SceneRun3D:
    """A finished 3-D scene run: the scene, what it built, the result, the A-scans of its
    receiving transducers ({name: (t_s, a_scan)}) and the summary."""

    scene: Scene
    built: BuiltScene
    result: Result
    a_scans: dict
    summary: dict

    @property
    def grid(self) -> Grid:
        return self.built.grid


def _peak_memory_bytes() -> dict:
    """The process's peak memory: the accelerator's peak bytes in use where JAX reports them,
    and the host's peak resident set (ru_maxrss) always."""
    import resource

    import jax

    out: dict[str, Any] = {"host_peak_rss_bytes": int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024}
    d = jax.devices()[0]
    if d.platform != "cpu":
        stats = d.memory_stats() or {}
        if "peak_bytes_in_use" in stats:
            out["device_peak_bytes"] = int(stats["peak_bytes_in_use"])
    return out


@contextlib.contextmanager
def _refusal(scene: Scene):
    """A run that does not fit (`RunTooLargeError`) as the scene's refusal, naming the file."""
    from ..solver.estimate import RunTooLargeError

    try:
        yield
    except RunTooLargeError as err:
        raise SceneTooLargeError(f"{scene.path}: [grid] {' '.join(str(err).split())}") from None


def run_scene3d(
    scene: Scene, *, available_bytes: int | None = None, mlups: float | None = None, quiet: bool = False
) -> SceneRun3D:
    """Build and run a 3-D scene: the estimate (memory, and time from the measured throughput or
    `mlups`) is printed to stderr before the run (unless `quiet`) and kept in the summary; a run
    that would not fit in `available_bytes` (default: this machine's available memory) is refused
    with `SceneTooLargeError`. Returns the run with the A-scans of the receiving transducers."""
    import equinox as eqx
    import jax

    from .. import __version__
    from ..observe.analytic3d import lattice_wavenumber_3d
    from ..solver.estimate import (
        check_compiled,
        check_fits,
        estimate_run,
        features_of,
        format_estimate,
    )
    from ..solver.loop import check_result, run
    from ..solver.stepper import Stepper

    if scene.kind.ndim != 3:
        raise SceneError(f'{scene.path}: [grid.kind] = {scene.grid.kind!r}; run_scene3d runs kind = "3d" scenes')
    t0 = time.perf_counter()
    built = scene.build(available_bytes=available_bytes)
    grid, n_steps = built.grid, built.n_steps
    stepper = Stepper.build(grid, built.medium, built.sources, built.sensors, built.edges)
    shape = tuple(grid.shape)
    feats = features_of(stepper, n_steps, mlups=mlups)
    nbytes, secs = estimate_run(shape, n_steps, grid.dtype, feats)
    line = format_estimate(shape, n_steps, nbytes, secs)
    if not quiet:
        print(line, file=sys.stderr, flush=True)
    with _refusal(scene):
        check_fits(shape, n_steps, nbytes, available=available_bytes, seconds=secs)
    build_s = time.perf_counter() - t0

    t1 = time.perf_counter()
    if not quiet:
        print("compiling the 3-D time loop (seconds; cached for the next run) ...", file=sys.stderr, flush=True)

    def whole_run(st):
        return check_result(run(st, n_steps), st)

    jitted: Any = eqx.filter_jit(whole_run)
    compiled = jitted.lower(stepper).compile()
    compile_s = time.perf_counter() - t1
    with _refusal(scene):  # XLA's figure for what the run allocates when it starts, against the memory now
        xla_bytes = check_compiled(compiled, shape, n_steps, available=available_bytes)
    if not quiet:
        print(f"compiled in {compile_s:.1f} s; running {n_steps} steps ...", file=sys.stderr, flush=True)
    t2 = time.perf_counter()
    result = compiled(stepper)
    jax.block_until_ready(result.peak_history)
    run_s = time.perf_counter() - t2
    wall = time.perf_counter() - t1
    memory = _peak_memory_bytes()

    a_scans, receivers = _a_scans(built, grid, result, n_steps)

    dist_cells = min(grid.courant * n_steps, math.sqrt(sum(n * n for n in shape)))
    omega = grid.omega
    k0 = omega / grid.courant
    k_axis, k_diag = (
        float(lattice_wavenumber_3d(omega, grid.courant, d, stencil=grid.stencil)) for d in ((1, 0, 0), (1, 1, 1))
    )
    perr = max(abs(k_axis - k0), abs(k_diag - k0)) * dist_cells
    edges = built.edges
    summary = {
        "difflattice_version": __version__,
        "scene": scene.path,
        "grid": grid.describe(),
        "medium": {
            "boundary_model": built.medium.boundary_model,
            "homogeneous": built.medium.is_homogeneous,
            "absorption_db_per_m": built.medium.absorption_db_per_m,
        },
        "edges": {s: getattr(edges, s) for s in ("x_lo", "x_hi", "y_lo", "y_hi", "z_lo", "z_hi")}
        | {"thickness_cells": edges.thickness_cells},
        "estimate": {
            "printed": line,
            "memory_bytes": nbytes,
            "time_s": secs,
            "xla_run_bytes": xla_bytes,
            "mlups_assumed": feats.mlups if feats.mlups is not None else "measured (solver.estimate.measure_mlups)",
        },
        "run": {
            "n_steps": n_steps,
            "duration_s": n_steps * grid.dt_s,
            "build_s": build_s,
            "wall_time_s": wall,
            "compile_s": compile_s,
            "note": "wall_time_s: the time loop including its compilation (compile_s); mlups over wall_time_s, "
            "mlups_excl_compile over the run alone",
            "mlups": math.prod(shape) * n_steps / wall / 1e6,
            "mlups_excl_compile": math.prod(shape) * n_steps / run_s / 1e6,
            "device": str(jax.devices()[0]),
            "machine": platform.machine(),
            "load_average": list(os.getloadavg()),
        },
        "memory": memory,
        "stability": {
            "finite": bool(np.all(np.isfinite(np.asarray(result.peak_history)))),
            "peak_pa": float(np.max(np.asarray(result.peak_history))),
            "final_peak_pa": float(np.asarray(result.peak_history)[-1]),
        },
        "receivers": receivers,
        "accuracy": {
            "farthest_distance_m": dist_cells * grid.dx_m,
            "expected_phase_error_periods": perr / (2 * math.pi),
            "note": "worst of the axis and diagonal directions, from the 3-D lattice's dispersion relation "
            "(analytic3d); above ~0.05 periods arrival times at that distance are not trustworthy: raise "
            "cells_per_wavelength",
        },
    }
    return SceneRun3D(scene, built, result, a_scans, summary)


def _a_scans(built: BuiltScene, grid: Grid, result: Result, n_steps: int) -> tuple[dict, dict]:
    """The A-scans of the receiving transducers ({name: (t_s, a_scan)}) and their summaries."""
    a_scans = {}
    t_s = np.arange(1, n_steps + 1) * grid.dt_s
    probes = np.asarray(result.probes) if result.probes is not None else np.zeros((n_steps, 0))
    receivers = {}
    for r in built.receivers:
        src = built.sources[r.source]
        lags = src.lags_s if bool(jnp.any(src.lags_s != 0)) else None
        a = np.asarray(received_signal(probes[:, r.start : r.stop], src.weights, lags, grid.dt_s))
        a_scans[r.name] = (t_s, a)
        gated = np.abs(a[r.gate_start_step :]) if r.gate_start_step < n_steps else np.zeros(1)
        k = int(np.argmax(gated))
        receivers[r.name] = {
            "cells": r.stop - r.start,
            "gate_start_step": r.gate_start_step,
            "gate_start_s": r.gate_start_step * grid.dt_s,
            "echo_peak": float(gated[k]),
            "echo_peak_s": (r.gate_start_step + k + 1) * grid.dt_s,
            "transmit_peak": float(np.abs(a[: max(1, r.gate_start_step)]).max()),
            "units": "Pa x cell weights (the weighted sum of the pressure over the transducer's cells)",
        }
    return a_scans, receivers


def _plane_label(axis: int, index: int, dx_m: float) -> tuple[str, tuple[str, str]]:
    names = tuple(n for i, n in enumerate("xyz") if i != axis)
    return f"{names[0]}-{names[1]} at {'xyz'[axis]} = {index * dx_m * 1e3:.1f} mm", (names[0], names[1])


def write_outputs3d(sr: SceneRun3D, out_dir: str | Path, *, data_format: str = "npz") -> dict:
    """Write a 3-D run's outputs into `out_dir`; returns the paths:

    - a_scan.csv (a header row, then t_s and one column per receiving transducer,
      `<name>_pa_x_weight`: the weighted sum of the pressure over its cells, Pa x cell weights,
      not a pressure) and a_scan.json (the same with the echo window), a_scan.png;
    - peak_slices.png: the peak level (dB re its maximum) on the orthogonal planes of
      `[sensors] snapshot_slices_m` (default: through the transducer's centre), transducer cells
      in cyan and rigid obstacles outlined; field_slices.png: the pressure there at the last
      step where the field is not empty (the last snapshot that holds a wave, when the wave has
      left the window by the end);
    - mip_z.png, mip_y.png: maximum-intensity projections of the peak level along z (seen from
      above) and y (from the side); probes.png: the `[sensors] probes_m` pressures;
    - sensors.npz (probe series, A-scans, the peak-level, RMS and arrival volumes where recorded,
      snapshot planes) or, with `data_format` "netcdf", sensors.nc (the same with coordinates in
      m and s and units as attributes); probes.csv (t_s, probe_<i>_pa) where probes were given;
      summary.json.
    """
    from .. import plots
    from . import datafiles

    datafiles.check_format(data_format)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    g, res, built = sr.grid, sr.result, sr.built
    files: dict[str, Any] = {}
    arrays: dict[str, np.ndarray] = {"peak_history_pa": np.asarray(res.peak_history)}
    if res.probes is not None:
        arrays["probes_pa"] = np.asarray(res.probes)
        arrays["probe_cells"] = np.asarray(built.sensors.probes)
    files |= _write_a_scans(sr, out, arrays)
    n_user = min((r.start for r in built.receivers), default=built.sensors.n_probes)
    if res.probes is not None and n_user > 0:  # the [sensors] probes_m points (before the receivers' cells)
        t = (np.arange(res.probes.shape[0]) + 1) * g.dt_s
        user = np.asarray(res.probes)[:, :n_user]
        fig = plots.time_series_plot(t, user, [f"probe {i}" for i in range(n_user)])
        files["probes"] = str(plots.save(fig, out / "probes.png"))
        cols_p = {"t_s": t} | {f"probe_{i}_pa": user[:, i] for i in range(n_user)}
        files["probes_csv"] = str(datafiles.write_csv(out / "probes.csv", cols_p))
    planes = built.sensors.snapshot_planes(tuple(g.shape)) or ()
    src_cells = [np.asarray(s.cells_array) for s in built.sources]
    rigid = None if built.medium.rigid is None else np.asarray(built.medium.rigid)
    marks, outlines = {}, {}

    def plane(a3, axis, index):
        return np.take(a3, index, axis=axis)

    for axis, index in planes:
        label, _ = _plane_label(axis, index, g.dx_m)
        keep = [i for i in range(3) if i != axis]
        marks[label] = [c[:, keep] for c in src_cells]
        if rigid is not None:
            outlines[label] = plane(rigid, axis, index)
    if res.p_rms is not None:
        arrays["p_rms_pa"] = np.asarray(res.p_rms)
    if res.arrival is not None:
        arrays["arrival_step"] = np.asarray(res.arrival)
    if res.p_max is not None:
        pmax = np.asarray(res.p_max)
        arrays["p_max_pa"] = pmax
        peak = {}
        for axis, index in planes:
            label, axes = _plane_label(axis, index, g.dx_m)
            peak[label] = (axes, plane(pmax, axis, index))
        fig = plots.slices_3d(
            peak, g.dx_m, floor_db=-40.0, marks=marks, outlines=outlines, title="peak level (dB re max)"
        )
        files["peak_slices"] = str(plots.save(fig, out / "peak_slices.png"))
        for axis in (2, 1):
            fig = plots.max_intensity_projection(pmax, g.dx_m, axis=axis, floor_db=-40.0)
            files[f"mip_{'xyz'[axis]}"] = str(plots.save(fig, out / f"mip_{'xyz'[axis]}.png"))
    n_steps = sr.summary["run"]["n_steps"]
    step, field_planes = _last_field_planes(sr, planes)
    note = "" if step == n_steps else f", the last snapshot that holds a wave (the run ends at step {n_steps})"
    fig = plots.slices_3d(
        field_planes,
        g.dx_m,
        marks=marks,
        outlines=outlines,
        title=f"pressure at step {step} ({step * g.dt_s * 1e6:.0f} µs){note}",
    )
    files["field_slices"] = str(plots.save(fig, out / "field_slices.png"))
    if res.snapshots is not None:
        snaps = res.snapshots if isinstance(res.snapshots, tuple) else (res.snapshots,)
        for (axis, index), s in zip(planes, snaps):
            arrays[f"snapshots_{'xyz'[axis]}{index}_pa"] = np.asarray(s)
        arrays["snapshot_steps"] = np.asarray(res.snapshot_steps)
    if data_format == "netcdf":
        files["sensors"] = str(datafiles.netcdf_3d(sr, arrays, out / "sensors.nc"))
    else:
        np.savez_compressed(out / "sensors.npz", allow_pickle=False, **arrays)
        files["sensors"] = str(out / "sensors.npz")
    sr.summary["files"] = files
    (out / "summary.json").write_text(json.dumps(sr.summary, indent=2, default=_json_default))
    files["summary"] = str(out / "summary.json")
    return files


def _write_a_scans(sr: SceneRun3D, out: Path, arrays: dict) -> dict:
    """a_scan.csv/.json/.png and, for a tone burst, echoes.json and a_scan_labelled.png (`echoes3d`)."""
    from .. import plots
    from . import datafiles

    files: dict[str, Any] = {}
    g = sr.grid
    if not sr.a_scans:
        return files
    names = list(sr.a_scans)
    t = next(iter(sr.a_scans.values()))[0]
    cols = np.stack([sr.a_scans[n][1] for n in names], axis=1)
    table = {"t_s": t} | {datafiles.column_name(n, "pa_x_weight"): sr.a_scans[n][1] for n in names}
    files["a_scan_csv"] = str(datafiles.write_csv(out / "a_scan.csv", table))
    doc = {
        "dt_s": g.dt_s,
        "t_s": t.tolist(),
        "a_scan": {n: sr.a_scans[n][1].tolist() for n in names},
        "receivers": sr.summary["receivers"],
    }
    (out / "a_scan.json").write_text(json.dumps(doc))
    files["a_scan_json"] = str(out / "a_scan.json")
    fig = plots.time_series_plot(t, cols, names, ylabel=A_SCAN_LABEL)
    files["a_scan_png"] = str(plots.save(fig, out / "a_scan.png"))
    for n in names:
        arrays[f"a_scan_{n}"] = sr.a_scans[n][1]
    t_rx = sr.scene.transducers[0]
    if sr.built.receivers and t_rx.signal == "burst":
        from . import echoes3d

        r = sr.built.receivers[0]
        t, a = sr.a_scans[r.name]
        src = sr.built.sources[r.source]
        centre = np.average(np.asarray(src.cells_array, float), axis=0, weights=np.abs(np.asarray(src.weights)))
        echoes = echoes3d.label_echoes(
            t,
            a,
            sr.scene,
            g,
            cycles=float(t_rx.cycles),
            gate_start_step=r.gate_start_step,
            centre_m=centre * g.dx_m,
        )
        (out / "echoes.json").write_text(json.dumps(echoes, indent=1, default=_json_default))
        files["echoes"] = str(out / "echoes.json")
        png = echoes3d.plot_labelled(t, a, echoes, r.gate_start_step, out / "a_scan_labelled.png")
        files["a_scan_labelled"] = str(png)
        sr.summary["echoes"] = [
            {
                k: e[k]
                for k in ("surface", "first_arrival", "path_m", "error_periods", "level_db", "resolved", "fit")
                + ("recorded", "delay_lattice_s", "record_end_s")
                if k in e
            }
            for e in echoes["echoes"]
        ]
    return files


A_SCAN_LABEL = "weighted sum over the face (Pa x cell weight)"
"""The A-scan's quantity: the receiving transducer's weighted sum of the pressure over its cells
(`received_signal`), in Pa times the (dimensionless) cell weights; not a pressure."""

EMPTY_FIELD = 1e-3
"""A field slice whose largest |p| is below this fraction of the run's peak counts as empty."""


def _last_field_planes(sr: SceneRun3D, planes) -> tuple[int, dict]:
    """The field on the snapshot planes at the last step where it is not empty: the last step of
    the run, or, where the wave has left the window by then (below `EMPTY_FIELD` x the run's
    peak), the last recorded snapshot above that. Returns (step, {label: (axes, 2-D array)})."""
    g, res = sr.grid, sr.result
    n_steps = sr.summary["run"]["n_steps"]
    final = np.asarray(res.final.pressure)
    labels = [_plane_label(axis, index, g.dx_m) for axis, index in planes]
    final_planes = {lab: (axes, np.take(final, index, axis=axis)) for (lab, axes), (axis, index) in zip(labels, planes)}
    peak = float(sr.summary["stability"]["peak_pa"]) or 1.0
    level = max((float(np.abs(a).max()) for _, a in final_planes.values()), default=0.0)
    if level >= EMPTY_FIELD * peak or res.snapshots is None or res.snapshot_steps is None:
        return n_steps, final_planes
    snaps = [np.asarray(s) for s in (res.snapshots if isinstance(res.snapshots, tuple) else (res.snapshots,))]
    steps = np.asarray(res.snapshot_steps).reshape(-1)
    for k in range(len(steps) - 1, -1, -1):
        if max(float(np.abs(s[k]).max()) for s in snaps) >= EMPTY_FIELD * peak:
            return int(steps[k]), {lab: (axes, s[k]) for (lab, axes), s in zip(labels, snaps)}
    return n_steps, final_planes


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def throughput(run: dict) -> str:
    """'compile 18.2 s + run 2.9 s, 41 MLUPS' from a run summary (MLUPS without the compilation),
    or 'N MLUPS incl. compile' where the compilation could not be separated."""
    if run.get("compile_s") is not None and run.get("mlups_excl_compile") is not None:
        return (
            f"compile {run['compile_s']:.1f} s + run {run['wall_time_s'] - run['compile_s']:.2f} s, "
            f"{run['mlups_excl_compile']:.0f} MLUPS"
        )
    return f"{run['mlups']:.0f} MLUPS incl. compile"


def report_lines(sr) -> list[str]:
    """A 3-D run's console lines: time against the estimate, peak memory, the A-scans."""
    from ..solver.estimate import format_bytes

    s = sr.summary
    r, est, mem = s["run"], s["estimate"], s["memory"]
    peak = mem.get("device_peak_bytes", mem["host_peak_rss_bytes"])
    lines = [
        f"{sr.scene.path}: {r['n_steps']} steps on {' x '.join(map(str, s['grid']['shape']))} cells "
        f"({s['grid']['cells_per_wavelength']:g} cells per wavelength) in {r['wall_time_s']:.2f} s "
        f"({throughput(r)}; estimated {est['time_s']:.3g} s); peak memory {format_bytes(peak)} "
        f"(estimated {format_bytes(est['memory_bytes'])} + runtime); expected phase error "
        f"{s['accuracy']['expected_phase_error_periods']:.3f} periods"
    ]
    for name, rec in s["receivers"].items():
        lines.append(
            f"A-scan {name!r}: echo peak {rec['echo_peak']:.3g} at {rec['echo_peak_s'] * 1e6:.1f} µs "
            f"(window from {rec['gate_start_s'] * 1e6:.1f} µs; transmit peak {rec['transmit_peak']:.3g})"
        )
    if s.get("echoes"):
        from .echoes3d import fit_line

        lines += [fit_line(e) for e in s["echoes"]]
    return lines
