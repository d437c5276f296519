"""What both native chunk kinds (2-D/rz `kernels._Chunk`, 3-D `volume.VolumeChunk`) hand their FFI
calls: the per-step source and phasor tables, the sensors' running records, the PML layers' fields
packed into flat arrays (one module both import: no import circle)."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..stepper import State, Stepper


def absent(dtype):
    """An empty array: an argument the call does not use."""
    return jnp.zeros((0,), dtype)


def step_tables(stepper: Stepper, dt, n_ph: int, n0, length: int):
    """Per-step source values (length, n_src) and phasor cos/sin (length,), as the stepper
    computes them for steps n0 + 1 .. n0 + length."""
    st, grid, sens = stepper, stepper.grid, stepper.sensors
    ns = n0 + 1 + jnp.arange(length, dtype=jnp.int32)
    if st.sources:
        vals = jax.vmap(st._source_values)(ns)
        vals = jnp.concatenate([v.reshape(length, -1) for v in vals], axis=1).astype(dt)
    else:
        vals = jnp.zeros((length, 0), dt)
    if n_ph:
        f = sens.phasor_frequency_hz or grid.frequency_hz
        w = grid.hz_to_lattice_omega(f)
        ang = (ns.astype(dt) * w) % (2 * math.pi)
        cos, sin = jnp.cos(ang), jnp.sin(ang)
        start = getattr(sens, "phasor_from_step", 0)
        if start:  # the stepper adds 0 * cos up to that step
            cos, sin = jnp.where(ns > start, cos, 0.0), jnp.where(ns > start, sin, 0.0)
    else:
        cos = sin = jnp.zeros((length,), dt)
    return vals, cos, sin


def stats_in(dt, st: State):
    """The sensors' running records of `st` as the call's inputs (empty arrays: not recorded)."""
    return [
        absent(dt) if st.phasor_re is None else st.phasor_re,
        absent(dt) if st.phasor_im is None else st.phasor_im,
        absent(dt) if st.p_max is None else st.p_max,
        absent(dt) if st.p_sq is None else st.p_sq,
        absent(jnp.int32) if st.arrival is None else st.arrival,
    ]


def pack_layers(layers, dt):
    """The layer boxes' fields as the kernel's three flat arrays: parts (px, py[, pz] per box), faces
    (wx, wy[, wz] per box), ring corrections (the boxes that have one)."""
    flat = lambda xs: jnp.concatenate([x.reshape(-1) for x in xs]) if xs else jnp.zeros((0,), dt)
    return (
        flat([x for f in layers for x in f.parts]),
        flat([x for f in layers for x in f.fluxes]),
        flat([f.c_r for f in layers if f.c_r is not None]),
    )


def unpack_layers(layers, packed):
    """`pack_layers` undone: new `LayerFields` shaped like `layers` from the kernel's arrays."""
    offsets = [0, 0, 0]

    def take(k, like):
        n = int(np.prod(like.shape))
        v = packed[k][offsets[k] : offsets[k] + n].reshape(like.shape)
        offsets[k] += n
        return v

    out = []
    for f in layers:
        parts = tuple(take(0, x) for x in f.parts)
        fluxes = tuple(take(1, x) for x in f.fluxes)
        c_r = None if f.c_r is None else take(2, f.c_r)
        out.append(
            eqx.tree_at(lambda g: (g.parts, g.fluxes, g.c_r), f, (parts, fluxes, c_r), is_leaf=lambda x: x is None)
        )
    return tuple(out)
