"""A fit report's figures: lobe, wavefront, aperture, convergence and the fitted transducer's
field image, rendered beside the error budget (`FigureWriter`: in a worker process where allowed)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from types import SimpleNamespace
from typing import Any, cast

import numpy as np

from .data import LobeData, WaveData
from .result import FitResult
from .transfer import Transfer


def model_family(spec) -> str:
    """The model family of a spec: "disc" (`fit.disc.DiscSpec`, rings on the axisymmetric
    lattice) or "line" (`fit.model.ModelSpec`, a line of cells on the 2-D lattice)."""
    return str(spec.kind)


def aperture_figure(ap: dict, *, truth: dict | None = None, title: str = "fitted aperture"):
    """The aperture plot from `aperture_arrays` (weights and lags relative to the centre cell with a
    band of ± total uncertainty); `truth` ({"y_m", "weights", "lags_s"}, any normalisation) is
    normalised the same way and overlaid."""
    from .. import plots

    args, kwargs = _aperture_plot_args(ap, truth=truth, title=title)
    return plots.aperture_plot(*args, **kwargs)


def _aperture_plot_args(ap: dict, *, truth: dict | None, title: str) -> tuple[tuple, dict]:
    y = np.asarray(ap["y_m"])
    w = np.asarray(ap.get("weights_re_centre", np.ones_like(y)))
    lag = np.asarray(ap.get("lags_re_centre_s", np.zeros_like(y)))
    ws, ls, labels = [w], [lag], ["fitted"]
    if "lags_alternative" in ap:
        ws.append(w)
        ls.append(np.asarray(ap["lags_alternative"]))
        labels.append("equally good (other symmetry)")
    t = None
    if truth is not None:
        ty = np.asarray(truth["y_m"], float)
        t = {"y_m": ty}
        if truth.get("weights") is not None:
            tw = np.asarray(truth["weights"], float)
            t["weights"] = tw / np.interp(0.0, ty, tw)
        if truth.get("lags_s") is not None:
            tl = np.asarray(truth["lags_s"], float)
            t["lags_s"] = tl - np.interp(0.0, ty, tl)
    we = ap.get("weights_total")
    le = ap.get("lags_total")
    kwargs = {
        "labels": labels,
        "title": title,
        "truth": t,
        "weight_label": "weight re centre cell",
        "weight_err": None if we is None else np.asarray(we, float),
        "lag_err_s": None if le is None else np.asarray(le, float),
    }
    return (y, ws, ls), kwargs


class FigureWriter:
    """Renders the report's figures: in a worker process where it may start one (two or more
    CPUs, `DIFFLATTICE_REPORT_WORKER` not "0"), so matplotlib's import, drawing and PNG encoding
    (~2 s for a fit report) run beside the error budget instead of after it; else in this
    process. Jobs are `plots` functions returning a Figure, with NumPy arguments, streamed to
    `python -m difflattice.plots --render-jobs -` as they come (a plain subprocess: the caller's
    main module is never imported again, as a multiprocessing child would). `defer` computes a
    job's arguments in a thread meanwhile (the field image's simulation)."""

    def __init__(self, background: bool):
        self._proc: Any = None
        self._err: Any = None
        self._done: dict[str, Path] = {}
        self._deferred: list[tuple] = []
        if background and _worker_allowed():
            self._proc, self._err = _take_spare() or _spawn()
        self._jobs: Any = None
        self._writer: Any = None
        if self._proc is not None:  # jobs are written by a thread: the worker reads its first only
            import queue  # once its imports are done, and a full pipe would stall the fit till then
            import threading

            self._jobs = queue.SimpleQueue()
            self._writer = threading.Thread(target=self._write_jobs, daemon=True)
            self._writer.start()

    def _write_jobs(self) -> None:
        while (job := self._jobs.get()) is not None:
            try:
                self._proc.stdin.write(job)
                self._proc.stdin.flush()
            except (BrokenPipeError, ValueError):  # the worker died (raised by `results`) or closed
                return

    def _stop_writer(self) -> None:
        if self._writer is not None:
            self._jobs.put(None)
            self._writer.join()
            self._writer = None

    def submit(self, name: str, fn: str, path: Path, *args, **kwargs) -> None:
        """Draw `plots.<fn>(*args, **kwargs)` into `path` (matplotlib is imported only where the
        figure is drawn)."""
        if self._proc is None:
            self._done[name] = _render(fn, path, args, kwargs)
            return
        import pickle

        self._jobs.put(pickle.dumps((name, fn, str(path), args, kwargs)))

    def defer(self, name: str, fn: str, path: Path, compute) -> None:
        """Submit `fn(*args, **kwargs)` with `(args, kwargs) = compute()`, computed in a thread
        from now on (its error is raised by `results`). With a worker process the job goes to it
        as soon as it is computed (drawn beside the rest of the fit); else `results` draws it."""
        import threading

        box: dict[str, Any] = {}

        def run():
            try:
                box["value"] = compute()
            except BaseException as e:  # re-raised in `results`
                box["error"] = e
                return
            if self._proc is not None:  # the job queue is thread-safe; `results` stops its writer later
                args, kwargs = box.pop("value")
                self.submit(name, fn, path, *args, **kwargs)

        t = threading.Thread(target=run, daemon=True)
        t.start()
        self._deferred.append((name, fn, path, t, box))

    def results(self) -> dict[str, Path]:
        """Wait for every figure; their paths by name (a worker's failure is raised here)."""
        try:
            for name, fn, path, t, box in self._deferred:
                t.join()
                if "error" in box:
                    raise box["error"]
                if "value" in box:  # not submitted by its thread (no worker process)
                    args, kwargs = box["value"]
                    self.submit(name, fn, path, *args, **kwargs)
            self._deferred = []
            if self._proc is not None:
                self._stop_writer()
                out, _ = self._proc.communicate()
                if self._proc.returncode != 0:
                    self._err.seek(0)
                    err = self._err.read().decode(errors="replace")
                    raise RuntimeError(
                        f"the report's figure worker failed (exit {self._proc.returncode}):\n{err[-3000:]}"
                    )
                self._done.update({k: Path(v) for k, v in json.loads(out.decode().strip().splitlines()[-1]).items()})
            return dict(self._done)
        finally:
            self.close()

    def close(self) -> None:
        for *_, t, _box in self._deferred:
            t.join()
        self._deferred = []
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()
        self._stop_writer()
        self._proc = None
        if self._err is not None:
            self._err.close()
            self._err = None


_SPARE: list[tuple[Any, Any]] = []
"""A worker started ahead by `prestart_worker` (process, its stderr file), for the next writer."""


def prestart_worker() -> None:
    """Start the figure worker now, before its first job: its imports (matplotlib, ~0.4 s CPU)
    then run beside the caller's set-up and fit (a core the fit leaves idle) instead of on the
    report's critical path. The next `FigureWriter(background=True)` takes it; one never taken
    reads the end of its input when this process ends, and exits."""
    spare = _take_spare()
    if spare is None and _worker_allowed():
        spare = _spawn()
    if spare is not None and spare[0] is not None:
        _SPARE.append(spare)


def _take_spare() -> tuple[Any, Any] | None:
    """The worker `prestart_worker` started, if it is still running."""
    while _SPARE:
        proc, err = _SPARE.pop()
        if proc.poll() is None:
            return proc, err
        err.close()
    return None


def _spawn() -> tuple[Any, Any]:
    """A worker process drawing the jobs on its stdin, and its stderr file; (None, None) where no
    process can start (then the figures are drawn in-process)."""
    import subprocess
    import sys
    import tempfile

    err = tempfile.TemporaryFile()
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "difflattice.plots", "--render-jobs", "-"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=err,
        )
    except OSError:  # no processes here: draw in-process
        err.close()
        return None, None
    return proc, err


def _worker_allowed() -> bool:
    if os.environ.get("DIFFLATTICE_REPORT_WORKER", "1") == "0":
        return False
    try:
        return len(os.sched_getaffinity(0)) >= 2
    except AttributeError:  # not Linux
        return (os.cpu_count() or 1) >= 2


def _render(fn: str, path: Path, args: tuple, kwargs: dict) -> Path:
    from .. import plots

    return plots.save(getattr(plots, fn)(*args, **kwargs), path)


def start_figures(
    out_dir: str | Path,
    fitted: FitResult,
    uniform: FitResult | None,
    transfer: Transfer,
    lobe: LobeData | None,
    wave: WaveData | None,
    *,
    field_image: bool = True,
    background: bool = True,
) -> FigureWriter:
    """Start the figures that do not depend on the error budget (lobe, wavefront, convergence,
    field image; `write_report` adds the aperture and collects them). The field image's
    simulation runs in a thread from here; the drawing, with `background`, in a worker process."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    w = FigureWriter(background)
    if lobe is not None:
        ref = float(np.max(lobe.level_db))
        lc: dict[str, Any] = {
            "measured": (np.asarray(lobe.level_db) - ref, "o"),
            "fitted model": np.asarray(fitted.model_curves["lobe_db"]) - ref,
        }
        if uniform is not None:
            lc["uniform model"] = (np.asarray(uniform.model_curves["lobe_db"]) - ref, "--")
        w.submit(
            "lobe",
            "lobe_plots",
            out / "lobe.png",
            np.asarray(lobe.angle_deg),
            lc,
            title=f"lobe at {lobe.range_m:g} m",
        )
    if wave is not None:
        to_us = 1e6 / (2 * math.pi * wave.frequency_hz)
        centre = int(np.argmin(np.abs(wave.x_m)))

        def arrival(phase):  # the models' phase falls with delay: arrival = -unwrapped phase / omega
            u = -np.unwrap(np.asarray(phase))
            return (u - u[centre]) * to_us

        wc: dict[str, Any] = {
            "measured": (arrival(wave.phase_rad), "o"),
            "fitted model": arrival(fitted.model_curves["wave_phase_rad"]),
        }
        if uniform is not None:
            wc["uniform model"] = (arrival(uniform.model_curves["wave_phase_rad"]), "--")
        w.submit(
            "wavefront",
            "wavefront_plot",
            out / "wavefront.png",
            np.asarray(wave.x_m),
            wc,
            ylabel="arrival re centre (µs, from phase)",
            title=f"near-field wavefront at z = {wave.z_m * 1e3:.1f} mm",
        )
    if fitted.trace is not None:
        w.submit("convergence", "convergence_plot", out / "convergence.png", _trace_arrays(fitted.trace))
    if field_image:  # its simulation runs beside the error budget
        w.defer("field", "field_image", out / "field.png", lambda: _field_image_args(fitted, transfer))
    return w


def trace_figure(trace):
    """Cost against solver iteration and against solve time, one colour per stage
    (`plots.convergence_plot` of the fit's `FitTrace`)."""
    from .. import plots

    return plots.convergence_plot(_trace_arrays(trace))


def _trace_arrays(trace) -> SimpleNamespace:
    """The trace's arrays, as `plots.convergence_plot` reads them (picklable without JAX)."""
    return SimpleNamespace(
        iteration=np.asarray(trace.iteration),
        stage=np.asarray(trace.stage),
        cost=np.asarray(trace.cost),
        accepted=np.asarray(trace.accepted),
        solve_s=np.asarray(trace.solve_s),
        stages=[dict(x) for x in trace.stages],
        compile_s=float(trace.compile_s),
    )


def _field_image_args(fitted: FitResult, transfer: Transfer) -> tuple[tuple, dict]:
    """Simulate the fitted transducer (a burst): the arguments of `plots.field_image` for a
    picture like the paper's Fig. 2: a line on the 2-D lattice, or a disc on the rz lattice
    (`transfer_disc.disc_field_image_args`, the meridian plane mirrored about the axis)."""
    if model_family(fitted.spec) == "disc":
        from .transfer_disc import disc_field_image_args

        return disc_field_image_args(fitted, cast(Any, transfer))
    import jax

    from ..lattice.grid import make_grid
    from ..lattice.medium import Medium
    from ..solver.loop import simulate
    from ..solver.sensors import Sensors
    from ..solver.sources import ToneBurst, line_transducer

    g0 = transfer.grid
    n = fitted.spec.n_cells
    nx, ny = int(5.5 * n), int(3.5 * n)
    grid = make_grid(
        frequency_hz=g0.frequency_hz,
        cells_per_wavelength=g0.cells_per_wavelength,
        c_max_m_s=g0.c_max_m_s,
        shape=(nx, ny),
        dtype="float32",
    )
    ph = fitted.physical
    src = line_transducer(
        grid,
        (30 * grid.dx_m, ny / 2 * grid.dx_m),
        n_cells=n,
        signal=ToneBurst(g0.frequency_hz, 8),
        weights=jax.device_put(np.asarray(ph["weights"], np.float32)),  # a transfer, not a program
        lags_s=jax.device_put(np.asarray(ph["lags_s"], np.float32)),
    )
    steps = int((nx - 60) / grid.courant)
    res = simulate(grid, Medium(g0.c_max_m_s, 1.2), src, Sensors(), n_steps=steps)
    kwargs = {
        "step": steps,
        "dt_s": grid.dt_s,
        "sources": [np.asarray(src.cells_array)],
        "title": "fitted transducer (8-cycle burst)",
    }
    return (np.asarray(res.final.pressure), grid.dx_m), kwargs
