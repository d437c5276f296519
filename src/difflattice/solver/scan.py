"""The JAX time loop: a scan of chunks of steps with the sensors recorded inside (the reference
implementation, and the path on GPUs), its `Result`, the chunking and grid sharding. The native
kernels and the adjoint build on it; `loop.run` chooses between them (`loop` is the one module
that imports them all, so the solver's imports form no circle)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float, Int

from .sensors import Sensors
from .stepper import State, Stepper


class Result(eqx.Module):
    """What `simulate` returns. Times are in steps of `grid.dt_s`; pressures in Pa.

    - `probes`: (n_steps, n_probes) pressure at the probe cells, steps 1..n_steps.
    - `phasors`: (m,) complex DFT sum_n p(n) exp(+i omega n) at the phasor cells.
    - `p_max`, `p_rms`: whole-field peak |p| and RMS; `arrival`: first step above threshold.
    - `snapshots`: (k, nx, ny) fields at steps `snapshot_steps`; on a 3-D grid a tuple with one
      (k, n_i, n_j) array per plane of `sensors.snapshot_slices` (or (k, nx, ny, nz) volumes).
    - `peak_history`: (n_chunks,) max |p| at the end of each chunk (`chunk_steps`).
    - `backend`: the backend that ran ("jax", "sharded", "native", "lattice adjoint"; see
      `solver.backends`) and `backend_why_not`: (name, reason) of each one passed over.
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
    backend: str = eqx.field(static=True, default="jax")
    backend_why_not: tuple[tuple[str, str], ...] = eqx.field(static=True, default=())

    @property
    def snapshot_steps(self) -> tuple[int, ...]:
        return self.chunk_steps

    @classmethod
    def of_final(cls, final: State, probes, peaks, snapshots, n_steps: int, chunk_steps) -> Result:
        """The result of a run that ended in `final` (its phasors, peak and RMS fields, arrival),
        with the probe series, per-chunk peaks and snapshots the loop collected: the one place a
        forward run's `Result` is assembled (JAX scan and native kernels alike)."""
        phasors = None
        if final.phasor_re is not None and final.phasor_im is not None:
            phasors = jax.lax.complex(final.phasor_re, final.phasor_im)
        p_rms = None if final.p_sq is None else jnp.sqrt(final.p_sq / n_steps)
        return cls(
            final=final,
            probes=probes,
            phasors=phasors,
            p_max=final.p_max,
            p_rms=p_rms,
            arrival=final.arrival,
            snapshots=snapshots,
            peak_history=peaks,
            n_steps=n_steps,
            chunk_steps=tuple(chunk_steps),
        )


class Joiner:
    """Joins the `Result`s of consecutive pieces of one run (each started from the last one's
    final state) into the run's `Result`: probes, peaks and snapshots concatenated, chunk steps
    counted from the run's start, phasors and field statistics from the last final state (they
    accumulate in the state). Host-side; keeps only the recorded series, not each piece's state.
    `keep_snapshots=False` drops the pieces' snapshots (a caller that thins them as they arrive)."""

    def __init__(self, keep_snapshots: bool = True):
        self.keep_snapshots = keep_snapshots
        self.done = 0
        self.final: State | None = None
        self.last: Result | None = None
        self.probes: list = []
        self.peaks: list = []
        self.snapshots: list = []
        self.steps: list[int] = []

    def add(self, piece: Result) -> None:
        """Append the next piece (its steps follow the pieces added so far)."""
        self.final, self.last = piece.final, piece
        if piece.probes is not None:
            self.probes.append(piece.probes)
        self.peaks.append(piece.peak_history)
        if self.keep_snapshots and piece.snapshots is not None:
            self.snapshots.append(piece.snapshots)
        self.steps += [self.done + s for s in piece.chunk_steps]
        self.done += piece.n_steps

    def result(self) -> Result:
        """The whole run's `Result` (at least one piece added)."""
        if self.final is None:
            raise ValueError("Joiner.result: no piece was added")
        cat = lambda *a: jnp.concatenate(a, axis=0)
        snaps = jax.tree_util.tree_map(cat, *self.snapshots) if self.snapshots else None
        probes = cat(*self.probes) if self.probes else None
        joined = Result.of_final(self.final, probes, cat(*self.peaks), snaps, self.done, self.steps)
        assert self.last is not None
        return dataclasses.replace(joined, backend=self.last.backend, backend_why_not=self.last.backend_why_not)


# ------------------------------------------------------------------------------------------
# the time loop

Checkpoint = Literal["sqrt"] | int | None


def chunking(n_steps: int, sensors: Sensors, checkpoint: Checkpoint) -> int:
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


def run_jax(
    stepper: Stepper,
    n_steps: int,
    *,
    state: State | None = None,
    checkpoint: Checkpoint = None,
    unroll: int | None = None,
    sharding: jax.sharding.Sharding | None = None,
) -> Result:
    """`n_steps` steps of the JAX loop from `state` (default: rest), sensors recorded in the scan
    (see `loop.run` for the arguments). Pure and jittable."""
    if unroll is None:
        unroll = 1 if stepper.staggered else 2
    sens = stepper.sensors
    chunk = chunking(n_steps, sens, checkpoint)
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

    return Result.of_final(final, ys, peaks, snaps, n_steps, steps)


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
