"""The spatial operator of every lattice: one flux stencil shared by the forward step and the
adjoint pass (see `coefficients.py` for the flux form and what each coefficient array means).

On an rz grid the radial faces of ring j are weighted by the metric (A_(j+1)/V_j, A_j/V_j, one
(1, ny) row each): ``L = L_z + V^(-1) L_r^A`` with L_z and the area-weighted L_r^A symmetric.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .coefficients import Lattice, wide_axis_rows
from .kinds import PAIR_WEIGHT, WIDE_AXIS_WEIGHT

# spatial operator


def _open_masks(lat: Lattice, shape):
    """Static 0/1 face masks closing rigid window sides when no conductance array carries them
    (homogeneous and speed-zero scenes), one per axis; None where every face is open."""
    masks = []
    for axis in range(len(shape)):
        lo, hi = (lat.ghosts[2 * axis + i] == "neumann" for i in (0, 1))
        m = None
        if lo or hi:
            m = np.ones(tuple(n + 1 if a == axis else 1 for a, n in enumerate(shape)))
            idx = (slice(None),) * axis
            m[idx + (0,)] = 0.0 if lo else 1.0
            m[idx + (-1,)] = 0.0 if hi else 1.0
        masks.append(m)
    return tuple(masks)


def _face_coefficients(lat: Lattice, shape, dtype):
    """Conductances of the faces along each axis (x: (nx+1, ny[, nz]), y: (nx, ny+1[, nz]), ...),
    or broadcastable masks, or None (all faces open with unit conductance). Rigid window sides
    are closed faces."""
    ndim = len(shape)
    if lat.bx is not None:
        return (lat.bx, lat.by, lat.bz)[:ndim]
    if lat.ax_lo is not None:  # paper model: closed sides are folded into the per-cell factors
        return (None,) * ndim
    return tuple(None if m is None else jnp.asarray(m, dtype) for m in _open_masks(lat, shape))


def _along(v, axis: int, sl: slice, inner: slice | None = None):
    """v sliced by `sl` along `axis` and by `inner` (default: all) along every other axis."""
    other = slice(None) if inner is None else inner
    return v[tuple(sl if a == axis else other for a in range(v.ndim))]


def _cell_factors(lat: Lattice, axis: int):
    """The paper model's per-cell (a_hi, a_lo) along `axis`, or (None, None)."""
    if axis == 0:
        return lat.ax_hi, lat.ax_lo
    if axis == 1:
        return lat.ay_hi, lat.ay_lo
    return None, None


def _shifted(q, axis: int):
    """(q at i+1, q at i-1) along `axis` with zero ghosts, built by concatenating a zero slab.
    The 3-D stencil uses it: XLA CPU fuses it into the update loop, where padding the whole field
    first and slicing it ran the 3-D leapfrog at 0.5-0.8x the speed (192^3 and 256^3 cells,
    homogeneous, measured interleaved). The split-field PML step keeps the padded face gradient
    (its concatenated form ran at 0.6x)."""
    n = q.shape[axis]
    zero = jnp.zeros(tuple(1 if a == axis else s for a, s in enumerate(q.shape)), q.dtype)
    hi = jnp.concatenate([jax.lax.slice_in_dim(q, 1, n, axis=axis), zero], axis=axis)
    lo = jnp.concatenate([zero, jax.lax.slice_in_dim(q, 0, n - 1, axis=axis)], axis=axis)
    return hi, lo


def face_gradient(lat: Lattice, q, axis: int):
    """b * (q_hi - q_lo) on every face along `axis`, outer faces included (n+1 faces); the
    window's ghost cells are zero and rigid sides are closed faces (b = 0). With the isotropic
    stencil the face values are then averaged across the face (`_across_faces`)."""
    qp = jnp.pad(q, 1)
    inner = slice(1, -1)
    g = _along(qp, axis, slice(1, None), inner) - _along(qp, axis, slice(None, -1), inner)
    b = _face_coefficients(lat, q.shape, q.dtype)[axis]
    if lat.stencil == "isotropic":
        return _across_faces(lat, g, b, axis)
    if lat.stencil == "wide":  # the compact part's face values less (e/4) b grad(W D_axis q)
        inner_d = _axis_weighted(lat, axis_second_difference(lat, q, axis))
        dp = jnp.pad(inner_d, 1)
        gd = _along(dp, axis, slice(1, None), inner) - _along(dp, axis, slice(None, -1), inner)
        return _across_faces(lat, g, b, axis) - (WIDE_AXIS_WEIGHT / 4.0) * (gd if b is None else b * gd)
    return g if b is None else b * g


def _across_faces(lat: Lattice, g, b, axis: int):
    """The isotropic stencil's face values ``M g`` for the differences g along `axis`:
    ``M = diag(b) + sum_t A^(-1) T_t / 12``, T_t the second difference across the faces along
    each other axis t with edge weights ``min(b_j, b_k) A_jk``, so M is symmetric in the
    face-area inner product, ``(1 - (ndim - 1) / 3) b <= M <= b`` (2/3 b on a plane, 1/3 b in a
    volume: positive, hence never less stable than the standard stencil on the same
    coefficients), and a closed face (b = 0) carries nothing. A is 1 on plane and volume grids
    and on the radial faces of an rz grid; for the axial faces of an rz grid A_j = j + 1/2 (the
    ring's face area) and A_jk = j + 1 (the ring boundary between them): the finite-volume radial
    Laplacian. The ends of the window (and the axis) add no edge: a mirror there. On a plane,
    ``L5 + T_x T_y / 6`` is the 9-point Mehrstellen Laplacian; in a volume, ``L7 + (T_x T_y +
    T_y T_z + T_z T_x) / 6`` is the 19-point compact isotropic one (Kowalczyk & van Walstijn
    2011's IISO, a = 1/6, b = 0; `grid.stability_limit`)."""
    flux = g if b is None else b * g
    out = flux
    w = PAIR_WEIGHT[lat.stencil] / 2.0  # 1/12 for the isotropic stencil (a = 1/6)
    for t in range(g.ndim):
        if t != axis and g.shape[t] >= 2:
            out = out + w * _transverse(lat, g, b, axis, t)
    return out


def _transverse(lat: Lattice, g, b, axis: int, t: int):
    """``A^(-1) T_t g`` across the faces along `t` (see `_across_faces`). In a volume a soft
    (zero-ghost) window side adds the edge to the ghost layer's faces, whose values are zero: the
    operator is then the whole-space one on the odd extension, so its spectrum stays inside the
    whole-space bound (without that edge rho(-L) = 5.77 > 16/3 was measured with soft sides)."""
    n_t = g.shape[t]
    d = _along(g, t, slice(1, None)) - _along(g, t, slice(None, -1))
    if b is not None:
        if b.shape[t] > 1:
            d = d * jnp.minimum(_along(b, t, slice(1, None)), _along(b, t, slice(None, -1)))
        else:
            d = d * b
    ring = lat.metric is not None and axis == 0
    if ring:  # edge weights: the ring boundaries' areas j + 1 between rings j and j + 1
        d = d * jnp.asarray(np.arange(1, n_t, dtype=float).reshape(1, -1), g.dtype)
    lo = hi = jnp.zeros_like(_along(d, t, slice(0, 1)))
    if g.ndim == 3:  # a soft window side: the edge to the zero ghost faces (odd mirror), see below
        flux = g if b is None else b * g
        if lat.ghosts[2 * t] == "dirichlet":
            lo = _along(flux, t, slice(0, 1))
        if lat.ghosts[2 * t + 1] == "dirichlet":
            hi = -_along(flux, t, slice(-1, None))
    corr = jnp.concatenate([d, hi], axis=t) - jnp.concatenate([lo, d], axis=t)
    if ring:
        corr = corr / jnp.asarray((np.arange(n_t, dtype=float) + 0.5).reshape(1, -1), g.dtype)
    return corr


def divergence(lat: Lattice, g, axis: int):
    """Net flux into each cell from the face values g along `axis` (without the factor K; per
    unit ring volume on an rz grid)."""
    g_hi = _along(g, axis, slice(1, None))
    g_lo = _along(g, axis, slice(None, -1))
    a_hi, a_lo = _cell_factors(lat, axis)
    if a_hi is not None:
        g_hi = a_hi * g_hi
        g_lo = a_lo * g_lo
    if axis == 1 and lat.metric is not None:
        g_hi = lat.metric.hi * g_hi
        g_lo = lat.metric.lo * g_lo
    return g_hi - g_lo


def operator(lat: Lattice, p):
    """The spatial operator D(P) = K L(q_scale P) of the scene (lattice units).

    Written as one 5-point (3-D: 7-point) stencil on a zero-padded copy of q, with the face
    conductances sliced per cell (``b[1:] (q_E - q) - b[:-1] (q - q_W)``), so XLA compiles it to
    one fused loop over the grid; forming the face differences as arrays first was 2x slower
    (memory traffic).
    """
    q = p if lat.q_scale is None else lat.q_scale * p
    return lat.K * stencil(lat, q)


def stencil(lat: Lattice, q):
    """L(q): the flux stencil without the factor K (symmetric unless the paper model's a-factors;
    V^(-1) times a symmetric one on an rz grid). The loop over axes unrolls at trace time: a
    plane or rz grid compiles the 2-D arithmetic only. The isotropic stencil is written in flux
    form (face values, `_across_faces`, then their divergence)."""
    if lat.stencil == "wide":
        return _wide_3d(lat, q)
    if lat.stencil == "isotropic":
        if q.ndim == 3 and lat.ax_lo is None:
            return _isotropic_uniform_3d(lat, q) if lat.bx is None else _isotropic_links_3d(lat, q)
        terms = [divergence(lat, face_gradient(lat, q, axis), axis) for axis in range(q.ndim)]
        return sum(terms[1:], terms[0])
    if q.ndim == 3:
        neighbours = [_shifted(q, axis) for axis in range(3)]
    else:
        qp = jnp.pad(q, 1)
        inner = slice(1, -1)
        neighbours = [(_along(qp, a, slice(2, None), inner), _along(qp, a, slice(None, -2), inner)) for a in range(2)]
    faces = _face_coefficients(lat, q.shape, q.dtype)
    m = lat.metric
    total = None
    for axis, ((hi, lo), b) in enumerate(zip(neighbours, faces)):
        a_hi, a_lo = _cell_factors(lat, axis)
        radial = axis == 1 and m is not None
        if b is None and a_hi is None and not radial:
            term = hi + lo - 2 * q
        else:
            c_hi: jax.Array | float = 1
            c_lo: jax.Array | float = 1
            if b is not None:  # the cell's high and low faces
                c_hi, c_lo = _along(b, axis, slice(1, None)), _along(b, axis, slice(None, -1))
            if a_hi is not None:
                c_hi, c_lo = a_hi * c_hi, a_lo * c_lo
            if axis == 1 and m is not None:  # ring faces: area over ring volume
                c_hi, c_lo = m.hi * c_hi, m.lo * c_lo
            term = c_hi * (hi - q) - c_lo * (q - lo)
        total = term if total is None else total + term
    return total


_AXIS_LINKS = ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1))
_FACE_DIAGONALS = tuple(
    v for v in ((a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)) if sum(abs(x) for x in v) == 2
)


def _isotropic_uniform_3d(lat: Lattice, q):
    """The 3-D isotropic stencil on uniform faces as its 19-point row: ``(sum of the 6 axis
    neighbours) / 3 + (sum of the 12 face-diagonal neighbours) / 6 - 4 q``, read from one copy of
    q padded by one ghost layer: the boundary cell itself on a rigid side (the even mirror), zero
    on the others (the odd mirror about the ghost cell). Equal to the flux form (`_across_faces`)
    there to rounding (`tests/core/test_3d_isotropic.py`), and 1.9x its speed on XLA's CPU loop
    (256 x 192 x 160, float32, interleaved: 199-230 against 107-123 MLUPS)."""
    qp = q
    for axis in range(3):
        for side in (0, 1):
            width = [(0, 0)] * 3
            width[axis] = (1, 0) if side == 0 else (0, 1)
            qp = jnp.pad(qp, width, mode="edge" if lat.ghosts[2 * axis + side] == "neumann" else "constant")
    n = q.shape

    def at(d):
        return qp[1 + d[0] : 1 + d[0] + n[0], 1 + d[1] : 1 + d[1] + n[1], 1 + d[2] : 1 + d[2] + n[2]]

    axis_sum = sum((at(d) for d in _AXIS_LINKS[1:]), at(_AXIS_LINKS[0]))
    diag_sum = sum((at(d) for d in _FACE_DIAGONALS[1:]), at(_FACE_DIAGONALS[0]))
    a = PAIR_WEIGHT[lat.stencil]  # L7 + a sum T_i T_j: axis 1 - 4a, diagonal a, centre -6 + 12a
    if a == 1.0 / 6.0:
        return axis_sum / 3.0 + diag_sum / 6.0 - 4.0 * q
    return (1.0 - 4.0 * a) * axis_sum + a * diag_sum - (6.0 - 12.0 * a) * q


def _pair_min(e, axis: int):
    n = e.shape[axis]
    return jnp.minimum(jax.lax.slice_in_dim(e, 0, n - 1, axis=axis), jax.lax.slice_in_dim(e, 1, n, axis=axis))


def _plaquette_weights(lat: Lattice, b, shape, dtype) -> dict:
    """W_p a / 2 (W_p / 12 for the isotropic stencil's a = 1/6) of every plaquette (a square of four cells) in each plane (a, c), a < c: the sum
    of the edge weights of `_across_faces` that filter across it, ``min`` of the two a-faces plus
    ``min`` of the two c-faces, a window side's ghost faces counting as open (soft side) or
    closed (rigid side). Shapes: faces along a and c (n + 1), cells along the third axis."""
    ext = []
    for ax in range(3):
        e = b[ax]
        for t in range(3):
            if t != ax:
                shp = list(e.shape)
                shp[t] = 1
                lo = jnp.full(shp, 1e30 if lat.ghosts[2 * t] == "dirichlet" else 0.0, dtype)
                hi = jnp.full(shp, 1e30 if lat.ghosts[2 * t + 1] == "dirichlet" else 0.0, dtype)
                e = jnp.concatenate([lo, e, hi], axis=t)
        ext.append(e)
    out = {}
    for a in range(3):
        for c in range(a + 1, 3):
            o = 3 - a - c
            wa = jax.lax.slice_in_dim(_pair_min(ext[a], c), 1, shape[o] + 1, axis=o)
            wc = jax.lax.slice_in_dim(_pair_min(ext[c], a), 1, shape[o] + 1, axis=o)
            out[(a, c)] = (wa + wc) * (PAIR_WEIGHT[lat.stencil] / 2.0)
    return out


def _isotropic_links_3d(lat: Lattice, q):
    """The 3-D isotropic stencil with face conductances (obstacles, density contrast) as the
    weighted graph Laplacian it is: by ``(q1 - q2 - q3 + q4)^2 = (sides)^2 - (diagonals)^2`` each
    plaquette's filter weight W_p / 12 (`_plaquette_weights`) moves from its four sides (axis
    links, whose weights start at the face conductances) to its two face diagonals. Summed over
    the 6 axis and 12 diagonal neighbours of one zero-padded copy of q: equal to the flux form
    (`_across_faces`) to rounding (1e-15 in float64 with cut cells, voxels and every side kind,
    `tests/core/test_3d_isotropic.py`) and 2.2x its speed on XLA's CPU loop (256 x 192 x 160 with a
    post, float32, interleaved: 200-212 against 89-96 MLUPS)."""
    shape, dtype = q.shape, q.dtype
    b = []
    for ax, bb in enumerate(_face_coefficients(lat, shape, dtype)):
        fshape = tuple(n + (1 if a == ax else 0) for a, n in enumerate(shape))
        b.append(jnp.ones(fshape, dtype) if bb is None else jnp.broadcast_to(bb, fshape).astype(dtype))
    plaq = _plaquette_weights(lat, b, shape, dtype)
    qp = jnp.pad(q, 1)

    def at(d):
        return qp[1 + d[0] : 1 + d[0] + shape[0], 1 + d[1] : 1 + d[1] + shape[1], 1 + d[2] : 1 + d[2] + shape[2]]

    out = None
    for a in range(3):
        w = b[a]
        for c in range(3):
            if c != a:
                wp = plaq[(min(a, c), max(a, c))]
                w = (
                    w
                    - jax.lax.slice_in_dim(wp, 0, shape[c], axis=c)
                    - jax.lax.slice_in_dim(wp, 1, shape[c] + 1, axis=c)
                )
        hi, lo = [0, 0, 0], [0, 0, 0]
        hi[a], lo[a] = 1, -1
        term = jax.lax.slice_in_dim(w, 1, shape[a] + 1, axis=a) * (at(hi) - q) + jax.lax.slice_in_dim(
            w, 0, shape[a], axis=a
        ) * (at(lo) - q)
        out = term if out is None else out + term
    for (a, c), wp in plaq.items():
        for da in (0, 1):
            for dc in (0, 1):  # the plaquette at corner (i + da, j + dc) joins cell (i, j) to its diagonal
                d = [0, 0, 0]
                d[a], d[c] = (1 if da else -1), (1 if dc else -1)
                w = jax.lax.slice_in_dim(jax.lax.slice_in_dim(wp, da, shape[a] + da, axis=a), dc, shape[c] + dc, axis=c)
                out = out + w * (at(d) - q)
    return out


def axis_second_difference(lat: Lattice, q, axis: int):
    """D_axis q: the wall-aware 1-D second difference along `axis`, ``b_hi (q_hi - q) - b_lo (q -
    q_lo)`` with the face conductances (or rigid sides' masks) and zero ghosts: the standard
    stencil's term for that axis. Symmetric negative semi-definite; with zero ghosts it is the
    whole-line operator on the odd extension about a soft side's ghost cell, with a closed face
    the one on the even extension about a rigid side."""
    hi, lo = _shifted(q, axis)
    b = _face_coefficients(lat, q.shape, q.dtype)[axis]
    if b is None:
        return hi + lo - 2 * q
    return _along(b, axis, slice(1, None)) * (hi - q) - _along(b, axis, slice(None, -1)) * (q - lo)


def _axis_weighted(lat: Lattice, d):
    """W d with W = K / c^2 per cell (rho / phi: density over fluid fraction; 1 in air), the
    weight between the two axis second differences of the wide stencil that makes ``K D W D``
    a c^4 (lattice units) operator like the continuum's and keeps ``D W D`` symmetric."""
    if lat.bx is None:
        return d
    return (lat.K / lat.c**2) * d


def _wide_3d(lat: Lattice, q):
    """The 3-D wide stencil (`kinds.WIDE_PAIR_WEIGHT`, `kinds.WIDE_AXIS_WEIGHT`):
    ``L = L_c - (e / 4) sum_axes D_a W D_a``, L_c the compact 19-point stencil with pair weight a
    (`_isotropic_uniform_3d`, `_isotropic_links_3d`: the isotropic stencil's forms with a = 0.08
    instead of 1/6) and D_a the wall-aware axis second difference (`axis_second_difference`).
    Each ``D_a W D_a = D_a^T W D_a`` is symmetric positive semi-definite for every face
    conductance (rigid obstacles, cut cells, closed window sides) and W > 0, so L stays symmetric
    negative semi-definite and the leapfrog conserves its discrete energy. Symbol in air:
    ``-4 [sum s_i + e sum s_i^2 - 4 a sum s_i s_j]``, s_i = sin^2(k_i / 2): 25 points (the 19
    compact ones and the 6 second axis neighbours)."""
    if lat.bx is None:
        return _wide_uniform_3d(lat, q)
    out = _isotropic_links_3d(lat, q)
    rows = lat.wide_rows
    if rows is None:  # a lattice built without them (not by `build_lattice`): formed here, each step
        rows = wide_axis_rows((lat.bx, lat.by, lat.bz), lat.K / lat.c**2, q.shape, q.dtype)
    c2, c1, c0 = rows[:3], rows[3:6], rows[6]  # c2, c1 padded low by 2 and 1 zero layers along their axis
    out = out + c0 * q
    qp = jnp.pad(q, 2)  # zero beyond the window (where the rows are zero or the ghost is)
    n = q.shape
    for axis in range(3):

        def at(d, axis=axis):
            return jax.lax.slice_in_dim(
                qp[tuple(slice(None) if a == axis else slice(2, 2 + n[a]) for a in range(3))],
                2 + d,
                2 + d + n[axis],
                axis=axis,
            )

        c1a, c2a = c1[axis], c2[axis]
        c1_here, c1_below = (jax.lax.slice_in_dim(c1a, i, i + n[axis], axis=axis) for i in (1, 0))
        c2_here, c2_below = (jax.lax.slice_in_dim(c2a, i, i + n[axis], axis=axis) for i in (2, 0))
        out = out + c2_here * at(2) + c1_here * at(1) + c1_below * at(-1) + c2_below * at(-2)
    return out


def _wide_uniform_3d(lat: Lattice, q):
    """The wide stencil on uniform faces as its 25-point row, read from one copy of q padded by two
    ghost layers: the even mirror about a rigid side's face (q_-1 = q_0, q_-2 = q_1) and the odd
    mirror about a soft side's ghost cell (q_-1 = 0, q_-2 = -q_0), the extensions on which the
    composed wall-aware differences (`_wide_3d`) are the whole-space operator: axis neighbours
    1 - 4a + e, face diagonals a, second axis neighbours -e/4, centre -(6 - 12a) - 9e/2. Equal to
    the composed form to rounding (`tests/core/test_wide_3d.py`); XLA's CPU loop ran the composed
    form at a fifth of the isotropic row's speed per cell update."""
    qp = q
    for axis in range(3):
        n = qp.shape[axis]
        first, second = (jax.lax.slice_in_dim(qp, i, i + 1, axis=axis) for i in (0, 1))
        last, before = (jax.lax.slice_in_dim(qp, n - 1 - i, n - i, axis=axis) for i in (0, 1))
        rigid_lo, rigid_hi = (lat.ghosts[2 * axis + side] == "neumann" for side in (0, 1))
        lo = [second, first] if rigid_lo else [-first, jnp.zeros_like(first)]
        hi = [last, before] if rigid_hi else [jnp.zeros_like(last), -last]
        qp = jnp.concatenate([*lo, qp, *hi], axis=axis)
    n = q.shape

    def at(d):
        return qp[2 + d[0] : 2 + d[0] + n[0], 2 + d[1] : 2 + d[1] + n[1], 2 + d[2] : 2 + d[2] + n[2]]

    a, e = PAIR_WEIGHT["wide"], WIDE_AXIS_WEIGHT
    axis_sum = sum((at(d) for d in _AXIS_LINKS[1:]), at(_AXIS_LINKS[0]))
    diag_sum = sum((at(d) for d in _FACE_DIAGONALS[1:]), at(_FACE_DIAGONALS[0]))
    far = [tuple(2 * x for x in d) for d in _AXIS_LINKS]
    far_sum = sum((at(d) for d in far[1:]), at(far[0]))
    return (1.0 - 4.0 * a + e) * axis_sum + a * diag_sum - (e / 4.0) * far_sum - (6.0 - 12.0 * a + 4.5 * e) * q


def adjoint_operator(lat: Lattice, lam):
    """D^T(lam) = q_scale L(K lam), valid where L is symmetric (every model but "paper"); on an rz
    grid L = V^(-1) S with S symmetric, so D^T(lam) = V L(K lam / V)."""
    if lat.metric is not None:
        v = lat.metric.volume
        return v * stencil(lat, lat.K * lam / v)
    y = stencil(lat, lat.K * lam)
    return y if lat.q_scale is None else lat.q_scale * y
