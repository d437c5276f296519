"""Memory and run-time estimates of a run, printed before a large (3-D) run starts, and the refusal
of a run that would not fit in memory.

`estimate_run(grid_shape, n_steps, dtype, features) -> (bytes, seconds)`:

- bytes: the arrays a run holds at its peak: the carried fields (leapfrog: P and P_prev; the
  split-field PML form: one pressure part per axis and one face flux per axis), counted
  `WORKING_SET_FACTOR` times (a scan step builds the new fields while the old ones are alive),
  the coefficient arrays (K, one face conductance per axis, the lattice speed, the soft-cell
  factor; none for a homogeneous medium), the medium maps they are built from, the recordings
  (probe series, phasors, snapshots, whole-field statistics), and for reverse mode the
  checkpointed states, and the 3-D isotropic and wide stencils' own temporaries
  (`STENCIL_WORKING_ARRAYS`). The JAX runtime itself (`RUNTIME_OVERHEAD_BYTES`) is added only when
  comparing with the available memory.
- seconds: cells x steps / (MLUPS x 1e6) plus a compile allowance, from an MLUPS figure measured
  on this machine for the same kind of step (`measure_mlups`: leapfrog or PML, homogeneous or
  with coefficient maps, on 160^3 (3-D) or 840 x 630 (2-D) cells; the slowest of 3 timed runs,
  so the figure is a pessimistic one on a shared machine; cached per machine under the user's
  cache directory), or one given in `RunFeatures.mlups`.

Available memory: the accelerator's free memory (`jax.Device.memory_stats`), else the host's
MemAvailable from /proc/meminfo, else ``os.sysconf`` free pages (no psutil).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import platform
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

WORKING_SET_FACTOR = 2.0
"""Peak bytes of the time loop / bytes of the carried fields (old and new state of a step);
measured with `benchmarks/estimate_3d.py` (peak RSS of 3-D runs against this model)."""

RUNTIME_OVERHEAD_BYTES = 600 * 2**20
"""Python, JAX and XLA's own memory (measured ~0.4-0.6 GiB RSS of an idle process after a first
compile on CPU), added to the estimate before comparing with the available memory."""

COMPILE_S = {2: 2.0, 3: 4.0}
"""Compile-time allowance per grid rank (seconds; measured on a 2-core CPU)."""

STENCIL_WORKING_ARRAYS = {(False, False): 7.5, (False, True): 12.0, (True, False): 11.0, (True, True): 25.0}
"""Grid-sized temporaries of a step of the 3-D isotropic and wide stencils (which run on the JAX
loop) beyond what the rest of the model counts, by (PML, coefficient maps): XLA keeps the
stencil's partial sums and shifted copies alive across its fusions. Measured from
`Compiled.memory_analysis()` of a whole run, float32, sponge / PML edges, isotropic and wide (the
larger), on 40 x 32 x 24 and 96 x 80 x 64 cells: homogeneous 7.19 / 6.47, with maps 11.86 / 10.72,
PML with maps 24.96 / 21.24 arrays; homogeneous PML 10.51 / 3.64 since the layers form their face
values on their boxes (session 16; 21.11 / 17.31 before, from whole-grid face arrays): it scales
with the layers' share of the grid, 6-cell layers being most of the smaller grid. The constants
are the larger, rounded up (`tests/core/test_3d_estimate.py` checks the model against XLA's figure
on a third grid)."""

RELOAD_AT_LOAD = 1.0
"""A cached throughput measured while the load average per core exceeded this is measured again
when the machine is at most half as loaded now (a figure taken on a busy machine said 2270 s for
a 287 s run)."""

FIT_FRACTION = 0.9
"""A run is refused above this fraction of the available memory (the rest: fragmentation)."""


@dataclass(frozen=True)
class RunFeatures:
    """What a run carries and records (the inputs of `estimate_run`).

    - `pml`: split-field PML stepper (one pressure part and one face flux per axis) instead of
      the two-field leapfrog; `sponge`: a sponge layer (one grid-sized damping factor).
    - `heterogeneous`: coefficient maps (K, face conductances per axis, lattice speed) exist
      (any medium map or obstacle); `soft`: a soft-obstacle factor map; `absorption`: P_prev kept
      by the PML stepper; `air_absorption`: air's two relaxation memory fields (and P_prev with a PML).
    - `n_probes`, `n_phasors`: recorded cells; `snapshot_cells` x `n_snapshots`: snapshots
      (a slice: nx ny cells; a full volume: nx ny nz); `field_stats`: how many of p_max, p_rms,
      arrival are recorded (each one grid-sized array).
    - `gradient`: reverse mode (adds `checkpoints` saved states and a second working set).
    - `mlups`: million lattice-cell updates per second to assume (None: measured, `measure_mlups`).
    - `stencil`: the grid's spatial stencil (the isotropic and wide ones are timed apart: they cost more per
      update; the wide one next to obstacles keeps 7 more grid-sized arrays).
    """

    pml: bool = True
    sponge: bool = False
    heterogeneous: bool = False
    soft: bool = False
    absorption: bool = False
    air_absorption: bool = False
    n_probes: int = 0
    n_phasors: int = 0
    snapshot_cells: int = 0
    n_snapshots: int = 0
    field_stats: int = 0
    gradient: bool = False
    checkpoints: int = 0
    mlups: float | None = None
    stencil: str = "standard"


class RunTooLargeError(ValueError):
    """A run's memory estimate exceeds the memory available on this machine."""


def _features(features) -> RunFeatures:
    if features is None:
        return RunFeatures()
    if isinstance(features, RunFeatures):
        return features
    if isinstance(features, dict):
        allowed = {f.name for f in dataclasses.fields(RunFeatures)}
        bad = set(features) - allowed
        if bad:
            raise ValueError(f"unknown run features {sorted(bad)}; allowed: {', '.join(sorted(allowed))}")
        return RunFeatures(**features)
    raise ValueError(f"features must be a RunFeatures or a dict, got {type(features).__name__}")


def memory_breakdown(grid_shape, n_steps: int, dtype: str, features=None) -> dict[str, int]:
    """Bytes per part of the estimate (see the module docstring); `estimate_run` sums them."""
    f = _features(features)
    shape = tuple(int(n) for n in grid_shape)
    if not shape or any(n < 1 for n in shape):
        raise ValueError(f"grid_shape = {grid_shape}: give positive cell counts")
    if dtype not in ("float32", "float64"):
        raise ValueError(f"dtype = {dtype!r}; allowed: 'float32', 'float64'")
    b = 4 if dtype == "float32" else 8
    ndim = len(shape)
    N = math.prod(shape)
    faces = sum(N // n * (n + 1) for n in shape)
    if f.pml:
        carried = ndim * N + faces + (N if (f.absorption or f.air_absorption) else 0)
    else:
        carried = 2 * N
    if f.air_absorption:
        carried += 2 * N
    coeff = 0
    maps = 0
    if f.heterogeneous:
        coeff = 2 * N + faces  # K, lattice speed c, one conductance per face
        maps = 3 * N  # the medium's SI maps (speed, density, occupancy)
    if f.soft:
        coeff += N
    if f.sponge:
        coeff += N  # the sponge's per-cell damping factor
    if f.heterogeneous and f.stencil == "wide" and ndim == 3:
        coeff += 7 * N  # the wide stencil's axis rows next to obstacles (`operators.wide_rows`)
    rec = f.n_probes * n_steps + 2 * f.n_phasors + f.snapshot_cells * f.n_snapshots + f.field_stats * N
    parts = {
        "fields": int(WORKING_SET_FACTOR * carried * b),
        "coefficients": int(coeff * b),
        "medium_maps": int(maps * b),
        "recordings": int(rec * b),
    }
    if ndim == 3 and f.stencil in ("isotropic", "wide"):
        parts["stencil_working"] = int(STENCIL_WORKING_ARRAYS[(f.pml, f.heterogeneous)] * N * b)
    if f.gradient:
        parts["checkpoints"] = int(max(f.checkpoints, math.isqrt(max(n_steps, 1))) * carried * b)
        parts["reverse_working"] = int(WORKING_SET_FACTOR * carried * b + coeff * b)
    return parts


def estimate_run(
    grid_shape, n_steps: int, dtype: Literal["float32", "float64"] = "float32", features=None
) -> tuple[int, float]:
    """(bytes, seconds) of a run of `n_steps` steps on a grid of `grid_shape` cells in `dtype`
    with `features` (a `RunFeatures` or a dict of its fields); see the module docstring."""
    f = _features(features)
    if not isinstance(n_steps, int) or n_steps < 1:
        raise ValueError(f"n_steps = {n_steps!r} must be a positive integer")
    nbytes = sum(memory_breakdown(grid_shape, n_steps, dtype, f).values())
    ndim = len(tuple(grid_shape))
    mlups = (
        f.mlups
        if f.mlups is not None
        else measure_mlups(
            ndim, "pml" if f.pml else "leapfrog", dtype, heterogeneous=f.heterogeneous, stencil=f.stencil
        )
    )
    if not mlups > 0:
        raise ValueError(f"mlups = {mlups}: must be > 0")
    cells = math.prod(int(n) for n in grid_shape)
    seconds = cells * n_steps / (mlups * 1e6) * (2.0 if f.gradient else 1.0) + COMPILE_S.get(ndim, 4.0)
    return int(nbytes), float(seconds)


# ------------------------------------------------------------------------------------------
# available memory and the refusal


def available_memory_bytes(device=None) -> int:
    """Free memory of `device` (a JAX device; default: the default device) in bytes: the
    accelerator's limit minus its use, or for a CPU the host's MemAvailable (/proc/meminfo), else
    free pages from ``os.sysconf``."""
    if device is None:
        try:
            import jax

            device = jax.devices()[0]
        except Exception:  # pragma: no cover - JAX absent
            device = None
    if device is not None and getattr(device, "platform", "cpu") != "cpu":
        stats = device.memory_stats() or {}
        if "bytes_limit" in stats:
            return int(stats["bytes_limit"] - stats.get("bytes_in_use", 0))
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))


def format_bytes(n: float) -> str:
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= scale:
            return f"{n / scale:.2f} {unit}"
    return f"{int(n)} B"


def format_estimate(grid_shape, n_steps: int, nbytes: int, seconds: float) -> str:
    cells = math.prod(int(n) for n in grid_shape)
    dims = " x ".join(str(int(n)) for n in grid_shape)
    time_part = "" if not math.isfinite(seconds) else f", estimated time {seconds:.3g} s"
    return (
        f"difflattice: run of {dims} = {cells / 1e6:.3g} M cells x {n_steps} steps: "
        f"estimated memory {format_bytes(nbytes)} (+ {format_bytes(RUNTIME_OVERHEAD_BYTES)} runtime){time_part}"
    )


def check_fits(
    grid_shape, n_steps: int, nbytes: int, *, available: int | None = None, seconds: float | None = None
) -> None:
    """Raise `RunTooLargeError` (naming the estimate and the fix) if `nbytes` plus the runtime does
    not fit in `FIT_FRACTION` of the available memory."""
    avail = available_memory_bytes() if available is None else int(available)
    need = nbytes + RUNTIME_OVERHEAD_BYTES
    if need > FIT_FRACTION * avail:
        est = format_estimate(grid_shape, n_steps, nbytes, seconds if seconds is not None else float("nan"))
        raise RunTooLargeError(
            f"{est}; this needs {format_bytes(need)} but only {format_bytes(avail)} is available "
            f"(refused above {FIT_FRACTION:.0%}). Fix: fewer cells (a smaller window or fewer cells "
            f"per wavelength: memory ~ (cells per wavelength)^{len(tuple(grid_shape))}), float32 instead of float64, "
            + ("snapshots as slices instead of volumes, " if len(tuple(grid_shape)) == 3 else "")
            + "or split the grid across devices (sharding)."
        )


def check_compiled(compiled, grid_shape, n_steps: int, *, available: int | None = None) -> int | None:
    """The bytes a compiled run will allocate when it starts (XLA's own figure: its temporaries
    and outputs; its arguments already exist), or None where the backend does not say; raises
    `RunTooLargeError` if they do not fit in `FIT_FRACTION` of the memory available now (of
    `available` less what this process holds, where a budget is given). `compiled`:
    a `jax.stages.Compiled` (or equinox's wrapper of one). Called after compiling, before the run:
    the check of the estimate against what will actually be allocated."""
    inner = getattr(compiled, "compiled", compiled)
    try:
        ma = inner.memory_analysis()
        need = int(ma.temp_size_in_bytes + ma.output_size_in_bytes - ma.alias_size_in_bytes)
    except (AttributeError, NotImplementedError, TypeError, RuntimeError):
        return None
    # `available` is a budget for the whole process: what it holds already (the lattice's arrays) counts
    avail = available_memory_bytes() if available is None else int(available) - _resident_bytes()
    if need > FIT_FRACTION * avail:
        dims = " x ".join(str(int(n)) for n in grid_shape)
        raise RunTooLargeError(
            f"the compiled run of {dims} cells x {n_steps} steps allocates {format_bytes(need)} when it starts "
            f"(XLA's temporaries and outputs) but only {format_bytes(avail)} is available now (refused above "
            f"{FIT_FRACTION:.0%}). Fix: fewer cells per wavelength or a smaller window, float32, or the standard "
            "stencil (the 3-D isotropic and wide stencils keep more temporaries)."
        )
    return need


def _resident_bytes() -> int:
    """This process's resident memory (Linux /proc; 0 where it cannot be read)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


# ------------------------------------------------------------------------------------------
# measured throughput


def _cache_path() -> Path:
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "difflattice" / f"mlups-{platform.node() or 'host'}.json"


def _device_key(ndim: int, stepper: str, dtype: str, heterogeneous: bool) -> str:
    import jax

    d = jax.devices()[0]
    medium = "maps" if heterogeneous else "homogeneous"
    return (
        f"{d.platform}:{getattr(d, 'device_kind', '')}:{os.cpu_count()}:jax{jax.__version__}:{ndim}d:{stepper}:"
        f"{medium}:{dtype}"
    )


def measure_mlups(
    ndim: int,
    stepper: Literal["leapfrog", "pml"] = "pml",
    dtype: Literal["float32", "float64"] = "float32",
    *,
    heterogeneous: bool = False,
    refresh: bool = False,
    stencil: str = "standard",
) -> float:
    """Million lattice-cell updates per second of `stepper` on a grid of rank `ndim` on this
    machine, homogeneous or with coefficient maps (`heterogeneous`: a rigid cut-cell wall): the
    slowest of 3 short timed runs (about a second in all), cached per machine, device, JAX version
    and case in ``~/.cache/difflattice/`` (delete the file or pass `refresh` to measure again,
    e.g. after the machine's load changed; a figure taken on a busy machine is measured again
    when the machine is quieter: `RELOAD_AT_LOAD`)."""
    if ndim not in (2, 3):
        raise ValueError(f"ndim = {ndim}: 2 or 3")
    if stepper not in ("leapfrog", "pml"):
        raise ValueError(f"stepper = {stepper!r}; allowed: 'leapfrog', 'pml'")
    if dtype not in ("float32", "float64"):
        raise ValueError(f"dtype = {dtype!r}; allowed: 'float32', 'float64'")
    key = _device_key(ndim, stepper, dtype, heterogeneous) + ("" if stencil == "standard" else f":{stencil}")
    path = _cache_path()
    cache: dict = {}
    if path.exists():
        try:
            cache = json.loads(path.read_text())
        except (OSError, ValueError):
            cache = {}
    if key in cache and not refresh and not _measured_busier(cache[key]):
        return float(cache[key]["mlups"])
    mlups = _time_run(ndim, stepper, dtype, heterogeneous, stencil)
    cache[key] = {
        "mlups": mlups,
        "measured_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "load_average": list(os.getloadavg()),
    }
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(cache, indent=1))
        tmp.replace(path)
    except OSError:
        pass
    return mlups


def _measured_busier(entry: dict) -> bool:
    """Whether a cached figure was taken on a busy machine (load per core above `RELOAD_AT_LOAD`)
    that is at most half as loaded now: then it is measured again."""
    cores = os.cpu_count() or 1
    try:
        then = float(entry["load_average"][0]) / cores
    except (KeyError, IndexError, TypeError, ValueError):
        return False
    return then > RELOAD_AT_LOAD and os.getloadavg()[0] / cores <= then / 2


def _time_run(
    ndim: int,
    stepper: str,
    dtype: Literal["float32", "float64"],
    heterogeneous: bool = False,
    stencil: str = "standard",
) -> float:
    """MLUPS of the slowest of 3 timed runs (after a compile run) of a homogeneous scene or one
    with a rigid wall as cut cells (K and face-conductance maps)."""
    import jax

    from ..lattice.coefficients import Edges
    from ..lattice.grid import make_grid
    from ..lattice.medium import Medium
    from .native import dispatch
    from .scan import run_jax
    from .stepper import Stepper

    def run(stepper, n: int):  # what `loop.run` does for a forward run: native where it runs, else JAX
        out = dispatch(
            stepper, n, state=None, checkpoint=None, unroll=None, sharding=None, adjoint="autodiff", backend="auto"
        )
        return out if out is not None else run_jax(stepper, n)

    if dtype == "float64" and not jax.config.read("jax_enable_x64"):
        raise ValueError("measure_mlups(dtype='float64') needs jax_enable_x64 (set it in your script)")
    shape = (160, 160, 160) if ndim == 3 else (840, 630)
    n_steps = 10 if ndim == 3 else 100
    courant = {"isotropic": 0.86, "wide": 0.595}.get(stencil, 0.57) if ndim == 3 else 0.7
    grid = make_grid(
        frequency_hz=40e3,
        cells_per_wavelength=12,
        c_max_m_s=343.0,
        shape=shape,
        courant=courant,
        dtype=dtype,
        kind="3d" if ndim == 3 else "2d",
        stencil="wide" if stencil == "wide" and ndim == 3 else ("isotropic" if stencil == "isotropic" else "standard"),
    )
    edges = Edges.all("pml", thickness_cells=8) if stepper == "pml" else Edges.all("rigid")
    medium = Medium(343.0, 1.2)
    if heterogeneous:
        import numpy as np

        x = np.arange(shape[0], dtype=float).reshape((-1,) + (1,) * (ndim - 1))
        wall = np.clip(x - 0.75 * shape[0], 0.0, 1.0) * np.ones(shape)  # a rigid slab, one cut-cell layer
        medium = Medium(343.0, 1.2, rigid=jax.numpy.asarray(wall, grid.jnp_dtype))
    st = Stepper.build(grid, medium, edges=edges)
    f = jax.jit(lambda s: run(s, n_steps).final)
    jax.block_until_ready(f(st))
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        jax.block_until_ready(f(st))
        times.append(time.perf_counter() - t0)
    return math.prod(shape) * n_steps / max(times) / 1e6


# ------------------------------------------------------------------------------------------
# a stepper's run


def features_of(
    stepper, n_steps: int, *, checkpoint=None, gradient: bool = False, mlups: float | None = None
) -> RunFeatures:
    """The `RunFeatures` of a run of `stepper` (a `solver.Stepper`) for `n_steps` steps."""
    import jax.numpy as jnp

    lat, sens = stepper.lattice, stepper.sensors
    shape = tuple(stepper.grid.shape)
    heterogeneous = lat.bx is not None or jnp.ndim(lat.K) != 0
    n_snap = 0
    snap_cells = 0
    if sens.snapshot_every is not None:
        n_snap = -(-n_steps // min(sens.snapshot_every, n_steps))
        planes = sens.snapshot_planes(shape)
        snap_cells = math.prod(shape) if planes is None else sum(math.prod(shape) // shape[a] for a, _ in planes)
    chunks = 0
    if checkpoint is not None and gradient:
        chunk = math.isqrt(n_steps) if checkpoint == "sqrt" else int(checkpoint)
        chunks = -(-n_steps // max(chunk, 1))
    return RunFeatures(
        pml=bool(stepper.staggered),
        sponge=lat.sponge is not None,
        heterogeneous=bool(heterogeneous),
        soft=lat.keep is not None,
        absorption=lat.eta > 0,
        air_absorption=getattr(lat, "relax", None) is not None,
        n_probes=sens.n_probes,
        n_phasors=sens.n_phasors,
        snapshot_cells=snap_cells,
        n_snapshots=n_snap,
        field_stats=int(sens.p_max) + int(sens.p_rms) + int(sens.arrival_threshold_pa is not None),
        gradient=gradient,
        checkpoints=chunks,
        mlups=mlups,
        stencil=lat.stencil,
    )


def preflight(
    stepper, n_steps: int, *, checkpoint=None, show: bool = False, available: int | None = None
) -> tuple[int, float]:
    """Estimate a run of `stepper` (memory; with `show` also the time, from the measured MLUPS,
    and print both), refuse it (`RunTooLargeError`) if it would not fit; returns (bytes, seconds)
    (seconds NaN when not shown)."""
    import sys

    f = features_of(stepper, n_steps, checkpoint=checkpoint)
    shape, dtype = tuple(stepper.grid.shape), stepper.grid.dtype
    if show:
        nbytes, secs = estimate_run(shape, n_steps, dtype, f)
        print(format_estimate(shape, n_steps, nbytes, secs), file=sys.stderr, flush=True)
    else:
        nbytes = sum(memory_breakdown(shape, n_steps, dtype, f).values())
        secs = float("nan")
    check_fits(shape, n_steps, nbytes, available=available, seconds=secs)
    return nbytes, secs
