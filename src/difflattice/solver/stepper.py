"""The stateless stepper (`Stepper.init` / `Stepper.step`) and its carried `State`.

Two steppers share one spatial operator (`difflattice.lattice.operators`):
- leapfrog ``P(t+1) = 2 P(t) - P(t-1) + D(P(t))``: state (P, P_prev), used without a PML;
- staggered split-field form, identical to the leapfrog where no PML damps, used with a PML:
  face fluxes ``w += b grad q`` and ``P_x += K div_x w``, ``P_y += K div_y w``, ``P = P_x + P_y``.

Both run on 2-D, axisymmetric (rz) and 3-D grids: the ring metric lives in the operator
(`Lattice.metric`); an rz grid's r_hi PML carries one more field, the ring correction `c_r` on the
layer's rings (`lattice.coefficients.RadialPML`); a 3-D grid's split-field form carries P_z and
the z face flux too (``P = P_x + P_y + P_z``). The loops over axes unroll at trace time, so a
plane or rz scene compiles exactly its 2-D arithmetic (no z term, no z field).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ..lattice.coefficients import Edges, Lattice, build_lattice
from ..lattice.grid import Grid
from ..lattice.medium import Medium
from ..lattice.operators import divergence, face_gradient, operator
from .sensors import Sensors
from .sources import PointSources


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
    c_r: Float[Array, "nx w"] | None  # rz r_hi PML: the ring metric's correction (outer rings)
    phasor_re: Float[Array, " m"] | None
    phasor_im: Float[Array, " m"] | None
    p_max: Float[Array, "nx ny"] | None
    p_sq: Float[Array, "nx ny"] | None
    arrival: Int[Array, "nx ny"] | None
    pz: Float[Array, "nx ny nz"] | None = None  # 3-D staggered only
    wz: Float[Array, "nx ny nz1"] | None = None

    @property
    def pressure(self) -> Float[Array, "nx ny"]:
        if self.p is not None:
            return self.p
        return self.px + self.py if self.pz is None else self.px + self.py + self.pz


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
    ) -> Stepper:
        if isinstance(sources, PointSources):
            sources = (sources,)
        sources = tuple(sources)
        if grid.dtype == "float64" and not jax.config.jax_enable_x64:
            raise ValueError(
                "grid.dtype is float64 but JAX runs in 32-bit mode: call "
                "jax.config.update('jax_enable_x64', True) first (or use dtype='float32')"
            )
        sensors.check_inside(grid)
        edges = edges.for_rank(grid.ndim)
        lat = build_lattice(grid, medium, edges)
        shape = tuple(grid.shape)
        dims = " x ".join(map(str, shape))
        L = edges.thickness_cells if (edges.kinds() & {"pml", "sponge"}) else 0
        for s in sources:
            if not isinstance(s.cells, np.ndarray):
                continue  # traced positions: not checkable at build time
            cells = s.cells_array
            if cells.size and cells.shape[1] != len(shape):
                raise ValueError(f"source cells have {cells.shape[1]} indices each; the {dims} grid needs {len(shape)}")
            if cells.size and ((cells < 0).any() or (cells >= np.asarray(shape)).any()):
                raise ValueError(f"source cells outside the {dims} grid")
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
        shape = tuple(self.grid.shape)
        nx = shape[0]
        dt = self.grid.jnp_dtype
        z = jnp.zeros(shape, dt)
        sens = self.sensors
        m = sens.n_phasors
        lat = self.lattice
        need_prev = (not self.staggered) or lat.eta > 0
        rad = None if lat.pml is None else lat.pml.radial

        def faces(axis):
            return jnp.zeros(tuple(n + 1 if a == axis else n for a, n in enumerate(shape)), dt)

        stag3 = self.staggered and len(shape) == 3
        return State(
            n=jnp.asarray(0, jnp.int32),
            p=None if self.staggered else z,
            p_prev=z if need_prev else None,
            px=z if self.staggered else None,
            py=z if self.staggered else None,
            pz=z if stag3 else None,
            wx=faces(0) if self.staggered else None,
            wy=faces(1) if self.staggered else None,
            wz=faces(2) if stag3 else None,
            src_acc=tuple(jnp.zeros(s.n_cells, dt) for s in self.sources if s.adds) if self.staggered else None,
            c_r=None if rad is None else jnp.zeros((nx, rad.width), dt),
            phasor_re=jnp.zeros(m, dt) if m else None,
            phasor_im=jnp.zeros(m, dt) if m else None,
            p_max=z if sens.p_max else None,
            p_sq=z if sens.p_rms else None,
            arrival=jnp.full(shape, -1, jnp.int32) if sens.arrival_threshold_pa else None,
        )

    def _source_values(self, n_next):
        dt = self.grid.jnp_dtype
        t = n_next.astype(dt) * self.grid.dt_s
        return [source_injection(s, t, self.grid, self.lattice).astype(dt) for s in self.sources]

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
            probes = p_new[cell_index(self.sensors.probes)]
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
            c = cell_index(src.cells)
            if src.adds:
                p_new = p_new.at[c].add(v)
            else:
                p_new = p_new.at[c].set(v)
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
        ndim = len(self.grid.shape)
        parts = (state.px, state.py, state.pz)[:ndim]
        fluxes = (state.wx, state.wy, state.wz)[:ndim]
        p = parts[0] + parts[1] if ndim == 2 else parts[0] + parts[1] + parts[2]
        p_eff = p if lat.eta == 0 else (1 + lat.eta) * p - lat.eta * state.p_prev
        q = p_eff if lat.q_scale is None else lat.q_scale * p_eff
        rad = pml.radial
        new_w = []
        for axis in range(ndim):
            a, b = pml.factors(axis, "face")
            new_w.append(a * fluxes[axis] + b * face_gradient(lat, q, axis))
        c_r = state.c_r
        new_p = []
        for axis in range(ndim):
            div = divergence(lat, new_w[axis], axis)
            if axis == 1 and rad is not None:  # cylindrical stretching of the ring metric in the r_hi layer
                wy = new_w[1]
                w = rad.width
                w_sum = wy[:, -w:] + wy[:, -w - 1 : -1] + state.wy[:, -w:] + state.wy[:, -w - 1 : -1]
                c_r = rad.decay * state.c_r + rad.drive * w_sum
                # zero-padded to full width, not added in place: XLA fuses the pad into the update
                # (measured, XLA CPU: an in-place strip update 0.6x the 2-D speed, the pad 0.75x)
                div = div + jnp.pad(c_r, ((0, 0), (div.shape[1] - w, 0)))
            a, b = pml.factors(axis, "cell")
            new_p.append(a * parts[axis] + b * (lat.K * div))
        if lat.keep is not None:
            new_p = [lat.keep * pa for pa in new_p]
        share = 1.0 / ndim  # each source value is split evenly over the pressure parts
        acc = list(state.src_acc)
        i_soft = 0
        for src, v in zip(self.sources, values):
            c = cell_index(src.cells)
            if src.adds:
                acc[i_soft] = acc[i_soft] + v
                part = share * acc[i_soft]
                i_soft += 1
                new_p = [pa.at[c].add(part) for pa in new_p]
            else:
                new_p = [pa.at[c].set(share * v) for pa in new_p]
        p_prev = p if state.p_prev is not None else None
        if ndim == 2:
            px, py = new_p
            wx, wy = new_w
            new = eqx.tree_at(
                lambda s: (s.px, s.py, s.wx, s.wy, s.src_acc, s.n, s.p_prev, s.c_r),
                state,
                (px, py, wx, wy, tuple(acc), state.n + 1, p_prev, c_r),
                is_leaf=lambda x: x is None,
            )
            return new, px + py
        new = eqx.tree_at(
            lambda s: (s.px, s.py, s.pz, s.wx, s.wy, s.wz, s.src_acc, s.n, s.p_prev),
            state,
            (*new_p, *new_w, tuple(acc), state.n + 1, p_prev),
            is_leaf=lambda x: x is None,
        )
        return new, new_p[0] + new_p[1] + new_p[2]

    def _record(self, state: State, p_new, n_next) -> State:
        sens = self.sensors
        updates = {}
        if sens.n_phasors:
            c = sens.phasor_cells
            f = sens.phasor_frequency_hz or self.grid.frequency_hz
            w = self.grid.hz_to_lattice_omega(f)
            ang = (n_next.astype(self.grid.jnp_dtype) * w) % (2 * math.pi)
            vals = p_new[cell_index(c)]
            if sens.phasor_from_step:
                vals = jnp.where(n_next > sens.phasor_from_step, vals, 0.0)
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


def source_injection(src: PointSources, t_s, grid: Grid, lat: Lattice):
    """What `src` adds to (or sets in) P at the new step's time `t_s` (see
    `PointSources.injected`); velocity sources scale by the lattice speed at their cells."""
    c = None
    if src.injection == "velocity":
        c = lat.c if jnp.ndim(lat.c) == 0 else lat.c[cell_index(src.cells)]
    return src.injected(t_s, grid.dt_s, c)


def cell_index(cells):
    """Advanced index of (n, d) cells into a d-dimensional field: `(c[:, 0], c[:, 1])`, plus `c[:, 2]` in 3-D."""
    return tuple(cells[:, i] for i in range(cells.shape[1]))


def _in_layer(cells: np.ndarray, shape, edges: Edges, L: int) -> np.ndarray:
    m = np.zeros(len(cells), bool)
    for axis, n in enumerate(shape):
        key = "xyz"[axis]
        i = cells[:, axis]
        if getattr(edges, f"{key}_lo") in ("pml", "sponge"):
            m |= i < L
        if getattr(edges, f"{key}_hi") in ("pml", "sponge"):
            m |= i >= n - L
    return m
