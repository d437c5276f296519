"""The time loop and the one entry point, `simulate`.

`simulate` is a pure function of its array inputs (medium maps, source weights and lags), so it
works under `jax.jit`, `jax.grad`, `jax.jvp` and `jax.vmap`. Sensors are recorded inside the
scan; the time loop is a scan of chunks of steps, which gives snapshots every k steps, a
per-chunk record of the peak |p| (instability detection), and memory-bounded reverse mode
(`checkpoint="sqrt"`: each chunk is recomputed in the backward pass, memory ~ sqrt(steps)).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from types import MappingProxyType
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..lattice.coefficients import Edges, speed_limit
from ..lattice.grid import Grid
from ..lattice.kinds import PLANE, VOLUME
from ..lattice.medium import Medium
from . import native
from .backends import Native, Request, choose
from .estimate import preflight as _preflight
from .program_cache import CachedProgram, Kernels
from .scan import Checkpoint, Joiner, Result, chunking
from .sensors import Sensors
from .sources import PointSources
from .stepper import State, Stepper


def run(
    stepper: Stepper,
    n_steps: int,
    *,
    state: State | None = None,
    checkpoint: Checkpoint = None,
    unroll: int | None = None,
    sharding: jax.sharding.Sharding | None = None,
    adjoint: Literal["autodiff", "lattice", "auto"] = "autodiff",
    backend: Literal["auto", "jax", "native"] = "auto",
) -> Result:
    """Run `n_steps` steps from `state` (default: rest) and collect the sensors. Pure and jittable.

    `unroll` (steps per scan iteration): None picks 2 for the leapfrog (it removes the copies of
    the carried fields that XLA adds to a rolled loop: 2x faster on CPU) and 1 for the staggered
    PML form (unrolling it made XLA fuse across steps and run up to 10x slower).

    `sharding`: a `jax.sharding.Sharding` of a grid-shaped array (e.g. `grid_sharding()`): the
    fields are kept split across its devices every step and XLA exchanges the one-cell halos
    (GPU clusters, or both cores of a CPU run with several host devices).

    `adjoint`: how reverse mode differentiates the run. "autodiff": JAX's reverse mode of the
    scan (the reference; also the only one with forward mode). "lattice": the adjoint wave
    equation run backwards (`difflattice.adjoint`): the same gradients at about twice the forward
    time for sources and bounded memory (`checkpoint` chunks, default sqrt(n_steps)) for medium
    maps; raises for scenes it does not support. "auto": "lattice" where supported.

    `backend`: "jax" (this loop: the reference, and the path on GPUs), "native" (the C++ kernels
    of `difflattice.solver.native` on a CPU: raises if the scene or machine is not supported), or
    "auto" (native where supported, else jax). Derivatives of a native run are the JAX loop's,
    except with adjoint="lattice", whose forward and backward runs are native where supported.
    The chooser is `backends.choose`; `Result.backend` names the backend that ran and
    `Result.backend_why_not` why each other one did not."""
    if not isinstance(n_steps, (int, np.integer)) or n_steps < 1:
        raise ValueError(f"n_steps = {n_steps!r} must be a positive integer")
    n_steps = int(n_steps)
    if adjoint not in ("autodiff", "lattice", "auto"):
        raise ValueError(f"adjoint = {adjoint!r}; allowed: 'autodiff', 'lattice', 'auto'")
    return choose(Request(stepper, n_steps, state, checkpoint, unroll, sharding, adjoint), backend).run()


INSTABILITY_MESSAGE = (
    "difflattice: the simulation produced non-finite pressure (numerical instability or overflow). "
    "Likely causes: a lattice speed above 1/sqrt(2) cells/step (1/sqrt(3) in 3-D; lower the grid courant), a strong "
    "density contrast at the stability limit with the conservative model (lower courant by ~1%), "
    "or float32 overflow from extreme source amplitudes (scale the weights or use float64)."
)
SPEED_MESSAGE = PLANE.speed_message
"""The error of a speed map above the plane (and rz) lattice's limit (`LatticeKind.speed_message`)."""
SPEED_MESSAGE_3D = VOLUME.speed_message
"""The same for a 3-D grid."""


def check_result(result: Result, stepper: Stepper) -> Result:
    """Raise (inside jit too, via `eqx.error_if`) if the run went non-finite."""
    bad = ~jnp.all(jnp.isfinite(result.peak_history))
    return eqx.error_if(result, bad, INSTABILITY_MESSAGE)


def simulate(
    grid: Grid,
    medium: Medium,
    sources: PointSources | Sequence[PointSources] = (),
    sensors: Sensors = Sensors(),
    *,
    n_steps: int,
    edges: Edges | None = None,
    checkpoint: Checkpoint = None,
    unroll: int | None = None,
    sharding: jax.sharding.Sharding | None = None,
    adjoint: Literal["autodiff", "lattice", "auto"] = "autodiff",
    throw: bool = True,
    backend: Literal["auto", "jax", "native"] = "auto",
    preflight: Literal["check", "print", "off"] = "check",
    progress: Progress | None = None,
) -> Result:
    """Simulate `n_steps` time steps of the scene and return what the sensors recorded.

    **Arguments:**
    - `grid`: the lattice and its units (`make_grid`).
    - `medium`: speeds, densities, obstacles and the boundary model (SI units).
    - `sources`: one or more `PointSources` (e.g. `line_transducer`).
    - `sensors`: what to record.
    - `n_steps`: number of time steps (static).
    - `edges`: window edges (default `Edges.default_for(grid.kind)`: a 20-cell PML on every side;
      an rz grid's y_lo is the axis).
    - `checkpoint`: None (plain reverse mode), "sqrt" (memory ~ sqrt(n_steps)) or a chunk length.
    - `unroll`: steps per scan iteration (None: the fastest per stepper, see `run`).
    - `sharding`: split the grid across devices (`grid_sharding()`); None: one device.
    - `adjoint`: reverse-mode method, "autodiff" (JAX's), "lattice" (adjoint wave equation,
      faster and memory-bounded) or "auto" (see `run`).
    - `throw`: raise on non-finite fields (otherwise inspect `result.peak_history`).
    - `backend`: "auto" (native CPU kernels where supported), "jax" or "native" (see `run`).
    - `preflight` (every lattice kind): "check" (default) refuses a run whose memory estimate does not fit
      in the available memory (`solver.estimate`, a `RunTooLargeError` naming the estimate and the
      fix), "print" also prints the memory and time estimate before the run starts, "off" skips
      both.
    - `progress`: None, or a callable `progress(steps_done, steps_total)` called on the host after
      each chunk of the run (`Result.chunk_steps`) has finished, e.g. a progress bar's update.
      The run is then a host loop of compiled pieces, one chunk each (`run_pieces`), whose joined
      `Result` equals the whole run's bit for bit; for an eager call (not under `jit`/`grad`)
      and with adjoint="autodiff" or "auto" (a piece starts from a state, which the lattice
      adjoint does not take). None (default): one compiled program, as if the option were absent.
    """
    stepper = Stepper.build(grid, medium, sources, sensors, edges)
    if preflight != "off":
        _preflight(stepper, n_steps, checkpoint=checkpoint, show=preflight == "print")
    traced = any(isinstance(v, jax.core.Tracer) for v in jax.tree_util.tree_leaves(stepper))
    if progress is not None:
        return _simulate_reporting(
            stepper, n_steps, checkpoint, unroll, sharding, adjoint, throw, backend, progress, traced
        )
    if traced:  # inside the caller's jit / vmap / grad: the checks run in the program (eqx.error_if)
        return _simulate(stepper, n_steps, checkpoint, unroll, sharding, adjoint, throw, backend)
    # called eagerly: the same checks in Python around the program, which then has no host
    # callback and so goes to the persistent compilation cache (a program with eqx.error_if's
    # callback never does: each new process compiled the whole run again)
    check_speed(stepper)
    result = _eager(stepper, n_steps, checkpoint, unroll, sharding, adjoint, backend)
    if throw:
        check_finite(result.peak_history)
    return result


Progress = Callable[[int, int], object]
"""A progress callback: `progress(steps_done, steps_total)`, called on the host."""


def _simulate_reporting(stepper, n_steps, checkpoint, unroll, sharding, adjoint, throw, backend, progress, traced):
    """`simulate` with a `progress` callback: the run's chunks as pieces (`run_pieces`), joined."""
    if traced:
        raise ValueError(
            "simulate(progress=...) reports from the host between compiled pieces: call it eagerly, "
            "not under jax.jit / grad / vmap (or leave progress=None there)"
        )
    if adjoint == "lattice":
        raise ValueError(
            "simulate(progress=...) runs pieces from a state, which adjoint='lattice' does not take: "
            "use adjoint='autodiff' (or 'auto'), or progress=None"
        )
    if not isinstance(n_steps, (int, np.integer)) or n_steps < 1:
        raise ValueError(f"n_steps = {n_steps!r} must be a positive integer")
    n_steps = int(n_steps)
    check_speed(stepper)
    chunk = chunking(n_steps, stepper.sensors, checkpoint)
    # a piece of one chunk chunks as the whole run does ("sqrt" is the whole run's chunk length)
    piece_checkpoint = chunk if checkpoint == "sqrt" else checkpoint
    ends = list(range(chunk, n_steps + 1, chunk)) + ([n_steps] if n_steps % chunk else [])
    joined = Joiner()
    for end, piece in zip(
        ends,
        run_pieces(stepper, ends, checkpoint=piece_checkpoint, unroll=unroll, sharding=sharding, backend=backend),
    ):
        joined.add(piece)
        progress(end, n_steps)
    result = joined.result()
    if throw:
        check_finite(result.peak_history)
    return result


def run_pieces(
    stepper: Stepper,
    ends: Iterable[int],
    *,
    state: State | None = None,
    checkpoint: Checkpoint = None,
    unroll: int | None = None,
    sharding: jax.sharding.Sharding | None = None,
    backend: Literal["auto", "jax", "native"] = "auto",
) -> Iterator[Result]:
    """Run from `state` (default: rest) to each step of `ends` (increasing) in turn, yielding
    each piece's `Result` (steps counted from the piece's start) once its arrays are ready.

    Host-side (not jittable): one compiled program per piece length, each piece starting from
    the last one's final state, so the pieces are the whole run cut at `ends` (`scan.Joiner`
    joins them). For progress reports, field moments and snapshots thinned as they arrive;
    the arguments are `run`'s."""
    st: State = stepper.init() if state is None else state
    done = 0
    for end in ends:
        n = int(end) - done
        if n < 1:
            raise ValueError(f"run_pieces: ends must increase from step {done + 1}, got {end}")
        res = _piece(st, stepper, n, checkpoint, unroll, sharding, backend)
        jax.block_until_ready(res.peak_history)
        yield res
        st, done = res.final, int(end)


@eqx.filter_jit
def _piece(state: State, stepper: Stepper, n_steps: int, checkpoint, unroll, sharding, backend) -> Result:
    return run(stepper, n_steps, state=state, checkpoint=checkpoint, unroll=unroll, sharding=sharding, backend=backend)


def check_speed(stepper: Stepper) -> None:
    """Raise `eqx.EquinoxRuntimeError` (the type `eqx.error_if` raises) with `SPEED_MESSAGE` if a
    concrete speed map exceeds the stability limit (eagerly: `simulate`'s out-of-program check)."""
    lat = stepper.lattice
    if jnp.ndim(lat.c) != 0:
        limit = speed_limit(lat, stepper.grid.kind)
        if float(jnp.max(lat.c)) > limit * (1 + 1e-6):
            raise eqx.EquinoxRuntimeError(stepper.grid.kind.speed_message)


def check_finite(peak_history) -> None:
    """Raise `eqx.EquinoxRuntimeError` with `INSTABILITY_MESSAGE` if a run's peak history (concrete)
    is not finite: the eager counterpart of `check_result`, for programs kept free of host
    callbacks (persistently cacheable), e.g. a vmapped batch of runs checked after it returns."""
    if not np.all(np.isfinite(np.asarray(peak_history))):
        raise eqx.EquinoxRuntimeError(INSTABILITY_MESSAGE)


def _simulate_fn(
    stepper: Stepper,
    n_steps: int,
    checkpoint,
    unroll: int | None,
    sharding,
    adjoint,
    throw: bool,
    backend: Literal["auto", "jax", "native"] = "auto",
    speed_check: bool = True,
) -> Result:
    lat = stepper.lattice
    if speed_check and (jnp.ndim(lat.c) != 0 or isinstance(lat.c, jax.core.Tracer)):
        # speeds may be traced (e.g. fitted): check the stability limit at run time
        limit = speed_limit(lat, stepper.grid.kind)
        stepper = eqx.error_if(stepper, jnp.max(lat.c) > limit * (1 + 1e-6), stepper.grid.kind.speed_message)
    result = run(
        stepper, n_steps, checkpoint=checkpoint, unroll=unroll, sharding=sharding, adjoint=adjoint, backend=backend
    )
    if throw:
        result = check_result(result, stepper)
    return result


_simulate = eqx.filter_jit(_simulate_fn)
"""The whole run as one program (`simulate`'s; traced into a caller's program under its `jit`)."""

NATIVE_GLUE_OPTIONS = MappingProxyType({"xla_backend_optimization_level": 0})
"""XLA compiler options of an eagerly called run on the native kernels on a plane (2-D) grid. The
program is glue round the kernels' FFI calls (the chunk loop, sources' tables, sensors' records),
whose run time LLVM's optimisation passes barely change, while they were most of its compile time
(a fit's first lattice run: 1.0 -> 0.6 s CPU); its results are the same bits (tests). Not on rz
grids, where level 0 changed a disc's run by rounding (5.6e-15 relative in float64, 3.7e-6 in
float32), nor on 3-D grids (not compared): they keep XLA's default, as does the JAX scan, whose
run time is the loop itself (`_simulate`)."""

_GLUE_JIT: dict[str, Any] = {"compiler_options": dict(NATIVE_GLUE_OPTIONS)}  # passed on to jax.jit
_simulate_native = eqx.filter_jit(_simulate_fn, **_GLUE_JIT)


def _native_ready() -> bool:
    return not isinstance(native.load(), str)


def _native_key() -> str:
    """What fixes a native run's program beyond its arguments: the kernels' settings read while
    tracing (threads, levels, schedule), the CPUs this process may use, the kernels' library."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cpus = os.cpu_count() or 1
    settings = sorted((k, v) for k, v in os.environ.items() if k.startswith("DIFFLATTICE_NATIVE"))
    lib = native.load()
    return f"{settings};cpus={cpus};lib={getattr(lib, 'path', lib)}"


_NATIVE_KERNELS = Kernels(frozenset(native.build.TARGETS), _native_ready, _native_key)
_simulate_native_cached = CachedProgram(_simulate_fn, NATIVE_GLUE_OPTIONS, kernels=_NATIVE_KERNELS)
_simulate_cached = CachedProgram(_simulate_fn, {}, kernels=_NATIVE_KERNELS)


def _eager(stepper: Stepper, n_steps, checkpoint, unroll, sharding, adjoint, backend) -> Result:
    """`simulate`'s program, called eagerly (no host callback): a run the chooser gives to the
    native kernels is kept whole on disk where the program cache is on (`program_cache`: a new
    process neither traces nor lowers it), compiled with `NATIVE_GLUE_OPTIONS` on a plane grid;
    any other run is `_simulate`."""
    args = (stepper, n_steps, checkpoint, unroll, sharding, adjoint, False, backend)
    kwargs: dict[str, Any] = {"speed_check": False}
    try:
        on_native = isinstance(
            choose(Request(stepper, n_steps, None, checkpoint, unroll, sharding, adjoint), backend).backend, Native
        )
    except Exception:  # noqa: BLE001 - a request the trace refuses: `_simulate` raises its own error
        on_native = False
    if not on_native:
        return _simulate(*args, **kwargs)
    plane = stepper.grid.kind is PLANE
    out = (_simulate_native_cached if plane else _simulate_cached)(args, kwargs)
    if out is not NotImplemented:
        return out
    return (_simulate_native if plane else _simulate)(*args, **kwargs)
