"""The time loop and the one entry point, `simulate`.

`simulate` is a pure function of its array inputs (medium maps, source weights and lags), so it
works under `jax.jit`, `jax.grad`, `jax.jvp` and `jax.vmap`. Sensors are recorded inside the
scan; the time loop is a scan of chunks of steps, which gives snapshots every k steps, a
per-chunk record of the peak |p| (instability detection), and memory-bounded reverse mode
(`checkpoint="sqrt"`: each chunk is recomputed in the backward pass, memory ~ sqrt(steps)).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float, Int

from ..lattice.coefficients import Edges, speed_limit
from ..lattice.grid import Grid
from ..lattice.kinds import PLANE, VOLUME
from ..lattice.medium import Medium
from .sensors import Sensors
from .sources import PointSources
from .stepper import State, Stepper


class Result(eqx.Module):
    """What `simulate` returns. Times are in steps of `grid.dt_s`; pressures in Pa.

    - `probes`: (n_steps, n_probes) pressure at the probe cells, steps 1..n_steps.
    - `phasors`: (m,) complex DFT sum_n p(n) exp(+i omega n) at the phasor cells.
    - `p_max`, `p_rms`: whole-field peak |p| and RMS; `arrival`: first step above threshold.
    - `snapshots`: (k, nx, ny) fields at steps `snapshot_steps`; on a 3-D grid a tuple with one
      (k, n_i, n_j) array per plane of `sensors.snapshot_slices` (or (k, nx, ny, nz) volumes).
    - `peak_history`: (n_chunks,) max |p| at the end of each chunk (`chunk_steps`).
    """

    final: State
    probes: Float[Array, "t n"] | None
    phasors: Complex[Array, " m"] | None
    p_max: Float[Array, "nx ny"] | None
    p_rms: Float[Array, "nx ny"] | None
    arrival: Int[Array, "nx ny"] | None
    snapshots: Float[Array, "k nx ny"] | tuple[Float[Array, "k ni nj"], ...] | None
    peak_history: Float[Array, " c"]
    n_steps: int = eqx.field(static=True)
    chunk_steps: tuple[int, ...] = eqx.field(static=True)

    @property
    def snapshot_steps(self) -> tuple[int, ...]:
        return self.chunk_steps


# ------------------------------------------------------------------------------------------
# the time loop

Checkpoint = Literal["sqrt"] | int | None


def _chunking(n_steps: int, sensors: Sensors, checkpoint: Checkpoint) -> int:
    if sensors.snapshot_every is not None:
        return min(sensors.snapshot_every, n_steps)
    if checkpoint == "sqrt":
        return max(1, math.ceil(math.sqrt(n_steps)))
    if isinstance(checkpoint, int) and not isinstance(checkpoint, bool):
        if checkpoint < 1:
            raise ValueError(f"checkpoint = {checkpoint}: give a chunk length >= 1 step")
        return min(checkpoint, n_steps)
    if checkpoint is not None:
        raise ValueError(f"checkpoint = {checkpoint!r}; allowed: None, 'sqrt' or a chunk length in steps")
    return min(n_steps, 128)


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
    except with adjoint="lattice", whose forward and backward runs are native where supported."""
    if not isinstance(n_steps, (int, np.integer)) or n_steps < 1:
        raise ValueError(f"n_steps = {n_steps!r} must be a positive integer")
    n_steps = int(n_steps)
    if adjoint not in ("autodiff", "lattice", "auto"):
        raise ValueError(f"adjoint = {adjoint!r}; allowed: 'autodiff', 'lattice', 'auto'")
    # --- native CPU kernels (issue 15): the one dispatch hook ------------------------------
    if backend != "jax":
        from . import native

        result = native.dispatch(
            stepper,
            n_steps,
            state=state,
            checkpoint=checkpoint,
            unroll=unroll,
            sharding=sharding,
            adjoint=adjoint,
            backend=backend,
        )
        if result is not None:
            return result
    # ------------------------------------------------------------------------------------------
    if adjoint != "autodiff":
        from . import adjoint as adj

        reason = adj.supports(stepper, state)
        if reason is None and sharding is None:
            on_native = False
            if backend != "jax":
                from . import native as nat

                why = nat.why_not(stepper, state, sharding)
                if why is not None and backend == "native":
                    raise ValueError(
                        f"backend='native' is not available for this run: {why} (use backend='auto' or 'jax')"
                    )
                on_native = why is None
            return _run_lattice_adjoint(stepper, n_steps, checkpoint, on_native)
        if adjoint == "lattice":
            raise ValueError(
                f"adjoint='lattice' does not support {reason or 'sharding'}: use adjoint='autodiff' "
                "(or 'auto' to choose per scene)"
            )
    if unroll is None:
        unroll = 1 if stepper.staggered else 2
    sens = stepper.sensors
    chunk = _chunking(n_steps, sens, checkpoint)
    n_chunks, rem = divmod(n_steps, chunk)
    final: State = stepper.init() if state is None else state
    constrain = _constrainer(stepper.grid.shape, sharding)
    final = constrain(final)

    def one(st, _):
        st, ys = stepper.step(st)
        return constrain(st), ys

    def chunk_scan(st, length):
        f = lambda s: jax.lax.scan(one, s, None, length=length, unroll=min(unroll, length))
        if checkpoint is not None:
            f = jax.checkpoint(f)
        return f(st)

    def outer(st, _):
        st, ys = chunk_scan(st, chunk)
        p = st.pressure
        peak = jnp.max(jnp.abs(p))
        snap = sens.snapshot_of(p) if sens.snapshot_every is not None else None
        return st, (ys, peak, snap)

    final, (ys, peaks, snaps) = jax.lax.scan(outer, final, None, length=n_chunks)
    steps = [chunk * (i + 1) for i in range(n_chunks)]
    if ys is not None:
        ys = ys.reshape(n_chunks * chunk, -1)
    if rem:
        final, ys_r = chunk_scan(final, rem)
        peaks = jnp.concatenate([peaks, jnp.max(jnp.abs(final.pressure))[None]])
        steps.append(n_steps)
        if ys is not None:
            ys = jnp.concatenate([ys, ys_r.reshape(rem, -1)], axis=0)
        if snaps is not None and sens.snapshot_every is not None:
            last = sens.snapshot_of(final.pressure)
            snaps = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b[None]], axis=0), snaps, last)

    phasors = None
    if final.phasor_re is not None and final.phasor_im is not None:
        phasors = jax.lax.complex(final.phasor_re, final.phasor_im)
    p_rms = None if final.p_sq is None else jnp.sqrt(final.p_sq / n_steps)
    return Result(
        final=final,
        probes=ys,
        phasors=phasors,
        p_max=final.p_max,
        p_rms=p_rms,
        arrival=final.arrival,
        snapshots=snaps,
        peak_history=peaks,
        n_steps=n_steps,
        chunk_steps=tuple(steps),
    )


def _run_lattice_adjoint(stepper: Stepper, n_steps: int, checkpoint: Checkpoint, native: bool) -> Result:
    from .adjoint import linear_run

    chunk = _chunking(n_steps, stepper.sensors, "sqrt" if checkpoint is None else checkpoint)
    probes, re, im, p, p_prev, peaks = linear_run(stepper, n_steps, chunk, native)
    final = eqx.tree_at(
        lambda s: (s.p, s.p_prev, s.n, s.phasor_re, s.phasor_im),
        stepper.init(),
        (p, p_prev, jnp.asarray(n_steps, jnp.int32), re, im),
        is_leaf=lambda x: x is None,
    )
    n_chunks, rem = divmod(n_steps, chunk)
    steps = [chunk * (i + 1) for i in range(n_chunks)] + ([n_steps] if rem else [])
    return Result(
        final=final,
        probes=probes,
        phasors=None if re is None else jax.lax.complex(re, im),
        p_max=None,
        p_rms=None,
        arrival=None,
        snapshots=None,
        peak_history=peaks,
        n_steps=n_steps,
        chunk_steps=tuple(steps),
    )


def _constrainer(shape, sharding):
    """Apply `sharding` to every grid-shaped field of a State (identity without a sharding)."""
    if sharding is None:
        return lambda st: st

    def f(st):
        return jax.tree_util.tree_map(
            lambda a: jax.lax.with_sharding_constraint(a, sharding) if a.shape == tuple(shape) else a, st
        )

    return f


def grid_sharding(devices: Sequence | None = None, axis: int = 0, ndim: int = 2) -> jax.sharding.NamedSharding:
    """A sharding that splits grid-shaped arrays of rank `ndim` (3 for a 3-D grid) along `axis`
    (0 = x) across `devices` (default: all devices). On a CPU,
    `XLA_FLAGS=--xla_force_host_platform_device_count=N` (set before JAX starts) gives N host
    devices, one per core."""
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    if ndim not in (2, 3) or not 0 <= axis < ndim:
        raise ValueError(f"grid_sharding(axis={axis}, ndim={ndim}): ndim is 2 or 3 and 0 <= axis < ndim")
    devs = np.asarray(jax.devices() if devices is None else list(devices))
    spec = PartitionSpec(*("grid" if a == axis else None for a in range(ndim)))
    return NamedSharding(Mesh(devs, ("grid",)), spec)


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
    edges: Edges = Edges(),
    checkpoint: Checkpoint = None,
    unroll: int | None = None,
    sharding: jax.sharding.Sharding | None = None,
    adjoint: Literal["autodiff", "lattice", "auto"] = "autodiff",
    throw: bool = True,
    backend: Literal["auto", "jax", "native"] = "auto",
    preflight: Literal["check", "print", "off"] = "check",
) -> Result:
    """Simulate `n_steps` time steps of the scene and return what the sensors recorded.

    **Arguments:**
    - `grid`: the lattice and its units (`make_grid`).
    - `medium`: speeds, densities, obstacles and the boundary model (SI units).
    - `sources`: one or more `PointSources` (e.g. `line_transducer`).
    - `sensors`: what to record.
    - `n_steps`: number of time steps (static).
    - `edges`: window edges (default: 20-cell PML on every side).
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
    """
    stepper = Stepper.build(grid, medium, sources, sensors, edges)
    if preflight != "off":
        from .estimate import preflight as _preflight

        _preflight(stepper, n_steps, checkpoint=checkpoint, show=preflight == "print")
    traced = any(isinstance(v, jax.core.Tracer) for v in jax.tree_util.tree_leaves(stepper))
    if traced:  # inside the caller's jit / vmap / grad: the checks run in the program (eqx.error_if)
        return _simulate(stepper, n_steps, checkpoint, unroll, sharding, adjoint, throw, backend)
    # called eagerly: the same checks in Python around the program, which then has no host
    # callback and so goes to the persistent compilation cache (a program with eqx.error_if's
    # callback never does: each new process compiled the whole run again)
    check_speed(stepper)
    result = _simulate(stepper, n_steps, checkpoint, unroll, sharding, adjoint, False, backend, speed_check=False)
    if throw:
        check_finite(result.peak_history)
    return result


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


@eqx.filter_jit
def _simulate(
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
