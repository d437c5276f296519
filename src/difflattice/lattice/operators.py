"""The spatial operator of every lattice: one flux stencil shared by the forward step and the
adjoint pass (see `coefficients.py` for the flux form and what each coefficient array means).

On an rz grid the radial faces of ring j are weighted by the metric (A_(j+1)/V_j, A_j/V_j, one
(1, ny) row each): ``L = L_z + V^(-1) L_r^A`` with L_z and the area-weighted L_r^A symmetric.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .coefficients import Lattice

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
    """Net flux into each cell from the face values g along `axis` (without the factor K; per
    unit ring volume on an rz grid)."""
    g_hi = g[1:] if axis == 0 else g[:, 1:]
    g_lo = g[:-1] if axis == 0 else g[:, :-1]
    a_hi = lat.ax_hi if axis == 0 else lat.ay_hi
    a_lo = lat.ax_lo if axis == 0 else lat.ay_lo
    if a_hi is not None:
        g_hi = a_hi * g_hi
        g_lo = a_lo * g_lo
    if axis == 1 and lat.metric is not None:
        g_hi = lat.metric.hi * g_hi
        g_lo = lat.metric.lo * g_lo
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
    """L(q): the flux stencil without the factor K (symmetric unless the paper model's a-factors;
    V^(-1) times a symmetric one on an rz grid)."""
    qp = jnp.pad(q, 1)
    east, west = qp[2:, 1:-1], qp[:-2, 1:-1]
    north, south = qp[1:-1, 2:], qp[1:-1, :-2]
    bx, by = _face_coefficients(lat, q.shape, q.dtype)
    m = lat.metric
    terms = []
    for axis, (hi, lo), b, a_hi, a_lo in (
        (0, (east, west), bx, lat.ax_hi, lat.ax_lo),
        (1, (north, south), by, lat.ay_hi, lat.ay_lo),
    ):
        radial = axis == 1 and m is not None
        if b is None and a_hi is None and not radial:
            terms.append(hi + lo - 2 * q)
            continue
        c_hi = c_lo = 1
        if b is not None:  # the cell's high and low faces
            c_hi, c_lo = (b[1:], b[:-1]) if axis == 0 else (b[:, 1:], b[:, :-1])
        if a_hi is not None:
            c_hi, c_lo = a_hi * c_hi, a_lo * c_lo
        if radial:  # ring faces: area over ring volume
            c_hi, c_lo = m.hi * c_hi, m.lo * c_lo
        terms.append(c_hi * (hi - q) - c_lo * (q - lo))
    return terms[0] + terms[1]


def adjoint_operator(lat: Lattice, lam):
    """D^T(lam) = q_scale L(K lam), valid where L is symmetric (every model but "paper"); on an rz
    grid L = V^(-1) S with S symmetric, so D^T(lam) = V L(K lam / V)."""
    if lat.metric is not None:
        v = lat.metric.volume
        return v * stencil(lat, lat.K * lam / v)
    y = stencil(lat, lat.K * lam)
    return y if lat.q_scale is None else lat.q_scale * y
