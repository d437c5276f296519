"""The native kernel of 3-D grids (`volume.cc`, FFI target `difflattice_volume`): what it runs,
its schedule, and one chunk of steps as one FFI call.

It runs the JAX 3-D loop's leapfrog with the standard 7-point stencil: homogeneous air (a scalar
K, no coefficient array: memory-lean) or K and the three face-conductance arrays of obstacles,
cut cells and media, rigid and soft window sides, sponge edges, soft cells (`keep`), with the
sources, probes, phasors and field statistics inside the loop; and the isotropic 19-point stencil
on uniform faces (air in a window of rigid, soft or sponge sides: `_isotropic_uniform_3d`). What
it does not run is refused by name (`unsupported_3d`), and the JAX loop runs it as before.
"""

from __future__ import annotations

import os

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..stepper import LeapfrogState, StaggeredState, State, Stepper
from .chunk_io import absent, pack_layers, stats_in, step_tables, unpack_layers
from .signatures import VOLUME, VOLUME_LAYERED

# the stencils the kernel implements, by `Grid.stencil` name
STENCILS_3D = ("standard", "isotropic")
# Temporal blocking: each thread advances LEVELS_3D steps per sweep over the x planes, so the planes
# in flight (about levels + 3 of each field a step reads) stay in cache: whole planes where they fit
# CACHE_BUDGET_BYTES (a share of L3), else bands of rows (`band_3d`). Each sweep reads and writes the
# two fields once (from memory at 256^3: ~4-5 ms a sweep on the 2-core Zen 5 EPYC), so deeper
# blocks pay: one thread, 256^3 x 100 steps, float32, homogeneous, CPU time (loaded machine, median
# of 4 interleaved runs, the C++ kernel alone): 4 levels 3232 MLUPS, 8 3684, 12 3778, 16 3756, 24
# 3421 (the planes in flight outgrow L3); quiet machine, 2 threads, whole run: 4 levels 5517, 8 6022,
# 16 6321. Bands of 16-64 rows were slower than whole planes in every run (their planes, 256 KB
# apart, share the same L2 sets).
CACHE_BUDGET_BYTES = 8 * 1024 * 1024
LEVELS_3D = 12


def cpus() -> int:
    """The CPUs this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def unsupported_3d(stepper: Stepper, state: State | None) -> str | None:
    """None if the 3-D kernel runs this scene, otherwise the reason (the JAX loop runs it)."""
    lat = stepper.lattice
    if lat.stencil not in STENCILS_3D:
        return (
            f"the {lat.stencil!r} stencil on a 3-D grid (the native 3-D kernel runs "
            f"{', '.join(repr(s) for s in STENCILS_3D)} only)"
        )
    if lat.stencil == "isotropic" and lat.bx is not None:
        return (
            "the 'isotropic' stencil with face conductances (obstacles, a density contrast) on a 3-D grid "
            "(the native 3-D kernel runs it on uniform faces: air with rigid or soft window sides)"
        )
    if stepper.staggered and lat.stencil != "standard":
        return (
            f"PML edges with the {lat.stencil!r} stencil on a 3-D grid (the native 3-D kernel's layers run the "
            "'standard' stencil; rigid, soft or sponge sides run the isotropic one)"
        )
    if stepper.staggered != (lat.pml is not None):
        return "a PML stepper without PML factors (or factors without the layers)"
    if lat.relax is not None:
        return "air absorption (Medium(air=...)) on a 3-D grid"
    if lat.eta != 0:
        return "viscous absorption (absorption_db_per_m) on a 3-D grid"
    if lat.q_scale is not None or lat.ax_lo is not None:
        return "a q_scale or paper-model term on a 3-D grid"
    if lat.metric is not None or any(lat.mur):
        return "a ring metric or Mur edges on a 3-D grid"
    if (lat.bx is None) != (lat.by is None) or (lat.bx is None) != (lat.bz is None):
        return "face conductances on some axes only"
    if state is not None and stepper.staggered != isinstance(state, StaggeredState):
        return "a start state of the other stepper"
    return None


def _fields(lat) -> int:
    """Arrays of the grid's size one step reads: P(n), P(n-1), and K, three face arrays, keep, sponge
    where present."""
    faces = 4 if lat.bx is not None else (1 if jnp.size(lat.K) > 1 else 0)
    return 2 + faces + (lat.keep is not None) + (lat.sponge is not None)


def levels_3d() -> int:
    """Steps each thread advances per sweep over the x planes (temporal blocking)."""
    env = os.environ.get("DIFFLATTICE_NATIVE_LEVELS")
    return max(1, int(env)) if env else LEVELS_3D


def band_3d(shape, itemsize: int, fields: int, levels: int) -> int:
    """Rows (along y) of the bands a plane is cut into so that a band of the planes in flight fits
    `CACHE_BUDGET_BYTES` (0: whole planes fit)."""
    env = os.environ.get("DIFFLATTICE_NATIVE_BAND")
    if env:
        return max(0, int(env))
    _, ny, nz = shape
    row = nz * itemsize * fields * (levels + 3)
    if ny * row <= CACHE_BUDGET_BYTES:
        return 0
    return int(max(4, CACHE_BUDGET_BYTES // row))


def threads_3d(nx: int, levels: int) -> int:
    """Threads of the pipeline over the x planes (as `kernels._threads`)."""
    env = os.environ.get("DIFFLATTICE_NATIVE_THREADS")
    if env:
        return max(1, int(env))
    return max(1, min(cpus(), nx // (4 * (levels + 2))))


def _plane_cells(cells, shape):
    """(n, 3) cells as the kernel's (plane i, j nz + k) pairs."""
    c = jnp.asarray(cells, jnp.int32).reshape(-1, 3)
    return jnp.stack([c[:, 0], c[:, 1] * shape[2] + c[:, 2]], axis=1)


class VolumeChunk:
    """The constant inputs of the 3-D kernel's calls for one stepper (built once per trace)."""

    def __init__(self, stepper: Stepper, threads: int, levels: int, band: int = 0):
        self.stepper = stepper
        grid, lat, sens = stepper.grid, stepper.lattice, stepper.sensors
        self.dt = dt = grid.jnp_dtype
        self.shape = shape = tuple(grid.shape)
        nx, ny, nz = shape
        full = lambda v, shp: absent(dt) if v is None else jnp.broadcast_to(jnp.asarray(v, dt), shp)
        K = jnp.asarray(lat.K, dt)
        self.K = K.reshape(()) if K.size == 1 else jnp.broadcast_to(K, shape)
        self.faces = [
            full(lat.bx, (nx + 1, ny, nz)),
            full(lat.by, (nx, ny + 1, nz)),
            full(lat.bz, (nx, ny, nz + 1)),
        ]
        self.keep, self.sponge = full(lat.keep, shape), full(lat.sponge, shape)
        closed = sum(1 << s for s, g in enumerate(lat.ghosts) if g == "neumann") if lat.bx is None else 0
        self.attrs = dict(
            threads=np.int64(threads),
            levels=np.int64(levels),
            band=np.int64(band),
            closed=np.int64(closed),
            stencil=np.int64(lat.stencil == "isotropic"),
            threshold=float(sens.arrival_threshold_pa or 0.0),
        )
        self.layered = stepper.staggered
        if self.layered:  # PML layers: the boxes and the factors' profiles along their axes
            pml = lat.pml
            assert pml is not None
            self.boxes = jnp.asarray(np.array([[v for r in b for v in r] for b in pml.boxes], np.int32).reshape(-1, 6))
            self.factors = []
            for axis, n in enumerate(shape):
                for where, m in (("cell", n), ("face", n + 1)):
                    for v in pml.factors(axis, where):
                        shp = tuple(m if a == axis else 1 for a in range(3))
                        self.factors.append(jnp.broadcast_to(jnp.asarray(v, dt), shp).reshape(-1))
        srcs = stepper.sources
        self.src_cells = (
            _plane_cells(jnp.concatenate([jnp.asarray(s.cells, jnp.int32).reshape(-1, 3) for s in srcs]), shape)
            if srcs
            else jnp.zeros((0, 2), jnp.int32)
        )
        self.src_hard = jnp.asarray(
            np.concatenate([np.full(s.n_cells, s.injection == "hard", np.int32) for s in srcs])
            if srcs
            else np.zeros(0, np.int32)
        )
        self.rec_cells = _plane_cells(sens.probes, shape)
        self.ph_cells = _plane_cells(sens.phasor_cells, shape)
        self.n_probes, self.n_ph = sens.n_probes, sens.n_phasors

    def tables(self, n0, length):
        return step_tables(self.stepper, self.dt, self.n_ph, n0, length)

    def advance(self, st: State, length: int):
        """`length` steps from `st`; returns the new state and the probes (length, n) or None."""
        assert isinstance(st, (LeapfrogState, StaggeredState))  # unsupported_3d() refuses other states
        vals, cos, sin = self.tables(st.n, length)
        stats = stats_in(self.dt, st)
        stat_names = ("ph_re", "ph_im", "p_max", "p_sq", "arrival")
        args = {
            "p": st.p,
            "pp": st.p_prev,
            "K": self.K,
            **dict(zip(("bx", "by", "bz"), self.faces)),
            "keep": self.keep,
            "sponge": self.sponge,
            "src_cells": self.src_cells,
            "src_hard": self.src_hard,
            "src_vals": vals,
            "rec_cells": self.rec_cells,
            "ph_cells": self.ph_cells,
            "ph_cos": cos,
            "ph_sin": sin,
            **dict(zip(stat_names, stats)),
            "n0": jnp.asarray(st.n, jnp.int32),
        }
        field = jax.ShapeDtypeStruct(self.shape, self.dt)
        rets = {
            "p": field,
            "pp": field,
            "rec": jax.ShapeDtypeStruct((length, self.n_probes), self.dt),
            **{k: jax.ShapeDtypeStruct(a.shape, a.dtype) for k, a in zip(stat_names, stats)},
        }
        sig = VOLUME
        if self.layered:
            assert isinstance(st, StaggeredState)
            lp, lw, _ = pack_layers(st.layers, self.dt)
            args |= {"lp": lp, "lw": lw, "boxes": self.boxes, **{f"f{i}": f for i, f in enumerate(self.factors)}}
            rets |= {"lp": jax.ShapeDtypeStruct(lp.shape, lp.dtype), "lw": jax.ShapeDtypeStruct(lw.shape, lw.dtype)}
            sig = VOLUME_LAYERED
        out = sig.call(args, rets, n_steps=np.int64(length), **self.attrs)
        if self.layered:
            assert isinstance(st, StaggeredState)
            empty = jnp.zeros((0,), self.dt)
            st = eqx.tree_at(lambda s: s.layers, st, unpack_layers(st.layers, (out["lp"], out["lw"], empty)))
        p, p_prev, rec = out["p"], out["pp"], out["rec"]
        stats_out = [out[k] for k in stat_names]
        names = ("phasor_re", "phasor_im", "p_max", "p_sq", "arrival")
        keys = ("p", "p_prev", "n", *(k for k in names if getattr(st, k) is not None))
        new = {"p": p, "p_prev": p_prev, "n": st.n + length, **dict(zip(names, stats_out))}
        st = eqx.tree_at(lambda s: tuple(getattr(s, k) for k in keys), st, tuple(new[k] for k in keys))
        return st, (rec if self.n_probes else None)


def schedule_3d(stepper: Stepper) -> tuple[int, int, int]:
    """(threads, levels, band) of the 3-D kernel for this stepper's grid."""
    grid = stepper.grid
    levels = levels_3d()
    band = band_3d(grid.shape, jnp.dtype(grid.jnp_dtype).itemsize, _fields(stepper.lattice), levels)
    return threads_3d(grid.shape[0], levels), levels, band


__all__ = ["STENCILS_3D", "VolumeChunk", "schedule_3d", "unsupported_3d"]
