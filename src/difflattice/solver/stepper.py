"""The stateless stepper (`Stepper.init` / `Stepper.step`) and its carried `State`.

Every scene steps the leapfrog ``P(t+1) = 2 P(t) - P(t-1) + D(P(t))`` over the whole grid, with
one spatial operator (`difflattice.lattice.operators`). A scene with PML edges adds the
split-field form on the layer's cells only (`PML.boxes`, the layer as disjoint boxes): there
face fluxes ``w += b grad q`` and ``P_x += K div_x w``, ``P_y += K div_y w``, ``P = P_x + P_y``
(each damped by its axis's PML factors), and the box's pressure replaces the leapfrog's. Where
no PML damps the two forms are the same scheme in exact arithmetic (P(n+1) - P(n) = K div
w(n+1/2)), so the boxes' outer faces, undamped, join them: a homogeneous interior with PML edges
runs the lossless leapfrog's arithmetic and pays the layer's cost on its cells only.

Both run on 2-D, axisymmetric (rz) and 3-D grids: the ring metric lives in the operator
(`Lattice.metric`); an rz grid's r_hi PML carries one more field, the ring correction `c_r` on the
layer's rings (`lattice.pml.RadialPML`); a 3-D grid's split-field form carries P_z and
the z face flux too (``P = P_x + P_y + P_z``). The loops over axes unroll at trace time, so a
plane or rz scene compiles exactly its 2-D arithmetic (no z term, no z field).
"""

from __future__ import annotations

import abc
import math
from collections.abc import Sequence
from typing import TypeVar, overload

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ..lattice.coefficients import Edges, Lattice, build_lattice
from ..lattice.grid import Grid
from ..lattice.medium import Medium
from ..lattice.operators import _along, _cell_factors, _face_coefficients, face_gradient, stencil
from ..lattice.spectrum import check_spectrum
from .sensors import Sensors
from .sources import PointSources


class State(eqx.Module):
    """The carried state after step `n`: the step count and the sensors' running records (None
    where the sensors do not ask for them). Each stepper carries its own fields on top:
    `LeapfrogState` or `StaggeredState` (`Stepper.init` gives the right one)."""

    n: Int[Array, ""]
    phasor_re: Float[Array, " m"] | None
    phasor_im: Float[Array, " m"] | None
    p_max: Float[Array, "*grid"] | None
    p_sq: Float[Array, "*grid"] | None
    arrival: Int[Array, "*grid"] | None

    @property
    @abc.abstractmethod
    def pressure(self) -> Float[Array, "*grid"]:
        """The pressure field P(n) in Pa."""


class LeapfrogState(State):
    """The leapfrog stepper's state: P(n) and P(n-1)."""

    p: Float[Array, "*grid"]
    p_prev: Float[Array, "*grid"]
    relax_q: tuple[Float[Array, "*grid"], ...] | None = None  # air absorption's memory fields Q_i

    @property
    def pressure(self) -> Float[Array, "*grid"]:
        return self.p


class LayerFields(eqx.Module):
    """The split-field PML's fields on one box of layer cells (`PML.boxes`, same order): the
    pressure's parts per axis (their sum is P there), the face fluxes per axis (the box's faces
    along that axis, its two outer ones included: one more than its cells along that axis), and
    on an rz grid's r_hi layer the ring correction `c_r` on the box's outer `width` rings."""

    parts: tuple[Float[Array, "*box"], ...]
    fluxes: tuple[Float[Array, "*faces"], ...]
    c_r: Float[Array, "rows w"] | None = None


class StaggeredState(State):
    """The state of a scene with PML edges: the leapfrog's P(n) and P(n-1) on the whole grid
    and the split-field fields of each layer box (`LayerFields`, in `PML.boxes` order)."""

    p: Float[Array, "*grid"]
    p_prev: Float[Array, "*grid"]
    layers: tuple[LayerFields, ...]
    relax_q: tuple[Float[Array, "*grid"], ...] | None = None  # air absorption's memory fields Q_i

    @property
    def pressure(self) -> Float[Array, "*grid"]:
        return self.p


S = TypeVar("S", bound=State)


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
        edges: Edges | None = None,
    ) -> Stepper:
        if isinstance(sources, PointSources):
            sources = (sources,)
        sources = tuple(sources)
        if grid.dtype == "float64" and not jax.config.read("jax_enable_x64"):
            raise ValueError(
                "grid.dtype is float64 but JAX runs in 32-bit mode: call "
                "jax.config.update('jax_enable_x64', True) first (or use dtype='float32')"
            )
        sensors.check_inside(grid)
        edges = (Edges.default_for(grid.kind) if edges is None else edges).for_rank(grid.ndim)
        lat = build_lattice(grid, medium, edges)
        check_spectrum(lat, tuple(grid.shape))  # 3-D isotropic stencil next to obstacles
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
    def init(self) -> LeapfrogState | StaggeredState:
        """The state at rest (step 0): a `StaggeredState` for a PML scene, else a `LeapfrogState`."""
        shape = tuple(self.grid.shape)
        dt = self.grid.jnp_dtype
        z = jnp.zeros(shape, dt)
        sens = self.sensors
        m = sens.n_phasors
        n = jnp.asarray(0, jnp.int32)
        phasor_re = jnp.zeros(m, dt) if m else None
        phasor_im = jnp.zeros(m, dt) if m else None
        p_max = z if sens.p_max else None
        p_sq = z if sens.p_rms else None
        arrival = jnp.full(shape, -1, jnp.int32) if sens.arrival_threshold_pa else None
        lat = self.lattice
        relax_q = None if lat.relax is None else tuple(z for _ in lat.relax.eps)
        if not self.staggered:
            return LeapfrogState(
                n=n,
                phasor_re=phasor_re,
                phasor_im=phasor_im,
                p_max=p_max,
                p_sq=p_sq,
                arrival=arrival,
                p=z,
                p_prev=z,
                relax_q=relax_q,
            )
        if lat.pml is None:
            raise ValueError("a PML stepper needs PML factors (build it with Stepper.build)")
        return StaggeredState(
            p=z,
            p_prev=z,
            layers=tuple(_zero_layer(lat.pml, box, dt, shape) for box in lat.pml.boxes),
            relax_q=relax_q,
            n=n,
            phasor_re=phasor_re,
            phasor_im=phasor_im,
            p_max=p_max,
            p_sq=p_sq,
            arrival=arrival,
        )

    def _source_values(self, n_next):
        dt = self.grid.jnp_dtype
        t = n_next.astype(dt) * self.grid.dt_s
        return [source_injection(s, t, self.grid, self.lattice).astype(dt) for s in self.sources]

    @overload
    def step(self, state: LeapfrogState) -> tuple[LeapfrogState, Float[Array, " n_probes"] | None]: ...
    @overload
    def step(self, state: StaggeredState) -> tuple[StaggeredState, Float[Array, " n_probes"] | None]: ...
    @overload
    def step(self, state: State) -> tuple[State, Float[Array, " n_probes"] | None]: ...
    def step(self, state: State) -> tuple[State, Float[Array, " n_probes"] | None]:
        """Advance one step; returns the new state and the probe pressures at the new step.

        `state` is this stepper's kind (`init()`'s type); the other stepper's state raises."""
        n_next = state.n + 1
        values = self._source_values(n_next)
        new: State
        if isinstance(state, (LeapfrogState, StaggeredState)) and isinstance(state, StaggeredState) == self.staggered:
            new, p_new = self._step_leapfrog(state, values)
        else:
            want = "StaggeredState" if self.staggered else "LeapfrogState"
            raise ValueError(
                f"this stepper carries a {want}, got a {type(state).__name__}: start from "
                "stepper.init() (or the final state of a run of the same scene)"
            )
        new = self._record(new, p_new, n_next)
        probes = None
        if self.sensors.n_probes:
            probes = p_new[cell_index(self.sensors.probes)]
        return new, probes

    def _step_leapfrog(
        self, state: LeapfrogState | StaggeredState, values
    ) -> tuple[LeapfrogState | StaggeredState, Float[Array, "*grid"]]:
        """The leapfrog over the grid, then (PML scenes) the split-field form on the layer's boxes."""
        lat = self.lattice
        p, p_prev = state.p, state.p_prev
        p_eff = p if lat.eta == 0 else (1 + lat.eta) * p - lat.eta * p_prev
        p_eff = _relaxed_operand(lat, state.relax_q, p_eff, p, p_prev)
        q = p_eff if lat.q_scale is None else lat.q_scale * p_eff
        d = lat.K * stencil(lat, q)  # = operators.operator(lat, p_eff)
        if lat.sponge is None:
            p_new = 2 * p - p_prev + d
        else:
            s = lat.sponge
            p_new = (2 * p - (1 - s) * p_prev + d) / (1 + s)
        if any(lat.mur):
            p_new = self._mur(p, p_new)
        if lat.keep is not None:
            p_new = lat.keep * p_new
        layers = None
        if isinstance(state, StaggeredState):
            p_new, layers = self._step_layers(state, q, p_new)
        for src, v in zip(self.sources, values):
            c = cell_index(src.cells)
            if src.adds:
                p_new = p_new.at[c].add(v)
            else:
                p_new = p_new.at[c].set(v)
        new = eqx.tree_at(lambda s: (s.p, s.p_prev, s.n), state, (p_new, p, state.n + 1))
        if layers is not None:
            new = eqx.tree_at(lambda s: s.layers, new, layers)
        if lat.relax is not None:
            new = eqx.tree_at(lambda s: s.relax_q, new, _relaxed_memory(lat, state.relax_q, p_new, p))
        return new, p_new

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

    def _step_layers(self, state: StaggeredState, q, p_new) -> tuple[Float[Array, "*grid"], tuple[LayerFields, ...]]:
        """The split-field form on each layer box from the operand `q` (the leapfrog's): the
        boxes' new fields, and `p_new` with each box's cells replaced by the sum of its parts."""
        pml = self.lattice.pml
        if pml is None or len(state.layers) != len(pml.boxes):
            raise ValueError(
                f"this stepper's PML has {0 if pml is None else len(pml.boxes)} layer boxes, the state "
                f"{len(state.layers)}: start from stepper.init() (or the final state of a run of the same scene)"
            )
        lat = self.lattice
        if lat.stencil in ("isotropic", "wide") and _local_face_values(lat, q.shape, q.dtype):
            grads = lambda box: _box_face_values(lat, q, box)
        elif lat.stencil in ("isotropic", "wide"):  # per-face arrays to cut: the whole grid's, sliced
            full = [face_gradient(lat, q, axis) for axis in range(q.ndim)]
            grads = lambda box: [g[_faces_of(box, a)] for a, g in enumerate(full)]
        else:  # from the box's cells and a one-cell halo (zero beyond the window)
            faces = _face_coefficients(lat, q.shape, q.dtype)
            grads = lambda box: _box_gradients(q, box, faces)
        layers = []
        for box, fields in zip(pml.boxes, state.layers):
            fields, p_box = _layer_step(lat, box, fields, grads(box))
            p_new = p_new.at[_cells_of(box)].set(p_box)
            layers.append(fields)
        return p_new, tuple(layers)

    def _record(self, state: S, p_new: Float[Array, "*grid"], n_next: Int[Array, ""]) -> S:
        """Add the new step's pressure `p_new` to the sensors' running records."""
        sens = self.sensors
        updates: dict[str, Array] = {}
        if sens.n_phasors:
            c = sens.phasor_cells
            f = sens.phasor_frequency_hz or self.grid.frequency_hz
            w = self.grid.hz_to_lattice_omega(f)
            ang = (n_next.astype(self.grid.jnp_dtype) * w) % (2 * math.pi)
            vals = p_new[cell_index(c)]
            if sens.phasor_from_step:
                vals = jnp.where(n_next > sens.phasor_from_step, vals, 0.0)
            updates["phasor_re"] = _carried(state.phasor_re, "phasors") + vals * jnp.cos(ang)
            updates["phasor_im"] = _carried(state.phasor_im, "phasors") + vals * jnp.sin(ang)
        if sens.p_max:
            updates["p_max"] = jnp.maximum(_carried(state.p_max, "p_max"), jnp.abs(p_new))
        if sens.p_rms:
            updates["p_sq"] = _carried(state.p_sq, "p_rms") + p_new * p_new
        if sens.arrival_threshold_pa:
            arrival = _carried(state.arrival, "arrival")
            hit = (arrival < 0) & (jnp.abs(p_new) > sens.arrival_threshold_pa)
            updates["arrival"] = jnp.where(hit, n_next, arrival)
        if not updates:
            return state
        keys = tuple(updates)
        return eqx.tree_at(lambda s: tuple(getattr(s, k) for k in keys), state, tuple(updates[k] for k in keys))


def _cells_of(box) -> tuple[slice, ...]:
    """The index of a box's cells."""
    return tuple(slice(lo, hi) for lo, hi in box)


def _faces_of(box, axis: int) -> tuple[slice, ...]:
    """The index of a box's faces along `axis` (in the face array of that axis: one more)."""
    return tuple(slice(lo, hi + 1) if a == axis else slice(lo, hi) for a, (lo, hi) in enumerate(box))


def _cut(v, index: tuple[slice, ...]):
    """A coefficient (a scalar, or an array broadcasting to the grid or a face array) at `index`:
    broadcast axes (length 1) are kept whole."""
    if isinstance(v, float) or jnp.ndim(v) == 0:
        return v
    return v[tuple(slice(None) if n == 1 else sl for n, sl in zip(jnp.shape(v), index))]


def _zero_layer(pml, box, dtype, grid_shape) -> LayerFields:
    """A box's fields at rest (`LayerFields`)."""
    shape = tuple(hi - lo for lo, hi in box)
    faces = lambda axis: tuple(n + 1 if a == axis else n for a, n in enumerate(shape))
    rad = pml.radial
    ring = rad is not None and len(box) == 2 and box[1][1] == grid_shape[1]
    return LayerFields(
        parts=tuple(jnp.zeros(shape, dtype) for _ in box),
        fluxes=tuple(jnp.zeros(faces(axis), dtype) for axis in range(len(box))),
        c_r=jnp.zeros((shape[0], rad.width), dtype) if ring else None,
    )


def _layer_step(lat: Lattice, box, f: LayerFields, grads) -> tuple[LayerFields, Float[Array, "*box"]]:
    """One step of the split-field form on one box: ``w = a_face w + b_face g`` (g: the box's
    face gradients, one array per axis), ``P_axis = a_cell P_axis + b_cell K div_axis w`` (plus
    the rz ring correction C on the r_hi rings), keep; returns the new fields and P = sum of parts."""
    pml = lat.pml
    assert pml is not None
    cells = _cells_of(box)
    new_w = []
    for axis, w in enumerate(f.fluxes):
        a, b = pml.factors(axis, "face")
        at = _faces_of(box, axis)
        new_w.append(_cut(a, at) * w + _cut(b, at) * grads[axis])
    c_r = f.c_r
    parts = []
    for axis, part in enumerate(f.parts):
        div = _box_divergence(lat, new_w[axis], axis, cells)
        if axis == 1 and f.c_r is not None:  # cylindrical stretching of the ring metric in the r_hi layer
            rad = pml.radial
            assert rad is not None
            wy, old, n = new_w[1], f.fluxes[1], rad.width
            w_sum = wy[:, -n:] + wy[:, -n - 1 : -1] + old[:, -n:] + old[:, -n - 1 : -1]
            c_r = rad.decay * f.c_r + rad.drive * w_sum
            # zero-padded to full width, not added in place: XLA fuses the pad into the update
            div = div + jnp.pad(c_r, ((0, 0), (div.shape[1] - n, 0)))
        a, b = pml.factors(axis, "cell")
        parts.append(_cut(a, cells) * part + _cut(b, cells) * (_cut(lat.K, cells) * div))
    if lat.keep is not None:
        keep = _cut(lat.keep, cells)
        parts = [keep * pa for pa in parts]
    p_box = parts[0]
    for pa in parts[1:]:
        p_box = p_box + pa
    return LayerFields(parts=tuple(parts), fluxes=tuple(new_w), c_r=c_r), p_box


def _box_gradients(q, box, faces) -> list:
    """`operators.face_gradient` (standard stencil) on a box's faces along each axis: b (q_hi -
    q_lo) from the box's cells and a one-cell halo, zero beyond the window (`faces`: the face
    conductances or masks per axis, None where unit)."""
    idx, pad = [], []
    for (lo, hi), n in zip(box, q.shape):
        idx.append(slice(max(lo - 1, 0), min(hi + 1, n)))
        pad.append((1 if lo == 0 else 0, 1 if hi == n else 0))
    qh = q[tuple(idx)]
    if any(p != (0, 0) for p in pad):
        qh = jnp.pad(qh, pad)
    inner = slice(1, -1)
    out = []
    for axis, b in enumerate(faces):
        g = _along(qh, axis, slice(1, None), inner) - _along(qh, axis, slice(None, -1), inner)
        out.append(g if b is None else _cut(b, _faces_of(box, axis)) * g)
    return out


FACE_HALO = 2
"""Cells round a layer box from which its isotropic or wide face values are formed: the wide
stencil's axis term reaches two cells along the face normal, the cross-face average one across."""


def _local_face_values(lat: Lattice, shape, dtype) -> bool:
    """Whether `_box_face_values` applies: no per-face or per-cell arrays to cut (uniform faces,
    no rigid window side, no paper-model factors) and no ring metric (whose weights count rings
    from the axis)."""
    if lat.bx is not None or lat.ax_lo is not None or lat.metric is not None:
        return False
    return all(b is None for b in _face_coefficients(lat, shape, dtype))


def _box_face_values(lat: Lattice, q, box) -> list:
    """`operators.face_gradient` (isotropic or wide stencil) on a box's faces along each axis,
    formed on the box and a `FACE_HALO`-cell halo instead of the whole grid: where the block
    meets the window its ghost rules are the window's; where it is cut inside, the values that
    the cut spoils lie in the halo and are not kept. Uniform faces only (`_local_face_values`)."""
    lo_s = [max(lo - FACE_HALO, 0) for lo, _ in box]
    hi_s = [min(hi + FACE_HALO, n) for (_, hi), n in zip(box, q.shape)]
    block = q[tuple(slice(a, b) for a, b in zip(lo_s, hi_s))]
    out = []
    for axis in range(q.ndim):
        f = face_gradient(lat, block, axis)
        keep = tuple(slice(lo - s, hi - s + (1 if a == axis else 0)) for a, ((lo, hi), s) in enumerate(zip(box, lo_s)))
        out.append(f[keep])
    return out


def _box_divergence(lat: Lattice, g, axis: int, cells):
    """`operators.divergence` of a box's face values `g` along `axis` (the box's cell factors)."""
    g_hi = _along(g, axis, slice(1, None))
    g_lo = _along(g, axis, slice(None, -1))
    a_hi, a_lo = _cell_factors(lat, axis)
    if a_hi is not None:
        g_hi = _cut(a_hi, cells) * g_hi
        g_lo = _cut(a_lo, cells) * g_lo
    if axis == 1 and lat.metric is not None:
        g_hi = _cut(lat.metric.hi, cells) * g_hi
        g_lo = _cut(lat.metric.lo, cells) * g_lo
    return g_hi - g_lo


def _relaxed_operand(lat: Lattice, relax_q, p_eff, p, p_prev):
    """Add air absorption's terms to the operand (`coefficients.AirRelaxation`):
    ``p_eff + eta (P(n) - P(n-1)) + sum_i eps_i Q_i(n)``; unchanged for lossless air."""
    r = lat.relax
    if r is None:
        return p_eff
    if relax_q is None:
        raise ValueError("air absorption needs its memory fields in the state: start from stepper.init()")
    out = p_eff + r.eta * (p - p_prev)
    for e, q in zip(r.eps, relax_q):
        out = out + e * q
    return out


def _relaxed_memory(lat: Lattice, relax_q, p_new, p):
    """The memory fields' exact update for P linear over the step: Q_i(n+1) = a_i Q_i(n) + g_i (P(n+1) - P(n))."""
    r = lat.relax
    assert r is not None and relax_q is not None
    dp = p_new - p
    return tuple(a * q + g * dp for a, g, q in zip(r.a, r.g, relax_q))


def _carried(record: Array | None, name: str) -> Array:
    """The state's running record `name`, which the sensors ask for (a clear error if absent)."""
    if record is None:
        raise ValueError(
            f"the sensors record {name} but the start state carries no {name} record: start from "
            "stepper.init() of this scene (or the final state of a run with the same sensors)"
        )
    return record


def source_injection(src: PointSources, t_s, grid: Grid, lat: Lattice):
    """What `src` adds to (or sets in) P at the new step's time `t_s` (see
    `PointSources.injected`); velocity sources scale by the lattice speed at their cells."""
    c = None
    if src.injection == "velocity":
        c = lat.c
        if not isinstance(c, float) and jnp.ndim(c) != 0:
            c = c[cell_index(src.cells)]
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
