"""The time loop: a stateless stepper (`init`/`step`) and one entry point, `simulate`.

`simulate` is a pure function of its array inputs (medium maps, source weights and lags), so it
works under `jax.jit`, `jax.grad`, `jax.jvp` and `jax.vmap`. Sensors are recorded inside the
scan; the time loop is a scan of chunks of steps, which gives snapshots every k steps, a
per-chunk record of the peak |p| (instability detection), and memory-bounded reverse mode
(`checkpoint="sqrt"`: each chunk is recomputed in the backward pass, memory ~ sqrt(steps)).

Two steppers share one spatial operator (see `lattice.py`):
- leapfrog ``P(t+1) = 2 P(t) - P(t-1) + D(P(t))``: state (P, P_prev), used without a PML;
- staggered split-field form, identical to the leapfrog where no PML damps, used with a PML:
  face fluxes ``w += b grad q`` and ``P_x += K div_x w``, ``P_y += K div_y w``, ``P = P_x + P_y``.
"""

from __future__ import annotations

import math
from typing import Literal, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float, Int

from .grid import Grid, MAX_COURANT
from .lattice import Edges, Lattice, build_lattice
from .medium import Medium
from .sensors import Sensors
from .source import PointSources


class State(eqx.Module):
    """The carried state after step `n` (fields not used by a scene are None)."""

    n: Int[Array, ""]
    p: Float[Array, "nx ny"] | None  # leapfrog: P(n)
    p_prev: Float[Array, "nx ny"] | None  # P(n-1): leapfrog, or staggered with absorption
    px: Float[Array, "nx ny"] | None  # staggered split pressure
    py: Float[Array, "nx ny"] | None
    wx: Float[Array, "nx1 ny"] | None  # staggered face fluxes
    wy: Float[Array, "nx ny1"] | None
    src_acc: tuple[Float[Array, " k"], ...] | None  # staggered soft-source running sums
    phasor_re: Float[Array, " m"] | None
    phasor_im: Float[Array, " m"] | None
    p_max: Float[Array, "nx ny"] | None
    p_sq: Float[Array, "nx ny"] | None
    arrival: Int[Array, "nx ny"] | None

    @property
    def pressure(self) -> Float[Array, "nx ny"]:
        return self.p if self.p is not None else self.px + self.py


class Result(eqx.Module):
    """What `simulate` returns. Times are in steps of `grid.dt_s`; pressures in Pa.

    - `probes`: (n_steps, n_probes) pressure at the probe cells, steps 1..n_steps.
    - `phasors`: (m,) complex DFT sum_n p(n) exp(+i omega n) at the phasor cells.
    - `p_max`, `p_rms`: whole-field peak |p| and RMS; `arrival`: first step above threshold.
    - `snapshots`: (k, nx, ny) fields at steps `snapshot_steps`.
    - `peak_history`: (n_chunks,) max |p| at the end of each chunk (`chunk_steps`).
    """

    final: State
    probes: Float[Array, "t n"] | None
    phasors: Complex[Array, " m"] | None
    p_max: Float[Array, "nx ny"] | None
    p_rms: Float[Array, "nx ny"] | None
    arrival: Int[Array, "nx ny"] | None
    snapshots: Float[Array, "k nx ny"] | None
    peak_history: Float[Array, " c"]
    n_steps: int = eqx.field(static=True)
    chunk_steps: tuple[int, ...] = eqx.field(static=True)

    @property
    def snapshot_steps(self) -> tuple[int, ...]:
        return self.chunk_steps


# ------------------------------------------------------------------------------------------
# spatial operator


def _open_masks(lat: Lattice, shape):
    """Static 0/1 face masks closing rigid window sides when no conductance array carries them
    (homogeneous and speed-zero scenes); None where every face is open."""
    nx, ny = shape
    x_lo, x_hi, y_lo, y_hi = (g == "neumann" for g in lat.ghosts)
    mx = my = None
    if x_lo or x_hi:
        mx = np.ones((nx + 1, 1))
        mx[0], mx[-1] = (0.0 if x_lo else 1.0), (0.0 if x_hi else 1.0)
    if y_lo or y_hi:
        my = np.ones((1, ny + 1))
        my[:, 0], my[:, -1] = (0.0 if y_lo else 1.0), (0.0 if y_hi else 1.0)
    return mx, my


def _face_coefficients(lat: Lattice, shape, dtype):
    """Conductances of the faces along x (nx+1, ny) and y (nx, ny+1), or broadcastable masks, or
    None (all faces open with unit conductance). Rigid window sides are closed faces."""
    if lat.bx is not None:
        return lat.bx, lat.by
    if lat.ax_lo is not None:  # paper model: closed sides are folded into the per-cell factors
        return None, None
    mx, my = _open_masks(lat, shape)
    return (None if mx is None else jnp.asarray(mx, dtype)), (None if my is None else jnp.asarray(my, dtype))


def face_gradient(lat: Lattice, q, axis: int):
    """b * (q_hi - q_lo) on every face along `axis`, outer faces included (n+1 faces); the
    window's ghost cells are zero and rigid sides are closed faces (b = 0)."""
    qp = jnp.pad(q, 1)
    g = qp[1:, 1:-1] - qp[:-1, 1:-1] if axis == 0 else qp[1:-1, 1:] - qp[1:-1, :-1]
    b = _face_coefficients(lat, q.shape, q.dtype)[axis]
    return g if b is None else b * g


def divergence(lat: Lattice, g, axis: int):
    """Net flux into each cell from the face values g along `axis` (without the factor K)."""
    g_hi = g[1:] if axis == 0 else g[:, 1:]
    g_lo = g[:-1] if axis == 0 else g[:, :-1]
    a_hi = lat.ax_hi if axis == 0 else lat.ay_hi
    a_lo = lat.ax_lo if axis == 0 else lat.ay_lo
    if a_hi is not None:
        g_hi = a_hi * g_hi
        g_lo = a_lo * g_lo
    return g_hi - g_lo


def operator(lat: Lattice, p):
    """The spatial operator D(P) = K L(q_scale P) of the scene (lattice units).

    Written as one 5-point stencil on a zero-padded copy of q, with the face conductances sliced
    per cell (``b[1:] (q_E - q) - b[:-1] (q - q_W)``), so XLA compiles it to one fused loop over
    the grid; forming the face differences as arrays first was 2x slower (memory traffic).
    """
    q = p if lat.q_scale is None else lat.q_scale * p
    return lat.K * stencil(lat, q)


def stencil(lat: Lattice, q):
    """L(q): the flux stencil without the factor K (symmetric unless the paper model's a-factors)."""
    qp = jnp.pad(q, 1)
    east, west = qp[2:, 1:-1], qp[:-2, 1:-1]
    north, south = qp[1:-1, 2:], qp[1:-1, :-2]
    bx, by = _face_coefficients(lat, q.shape, q.dtype)
    terms = []
    for axis, (hi, lo), b, a_hi, a_lo in (
        (0, (east, west), bx, lat.ax_hi, lat.ax_lo),
        (1, (north, south), by, lat.ay_hi, lat.ay_lo),
    ):
        if b is None and a_hi is None:
            terms.append(hi + lo - 2 * q)
            continue
        c_hi = c_lo = 1
        if b is not None:  # the cell's high and low faces
            c_hi, c_lo = (b[1:], b[:-1]) if axis == 0 else (b[:, 1:], b[:, :-1])
        if a_hi is not None:
            c_hi, c_lo = a_hi * c_hi, a_lo * c_lo
        terms.append(c_hi * (hi - q) - c_lo * (q - lo))
    return terms[0] + terms[1]


def adjoint_operator(lat: Lattice, lam):
    """D^T(lam) = q_scale L(K lam), valid where L is symmetric (every model but "paper")."""
    y = stencil(lat, lat.K * lam)
    return y if lat.q_scale is None else lat.q_scale * y


# ------------------------------------------------------------------------------------------
# stepper


class Stepper(eqx.Module):
    """Stateless stepper: `init()` gives the zero state, `step(state)` advances one time step.

    Build it with `Stepper.build(grid, medium, sources, sensors, edges)`; it is a pytree whose
    arrays (medium coefficients, source weights and lags) are differentiable.
    """

    grid: Grid
    lattice: Lattice
    sources: tuple[PointSources, ...]
    sensors: Sensors
    staggered: bool = eqx.field(static=True)

    @classmethod
    def build(
        cls,
        grid: Grid,
        medium: Medium,
        sources: PointSources | Sequence[PointSources] = (),
        sensors: Sensors = Sensors(),
        edges: Edges = Edges(),
    ) -> "Stepper":
        if isinstance(sources, PointSources):
            sources = (sources,)
        sources = tuple(sources)
        if grid.dtype == "float64" and not jax.config.jax_enable_x64:
            raise ValueError(
                "grid.dtype is float64 but JAX runs in 32-bit mode: call "
                "jax.config.update('jax_enable_x64', True) first (or use dtype='float32')"
            )
        sensors.check_inside(grid)
        lat = build_lattice(grid, medium, edges)
        nx, ny = grid.shape
        L = edges.thickness_cells if (edges.kinds() & {"pml", "sponge"}) else 0
        for s in sources:
            if not isinstance(s.cells, np.ndarray):
                continue  # traced positions: not checkable at build time
            cells = s.cells_array
            if cells.size and ((cells < 0).any() or (cells[:, 0] >= nx).any() or (cells[:, 1] >= ny).any()):
                raise ValueError(f"source cells outside the {nx} x {ny} grid")
        if L:
            for s in sources:
                if not isinstance(s.cells, np.ndarray):
                    continue
                c = s.cells_array
                inside = _in_layer(c, grid.shape, edges, L)
                if inside.any():
                    raise ValueError(
                        f"{int(inside.sum())} source cells lie in the {L}-cell absorbing layer: "
                        "move the transducer inward or enlarge the grid"
                    )
        return cls(grid, lat, sources, sensors, staggered=edges.uses_pml)

    # -- state ---------------------------------------------------------------------------
    def init(self) -> State:
        nx, ny = self.grid.shape
        dt = self.grid.jnp_dtype
        z = jnp.zeros((nx, ny), dt)
        sens = self.sensors
        m = sens.n_phasors
        lat = self.lattice
        need_prev = (not self.staggered) or lat.eta > 0
        return State(
            n=jnp.asarray(0, jnp.int32),
            p=None if self.staggered else z,
            p_prev=z if need_prev else None,
            px=z if self.staggered else None,
            py=z if self.staggered else None,
            wx=jnp.zeros((nx + 1, ny), dt) if self.staggered else None,
            wy=jnp.zeros((nx, ny + 1), dt) if self.staggered else None,
            src_acc=tuple(jnp.zeros(s.n_cells, dt) for s in self.sources if s.injection == "soft")
            if self.staggered
            else None,
            phasor_re=jnp.zeros(m, dt) if m else None,
            phasor_im=jnp.zeros(m, dt) if m else None,
            p_max=z if sens.p_max else None,
            p_sq=z if sens.p_rms else None,
            arrival=jnp.full((nx, ny), -1, jnp.int32) if sens.arrival_threshold_pa else None,
        )

    def _source_values(self, n_next):
        dt = self.grid.jnp_dtype
        t = n_next.astype(dt) * self.grid.dt_s
        return [s.values(t).astype(dt) for s in self.sources]  # weights given in another dtype

    def step(self, state: State) -> tuple[State, Float[Array, " n_probes"] | None]:
        """Advance one step; returns the new state and the probe pressures at the new step."""
        n_next = state.n + 1
        values = self._source_values(n_next)
        if self.staggered:
            state, p_new = self._step_staggered(state, values)
        else:
            state, p_new = self._step_leapfrog(state, values)
        state = self._record(state, p_new, n_next)
        probes = None
        if self.sensors.n_probes:
            c = self.sensors.probes
            probes = p_new[c[:, 0], c[:, 1]]
        return state, probes

    def _step_leapfrog(self, state: State, values):
        lat = self.lattice
        p, p_prev = state.p, state.p_prev
        p_eff = p if lat.eta == 0 else (1 + lat.eta) * p - lat.eta * p_prev
        d = operator(lat, p_eff)
        if lat.sponge is None:
            p_new = 2 * p - p_prev + d
        else:
            s = lat.sponge
            p_new = (2 * p - (1 - s) * p_prev + d) / (1 + s)
        if any(lat.mur):
            p_new = self._mur(p, p_new)
        if lat.keep is not None:
            p_new = lat.keep * p_new
        for src, v in zip(self.sources, values):
            c = src.cells
            if src.injection == "soft":
                p_new = p_new.at[c[:, 0], c[:, 1]].add(v)
            else:
                p_new = p_new.at[c[:, 0], c[:, 1]].set(v)
        return eqx.tree_at(lambda s: (s.p, s.p_prev, s.n), state, (p_new, p, state.n + 1)), p_new

    def _mur(self, p, p_new):
        """First-order Mur absorbing edges: P_edge(t+1) = P_in(t) + k (P_in(t+1) - P_edge(t))."""
        lat = self.lattice
        c = lat.c
        x_lo, x_hi, y_lo, y_hi = lat.mur
        cfield = c if jnp.ndim(c) == 0 else None

        def k_of(idx):
            cc = cfield if cfield is not None else c[idx]
            return (cc - 1) / (cc + 1)

        if x_lo:
            p_new = p_new.at[0].set(p[1] + k_of(0) * (p_new[1] - p[0]))
        if x_hi:
            p_new = p_new.at[-1].set(p[-2] + k_of(-1) * (p_new[-2] - p[-1]))
        if y_lo:
            p_new = p_new.at[:, 0].set(p[:, 1] + k_of((slice(None), 0)) * (p_new[:, 1] - p[:, 0]))
        if y_hi:
            p_new = p_new.at[:, -1].set(p[:, -2] + k_of((slice(None), -1)) * (p_new[:, -2] - p[:, -1]))
        return p_new

    def _step_staggered(self, state: State, values):
        lat = self.lattice
        pml = lat.pml
        p = state.px + state.py
        p_eff = p if lat.eta == 0 else (1 + lat.eta) * p - lat.eta * state.p_prev
        q = p_eff if lat.q_scale is None else lat.q_scale * p_eff
        wx = pml.ax_face * state.wx + pml.bx_face * face_gradient(lat, q, 0)
        wy = pml.ay_face * state.wy + pml.by_face * face_gradient(lat, q, 1)
        px = pml.ax_cell * state.px + pml.bx_cell * (lat.K * divergence(lat, wx, 0))
        py = pml.ay_cell * state.py + pml.by_cell * (lat.K * divergence(lat, wy, 1))
        if lat.keep is not None:
            px, py = lat.keep * px, lat.keep * py
        acc = list(state.src_acc)
        i_soft = 0
        for src, v in zip(self.sources, values):
            c = src.cells
            if src.injection == "soft":
                acc[i_soft] = acc[i_soft] + v
                half = 0.5 * acc[i_soft]
                i_soft += 1
                px = px.at[c[:, 0], c[:, 1]].add(half)
                py = py.at[c[:, 0], c[:, 1]].add(half)
            else:
                px = px.at[c[:, 0], c[:, 1]].set(0.5 * v)
                py = py.at[c[:, 0], c[:, 1]].set(0.5 * v)
        p_prev = p if state.p_prev is not None else None
        new = eqx.tree_at(
            lambda s: (s.px, s.py, s.wx, s.wy, s.src_acc, s.n, s.p_prev),
            state,
            (px, py, wx, wy, tuple(acc), state.n + 1, p_prev),
            is_leaf=lambda x: x is None,
        )
        return new, px + py

    def _record(self, state: State, p_new, n_next) -> State:
        sens = self.sensors
        updates = {}
        if sens.n_phasors:
            c = sens.phasor_cells
            f = sens.phasor_frequency_hz or self.grid.frequency_hz
            w = self.grid.hz_to_lattice_omega(f)
            ang = (n_next.astype(self.grid.jnp_dtype) * w) % (2 * math.pi)
            vals = p_new[c[:, 0], c[:, 1]]
            updates["phasor_re"] = state.phasor_re + vals * jnp.cos(ang)
            updates["phasor_im"] = state.phasor_im + vals * jnp.sin(ang)
        if sens.p_max:
            updates["p_max"] = jnp.maximum(state.p_max, jnp.abs(p_new))
        if sens.p_rms:
            updates["p_sq"] = state.p_sq + p_new * p_new
        if sens.arrival_threshold_pa:
            hit = (state.arrival < 0) & (jnp.abs(p_new) > sens.arrival_threshold_pa)
            updates["arrival"] = jnp.where(hit, n_next, state.arrival)
        if not updates:
            return state
        keys = tuple(updates)
        return eqx.tree_at(lambda s: tuple(getattr(s, k) for k in keys), state, tuple(updates[k] for k in keys))


def _in_layer(cells: np.ndarray, shape, edges: Edges, L: int) -> np.ndarray:
    nx, ny = shape
    ix, iy = cells[:, 0], cells[:, 1]
    m = np.zeros(len(cells), bool)
    if edges.x_lo in ("pml", "sponge"):
        m |= ix < L
    if edges.x_hi in ("pml", "sponge"):
        m |= ix >= nx - L
    if edges.y_lo in ("pml", "sponge"):
        m |= iy < L
    if edges.y_hi in ("pml", "sponge"):
        m |= iy >= ny - L
    return m


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
    sharding: "jax.sharding.Sharding | None" = None,
    adjoint: Literal["autodiff", "lattice", "auto"] = "autodiff",
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
    maps; raises for scenes it does not support. "auto": "lattice" where supported."""
    if not isinstance(n_steps, (int, np.integer)) or n_steps < 1:
        raise ValueError(f"n_steps = {n_steps!r} must be a positive integer")
    n_steps = int(n_steps)
    if adjoint not in ("autodiff", "lattice", "auto"):
        raise ValueError(f"adjoint = {adjoint!r}; allowed: 'autodiff', 'lattice', 'auto'")
    if adjoint != "autodiff":
        from . import adjoint as adj

        reason = adj.supports(stepper, state)
        if reason is None and sharding is None:
            return _run_lattice_adjoint(stepper, n_steps, checkpoint)
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
    state = stepper.init() if state is None else state
    constrain = _constrainer(stepper.grid.shape, sharding)
    state = constrain(state)

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
        snap = p if sens.snapshot_every is not None else None
        return st, (ys, peak, snap)

    state, (ys, peaks, snaps) = jax.lax.scan(outer, state, None, length=n_chunks)
    steps = [chunk * (i + 1) for i in range(n_chunks)]
    if ys is not None:
        ys = ys.reshape(n_chunks * chunk, -1)
    if rem:
        state, ys_r = chunk_scan(state, rem)
        peaks = jnp.concatenate([peaks, jnp.max(jnp.abs(state.pressure))[None]])
        steps.append(n_steps)
        if ys is not None:
            ys = jnp.concatenate([ys, ys_r.reshape(rem, -1)], axis=0)
        if snaps is not None and sens.snapshot_every is not None:
            snaps = jnp.concatenate([snaps, state.pressure[None]], axis=0)

    phasors = None
    if state.phasor_re is not None:
        phasors = jax.lax.complex(state.phasor_re, state.phasor_im)
    p_rms = None if state.p_sq is None else jnp.sqrt(state.p_sq / n_steps)
    return Result(
        final=state,
        probes=ys,
        phasors=phasors,
        p_max=state.p_max,
        p_rms=p_rms,
        arrival=state.arrival,
        snapshots=snaps,
        peak_history=peaks,
        n_steps=n_steps,
        chunk_steps=tuple(steps),
    )


def _run_lattice_adjoint(stepper: Stepper, n_steps: int, checkpoint: Checkpoint) -> Result:
    from .adjoint import linear_run

    chunk = _chunking(n_steps, stepper.sensors, "sqrt" if checkpoint is None else checkpoint)
    probes, re, im, p, p_prev, peaks = linear_run(stepper, n_steps, chunk)
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


def grid_sharding(devices: Sequence | None = None, axis: int = 0) -> "jax.sharding.NamedSharding":
    """A sharding that splits grid-shaped arrays along `axis` (0 = x) across `devices` (default:
    all devices). On a CPU, `XLA_FLAGS=--xla_force_host_platform_device_count=N` (set before JAX
    starts) gives N host devices, one per core."""
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    devs = np.asarray(jax.devices() if devices is None else list(devices))
    spec = PartitionSpec("grid", None) if axis == 0 else PartitionSpec(None, "grid")
    return NamedSharding(Mesh(devs, ("grid",)), spec)


INSTABILITY_MESSAGE = (
    "difflattice: the simulation produced non-finite pressure (numerical instability or overflow). "
    "Likely causes: a lattice speed above 1/sqrt(2) cells/step (lower the grid courant), a strong "
    "density contrast at the stability limit with the conservative model (lower courant by ~1%), "
    "or float32 overflow from extreme source amplitudes (scale the weights or use float64)."
)
SPEED_MESSAGE = (
    "difflattice: a medium speed exceeds 1/sqrt(2) cells/step, the 2-D stability limit: lower the "
    "grid courant or set c_max_m_s to the fastest medium's speed."
)


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
    sharding: "jax.sharding.Sharding | None" = None,
    adjoint: Literal["autodiff", "lattice", "auto"] = "autodiff",
    throw: bool = True,
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
    """
    stepper = Stepper.build(grid, medium, sources, sensors, edges)
    return _simulate(stepper, n_steps, checkpoint, unroll, sharding, adjoint, throw)


@eqx.filter_jit
def _simulate(stepper: Stepper, n_steps: int, checkpoint, unroll: int | None, sharding, adjoint, throw: bool) -> Result:
    lat = stepper.lattice
    if jnp.ndim(lat.c) != 0 or isinstance(lat.c, jax.core.Tracer):
        # speeds may be traced (e.g. fitted): check the stability limit at run time
        stepper = eqx.error_if(stepper, jnp.max(lat.c) > MAX_COURANT * (1 + 1e-6), SPEED_MESSAGE)
    result = run(stepper, n_steps, checkpoint=checkpoint, unroll=unroll, sharding=sharding, adjoint=adjoint)
    if throw:
        result = check_result(result, stepper)
    return result
