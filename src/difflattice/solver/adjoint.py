"""Reverse mode by the adjoint wave equation: the gradient of a run is a second wave simulation
run backwards in time (`run(..., adjoint="lattice")`).

JAX's own reverse mode of the scan stores a full field per step for coefficient gradients and
transposes the stencil into padded copies; here the backward pass is the same fused stencil as
the forward pass:

- adjoint fields: with ``S(p, p') = keep ((2 p - (1 - s) p' + D p) / (1 + s))`` and
  ``a = keep g / (1 + s)``, the cotangents of (p(n), p(n-1)) are ``2 a + D^T a + g'`` and
  ``-(1 - s) a``, where ``D^T a = q_scale L(K a)`` (L is symmetric), or ``V L(K a / V)`` on an rz
  grid (L = V^(-1) times a symmetric operator, V the ring volumes);
- source gradients: the adjoint field at the source cells, chained through the drive signal;
- coefficient gradients (medium maps, shapes): per step, the cotangent of the lattice
  coefficients at the forward fields, which are recomputed chunk by chunk from states saved
  every ``chunk`` steps (memory ~ sqrt(n_steps) fields with ``chunk = sqrt(n_steps)``).
  When no coefficient is differentiated, nothing is saved or recomputed.

Supported: the leapfrog stepper (no PML, no Mur edges, no absorption, not the "paper" model),
starting at rest, recording probes, phasors and the final fields. `supports` says why not
otherwise; `run(..., adjoint="auto")` then falls back to JAX's reverse mode. The plain JAX path is
the reference: tests compare the two.

On a CPU with the native kernels (`backend="auto"`), the forward run is native, and so is the
backward run where the lattice has no q_scale, keep, sponge or viscous term (K and face
conductances, plane or rz: `native.kernels.adjoint_supported`): source gradients by the kernels'
adjoint step (temporal blocking, nothing stored), coefficient gradients (K, bx, by) by
`difflattice_adjoint_chunk`, which steps the forward field back from each segment's saved end
alongside the adjoint (the leapfrog is reversible; the reconstruction's rounding restarts from an
exact saved field every segment of `NATIVE_SEGMENT_STEPS` steps, two fields saved per segment)
with the cotangents fused into the same pass.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..lattice.operators import _along, _face_coefficients, operator, stencil
from .native.kernels import adjoint_supported, chunk_kernel
from .stepper import cell_index, source_injection


def supports(stepper, state=None) -> str | None:
    """None if the adjoint path handles this scene, otherwise the reason it does not."""
    lat = stepper.lattice
    sens = stepper.sensors
    if stepper.staggered:
        return "a PML edge (the split-field form on the layer's cells)"
    if lat.stencil != "standard":
        return "the isotropic stencil (the hand-written coefficient cotangents are the standard stencil's)"
    if any(lat.mur):
        return "Mur edges"
    if lat.eta != 0:
        return "absorption (viscous term)"
    if getattr(lat, "relax", None) is not None:
        return "air absorption (relaxation memory fields; JAX's reverse mode differentiates it)"
    if lat.ax_lo is not None:
        return 'the "paper" boundary model (non-symmetric operator)'
    if state is not None:
        return "a start state other than rest"
    if sens.p_max or sens.p_rms or sens.arrival_threshold_pa or sens.snapshot_every is not None:
        return "nonlinear or field-history sensors (p_max, p_rms, arrival, snapshots)"
    return None


def _linear_step(lat, p, p_prev):
    """The source-free leapfrog step S(p, p_prev) (the stepper's, restricted to supported scenes)."""

    d = operator(lat, p)
    if lat.sponge is None:
        new = 2 * p - p_prev + d
    else:
        new = (2 * p - (1 - lat.sponge) * p_prev + d) / (1 + lat.sponge)
    return new if lat.keep is None else lat.keep * new


def _angles(grid, sensors, n):
    f = sensors.phasor_frequency_hz or grid.frequency_hz
    w = grid.hz_to_lattice_omega(f)
    return (n.astype(grid.jnp_dtype) * w) % (2 * math.pi)


# The native backward pass steps the forward fields back from saved ends, so its segments can be
# much longer than the forward run's chunks (its memory is 2 fields per segment, its rounding
# restarts from an exact field at every segment end): the saved fields are taken every
# `native_segment(chunk)` steps. Each segment costs one kernel call and two field copies, whose
# fixed cost dominated at sqrt(n_steps)-step segments (measured: 840x630 x 1000 steps, a speed-map
# gradient 0.88 s with 31-step segments, 0.59 s with 250).
NATIVE_SEGMENT_STEPS = 256


def native_segment(chunk: int) -> int:
    """The native backward pass's segment length: the multiple of `chunk` nearest
    `NATIVE_SEGMENT_STEPS` (at least one chunk)."""
    return chunk * max(1, round(NATIVE_SEGMENT_STEPS / chunk))


def _forward(stepper, n_steps: int, chunk: int, save, native: bool):
    """Run from rest; returns (probes, phasor_re, phasor_im, p, p_prev, peaks), (saved, rem_start).
    `save`: False (nothing), "starts" (each chunk's start (p, p_prev), stacked, and the remainder
    chunk's start) or a segment length in steps, a multiple of `chunk` (the fields at the end of
    each whole segment, stacked; rem_start None). `native`: each chunk of steps one call of the
    native kernels (else the JAX scan)."""
    n_chunks, rem = divmod(n_steps, chunk)
    if native:
        advance = chunk_kernel(stepper).advance
    else:

        def advance(st, length):
            return jax.lax.scan(lambda s, _: stepper.step(s), st, None, length=length, unroll=min(2, length))

    starts = save == "starts"

    def outer(st, _):
        start = (st.p, st.p_prev) if starts else None
        st, ys = advance(st, chunk)
        return st, (ys, jnp.max(jnp.abs(st.p)), start)

    def chunks(st, n):
        """n chunks: (state, (probes (n * chunk, n_probes) or None, peaks (n,), starts or None))."""
        st, (ys, peaks, saved) = jax.lax.scan(outer, st, None, length=n)
        return st, (None if ys is None else ys.reshape(n * chunk, -1), peaks, saved)

    st = stepper.init()
    saved = None
    if save and not starts:  # whole segments of m chunks, each end saved, then the chunks left
        m = save // chunk
        n_seg, left = divmod(n_chunks, m)
        ys_parts: list = []
        peak_parts: list = []
        if n_seg:

            def group(st, _):
                st, (ys, peaks, _) = chunks(st, m)
                return st, (ys, peaks, (st.p, st.p_prev))

            st, (ys, peaks, saved) = jax.lax.scan(group, st, None, length=n_seg)
            ys_parts.append(None if ys is None else ys.reshape(n_seg * m * chunk, -1))
            peak_parts.append(peaks.reshape(-1))
        if left:
            st, (ys, peaks, _) = chunks(st, left)
            ys_parts.append(ys)
            peak_parts.append(peaks)
        ys = None if stepper.sensors.n_probes == 0 else jnp.concatenate(ys_parts)
        peaks = jnp.concatenate(peak_parts)
    else:
        st, (ys, peaks, saved) = chunks(st, n_chunks)
    rem_start = None
    if rem:
        rem_start = (st.p, st.p_prev) if starts else None
        st, ys_r = advance(st, rem)
        peaks = jnp.concatenate([peaks, jnp.max(jnp.abs(st.p))[None]])
        if ys is not None:
            ys = jnp.concatenate([ys, ys_r.reshape(rem, -1)], axis=0)
    return (ys, st.phasor_re, st.phasor_im, st.p, st.p_prev, peaks), (saved, rem_start)


@eqx.filter_custom_vjp
def linear_run(stepper, n_steps: int, chunk: int, native: bool = False):
    """Outputs (probes, phasor_re, phasor_im, p_final, p_prev_final, peak_history). `native`: the
    forward run and, where `native.kernels.adjoint_supported`, the backward run on the native
    kernels (the caller checked they run this scene)."""
    return _forward(stepper, n_steps, chunk, save=False, native=native)[0]


@linear_run.def_fwd
def _linear_run_fwd(perturbed, stepper, n_steps, chunk, native=False):
    save: bool | str | int = False
    if _lattice_perturbed(perturbed):  # coefficient gradients need the forward fields
        # the native pass steps back from saved segment ends, the JAX pass recomputes from chunk starts
        save = native_segment(chunk) if _native_path(stepper, perturbed, native) else "starts"
    out, saved = _forward(stepper, n_steps, chunk, save=save, native=native)
    final = (out[3], out[4]) if save else None  # (the native backward steps back from the end)
    return out, (*saved, final)


def _lattice_perturbed(perturbed) -> bool:
    return any(jax.tree_util.tree_leaves(perturbed.lattice))


def _fields_wanted(lat, perturbed) -> tuple[str, ...]:
    """The lattice fields whose gradients are wanted (the step reads K, q_scale, bx, by[, bz],
    keep, sponge)."""
    return tuple(
        f
        for f in ("K", "q_scale", "bx", "by", "bz", "keep", "sponge")
        if getattr(lat, f) is not None and any(jax.tree_util.tree_leaves(getattr(perturbed.lattice, f)))
    )


def _native_path(stepper, perturbed, native: bool) -> bool:
    """Whether the backward pass runs on the native kernels."""
    return native and set(_fields_wanted(stepper.lattice, perturbed)) <= {"K", "bx", "by"} and _native_backward(stepper)


@linear_run.def_bwd
def _linear_run_bwd(starts, grads, perturbed, stepper, n_steps, chunk, native=False):
    """The backward pass: the output cotangents injected into the adjoint field step by step (the
    native kernels' pass or the JAX scan's), then the per-step source cotangents chained through
    the drive signals, and the coefficient cotangents."""
    lat = stepper.lattice
    grid, sens = stepper.grid, stepper.sensors
    dtype = grid.jnp_dtype
    g_probes, g_re, g_im, g_p, g_pp, _ = grads
    zeros = jnp.zeros(grid.shape, dtype)
    g1 = zeros if g_p is None else g_p.astype(dtype)
    g0 = zeros if g_pp is None else g_pp.astype(dtype)
    m = sens.n_phasors
    use_phasors = bool(m and (g_re is not None or g_im is not None))
    g_re = jnp.zeros(m, dtype) if (m and g_re is None) else g_re
    g_im = jnp.zeros(m, dtype) if (m and g_im is None) else g_im
    n_probes = sens.n_probes
    if n_probes and g_probes is None:
        g_probes = jnp.zeros((n_steps, n_probes), dtype)
    # row n of probes_all: the cotangent of the probes recorded at step n (row 0: none)
    probes_all = jnp.concatenate([jnp.zeros((1, n_probes), dtype), g_probes.astype(dtype)]) if n_probes else None
    phasor_ct = (g_re, g_im) if use_phasors else None
    inject = _injector(stepper, probes_all, phasor_ct)
    fields_wanted = _fields_wanted(lat, perturbed) if _lattice_perturbed(perturbed) else ()
    g1 = inject(g1, jnp.asarray(n_steps, jnp.int32), None if probes_all is None else probes_all[n_steps])
    if _native_path(stepper, perturbed, native):
        src_cts, lat_ct = _native_backward_pass(
            stepper, g1, g0, n_steps, native_segment(chunk), starts, probes_all, phasor_ct, fields_wanted
        )
    else:
        src_cts, lat_ct = _jax_backward_pass(stepper, g1, g0, n_steps, chunk, starts, probes_all, inject, fields_wanted)
    src_grads, c_ct = _source_gradients(stepper, perturbed, src_cts, n_steps)
    if c_ct is not None:
        lat_ct = dict(lat_ct)
        lat_ct["c"] = c_ct
    return _cotangent_tree(stepper, perturbed, src_grads, lat_ct)


def _injector(stepper, probes_all, phasor_ct):
    """inject(g, n, probe_row): the cotangents of the outputs recorded at step n (none at step 0)
    added to that step's field. Done at the end of each backward step, after the stencil (as the
    forward step adds its sources last), so XLA keeps the stencil's padded input fused."""
    grid, sens = stepper.grid, stepper.sensors
    dtype = grid.jnp_dtype

    def inject(g, n, probe_row):
        if probes_all is not None:
            g = g.at[cell_index(sens.probes)].add(probe_row)
        if phasor_ct is not None:
            g_re, g_im = phasor_ct
            c = cell_index(sens.phasor_cells)
            ang = _angles(grid, sens, n)
            w = jnp.where(n > sens.phasor_from_step, 1.0, 0.0).astype(dtype)
            g = g.at[c].add(w * (g_re * jnp.cos(ang) + g_im * jnp.sin(ang)))
        return g

    return inject


def _lattice_cotangents(lat, fields_wanted, g, a, ka, p_n, p_nm1):
    """Cotangents of one step's coefficients at the forward fields (p(n), p(n-1)), by hand:
    dK = a L(q), dq_scale = p L(K a), db = -grad(q) grad(K a) per face, dkeep = g u,
    dsponge = a (p(n-1) - u) with u the step before `keep`."""
    out = {}
    q = p_n if lat.q_scale is None else lat.q_scale * p_n
    need_lq = any(f in fields_wanted for f in ("K", "keep", "sponge"))
    lq = stencil(lat, q) if need_lq else None
    if "K" in fields_wanted:
        v = a * lq
        out["K"] = jnp.sum(v) if jnp.ndim(lat.K) == 0 else v
    if "q_scale" in fields_wanted:
        out["q_scale"] = p_n * stencil(lat, ka)
    if q.ndim == 3:  # 3-D: one face conductance per axis, no metric
        qp, kp = jnp.pad(q, 1), jnp.pad(ka, 1)
        inner = slice(1, -1)
        for f, axis in (("bx", 0), ("by", 1), ("bz", 2)):
            if f in fields_wanted:
                dq = _along(qp, axis, slice(1, None), inner) - _along(qp, axis, slice(None, -1), inner)
                dk = _along(kp, axis, slice(1, None), inner) - _along(kp, axis, slice(None, -1), inner)
                out[f] = -dq * dk
    else:
        for f, axis in (("bx", 0), ("by", 1)):
            if f in fields_wanted:
                qp = jnp.pad(q, 1)
                if axis == 0:
                    kp = jnp.pad(ka, 1)
                    out[f] = -(qp[1:, 1:-1] - qp[:-1, 1:-1]) * (kp[1:, 1:-1] - kp[:-1, 1:-1])
                elif lat.metric is None:
                    kp = jnp.pad(ka, 1)
                    out[f] = -(qp[1:-1, 1:] - qp[1:-1, :-1]) * (kp[1:-1, 1:] - kp[1:-1, :-1])
                else:  # rz: a radial face of area A couples ka / V on either side
                    kp = jnp.pad(ka / lat.metric.volume, 1)
                    out[f] = -lat.metric.area * (qp[1:-1, 1:] - qp[1:-1, :-1]) * (kp[1:-1, 1:] - kp[1:-1, :-1])
    if "keep" in fields_wanted or "sponge" in fields_wanted:
        s_ = lat.sponge
        u = 2 * p_n - p_nm1 + lat.K * lq if s_ is None else (2 * p_n - (1 - s_) * p_nm1 + lat.K * lq) / (1 + s_)
        if "keep" in fields_wanted:
            out["keep"] = g * u
        if "sponge" in fields_wanted:
            out["sponge"] = a * (p_nm1 - u)
    return out


def _jax_backward_pass(stepper, g1, g0, n_steps: int, chunk: int, starts, probes_all, inject, fields_wanted):
    """The backward pass as a JAX scan, chunk by chunk from the last (the forward fields, where
    coefficient cotangents need them, recomputed from each chunk's saved start): (per-step source
    cotangents, one (n_steps, n_cells) array per source; coefficient cotangents {field: array})."""
    lat, grid = stepper.lattice, stepper.grid
    dtype = grid.jnp_dtype
    need_prev = "keep" in fields_wanted or "sponge" in fields_wanted

    def back_step(carry, xs):
        """From the cotangents of (p(n+1), p(n)) to those of (p(n), p(n-1))."""
        g1, g0, lat_ct = carry
        n_next, probe_row, fields = xs
        src_ct = []
        for src in reversed(stepper.sources):
            c = cell_index(src.cells)
            src_ct.append(g1[c])
            if not src.adds:
                g1 = g1.at[c].set(0.0)
        src_ct = tuple(reversed(src_ct))
        a = g1 if lat.keep is None else lat.keep * g1
        if lat.sponge is not None:
            a = a / (1 + lat.sponge)
        ka = lat.K * a
        y = stencil(lat, ka) if lat.metric is None else lat.metric.volume * stencil(lat, ka / lat.metric.volume)
        if fields_wanted:
            p_n, p_nm1 = fields if need_prev else (fields, None)
            ct = _lattice_cotangents(lat, fields_wanted, g1, a, ka, p_n, p_nm1)
            lat_ct = {k: lat_ct[k] + ct[k] for k in lat_ct}
        new_g1 = 2 * a + (y if lat.q_scale is None else lat.q_scale * y) + g0
        new_g1 = inject(new_g1, n_next - 1, probe_row)
        new_g0 = -a if lat.sponge is None else -(1 - lat.sponge) * a
        return (new_g1, new_g0, lat_ct), src_ct

    def fwd_one(c, n_next):
        p, pp = c
        new = _linear_step(lat, p, pp)
        t = n_next.astype(dtype) * grid.dt_s
        for src in stepper.sources:
            cc = cell_index(src.cells)
            v = source_injection(src, t, grid, lat).astype(dtype)
            new = new.at[cc].add(v) if src.adds else new.at[cc].set(v)
        return (new, p), ((p, pp) if need_prev else p)

    def segment(carry, n_first, length, start):
        """Backward over steps n_first+1 .. n_first+length (recomputing their fields if needed)."""
        ns = n_first + 1 + jnp.arange(length)
        rows = None if probes_all is None else jax.lax.dynamic_slice_in_dim(probes_all, n_first, length, 0)
        fields = None
        if fields_wanted:
            _, fields = jax.lax.scan(fwd_one, start, ns, unroll=min(2, length))
        return jax.lax.scan(back_step, carry, (ns, rows, fields), reverse=True, unroll=min(2, length))

    lat_ct0 = {f: jnp.zeros(jnp.shape(getattr(lat, f)), dtype) for f in fields_wanted}
    full_starts, rem_start = starts[:2]
    carry, pieces = _chunks_backwards(segment, (g1, g0, lat_ct0), n_steps, chunk, full_starts, rem_start)
    src_cts = tuple(jnp.concatenate([pc[i] for pc in pieces], axis=0) for i in range(len(stepper.sources)))
    return src_cts, carry[2]


def _source_gradients(stepper, perturbed, src_cts, n_steps: int):
    """The per-step source cotangents chained through the drive signals (weights, lags) and, for
    velocity sources, the lattice speed at their cells: (one gradient tree per source, the
    speed's cotangent or None)."""
    lat, grid = stepper.lattice, stepper.grid
    dtype = grid.jnp_dtype
    t_all = (jnp.arange(1, n_steps + 1)).astype(dtype) * grid.dt_s
    src_grads = []
    want_c = any(s.injection == "velocity" for s in stepper.sources) and any(
        jax.tree_util.tree_leaves(perturbed.lattice.c)
    )
    c_ct = None
    for src, ct in zip(stepper.sources, src_cts):

        def injected(s, c):
            lat_c = eqx.tree_at(lambda L: L.c, lat, c)
            return jax.vmap(lambda t: source_injection(s, t, grid, lat_c))(t_all)

        _, vjp = jax.vjp(injected, src, lat.c)
        g, gc = vjp(ct.astype(dtype))
        src_grads.append(g)
        if want_c and src.injection == "velocity":
            c_ct = gc if c_ct is None else c_ct + gc
    return src_grads, c_ct


def _cotangent_tree(stepper, perturbed, src_grads, lat_ct):
    """The stepper-shaped cotangent: the sources' gradients where perturbed, the lattice's
    coefficient cotangents, None elsewhere."""
    out = jax.tree_util.tree_map(lambda _: None, stepper)
    sources_ct = tuple(_mask(g, pt) for g, pt in zip(src_grads, perturbed.sources))
    out = eqx.tree_at(lambda s: s.sources, out, sources_ct, is_leaf=lambda x: x is None)
    if lat_ct:
        lat = stepper.lattice
        lat_grad = jax.tree_util.tree_map(lambda _: None, lat)
        names = tuple(lat_ct)
        lat_grad = eqx.tree_at(
            lambda L: tuple(getattr(L, f) for f in names),
            lat_grad,
            tuple(lat_ct[f] for f in names),
            is_leaf=lambda x: x is None,
        )
        out = eqx.tree_at(lambda s: s.lattice, out, lat_grad, is_leaf=lambda x: x is None)
    return out


def _native_backward(stepper) -> bool:
    """Whether the native kernels run this backward pass.
    It records every source cell, then zeroes the hard ones; JAX's backward step does both source
    by source (last first), which differs only where a hard source shares a cell with another
    source: so hard sources run natively when they are the only source."""
    srcs = stepper.sources
    return adjoint_supported(stepper) and (len(srcs) <= 1 or all(s.adds for s in srcs))


def _native_backward_pass(stepper, g1, g0, n_steps: int, segment: int, saved, probes_all, phasor_ct, fields_wanted):
    """The backward pass on the native kernels: (per-step source cotangents, one (n_steps,
    n_cells) array per source; coefficient cotangents {field: array}).

    With a(n) the cotangent of p(n) after the hard sources' zeroing, the backward step is
    a(n-1) = 2 a(n) + V L(K a(n) / V) - a(n+1) + injections (V the ring volumes on an rz grid,
    else 1), so x = a / V follows the kernel's x' = 2 x + L(K x) - h with the injections divided
    by V; the record of x at the source cells (before the zeroing) times V is the cotangent of p(n)
    there. Without coefficient cotangents the kernel's adjoint mode runs the whole pass (temporal
    blocking, no stored fields); with them, `difflattice_adjoint_chunk` runs it segment by segment
    (`segment` steps each, then the rest) from the fields the forward run saved at each segment's
    end (`saved` = (stacked ends, None, final fields)), stepping the forward field back alongside."""
    lat, grid, sens = stepper.lattice, stepper.grid, stepper.sensors
    dtype, shape = grid.jnp_dtype, grid.shape
    nx, ny = shape
    kern = chunk_kernel(stepper)
    srcs = stepper.sources
    cells_of = lambda c: jnp.asarray(c, jnp.int32).reshape(-1, 2)
    empty = jnp.zeros((0, 2), jnp.int32)
    cells = jnp.concatenate([cells_of(s.cells) for s in srcs]) if srcs else empty
    hard = np.concatenate([np.full(s.n_cells, not s.adds) for s in srcs]) if srcs else np.zeros(0, bool)
    zero_cells = cells[np.flatnonzero(hard)]
    m = lat.metric
    vol = None if m is None else jnp.broadcast_to(jnp.asarray(m.volume, dtype), shape)
    at = lambda f, c: f[c[:, 0], c[:, 1]]

    inj = []  # the output cotangents' cells: probes, then phasor cells
    if probes_all is not None:
        inj.append(cells_of(sens.probes))
    if phasor_ct is not None:
        inj.append(cells_of(sens.phasor_cells))
    inj_cells = jnp.concatenate(inj) if inj else empty
    inv_v = None if vol is None else 1.0 / at(vol, inj_cells)

    def rows(ns):
        """The injections at steps `ns` (descending), one row per step."""
        cols = []
        if probes_all is not None:
            cols.append(probes_all[ns])
        if phasor_ct is not None:
            g_re, g_im = phasor_ct
            ang = _angles(grid, sens, ns)[:, None]
            w = jnp.where(ns > sens.phasor_from_step, 1.0, 0.0).astype(dtype)[:, None]
            cols.append(w * (g_re[None] * jnp.cos(ang) + g_im[None] * jnp.sin(ang)))
        v = jnp.concatenate(cols, axis=1).astype(dtype) if cols else jnp.zeros((ns.shape[0], 0), dtype)
        return v if inv_v is None else v * inv_v[None]

    first = at(g1, cells)  # the cotangent at the sources of p(n_steps)
    a = g1.at[zero_cells[:, 0], zero_cells[:, 1]].set(0.0)
    x, h = (a, -g0) if vol is None else (a / vol, -g0 / vol)
    lat_ct = {}
    if not fields_wanted:
        m_steps = n_steps - 1  # steps n_steps - 1 .. 1 (step 0's cotangent is not needed: the run starts at rest)
        per_call = min(m_steps, 512)
        recs = []
        if m_steps:
            n_calls, rem = divmod(m_steps, per_call)

            def call(x, h, n_hi, length):
                ns = n_hi - jnp.arange(length, dtype=jnp.int32)
                return kern.adjoint_steps(x, h, length, inj_cells, rows(ns), cells, zero_cells)

            def body(c, j):
                x, h, rec = call(*c, (n_steps - 1 - j * per_call).astype(jnp.int32), per_call)
                return (x, h), rec

            (x, h), rec = jax.lax.scan(body, (x, h), jnp.arange(n_calls, dtype=jnp.int32))
            recs.append(rec.reshape(n_calls * per_call, -1))
            if rem:
                recs.append(call(x, h, jnp.asarray(rem, jnp.int32), rem)[2])
        later = jnp.concatenate(recs) if recs else jnp.zeros((0, cells.shape[0]), dtype)
        desc = jnp.concatenate([first[None], later])  # rows: steps n_steps .. 1
    else:
        bx, by = _face_coefficients(lat, shape, dtype)
        faces = (
            jnp.ones((nx + 1, ny), dtype) if bx is None else jnp.broadcast_to(jnp.asarray(bx, dtype), (nx + 1, ny)),
            jnp.ones((nx, ny + 1), dtype) if by is None else jnp.broadcast_to(jnp.asarray(by, dtype), (nx, ny + 1)),
        )
        row = lambda v, n: jnp.broadcast_to(jnp.asarray(v, dtype).reshape(-1), (n,))
        metric = (  # a plane grid: no metric (empty arrays), the kernel's unit-factor loop
            (jnp.zeros((0,), dtype),) * 4
            if m is None
            else (row(m.lo, ny), row(m.hi, ny), row(m.volume, ny), row(m.area, ny + 1))
        )
        full = {"K": (nx, ny), "bx": (nx + 1, ny), "by": (nx, ny + 1)}
        acc0 = tuple(jnp.zeros(full[f] if f in fields_wanted else (0,), dtype) for f in ("K", "bx", "by"))

        def backwards(carry, n_first, length, end):
            x, h, acc = carry
            ns = n_first + length - 1 - jnp.arange(length, dtype=jnp.int32)  # the injections' steps
            x, h, rec, acc = kern.adjoint_chunk(
                end, x, h, length, n_first, faces, metric, inj_cells, rows(ns), cells, zero_cells, acc
            )
            return (x, h, acc), rec[::-1]  # rows: steps n_first .. n_first + length - 1

        # each segment steps the forward field back from its end: the saved field at a whole
        # segment's end, the run's final fields for the rest
        ends, _, final = saved
        carry, asc = _chunks_backwards(backwards, (x, h, acc0), n_steps, segment, ends, final)
        acc = carry[2]
        for f, v in zip(("K", "bx", "by"), acc):
            if f in fields_wanted:
                lat_ct[f] = _sum_to(v, jnp.shape(getattr(lat, f)))
        later = jnp.concatenate(asc)[1:]  # steps 1 .. n_steps - 1 (step 0's record dropped)
        desc = jnp.concatenate([first[None], later[::-1]])
    if vol is not None:
        desc = desc.at[1:].multiply(at(vol, cells)[None])
    ct = desc[::-1]  # rows: steps 1 .. n_steps
    bounds = np.cumsum([0] + [s.n_cells for s in srcs])
    return tuple(ct[:, bounds[i] : bounds[i + 1]] for i in range(len(srcs))), lat_ct


def _chunks_backwards(segment, carry, n_steps: int, chunk: int, full_xs, rem_x):
    """`segment(carry, n_first, length, x)` over the run's chunks from the last to the first: the
    remainder chunk (steps n_chunks * chunk + 1 .. n_steps) with `rem_x`, then the full chunks in
    a reverse scan over `full_xs` (stacked per chunk). Returns (carry, [the full chunks' outputs
    joined along the steps, the remainder's]) in step order."""
    n_chunks, rem = divmod(n_steps, chunk)
    pieces = []
    if rem:
        carry, out = segment(carry, jnp.asarray(n_chunks * chunk, jnp.int32), rem, rem_x)
        pieces.append(out)
    if n_chunks:

        def body(c, xs):
            k, x = xs
            return segment(c, k * chunk, chunk, x)

        ks = jnp.arange(n_chunks, dtype=jnp.int32)
        carry, outs = jax.lax.scan(body, carry, (ks, full_xs), reverse=True)
        pieces.insert(0, jax.tree_util.tree_map(lambda a: a.reshape(n_chunks * chunk, -1), outs))
    return carry, pieces


def _sum_to(v, shape):
    """Sum a full-grid cotangent down to the (broadcast) shape of its coefficient."""
    if tuple(v.shape) == tuple(shape):
        return v
    if len(shape) == 0:
        return jnp.sum(v)
    axes = tuple(i for i, (a, b) in enumerate(zip(v.shape, shape)) if b == 1 and a != 1)
    return jnp.sum(v, axis=axes, keepdims=True).reshape(shape)


def _mask(grad_tree, perturbed_tree):
    """Keep the gradient leaves whose perturbed flag is True; None elsewhere."""
    g_leaves, treedef = jax.tree_util.tree_flatten(grad_tree, is_leaf=lambda x: x is None)
    p_leaves = jax.tree_util.tree_leaves(perturbed_tree, is_leaf=lambda x: x is None)
    if len(g_leaves) != len(p_leaves):
        raise AssertionError("internal: gradient and perturbed trees differ")
    return jax.tree_util.tree_unflatten(
        treedef, [g if (p is True and g is not None) else None for g, p in zip(g_leaves, p_leaves)]
    )
