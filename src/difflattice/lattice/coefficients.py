"""Lattice coefficients: a `Medium` and `Edges` turned into the arrays the time step uses.

The spatial operator of every boundary model is written in one flux form, per axis,

    D(P)_i = K_i [ a_hi,i  b_{i+1/2} (q_{i+1} - q_i)  -  a_lo,i  b_{i-1/2} (q_i - q_{i-1}) ]

- homogeneous:   K = c^2,      q = P,      b = a = 1            (the 5-point leapfrog)
- speed_zero:    K = 1,        q = c^2 P,  b = a = 1            (eq. 10, c = 0 in obstacles)
- paper:         K = 1,        q = c^2 P,  a = 1 - R (eqs. 17-19, R seen from the cell)
- conservative:  K = rho c^2,  q = P,      b = face-averaged 1/rho = 2/(rho_i + rho_j)

so ``P(t+1) = 2 P(t) - P(t-1) + D(P(t))``. Arrays that a scene does not need are ``None`` and
the compiled step contains no work for them.

On an axisymmetric grid (`Grid.kind` = "rz", axis 0 = z, axis 1 = r) the same flux form is the
exact finite-volume operator on ring cells once each cell's K is divided by its ring volume and
each face conductance multiplied by its face area (per radian, lattice units): V_j = j + 1/2,
axial faces (j + 1/2), radial faces A_f = f at r = f. The axial areas cancel against V, so only
the radial faces carry a metric: `AxisymMetric` holds the per-ring factors A_(j+1)/V_j and
A_j/V_j, broadcast as (1, ny) rows (no full-size arrays). The axis face has A_0 = 0: it is closed
and ring 0 needs no 1/r. The operator is V^(-1) times a symmetric one, so the energy
sum V (dP/dt)^2 / K + ... is conserved (tests/core/test_axisym_stability.py).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .grid import Grid, GridKind, StencilKind, check_courant, stability_limit
from .kinds import MAX_COURANT_WIDE_FACES, WIDE_AXIS_WEIGHT, LatticeKind, as_kind
from .medium import Medium
from .pml import PML, Box, RadialPML, layer_boxes, pml_factors  # noqa: F401 (re-exported)
from .relaxation import AirRelaxation, _check_absorbing_speed, absorbing_courant, air_relaxation  # noqa: F401 (re-exported)

EdgeKind = Literal["pml", "mur", "sponge", "rigid", "soft", "axis"]
EDGE_KINDS = ("pml", "mur", "sponge", "rigid", "soft", "axis")
ABSORBING = ("pml", "mur", "sponge")


class Edges(eqx.Module):
    """Window edges, per side: "pml" (perfectly matched layer), "mur" (first-order absorbing),
    "sponge" (graded damping), "rigid" (reflecting, R = +1) or "soft" (reflecting, R = -1); on an
    axisymmetric ("rz") grid the y_lo side is "axis" (r = 0; see `Edges.axisymmetric`).

    `z_lo`, `z_hi` are the sides of a 3-D grid (None: "pml", the default of every side; a 2-D or
    rz grid ignores them). Mur edges and the axis are not available on a 3-D grid.

    PML and sponge layers lie inside the grid, `thickness_cells` deep. PML cannot be mixed with
    Mur or sponge on other sides. `pml_order` and `pml_r0` shape the PML damping profile
    sigma(d) = sigma_max (d/L)^order with sigma_max = (order + 1) c ln(1/r0) / (2 L).
    """

    x_lo: EdgeKind = eqx.field(static=True, default="pml")
    x_hi: EdgeKind = eqx.field(static=True, default="pml")
    y_lo: EdgeKind = eqx.field(static=True, default="pml")
    y_hi: EdgeKind = eqx.field(static=True, default="pml")
    thickness_cells: int = eqx.field(static=True, default=20)
    pml_order: float = eqx.field(static=True, default=4.0)
    pml_r0: float = eqx.field(static=True, default=1e-8)
    sponge_strength: float = eqx.field(static=True, default=0.2)
    z_lo: EdgeKind | None = eqx.field(static=True, default=None)
    z_hi: EdgeKind | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        for side in self.sides + self.sides_z:
            kind = getattr(self, side)
            if kind is None and side in self.sides_z:
                continue
            if kind not in EDGE_KINDS:
                raise ValueError(f"edge {side} = {kind!r}; allowed: {', '.join(EDGE_KINDS)}")
            if kind == "axis" and side != "y_lo":
                raise ValueError(
                    f"edge {side} = 'axis': the axis r = 0 of an rz grid is its y_lo side (axis 1 is r); "
                    "use Edges.axisymmetric(z_lo=..., z_hi=..., r_hi=...)"
                )
        absorbing = self.kinds() & set(ABSORBING)
        if len(absorbing) > 1:
            raise ValueError(
                f"edges mix absorbing kinds {sorted(absorbing)}: use one of pml, mur, sponge "
                "(rigid or soft sides may be combined with any)"
            )
        if self.thickness_cells < 1 and absorbing & {"pml", "sponge"}:
            raise ValueError(f"thickness_cells = {self.thickness_cells} must be >= 1")

    sides = ("x_lo", "x_hi", "y_lo", "y_hi")
    sides_z = ("z_lo", "z_hi")

    @classmethod
    def all(cls, kind: EdgeKind, **kwargs) -> Edges:
        """The same `kind` on every side (the z sides too, used by a 3-D grid only)."""
        return cls(x_lo=kind, x_hi=kind, y_lo=kind, y_hi=kind, z_lo=kind, z_hi=kind, **kwargs)

    def sides_for(self, ndim: int) -> tuple[str, ...]:
        """The sides of a grid of rank `ndim` (x_lo, x_hi[, y_lo, y_hi[, z_lo, z_hi]])."""
        return (self.sides + self.sides_z)[: 2 * ndim]

    def for_rank(self, ndim: int) -> Edges:
        """These edges for a grid of rank `ndim`: a plane or rz grid drops the z sides, a 3-D grid
        fills unset ones with "pml" (and refuses Mur edges, which exist in 2-D only); a rank-1 grid
        refuses PML and Mur edges."""
        if ndim < 2 and self.kinds() & {"pml", "mur"}:
            raise ValueError(
                "PML and Mur edges are written for rank-2 and rank-3 grids (the split-field state has x and y "
                "parts): use sponge, rigid or soft edges on a rank-1 grid (e.g. Edges.all('sponge'))"
            )
        if ndim < 3:
            if self.z_lo is None and self.z_hi is None:
                return self
            return dataclasses.replace(self, z_lo=None, z_hi=None)
        out = self
        if self.z_lo is None or self.z_hi is None:
            out = dataclasses.replace(self, z_lo=self.z_lo or "pml", z_hi=self.z_hi or "pml")
        if "mur" in out.kinds():
            raise ValueError("Mur edges are implemented for 2-D grids only: use 'pml' (or 'sponge') on a 3-D grid")
        return out

    @classmethod
    def axisymmetric(cls, z_lo: EdgeKind = "pml", z_hi: EdgeKind = "pml", r_hi: EdgeKind = "pml", **kwargs) -> Edges:
        """Edges of an rz grid: z_lo / z_hi (axis 0) and the outer radius r_hi; y_lo is the axis.
        A rigid baffle is `z_lo="rigid"` (the closed face z = 0)."""
        return cls(x_lo=z_lo, x_hi=z_hi, y_lo="axis", y_hi=r_hi, **kwargs)

    @classmethod
    def default_for(cls, kind: LatticeKind | str) -> Edges:
        """The default window of a grid of `kind`: a 20-cell PML on every side (rz: on z_lo,
        z_hi and r_hi; its y_lo is the axis)."""
        return cls.axisymmetric() if as_kind(kind).has_axis_edge else cls()

    def check_kind(self, kind: LatticeKind | str) -> None:
        """Refuse edges that do not fit a grid of `kind` ("2d", "rz" or "3d")."""
        kind = as_kind(kind)
        if kind.has_axis_edge and self.y_lo != "axis":
            raise ValueError(
                f"on an rz grid the y_lo side is the axis r = 0, got y_lo = {self.y_lo!r} (an absorbing "
                "or reflecting layer cannot lie on the axis): use Edges.axisymmetric(z_lo=..., z_hi=..., "
                "r_hi=...) or Edges(..., y_lo='axis')"
            )
        if not kind.has_axis_edge and "axis" in self.kinds():
            raise ValueError(f"edge 'axis' is only for rz grids (Grid.kind = 'rz'); a {kind} grid has none")

    def kinds(self) -> set[str]:
        return {getattr(self, s) for s in self.sides + self.sides_z if getattr(self, s) is not None}

    @property
    def uses_pml(self) -> bool:
        return "pml" in self.kinds()

    def ghost(self, side: str) -> Literal["neumann", "dirichlet"]:
        """Value beyond the window: rigid -> mirror (zero flux); everything else -> zero."""
        return "neumann" if getattr(self, side) == "rigid" else "dirichlet"

    def layer_depth(self, n: int, lo: str, hi: str, *, faces: bool) -> np.ndarray:
        """Depth (in cells) into an absorbing layer along one axis, 0 outside it."""
        L = self.thickness_cells
        x = np.arange(n + 1) - 0.5 if faces else np.arange(n, dtype=float)
        d = np.zeros_like(x, dtype=float)
        if getattr(self, lo) in ("pml", "sponge"):
            d = np.maximum(d, (L - 0.5) - x)
        if getattr(self, hi) in ("pml", "sponge"):
            d = np.maximum(d, x - (n - 1 - (L - 0.5)))
        return np.clip(d, 0.0, L)


class AxisymMetric(eqx.Module):
    """Ring-cell metric of an rz lattice (lattice units, per radian; broadcast along z).

    - `volume`: ring volumes V_j = j + 1/2 (= r_j, cell centre radius).
    - `area`: radial face areas A_f = f at r = f, f = 0 .. ny (A_0 = 0: the axis is closed).
    - `hi`, `lo`: A_(j+1) / V_j and A_j / V_j, the factors of ring j's outer and inner radial
      faces in the operator.
    """

    volume: Float[Array, "1 ny"]
    area: Float[Array, "1 ny1"]
    hi: Float[Array, "1 ny"]
    lo: Float[Array, "1 ny"]

    @classmethod
    def build(cls, ny: int, dtype) -> AxisymMetric:
        j = np.arange(ny, dtype=float)
        f = np.arange(ny + 1, dtype=float)
        v = j + 0.5
        row = lambda a: jnp.asarray(a.reshape(1, -1), dtype)
        return cls(volume=row(v), area=row(f), hi=row(f[1:] / v), lo=row(f[:-1] / v))


class Lattice(eqx.Module):
    """Everything the step needs, in lattice units. `None` = term absent (not compiled).
    `metric` is the ring-cell metric of an rz grid (None on a 2-D grid)."""

    K: Float[Array, "nx ny"] | float
    q_scale: Float[Array, "nx ny"] | None
    bx: Float[Array, "nx1 ny"] | None
    by: Float[Array, "nx ny1"] | None
    ax_lo: Float[Array, "nx ny"] | None
    ax_hi: Float[Array, "nx ny"] | None
    ay_lo: Float[Array, "nx ny"] | None
    ay_hi: Float[Array, "nx ny"] | None
    keep: Float[Array, "nx ny"] | None
    c: Float[Array, "nx ny"] | float  # lattice speed (cells/step): Mur edges, run-time checks
    sponge: Float[Array, "nx ny"] | None
    pml: PML | None
    metric: AxisymMetric | None
    eta: float = eqx.field(static=True)
    ghosts: tuple[str, ...] = eqx.field(static=True)
    mur: tuple[bool, ...] = eqx.field(static=True)
    bz: Float[Array, "nx ny nz1"] | None = None  # 3-D grids only
    stencil: StencilKind = eqx.field(static=True, default="standard")  # `Grid.stencil`: "standard" | "isotropic"
    uniform_faces: bool = eqx.field(static=True, default=True)  # the stencil's limit holds (`speed_limit`, `spectrum`)
    relax: AirRelaxation | None = None  # air's absorption (None: lossless, no fields, no work)
    wide_rows: tuple[Float[Array, "nx ny nz"], ...] | None = (
        None  # the 3-D wide stencil's axis rows next to obstacles (`operators.wide_rows`)
    )

    def conductance(self, axis: int):
        """The face conductances along `axis` (None: unit conductance)."""
        return (self.bx, self.by, self.bz)[axis]


def _along(v, axis: int, sl: slice):
    """v sliced by `sl` along `axis` (all of every other axis)."""
    return v[(slice(None),) * axis + (sl,)]


def _faces(v, axis: int, fn):
    """Interior face values fn(v_lo, v_hi) along `axis`, shape n-1 along that axis."""
    return fn(_along(v, axis, slice(None, -1)), _along(v, axis, slice(1, None)))


def _with_outer(interior, edge_lo, edge_hi, axis: int):
    return jnp.concatenate([edge_lo, interior, edge_hi], axis=axis)


def _edge(v, axis: int, hi: bool):
    return _along(v, axis, slice(-1, None) if hi else slice(None, 1))


def _device(x, dtype):
    """`x` as a device array of `dtype`; a concrete value is converted on the host (in a fresh
    process each eager conversion would be an XLA program of its own to trace, lower and load)."""
    if isinstance(x, jax.core.Tracer):
        return jnp.asarray(x, dtype)
    return jax.device_put(np.asarray(x, dtype=np.dtype(dtype)))  # jnp.asarray of NumPy: a program


def _checked_inputs(grid: Grid, medium: Medium, edges: Edges):
    """(edges for the grid's rank, lattice speed c, density rho), after refusing what does not fit
    the grid (a boundary model, shapes, the stability limit, the isotropic stencil's needs)."""
    edges = edges.for_rank(grid.ndim)
    edges.check_kind(grid.kind)
    if medium.boundary_model not in grid.kind.boundary_models:
        raise ValueError(
            f"boundary_model = {medium.boundary_model!r} is not available on an {grid.kind} grid: only the "
            "'conservative' (finite-volume) model has a ring-volume and a 3-D form; use "
            "Medium(..., boundary_model='conservative') (rigid and soft obstacles as cut cells)"
        )
    dtype = grid.jnp_dtype
    shape = tuple(grid.shape)
    c = _device(grid.speed_to_lattice(medium.sound_speed_m_s), dtype)
    rho = _device(medium.density_kg_m3, dtype)
    for name, arr in (("sound_speed_m_s", c), ("density_kg_m3", rho), ("rigid", medium.rigid), ("soft", medium.soft)):
        if arr is not None and jnp.ndim(arr) != 0 and tuple(jnp.shape(arr)) != shape:
            raise ValueError(f"medium.{name} has shape {jnp.shape(arr)}, expected the grid shape {shape}")
    _check_speed(c, grid.kind, grid.stencil)
    if grid.stencil in ("isotropic", "wide") and medium.boundary_model == "paper":
        raise ValueError(
            f"stencil = {grid.stencil!r} needs a symmetric flux form: boundary_model = 'paper' (eq. 10's per-cell "
            "factors) has none; use Medium(..., boundary_model='conservative') or stencil='standard'"
        )
    return edges, c, rho


def _materials(medium: Medium, c, rho, shape: tuple[int, ...], dtype) -> dict:
    """The boundary model's flux-form coefficients (K, q_scale, bx, by, bz, keep and the paper
    model's per-cell factors ax_lo .. ay_hi; None where absent) of the medium's maps."""
    ndim = len(shape)
    model = medium.boundary_model
    rigid = None if medium.rigid is None else jnp.clip(jnp.asarray(medium.rigid, dtype), 0, 1)
    if rigid is not None and model == "conservative":
        # A cut cell with almost no fluid left (phi < 1e-3) is closed: with K / phi its pressure
        # follows its neighbours at negligible energy, but clusters of such cells inside a wall
        # ring on their own (|p| ~ 0.3 of the source after 1500 steps in a rigid horn).
        rigid = jnp.where(rigid > 1 - 1e-3, 1.0, rigid).astype(dtype)
    soft = None if medium.soft is None else jnp.clip(jnp.asarray(medium.soft, dtype), 0, 1)
    homogeneous = jnp.ndim(c) == 0 and jnp.ndim(rho) == 0 and rigid is None and soft is None

    K = c**2 if isinstance(c, jax.core.Tracer) else _device(np.asarray(c) ** 2, dtype)
    q_scale = bx = by = bz = None
    a = {"ax_lo": None, "ax_hi": None, "ay_lo": None, "ay_hi": None}
    keep = None

    if homogeneous:
        pass
    elif model == "conservative":
        cf = jnp.broadcast_to(c, shape)
        rf = jnp.broadcast_to(rho, shape)
        K = rf * cf**2
        faces = []
        for axis in range(ndim):
            b = _faces(rf, axis, lambda l, h: 2.0 / (l + h))
            b = _with_outer(b, 1.0 / _edge(rf, axis, False), 1.0 / _edge(rf, axis, True), axis)
            if rigid is not None:
                openf = _faces(1 - rigid, axis, jnp.minimum)
                b = b * _with_outer(openf, 1 - _edge(rigid, axis, False), 1 - _edge(rigid, axis, True), axis)
            if soft is not None:
                # Dirichlet at the face of a soft cell: the half-cell gap doubles the conductance.
                # Only next to a fully soft cell: a partly soft cell (smooth rasterisation) keeps
                # unit conductance, its `keep` < 1 does the rest. (Doubling partly soft faces,
                # 1 + s_l + s_h, made k (2 + d) < -(1 + k) possible: unstable at the Courant limit.)
                dbl = _faces(soft, axis, lambda l, h: 1 + (l >= 1).astype(l.dtype) + (h >= 1).astype(h.dtype))
                b = b * _with_outer(
                    dbl, jnp.ones_like(_edge(soft, axis, False)), jnp.ones_like(_edge(soft, axis, True)), axis
                )
            faces.append(b)
        bx, by = faces[:2]
        bz = faces[2] if ndim == 3 else None
        if rigid is not None:
            # Cut cells: a partly rigid cell (smooth rasterisation) holds the fluid fraction
            # phi = 1 - rigid, so its pressure responds to the net flux as K / phi; a face is open
            # by min(phi_l, phi_h) <= phi, so the local speed never exceeds the fluid's (stable at
            # the Courant limit) and the cell no longer rings as a weakly coupled resonator (K
            # unchanged with product apertures held energy for thousands of steps; measured in
            # tests/core/test_stability_energy.py). Hard (0/1) occupancy is unchanged.
            K = K / jnp.maximum(1 - rigid, 1e-12)
        if soft is not None:
            keep = 1 - soft
    else:  # "paper" and "speed_zero": eq. 10, q = c^2 P
        cf = jnp.broadcast_to(c, shape)
        K = jnp.asarray(1.0, dtype)
        obstacle = None
        if rigid is not None or soft is not None:
            obstacle = jnp.clip((0 if rigid is None else rigid) + (0 if soft is None else soft), 0, 1)
            keep = 1 - obstacle
        if model == "speed_zero":
            q_scale = cf**2 if obstacle is None else cf**2 * (1 - obstacle)
        else:
            q_scale = cf**2
            z = jnp.broadcast_to(rho, shape) * cf
            zero = jnp.zeros(shape, dtype)
            pr = zero if rigid is None else rigid
            ps = zero if soft is None else soft
            for axis, lo_key, hi_key in ((0, "ax_lo", "ax_hi"), (1, "ay_lo", "ay_hi")):
                # R seen from the low cell looking into the high cell, fluids only (eq. 14)
                r_lh = _faces(
                    z, axis, lambda l, h: jnp.where(l + h > 0, (h - l) / jnp.where(l + h > 0, l + h, 1.0), 0.0)
                )
                r_seen_lo = _faces_pair(r_lh, pr, ps, axis, from_low=True)
                r_seen_hi = _faces_pair(-r_lh, pr, ps, axis, from_low=False)
                ones = jnp.ones_like(_edge(z, axis, False))
                # alpha at the cell's high face (cell is the low side of that face) and low face
                a[hi_key] = _with_outer_cells(1 - r_seen_lo, ones, axis, high=True)
                a[lo_key] = _with_outer_cells(1 - r_seen_hi, ones, axis, high=False)
    return dict(K=K, q_scale=q_scale, bx=bx, by=by, bz=bz, keep=keep, **a)


def _viscous(grid: Grid, medium: Medium) -> float:
    """The viscous coefficient eta of `absorption_db_per_m` (0: none), refused when too strong."""
    eta = 0.0
    if medium.absorption_db_per_m > 0:
        alpha_cell = medium.absorption_db_per_m / (20 / math.log(10)) * grid.dx_m
        c_ref = float(grid.courant)
        eta = 2 * alpha_cell * c_ref / grid.omega**2
        if eta > 0.05:
            # eta grows in proportion to the resolution (alpha dx / omega^2 with omega ~ 1 / cells
            # per wavelength): a finer grid makes it worse, a coarser one better
            most = grid.cells_per_wavelength * 0.05 / eta
            raise ValueError(
                f"absorption_db_per_m = {medium.absorption_db_per_m} is too strong for this grid "
                f"(viscous coefficient {eta:.3g} > 0.05 per step, in proportion to the resolution): use at most "
                f"{most:.3g} cells per wavelength (now {grid.cells_per_wavelength:g}) or a smaller absorption"
            )
    return eta


def build_lattice(grid: Grid, medium: Medium, edges: Edges) -> Lattice:
    """Turn SI maps into lattice coefficients (differentiable in the medium's arrays).

    On an rz grid the material coefficients are those of the 2-D conservative model in the
    meridian plane and `metric` adds the ring volumes and radial face areas; obstacles are bodies
    of revolution (their occupancy is the ring's volume fraction).

    On a 3-D grid the conservative form is built in all three axes (a z face conductance `bz`),
    with PML, sponge, rigid and soft edges; the paper's eq. 10 models are 2-D only."""
    edges, c, rho = _checked_inputs(grid, medium, edges)
    dtype = grid.jnp_dtype
    shape = tuple(grid.shape)
    ndim = len(shape)
    ny = shape[1] if ndim > 1 else 1
    coef = _materials(medium, c, rho, shape, dtype)
    K, q_scale, keep = coef.pop("K"), coef.pop("q_scale"), coef.pop("keep")
    bx, by, bz = coef.pop("bx"), coef.pop("by"), coef.pop("bz")
    a = coef
    eta = _viscous(grid, medium)

    relax = None
    if medium.air is not None:
        relax = air_relaxation(grid, medium.air, dtype)
        _check_absorbing_speed(c, relax, grid)

    sides = edges.sides_for(ndim)
    ghosts = tuple(edges.ghost(s) for s in sides)
    # A rigid (Neumann) window side is a closed outer face: fold it into the face conductances
    # (or the paper model's per-cell factors) so the step pads with zeros only (one fused loop).
    closed = tuple(g == "neumann" for g in ghosts)
    if bx is not None:
        closed_faces = _close_faces((bx, by, bz)[:ndim], closed)
        bx, by = closed_faces[:2]
        bz = closed_faces[2] if ndim == 3 else None
    elif a["ax_lo"] is not None:
        a = _close_cells(a, closed)
    # the isotropic stencil's sqrt(3)/2 holds for uniform face conductances (one density, no obstacles), in a
    # volume with rigid obstacles if the operator's measured spectrum allows (`spectrum.check_spectrum`, at
    # `Stepper.build`); otherwise its bound is the standard stencil's (`speed_limit`)
    uniform_faces = medium.rigid is None and medium.soft is None and _uniform(medium.density_kg_m3)
    # (the spectrum of a lattice whose maps are traced, e.g. under jax.grad, cannot be measured)
    concrete = not any(isinstance(v, jax.core.Tracer) for v in (c, medium.rigid, medium.soft, medium.density_kg_m3))
    measure = ndim == 3 and medium.soft is None and _uniform(medium.density_kg_m3) and concrete
    if grid.stencil == "wide":  # its operator's spectrum is measured whenever the faces are not uniform
        measure = concrete
        if not uniform_faces and not measure:
            _check_wide_faces(c)
    if grid.stencil == "isotropic" and not uniform_faces and not measure:
        _check_speed(c, grid.kind, "standard", why=ISOTROPIC_WITH_FACES)
    mur = tuple(getattr(edges, s) == "mur" for s in sides)
    sponge = _sponge(grid, edges, dtype) if "sponge" in edges.kinds() else None
    pml = pml_factors(grid, edges, dtype) if edges.uses_pml else None
    metric = AxisymMetric.build(ny, dtype) if grid.kind.ring_metric else None
    lat = Lattice(
        K=K,
        q_scale=q_scale,
        bx=bx,
        by=by,
        keep=keep,
        c=c,
        sponge=sponge,
        pml=pml,
        metric=metric,
        eta=eta,
        ghosts=ghosts,
        mur=mur,
        bz=bz,
        stencil=grid.stencil,
        uniform_faces=bool(uniform_faces or measure),
        relax=relax,
        **a,
    )
    if grid.stencil == "wide" and bx is not None:  # its axis rows next to obstacles, formed once
        rows = wide_axis_rows((bx, by, bz), K / c**2, shape, dtype)
        lat = eqx.tree_at(lambda lt: lt.wide_rows, lat, rows, is_leaf=lambda v: v is None)
    return lat


def _shift(v, axis: int, up: bool):
    """v at i + 1 (`up`) or i - 1 along `axis`, zero beyond the ends."""
    n = v.shape[axis]
    zero = jnp.zeros(tuple(1 if a == axis else m for a, m in enumerate(v.shape)), v.dtype)
    if up:
        return jnp.concatenate([jax.lax.slice_in_dim(v, 1, n, axis=axis), zero], axis=axis)
    return jnp.concatenate([zero, jax.lax.slice_in_dim(v, 0, n - 1, axis=axis)], axis=axis)


def wide_axis_rows(faces, w, shape, dtype) -> tuple:
    """``-(e/4) D_a W D_a`` of the 3-D wide stencil (`operators._wide_3d`) as 5-point rows along
    each axis a, from the face conductances `faces` (bx, by, bz; rigid window sides closed) and
    the per-cell weight `w` = K / c^2: with b+ and b- a cell's high and low face conductances,
    ``c2_i = b+_i W_(i+1) b+_(i+1)`` to q_(i+2), ``c1_i = -b+_i [W_(i+1) (b+_(i+1) + b+_i) + W_i
    (b+_i + b-_i)]`` to q_(i+1), the row symmetric (c1_(i-1) to q_(i-1), c2_(i-2) to q_(i-2)),
    and ``W_(i+1) b+_i^2 + W_i (b+_i + b-_i)^2 + W_(i-1) b-_i^2`` to q_i, all times -e/4: the two
    wall-aware second differences composed, to rounding (`tests/core/test_wide_3d.py`). Returns
    (c2_x, c2_y, c2_z, c1_x, c1_y, c1_z, c0 summed over the axes), c2 and c1 padded at the low
    end of their axis by two and one zero layers so that the step reads the row below by slicing;
    `build_lattice` stores them (7 grid arrays, `Lattice.wide_rows`) so the step only reads them:
    composing the differences in the step ran XLA's CPU loop at an eighth of the isotropic links'
    speed next to a post, forming these rows in the step at a fifth, reading them shifted by
    concatenation at 1/2.5-1/4, sliced from the padded rows at about 1/2 (80^3, interleaved)."""
    s = -WIDE_AXIS_WEIGHT / 4.0
    w = jnp.broadcast_to(jnp.asarray(w, dtype), shape)
    c2s, c1s, c0 = [], [], None
    for axis in range(3):
        fshape = tuple(m + 1 if a == axis else m for a, m in enumerate(shape))
        b = jnp.broadcast_to(faces[axis], fshape).astype(dtype)
        bp, bm = _along(b, axis, slice(1, None)), _along(b, axis, slice(None, -1))  # b+_i, b-_i
        wp, wm = _shift(w, axis, True), _shift(w, axis, False)  # zero beyond the window, where b = 0 or q = 0
        bpp = _shift(bp, axis, True)  # b+_(i+1)
        low = [(0, 0)] * 3
        low[axis] = (2, 0)
        c2s.append(jnp.pad(s * bp * wp * bpp, low))  # padded low: the step slices the row below
        low[axis] = (1, 0)
        c1s.append(jnp.pad(-s * bp * (wp * (bpp + bp) + w * (bp + bm)), low))
        term = s * (wp * bp * bp + w * (bp + bm) ** 2 + wm * bm * bm)
        c0 = term if c0 is None else c0 + term
    return (*c2s, *c1s, c0)


def _close_faces(faces, closed):
    """Zero the outermost faces of the closed window sides (`faces`: one array per axis)."""
    out = []
    for axis, b in enumerate(faces):
        idx = (slice(None),) * axis
        if closed[2 * axis]:
            b = b.at[idx + (0,)].set(0.0)
        if closed[2 * axis + 1]:
            b = b.at[idx + (-1,)].set(0.0)
        out.append(b)
    return tuple(out)


def _close_cells(a, closed):
    x_lo, x_hi, y_lo, y_hi = closed
    a = dict(a)
    if x_lo:
        a["ax_lo"] = a["ax_lo"].at[0].set(0.0)
    if x_hi:
        a["ax_hi"] = a["ax_hi"].at[-1].set(0.0)
    if y_lo:
        a["ay_lo"] = a["ay_lo"].at[:, 0].set(0.0)
    if y_hi:
        a["ay_hi"] = a["ay_hi"].at[:, -1].set(0.0)
    return a


def _faces_pair(r_lh, pr, ps, axis, *, from_low: bool):
    """Blend the fluid R with ideal obstacles occupying the cell across the face."""
    other = (lambda v: v[1:] if axis == 0 else v[:, 1:]) if from_low else (lambda v: v[:-1] if axis == 0 else v[:, :-1])
    r_o, s_o = other(pr), other(ps)
    # a soft neighbour reflects with R = -1 (a = 1 - R = 2) only when fully soft: a partly soft
    # cell (smooth rasterisation) doubling its faces made the step unstable at the Courant limit
    s_full = (s_o >= 1).astype(s_o.dtype)
    return (1 - r_o - s_o) * r_lh + r_o - s_full


def _with_outer_cells(interior_faces, ones, axis, *, high: bool):
    """Per-cell array of a face quantity: the cell's high face (or low face); outer faces = 1."""
    parts = [interior_faces, ones] if high else [ones, interior_faces]
    return jnp.concatenate(parts, axis=axis)


ISOTROPIC_WITH_FACES = (
    "with obstacles or a density contrast the isotropic stencil is guaranteed "
    "stable only up to the standard limit (its flux filter M <= diag(b) bounds it by the standard "
    "operator; next to cut cells the filter's 2/3 reduction of the checkerboard is lost: c^2 rho = 4.23 "
    "measured at sqrt(3)/2), so lower `courant` to <= 1/sqrt(2) for this scene, or use stencil='standard'"
)


def _check_wide_faces(c) -> None:
    """Refuse a wide-stencil lattice with traced obstacles above `kinds.MAX_COURANT_WIDE_FACES`."""
    try:
        cmax = float(jnp.max(c))
    except Exception:  # traced: checked at run time (`speed_limit`)
        return
    if cmax > MAX_COURANT_WIDE_FACES * (1 + 1e-9):
        raise ValueError(
            f"the fastest medium's speed {cmax:.6f} cells/step exceeds {MAX_COURANT_WIDE_FACES:.6f} = "
            "1/sqrt(3 (1 + e)), the 3-D wide stencil's bound for obstacles or a density contrast whose spectrum "
            "cannot be measured (traced maps, e.g. under jax.grad): lower `courant` to <= 0.516 for this run, "
            "or use stencil='isotropic' or 'standard'"
        )


def _uniform(v) -> bool:
    """A scalar, or a concrete array of one value (a traced one counts as varying)."""
    if jnp.ndim(v) == 0:
        return True
    try:
        return float(jnp.max(v) - jnp.min(v)) == 0.0
    except Exception:  # traced
        return False


def speed_limit(lat: Lattice, kind: LatticeKind | GridKind) -> float:
    """The largest stable lattice speed for these coefficients: `stability_limit(kind, stencil)`,
    except that the isotropic stencil with obstacles or a density contrast keeps the standard limit,
    and the wide one with traced (unmeasured) obstacles `kinds.MAX_COURANT_WIDE_FACES`."""
    if lat.stencil == "wide" and not lat.uniform_faces:
        return MAX_COURANT_WIDE_FACES
    return stability_limit(kind, lat.stencil if lat.uniform_faces else "standard")


def _check_speed(c, kind: LatticeKind | GridKind = "2d", stencil: StencilKind = "standard", why: str = "") -> None:
    try:
        cmax = float(np.max(np.asarray(c)))  # on the host: no eager XLA program for a number
    except Exception:  # traced: checked at run time by the solver
        return
    try:
        check_courant(cmax, what="the fastest medium's speed", kind=kind, stencil=stencil)
    except ValueError as e:
        raise ValueError(f"{e} ({why})" if why else str(e)) from None


def _axis_shape(axis: int, ndim: int) -> tuple[int, ...]:
    """Broadcast shape of a 1-D profile along `axis` of a rank-`ndim` field."""
    return tuple(-1 if a == axis else 1 for a in range(ndim))


def _sponge(grid: Grid, edges: Edges, dtype):
    L = edges.thickness_cells
    ndim = len(grid.shape)
    sigma = np.zeros((1,) * ndim)  # broadcasts up to the grid's shape
    for axis, n in enumerate(grid.shape):
        key = "xyz"[axis]
        d = edges.layer_depth(n, f"{key}_lo", f"{key}_hi", faces=False)
        sigma = sigma + (d.reshape(_axis_shape(axis, ndim)) / L) ** 2
    return jnp.asarray(edges.sponge_strength * sigma, dtype)
