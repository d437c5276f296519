"""The stateless stepper (`Stepper.init` / `Stepper.step`) and its carried `State`.

Two steppers share one spatial operator (`difflattice.lattice.operators`):
- leapfrog ``P(t+1) = 2 P(t) - P(t-1) + D(P(t))``: state (P, P_prev), used without a PML;
- staggered split-field form, identical to the leapfrog where no PML damps, used with a PML:
  face fluxes ``w += b grad q`` and ``P_x += K div_x w``, ``P_y += K div_y w``, ``P = P_x + P_y``.

Both run on 2-D and on axisymmetric (rz) grids: the ring metric lives in the operator
(`Lattice.metric`); an rz grid's r_hi PML carries one more field, the ring correction `c_r` on the
layer's rings (`lattice.coefficients.RadialPML`).
"""

from __future__ import annotations

import math
from typing import Sequence

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

    @property
    def pressure(self) -> Float[Array, "nx ny"]:
        return self.p if self.p is not None else self.px + self.py


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
        rad = None if lat.pml is None else lat.pml.radial
        return State(
            n=jnp.asarray(0, jnp.int32),
            p=None if self.staggered else z,
            p_prev=z if need_prev else None,
            px=z if self.staggered else None,
            py=z if self.staggered else None,
            wx=jnp.zeros((nx + 1, ny), dt) if self.staggered else None,
            wy=jnp.zeros((nx, ny + 1), dt) if self.staggered else None,
            src_acc=tuple(jnp.zeros(s.n_cells, dt) for s in self.sources if s.adds)
            if self.staggered
            else None,
            c_r=None if rad is None else jnp.zeros((nx, rad.width), dt),
            phasor_re=jnp.zeros(m, dt) if m else None,
            phasor_im=jnp.zeros(m, dt) if m else None,
            p_max=z if sens.p_max else None,
            p_sq=z if sens.p_rms else None,
            arrival=jnp.full((nx, ny), -1, jnp.int32) if sens.arrival_threshold_pa else None,
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
            if src.adds:
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
        rad = pml.radial
        wx = pml.ax_face * state.wx + pml.bx_face * face_gradient(lat, q, 0)
        wy = pml.ay_face * state.wy + pml.by_face * face_gradient(lat, q, 1)
        px = pml.ax_cell * state.px + pml.bx_cell * (lat.K * divergence(lat, wx, 0))
        div_y = divergence(lat, wy, 1)
        c_r = state.c_r
        if rad is not None:  # cylindrical stretching of the ring metric in the r_hi layer
            w = rad.width
            w_sum = wy[:, -w:] + wy[:, -w - 1:-1] + state.wy[:, -w:] + state.wy[:, -w - 1:-1]
            c_r = rad.decay * state.c_r + rad.drive * w_sum
            # zero-padded to full width, not added in place: XLA fuses the pad into the update
            # (measured, XLA CPU: an in-place strip update 0.6x the 2-D speed, the pad 0.75x)
            div_y = div_y + jnp.pad(c_r, ((0, 0), (div_y.shape[1] - w, 0)))
        py = pml.ay_cell * state.py + pml.by_cell * (lat.K * div_y)
        if lat.keep is not None:
            px, py = lat.keep * px, lat.keep * py
        acc = list(state.src_acc)
        i_soft = 0
        for src, v in zip(self.sources, values):
            c = src.cells
            if src.adds:
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
            lambda s: (s.px, s.py, s.wx, s.wy, s.src_acc, s.n, s.p_prev, s.c_r),
            state,
            (px, py, wx, wy, tuple(acc), state.n + 1, p_prev, c_r),
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
        c = lat.c if jnp.ndim(lat.c) == 0 else lat.c[src.cells[:, 0], src.cells[:, 1]]
    return src.injected(t_s, grid.dt_s, c)


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
