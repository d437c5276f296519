"""The time loop on the native kernels: the chunked loop of `loop.run` (same chunks, peak history,
snapshots and `Result`), each chunk of steps one XLA FFI call that also injects the sources and
records probes, phasors and field statistics.

Derivatives: the native loop is a `custom_jvp` whose rule is the JAX reference loop
(`loop.run(..., backend="jax")`), so `jax.jvp`, `jax.grad` and `jax.jacfwd` through a native run
give JAX's own derivatives (never the derivative of an opaque call, never silently wrong); only
runs that are not differentiated execute the native kernel. Reverse mode at native speed is
`adjoint="lattice"` (solver/adjoint.py), whose forward and backward runs call these kernels
(`_Chunk.advance`, `adjoint_steps`, `adjoint_chunk`).
"""

from __future__ import annotations

import dataclasses
import os

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ...lattice.coefficients import Lattice
from ...lattice.operators import _face_coefficients
from ..scan import Result, chunking, run_jax
from ..stepper import LeapfrogState, StaggeredState, State, Stepper
from .chunk_io import pack_layers, stats_in, step_tables, unpack_layers
from .signatures import ADJOINT_CHUNK, LAYERED, LEAPFROG
from .volume import VolumeChunk, schedule_3d, unsupported_3d

# Lattice fields the kernels implement; a field added to `Lattice` later is refused (the JAX loop
# runs) until the kernels learn it
KNOWN_LATTICE_FIELDS = frozenset(
    {
        "K",
        "q_scale",
        "bx",
        "by",
        "ax_lo",
        "ax_hi",
        "ay_lo",
        "ay_hi",
        "keep",
        "c",
        "sponge",
        "pml",
        "metric",
        "eta",
        "ghosts",
        "mur",
        "stencil",  # both run natively (attribute `stencil` of the FFI calls)
        "uniform_faces",  # a stability-limit fact, no term
        "relax",  # air absorption: memory fields Q_O, Q_N (both kernels; `_relax_unsupported`)
    }
)
# likewise the carried state, the sensors' options and the sources' injection modes
KNOWN_STATE_FIELDS = frozenset(
    {
        "n",
        "p",
        "p_prev",
        "layers",
        "phasor_re",
        "phasor_im",
        "p_max",
        "p_sq",
        "arrival",
        "relax_q",
    }
)
KNOWN_SENSOR_FIELDS = frozenset(
    {
        "probes",
        "phasor_cells",
        "phasor_frequency_hz",
        "p_max",
        "p_rms",
        "arrival_threshold_pa",
        "snapshot_every",
        "phasor_from_step",
        "snapshot_slices",  # 3-D grids: the planes kept (`Sensors.snapshot_of`, taken outside the kernels)
    }
)
KNOWN_INJECTIONS = frozenset({"soft", "hard", "velocity"})
L1_BYTES = 40 * 1024  # working-set budgets of the temporal blocking (most x86 cores: 48 KB L1d,
L2_BYTES = 512 * 1024  # >= 1 MB L2)


def unsupported(stepper: Stepper, state: State | None, sharding) -> str | None:
    """None if the native kernels run this scene, otherwise the reason they do not."""
    if sharding is not None:
        return "a sharded run (the native kernels run on one host)"
    if jax.default_backend() != "cpu":
        return f"the {jax.default_backend()} backend (the native kernels run on CPUs)"
    grid, lat = stepper.grid, stepper.lattice
    rank = len(grid.shape)
    if rank not in (2, 3):
        return f"a {rank}-D grid (the native kernels are 2-D, rz and 3-D)"
    if grid.dtype not in ("float32", "float64"):
        return f"dtype {grid.dtype}"
    if type(stepper) is not Stepper or type(lat) is not Lattice:
        return f"a custom stepper ({type(stepper).__name__})"
    known = KNOWN_LATTICE_FIELDS | ({"bz"} if rank == 3 else set())
    extra = [f.name for f in dataclasses.fields(lat) if f.name not in known and getattr(lat, f.name) is not None]
    if extra:
        return f"lattice terms the kernels do not implement ({', '.join(extra)})"
    sens = stepper.sensors
    new_options = [
        f.name for f in dataclasses.fields(sens) if f.name not in KNOWN_SENSOR_FIELDS and _is_set(getattr(sens, f.name))
    ]
    if new_options:
        return f"sensor options the kernels do not implement ({', '.join(new_options)})"
    modes = {s.injection for s in stepper.sources} - KNOWN_INJECTIONS
    if modes:
        return f"source injection {', '.join(sorted(modes))}"
    carried = jax.eval_shape(stepper.init)
    new_state = [
        f.name
        for f in dataclasses.fields(carried)
        if f.name not in KNOWN_STATE_FIELDS and getattr(carried, f.name) is not None
    ]
    if new_state:
        return f"carried state the kernels do not update ({', '.join(new_state)})"
    if rank == 3:
        return unsupported_3d(stepper, state)
    if any(lat.mur):
        return "Mur edges"
    why = _relax_unsupported(stepper)
    if why:
        return why
    if lat.stencil != "standard":
        m = getattr(lat, "metric", None)
        if m is not None and not all(jnp.shape(v)[:-1] in ((), (1,)) for v in (m.lo, m.hi)):
            return "the isotropic stencil with an rz metric that varies along z"
    rad = None if lat.pml is None else getattr(lat.pml, "radial", None)
    if rad is not None and not (hasattr(rad, "decay") and hasattr(rad, "drive")):
        return "an rz r_hi PML correction the kernels do not implement"
    if lat.ax_lo is not None:
        return 'the "paper" boundary model'
    nx, ny = grid.shape
    layouts = {
        "K": (nx, ny),
        "q_scale": (nx, ny),
        "keep": (nx, ny),
        "sponge": (nx, ny),
        "bx": (nx + 1, ny),
        "by": (nx, ny + 1),
    }
    for name, full in layouts.items():
        v = getattr(lat, name)
        if v is not None and not _broadcasts(jnp.shape(v), full):
            return f"a {name} array of shape {jnp.shape(v)} (not a row, column or full layout of {full})"
    if stepper.staggered and lat.pml is None:
        return "a staggered stepper without PML factors"
    metric = getattr(lat, "metric", None)
    if metric is not None and not all(_broadcasts(jnp.shape(v), (nx, ny)) for v in (metric.lo, metric.hi)):
        return "an rz metric that is not a row, column or full layout"
    if state is not None and stepper.staggered != isinstance(state, StaggeredState):
        return "a start state of the other stepper"
    return None


def _relax_unsupported(stepper: Stepper) -> str | None:
    """Why the kernels cannot run this scene's air absorption (None: no absorption, or one they run)."""
    r = stepper.lattice.relax
    if r is None:
        return None
    if len(r.eps) != 2 or len(r.a) != 2 or len(r.g) != 2:
        return f"air absorption with {len(r.eps)} relaxation processes (the kernels carry two: O2, N2)"
    if any(jnp.size(v) != 1 for v in (r.eta, *r.eps, *r.a, *r.g)):
        return "air absorption whose coefficients vary in space (the kernels take one value each)"
    return None


def _relax_coefficients(lat: Lattice, dt):
    """The leapfrog kernel's 7 air-absorption coefficients (eta, eps_O, eps_N, a_O, a_N, g_O, g_N)."""
    r = lat.relax
    assert r is not None
    return jnp.stack([jnp.asarray(v, dt).reshape(()) for v in (r.eta, *r.eps, *r.a, *r.g)])


def _bands(stepper: Stepper) -> bool:
    """Row bands with a barrier per step instead of the pipeline of blocked steps, only where
    `DIFFLATTICE_NATIVE_SCHEDULE=bands` asks (leapfrog only). Measured on a quiet 2-vCPU EPYC,
    840x630 x 1000, two threads: pipeline 8621 MLUPS (median of 5; numba's two threads 8761),
    bands 3618 (best 7549: a barrier per step stalls both threads whenever one is disturbed)."""
    return os.environ.get("DIFFLATTICE_NATIVE_SCHEDULE") == "bands" and not stepper.staggered


def _is_set(v) -> bool:
    """An option away from its 'off' value (None, False, 0, empty)."""
    if v is None or isinstance(v, bool):
        return bool(v)
    if isinstance(v, (int, float)):
        return v != 0
    if hasattr(v, "size"):
        return int(v.size) > 0
    if isinstance(v, (tuple, list)):
        return len(v) > 0
    return True


def _broadcasts(shape, full) -> bool:
    n, m = full
    return tuple(shape) in ((), (1,), (1, 1), (n, m), (n, 1), (1, m))


def _threads(nx: int, levels: int) -> int:
    """Threads of the pipeline: every CPU this process may use, but no more than keep the
    pipeline's fill and drain (each thread starts ~levels + 2 rows after the one before it) under
    a quarter of a sweep."""
    env = os.environ.get("DIFFLATTICE_NATIVE_THREADS")
    if env:
        return max(1, int(env))
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cpus = os.cpu_count() or 1
    return max(1, min(cpus, nx // (4 * (levels + 2))))


def _levels(ny: int, itemsize: int, staggered: bool, extra_fields: int = 0) -> int:
    """Steps each thread advances per sweep over the rows (temporal blocking): as many as keep a
    sweep's rows (about `levels + 2` rows of each field) in L1, else in L2. Measured on a Xeon
    (Sapphire Rapids class, 2 cores; benchmarks/native_tuning.py): rows of 630 cells ran fastest
    with 8 steps per sweep (L1), rows of 2048 with 32 (L2). `extra_fields`: more fields a step
    reads and writes per row (air absorption: the two memory fields, and P(n-1) with a PML)."""
    env = os.environ.get("DIFFLATTICE_NATIVE_LEVELS")
    if env:
        return max(1, int(env))
    row = ny * itemsize * ((6 if staggered else 2) + extra_fields)  # bytes of one row of every field a step touches
    in_l1 = L1_BYTES // row
    if in_l1 >= 6:
        return min(in_l1, 16)
    return max(2, min(32, L2_BYTES // row - 2))


# ------------------------------------------------------------------------------------------
# one chunk of steps = one FFI call


_STATS = ("ph_re", "ph_im", "p_max", "p_sq", "arrival")  # the sensors' running records, as the kernels name them


def _absent(dtype):
    return jnp.zeros((0,), dtype)


def _cells(cells):
    return jnp.asarray(cells, jnp.int32).reshape(-1, 2)


class _Chunk:
    """The constant inputs of the FFI calls of one stepper (built once per trace)."""

    def __init__(self, stepper: Stepper, threads: int, levels: int, bands: bool):
        self.stepper = stepper
        grid, lat, sens = stepper.grid, stepper.lattice, stepper.sensors
        self.dt = dt = grid.jnp_dtype
        self.shape = grid.shape
        self.attrs = dict(
            threads=np.int64(threads),
            levels=np.int64(levels),
            eta=float(lat.eta),
            threshold=float(sens.arrival_threshold_pa or 0.0),
        )
        self.bands = np.int64(bands)
        as_dt = lambda v: _absent(dt) if v is None else jnp.asarray(v, dt)
        bx, by = _face_coefficients(lat, self.shape, dt)
        self.coef = [as_dt(lat.K), as_dt(bx), as_dt(by), as_dt(lat.q_scale), as_dt(lat.keep)]
        metric = getattr(lat, "metric", None)  # rz grids: per-ring factors of the radial faces
        self.metric = [as_dt(None if metric is None else metric.lo), as_dt(None if metric is None else metric.hi)]
        self.sponge = as_dt(lat.sponge)
        self.relax = _absent(dt) if lat.relax is None else _relax_coefficients(lat, dt)
        if stepper.staggered:
            pml = lat.pml
            self.pml = [
                as_dt(getattr(pml, k))
                for k in ("ax_cell", "bx_cell", "ax_face", "bx_face", "ay_cell", "by_cell", "ay_face", "by_face")
            ]
            rad = getattr(pml, "radial", None)  # rz r_hi layer: the ring field C's update factors
            self.radial = [
                as_dt(None if rad is None else rad.decay.reshape(-1)),
                as_dt(None if rad is None else rad.drive.reshape(-1)),
            ]
            assert pml is not None
            self.boxes = jnp.asarray(
                np.array([[r0, r1, c0, c1] for (r0, r1), (c0, c1) in pml.boxes], np.int32).reshape(-1, 4)
            )
        srcs = stepper.sources
        self.src_cells = (
            _cells(jnp.concatenate([_cells(s.cells) for s in srcs])) if srcs else jnp.zeros((0, 2), jnp.int32)
        )
        self.src_hard = jnp.asarray(
            np.concatenate([np.full(s.n_cells, s.injection == "hard", np.int32) for s in srcs])
            if srcs
            else np.zeros(0, np.int32)
        )
        self.rec_cells = _cells(sens.probes)
        self.ph_cells = _cells(sens.phasor_cells)
        self.n_probes, self.n_ph = sens.n_probes, sens.n_phasors

    def tables(self, n0, length):
        """Per-step source values (length, n_src) and phasor cos/sin (length,) (`chunk_io.step_tables`)."""
        return step_tables(self.stepper, self.dt, self.n_ph, n0, length)

    def _stats_in(self, st: State):
        return stats_in(self.dt, st)

    def advance(self, st: State, length: int):
        """`length` steps from `st`; returns the new state and the probes (length, n) or None."""
        assert isinstance(st, (LeapfrogState, StaggeredState))  # unsupported() refuses other states
        vals, cos, sin = self.tables(st.n, length)
        stats = self._stats_in(st)
        n0 = jnp.asarray(st.n, jnp.int32)
        rq = [] if st.relax_q is None else [*st.relax_q, self.relax]
        args = {
            "p": st.p,
            "pp": st.p_prev,
            **dict(zip(("K", "bx", "by", "qs", "keep"), self.coef)),
            "sponge": self.sponge,
            **dict(zip(("my_lo", "my_hi"), self.metric)),
            "src_cells": self.src_cells,
            "src_hard": self.src_hard,
            "src_vals": vals,
            "rec_cells": self.rec_cells,
            "zero_cells": jnp.zeros((0, 2), jnp.int32),
            "ph_cells": self.ph_cells,
            "ph_cos": cos,
            "ph_sin": sin,
            **dict(zip(_STATS, stats)),
            "n0": n0,
        }
        field = jax.ShapeDtypeStruct(self.shape, self.dt)
        rets = {
            "p": field,
            "pp": field,
            "rec": jax.ShapeDtypeStruct((length, self.n_probes), self.dt),
            **{k: jax.ShapeDtypeStruct(a.shape, a.dtype) for k, a in zip(_STATS, stats)},
        }
        sig = LEAPFROG
        layered = isinstance(st, StaggeredState)
        if layered:  # PML layers: the boxes' fields packed (parts, faces, ring corrections), then the factors
            assert isinstance(st, StaggeredState)
            packed = dict(zip(("lp", "lw", "lc"), _pack_layers(st.layers, self.dt)))
            args |= packed | {"boxes": self.boxes}
            args |= dict(zip(("axc", "bxc", "axf", "bxf", "ayc", "byc", "ayf", "byf"), self.pml))
            args |= dict(zip(("rad_decay", "rad_drive"), self.radial))
            rets |= {k: jax.ShapeDtypeStruct(a.shape, a.dtype) for k, a in packed.items()}
            sig = LAYERED
        if rq:  # air absorption: the memory fields and coefficients (a lossless call passes none)
            args |= dict(zip(("rq0", "rq1", "relax"), rq))
            rets |= {k: jax.ShapeDtypeStruct(a.shape, a.dtype) for k, a in zip(("rq0", "rq1"), rq)}
        out = sig.call(
            args,
            rets,
            n_steps=np.int64(length),
            combine=np.int64(0),
            stencil=np.int64(self.stepper.lattice.stencil == "isotropic"),
            bands=np.int64(0) if layered else self.bands,
            **self.attrs,
        )
        st = eqx.tree_at(lambda s: (s.p, s.p_prev), st, (out["p"], out["pp"]))
        if layered:
            assert isinstance(st, StaggeredState)
            st = eqx.tree_at(lambda s: s.layers, st, _unpack_layers(st.layers, (out["lp"], out["lw"], out["lc"])))
        if rq:
            st = eqx.tree_at(lambda s: s.relax_q, st, (out["rq0"], out["rq1"]))
        rec, stats_out = out["rec"], [out[k] for k in _STATS]
        names = ("phasor_re", "phasor_im", "p_max", "p_sq", "arrival")
        present = tuple(k for k in names if getattr(st, k) is not None)
        if present:
            new = dict(zip(names, stats_out))
            st = eqx.tree_at(lambda s: tuple(getattr(s, k) for k in present), st, tuple(new[k] for k in present))
        st = eqx.tree_at(lambda s: s.n, st, st.n + length)
        return st, (rec if self.n_probes else None)

    def adjoint_steps(self, x, h, length: int, inj_cells, inj_vals, rec_cells, zero_cells):
        """`length` steps of the adjoint recurrence ``x' = 2 x + L(K x) - h`` (kernel mode
        ``combine = 2``; the pair (x, h) becomes (x', x)). After each step `inj_vals[k]` is added
        at `inj_cells`, `rec_cells` are recorded, then `zero_cells` set to zero. The lattice must
        have no q_scale, keep, sponge or viscous term (the caller checks: `adjoint_supported`).
        Returns (x, h, records (length, n_rec))."""
        dt = self.dt
        e = _absent(dt)
        field = jax.ShapeDtypeStruct(self.shape, dt)
        absent_ret = jax.ShapeDtypeStruct((0,), dt)
        args = {
            "p": x,
            "pp": h,
            **dict(zip(("K", "bx", "by"), self.coef[:3])),
            **dict.fromkeys(("qs", "keep", "sponge"), e),
            **dict(zip(("my_lo", "my_hi"), self.metric)),
            "src_cells": inj_cells,
            "src_hard": jnp.zeros((inj_cells.shape[0],), jnp.int32),
            "src_vals": inj_vals.astype(dt),
            "rec_cells": rec_cells,
            "zero_cells": zero_cells,
            "ph_cells": jnp.zeros((0, 2), jnp.int32),
            "ph_cos": jnp.zeros((length,), dt),
            "ph_sin": jnp.zeros((length,), dt),
            **dict.fromkeys(("ph_re", "ph_im", "p_max", "p_sq"), e),
            "arrival": _absent(jnp.int32),
            "n0": jnp.asarray(0, jnp.int32),
        }
        rets = {
            "p": field,
            "pp": field,
            "rec": jax.ShapeDtypeStruct((length, int(rec_cells.shape[0])), dt),
            **dict.fromkeys(("ph_re", "ph_im", "p_max", "p_sq"), absent_ret),
            "arrival": jax.ShapeDtypeStruct((0,), jnp.int32),
        }
        out = LEAPFROG.call(
            args,
            rets,
            ("p", "pp"),  # in place: the fields only
            n_steps=np.int64(length),
            combine=np.int64(2),
            stencil=np.int64(0),
            bands=np.int64(0),
            **self.attrs,
        )
        return out["p"], out["pp"], out["rec"]

    def adjoint_chunk(self, end, x, h, length: int, n0, faces, metric, inj_cells, inj_vals, rec_cells, zero_cells, acc):
        """The lattice adjoint's backward pass over steps n0 + length .. n0 + 1 with the
        coefficients' cotangents (`difflattice_adjoint_chunk`): the forward fields are stepped
        back from `end` = (p(n0 + length), p(n0 + length - 1)) alongside; `faces` = the full (bx,
        by) arrays; `metric` = (ml, mh, volumes, areas) rows (empty arrays on a plane grid); `acc` =
        the (dK, dbx, dby) sums so far (empty arrays: not wanted). Returns (x, h, records (length,
        n_rec), acc)."""
        dt = self.dt
        vals, _, _ = self.tables(n0 - 2, length + 2)  # steps n0 - 1 .. n0 + length
        steps = n0 - 1 + jnp.arange(length + 2, dtype=jnp.int32)
        vals = jnp.where((steps >= 1)[:, None], vals, 0.0).astype(dt)  # p(0) = 0: the run starts at rest
        field = jax.ShapeDtypeStruct(self.shape, dt)
        acc_names = ("dK", "dbx", "dby")
        args = {
            "p_end": end[0],
            "pp_end": end[1],
            "x": x,
            "h": h,
            "K": self.coef[0],
            **dict(zip(("bx", "by"), faces)),
            **dict(zip(("ml", "mh", "vol", "area"), metric)),
            "src_cells": self.src_cells,
            "src_hard": self.src_hard,
            "src_vals": vals,
            "inj_cells": inj_cells,
            "inj_vals": inj_vals.astype(dt),
            "rec_cells": rec_cells,
            "zero_cells": zero_cells,
            **dict(zip(acc_names, acc)),
        }
        rets = {
            "x": field,
            "h": field,
            "rec": jax.ShapeDtypeStruct((length, int(rec_cells.shape[0])), dt),
            **{k: jax.ShapeDtypeStruct(a.shape, dt) for k, a in zip(acc_names, acc)},
        }
        out = ADJOINT_CHUNK.call(
            args,
            rets,
            n_steps=np.int64(length),
            threads=self.attrs["threads"],
            levels=np.int64(_levels(self.shape[1], jnp.dtype(dt).itemsize, True)),
        )
        return out["x"], out["h"], out["rec"], tuple(out[k] for k in acc_names)


_pack_layers, _unpack_layers = pack_layers, unpack_layers  # (the names of old)


# ------------------------------------------------------------------------------------------
# the loop


def _native_loop(stepper: Stepper, state: State, n_steps: int, chunk: int, threads: int, levels: int, bands: bool):
    """(final state, probes, peak history, snapshots) of `loop.run`, on the native kernels."""
    sens = stepper.sensors
    kern = (
        _Chunk(stepper, threads, levels, bands)
        if stepper.grid.ndim == 2
        else VolumeChunk(stepper, *schedule_3d(stepper))
    )
    n_chunks, rem = divmod(n_steps, chunk)

    def outer(st, _):
        st, ys = kern.advance(st, chunk)
        p = st.pressure
        return st, (ys, jnp.max(jnp.abs(p)), sens.snapshot_of(p) if sens.snapshot_every is not None else None)

    state, (ys, peaks, snaps) = jax.lax.scan(outer, state, None, length=n_chunks)
    if ys is not None:
        ys = ys.reshape(n_chunks * chunk, -1)
    if rem:
        state, ys_r = kern.advance(state, rem)
        peaks = jnp.concatenate([peaks, jnp.max(jnp.abs(state.pressure))[None]])
        if ys is not None:
            ys = jnp.concatenate([ys, ys_r.reshape(rem, -1)], axis=0)
        if snaps is not None:  # a 3-D grid's snapshots: a tuple of planes (`Sensors.snapshot_of`)
            last = sens.snapshot_of(state.pressure)
            snaps = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b[None]], axis=0), snaps, last)
    return state, ys, peaks, snaps


@eqx.filter_custom_jvp
def _loop(stepper, state, *, n_steps, chunk, checkpoint, unroll, threads, levels, bands):
    return _native_loop(stepper, state, n_steps, chunk, threads, levels, bands)


@_loop.def_jvp
def _loop_jvp(primals, tangents, *, n_steps, chunk, checkpoint, unroll, threads, levels, bands):
    """Derivatives of the native loop = those of the JAX reference loop (same chunks)."""

    def reference(stepper, state):
        r = run_jax(stepper, n_steps, state=state, checkpoint=checkpoint, unroll=unroll)
        return r.final, r.probes, r.peak_history, r.snapshots

    return eqx.filter_jvp(reference, primals, tangents)


def schedule(stepper: Stepper) -> tuple[int, int, bool]:
    """(threads, levels, bands) of the kernels for this stepper's grid."""
    if stepper.grid.ndim == 3:
        return (*schedule_3d(stepper)[:2], False)
    nx, ny = stepper.grid.shape
    extra = 0 if stepper.lattice.relax is None else 2  # Q_O, Q_N
    # PML layers: the leapfrog's rows (the layer's fields are a few columns of most rows)
    levels = _levels(ny, jnp.dtype(stepper.grid.jnp_dtype).itemsize, False, extra)
    bands = _bands(stepper)
    return _threads(nx, 0 if bands else levels), levels, bands


def chunk_kernel(stepper: Stepper) -> _Chunk | VolumeChunk:
    """The FFI calls of one stepper (forward chunks; adjoint steps on 2-D and rz grids)."""
    if stepper.grid.ndim == 3:
        return VolumeChunk(stepper, *schedule_3d(stepper))
    return _Chunk(stepper, *schedule(stepper))


def adjoint_supported(stepper: Stepper) -> bool:
    """Whether the kernel's adjoint mode runs this stepper's backward pass: the leapfrog with K
    and face conductances only (no q_scale, keep, sponge or viscous term; 5-point stencil)."""
    lat = stepper.lattice
    return (
        stepper.grid.ndim == 2
        and not stepper.staggered
        and lat.stencil == "standard"
        and lat.q_scale is None
        and lat.keep is None
        and lat.sponge is None
        and lat.eta == 0
        and lat.relax is None
    )


def run_native(stepper: Stepper, n_steps: int, *, state: State | None, checkpoint, unroll):
    """`loop.run` on the native kernels (the caller checked `unsupported` and the library)."""
    chunk = chunking(n_steps, stepper.sensors, checkpoint)
    state = stepper.init() if state is None else state
    threads, levels, bands = schedule(stepper)
    final, ys, peaks, snaps = _loop(
        stepper,
        state,
        n_steps=n_steps,
        chunk=chunk,
        checkpoint=checkpoint,
        unroll=unroll,
        threads=threads,
        levels=levels,
        bands=bands,
    )
    n_chunks, rem = divmod(n_steps, chunk)
    steps = [chunk * (i + 1) for i in range(n_chunks)] + ([n_steps] if rem else [])
    return Result.of_final(final, ys, peaks, snaps, n_steps, steps)
