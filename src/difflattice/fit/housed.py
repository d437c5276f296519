"""Housed transducers on the axisymmetric lattice: the diaphragm in its can, recessed behind the
front face, behind a front plate with an opening, fitted by gradient through the geometry.

A housed transducer is modelled as it is built (all lengths in metres, the can's axis on the
lattice axis, its front facing +z):

- the can: a rigid body of revolution of outer radius `R` (`Housing.outer_diameter_m / 2`) and
  length `L` (`Housing.length_m`, from its back to its front face), closed behind the diaphragm
  (`back = "closed"`: solid from the diaphragm to the back) or open (`back = "open"`: a tube, the
  diaphragm a rigid plate one cell thick across the bore whose rear face radiates in antiphase,
  a velocity source of the opposite sign into the cell behind it);
- the bore: the air-filled cylinder of radius `R_in = R - wall` in front of the diaphragm, `d`
  deep (the recess: the diaphragm lies `d` behind the front face; `d = 0`: flush, the "can"
  baffle of `fit.disc`);
- the diaphragm: a disc of radius `a <= R_in` at the bottom of the bore, a velocity source of
  ring cells (`solver.sources.disc_transducer`), uniform or with a free per-ring velocity profile
  (log-weights and lags, the centre ring pinned);
- the front plate: a rigid annulus `plate` thick at the front face, from the opening radius `b`
  out to the bore (`b <= R_in`; absent when not fitted).

Geometry is differentiable: every body is rasterised as exact ring-volume fractions (the cut-cell
rigid model of `lattice.coefficients`), each a product of an axial interval's share of a row and
a radial interval's share of a ring's volume, both continuous and piecewise smooth in the
interval's ends; the diaphragm's radius enters by its ring area fractions. The diaphragm row is
fixed (static), so the recess moves the front face and the can's back, never the source: a
static grid serves every admissible geometry.

The lobe is the far-field pattern (`observe.farfield_rz.far_field_rz`, continuum wavenumber) of
the phasors on a closed Kirchhoff-Helmholtz cylinder round the whole can: a datasheet's
directivity is a far-field pattern, and its magnitude does not depend on the point the angles
are measured from. Levels are 20 log10 |F| plus a fitted gain (a table's 0 dB is arbitrary).

Raw (unconstrained) parameters, as in `fit.model`: `diam` (a = R_in sigmoid), `recess`
(d = d_min + (d_max - d_min) sigmoid, d_max = L - one cell: the can keeps a back), `opening`
(b = R_in sigmoid), `gain_db`, and for the free profile `w` and `lag` (rings 1..n-1: log-weight
and artanh(2 lag / T)). Bounds come from the can: nothing is larger than the can.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..lattice.window import Span
from ..transforms import logit
from .family import FamilyParams
from .housed_profiles import bend_from_raw, bend_to_raw, bending_weights, cone_lags_s, ring_centroid_s

FAMILIES = ("flat", "recessed", "opening", "cone", "bending", "profile")
"""The ladder of housed model families, simplest first: a flat piston flush with the can's front
("flat"), a piston recessed in the bore ("recessed"), recessed behind a front plate with an
opening ("opening"), a flush cone of depth h ("cone") or a flush plate in bending ("bending"), one
shape parameter each (`fit.housed_profiles`), a flush face with a free velocity profile
("profile", the free-profile disc of `fit.disc` in its can: the family that fits by freedom)."""

FAMILY_PARAMS = {
    "flat": ("diam", "gain_db"),
    "recessed": ("diam", "recess", "gain_db"),
    "opening": ("diam", "recess", "opening", "gain_db"),
    "cone": ("diam", "cone", "gain_db"),
    "bending": ("diam", "bend", "gain_db"),
    "profile": ("diam", "gain_db", "w", "lag"),
}


FIXABLE = {"diam": "diaphragm", "recess": "recess", "opening": "opening"}
"""Raw geometry parameters and the names under which `HousedSpec.fixed` holds them at the spec's
value (`diaphragm_m`, `recess_m`, `opening_m`), e.g. an opening read off the outline drawing."""


class HousedParams(FamilyParams):
    """Raw (unconstrained) parameters of a housed model (`HousedSpec`): the fields of its family
    (`FAMILY_PARAMS`) less those held `fixed`, the rest None. Fields in alphabetical
    (`ravel_pytree`) order. R_in is the bore's radius."""

    bend: Float[Array, ""] | None = None
    """Bending profile's q ("bending": velocity 1 - q (r/a)^2; `housed_profiles.bend_from_raw`)."""
    cone: Float[Array, ""] | None = None
    """Cone depth, artanh(h / L) ("cone": h in (-L, L), L the can's length; rim lag h (r/a) / c)."""
    diam: Float[Array, ""] | None = None
    """Diaphragm, logit(a / R_in) (radius a = R_in sigmoid(diam))."""
    gain_db: Float[Array, ""] | None = None
    """Level offset, dB: 20 log10 |F| of the far field to the table's levels."""
    lag: Float[Array, " n_rings_1"] | None = None
    """Free lag profile ("profile"), artanh(2 tau / T) of rings 1..n-1 (ring 0 pinned at 0)."""
    opening: Float[Array, ""] | None = None
    """Front plate's opening, logit(b / R_in) (radius b = R_in sigmoid(opening); "opening")."""
    phase0: Float[Array, ""] | None = None
    """Wavefront phase offset, rad (fitted with wavefront data only: the rig's phase reference is
    the drive's, not the model's; `fit.ladder.fit_housed`)."""
    recess: Float[Array, ""] | None = None
    """Recess, logit((d - d_min) / (d_max - d_min)) (depth d of the diaphragm behind the front
    face; d_max the can's length less one cell)."""
    w: Float[Array, " n_rings_1"] | None = None
    """Free log-weight profile ("profile"), log w of rings 1..n-1 (ring 0 pinned at 1)."""


@dataclass(frozen=True)
class Housing:
    """Outline dimensions of a can (a datasheet's outline drawing), metres: `outer_diameter_m`,
    `length_m` (back to front face), the wall `wall_m` (the bore is the outer diameter less two
    walls), the front plate's thickness `plate_m` (used by the "opening" family), the `back`:
    "closed" (solid behind the diaphragm) or "open" (a tube; the diaphragm's rear radiates), and
    the `front`: "free" (the can stands in free air) or "flange" (the front face continues as an
    infinite rigid baffle: the can set flush in a wall or panel, as many sonar units are mounted;
    the outer diameter then only bounds the bore, and the back must be closed)."""

    outer_diameter_m: float
    length_m: float
    wall_m: float = 0.5e-3
    plate_m: float = 1.0e-3
    back: Literal["closed", "open"] = "closed"
    front: Literal["free", "flange"] = "free"

    def __post_init__(self):
        for name in ("outer_diameter_m", "length_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"housing {name} = {v!r} must be a positive length in metres")
        if not 0 <= self.wall_m < 0.5 * self.outer_diameter_m:
            raise ValueError(
                f"housing wall_m = {self.wall_m} m must be >= 0 and less than the outer radius "
                f"{0.5 * self.outer_diameter_m} m"
            )
        if not 0 < self.plate_m < self.length_m:
            raise ValueError(f"housing plate_m = {self.plate_m} m must be in (0, length_m = {self.length_m}) m")
        if self.back not in ("closed", "open"):
            raise ValueError(f"housing back = {self.back!r}; allowed: 'closed', 'open' (the diaphragm's rear radiates)")
        if self.front not in ("free", "flange"):
            raise ValueError(
                f"housing front = {self.front!r}; allowed: 'free' (a can in free air), 'flange' (in a baffle)"
            )
        if self.front == "flange" and self.back == "open":
            raise ValueError(
                "housing front = 'flange' with back = 'open': a can set in an infinite baffle has no rear field "
                "in the model; use back = 'closed' (or front = 'free' for an open-backed can in free air)"
            )

    @property
    def outer_radius_m(self) -> float:
        return 0.5 * self.outer_diameter_m

    @property
    def bore_radius_m(self) -> float:
        return self.outer_radius_m - self.wall_m


# ------------------------------------------------------------------------------------------
# exact cut-cell fractions of axis-aligned bodies of revolution


def _select_clip01(x):
    """clip(x, 0, 1) differentiated through selects (see `lattice.geometry`: `jnp.clip` can drop
    its gradient under jit)."""
    return jnp.where(x < 0, 0.0, jnp.where(x > 1, 1.0, x))


def row_fractions(z_lo, z_hi, n_rows: int, dtype):
    """Share of each row [i, i + 1] (cells) inside the axial interval [z_lo, z_hi] (cells)."""
    i = jnp.arange(n_rows, dtype=dtype)
    lo = jnp.where(i >= z_lo, i, z_lo)
    hi = jnp.where(i + 1 <= z_hi, i + 1, z_hi)
    return _select_clip01(hi - lo)


def ring_volume_fractions(r_lo, r_hi, n_rings: int, dtype):
    """Share of each ring's volume (r in [j, j + 1] cells) inside radii [r_lo, r_hi] (cells):
    exact for a body of revolution, continuous in both radii."""
    j = jnp.arange(n_rings, dtype=dtype)

    def below(r):
        return _select_clip01((r * r - j * j) / (2 * j + 1))

    return _select_clip01(below(r_hi) - below(r_lo))


# ------------------------------------------------------------------------------------------
# the model


@dataclass(frozen=True)
class HousedLayout:
    """The static lattice layout of a housed model: grid shape (rows, rings), the diaphragm's row,
    the Kirchhoff-Helmholtz cylinder (rows `iz0`..`iz1`, rings 0..`jr`), run length."""

    shape: tuple[int, int]
    diaphragm_row: int
    iz0: int
    iz1: int
    jr: int
    n_steps: int
    dx_m: float


@dataclass(frozen=True)
class HousedSpec:
    """Static description of a housed model: the can (`housing`), drive `frequency_hz`, speed of
    sound `c_m_s`, lattice resolution `cells_per_wavelength`, the `family` (`FAMILIES`), initial
    (or fixed) geometry (`diaphragm_m`, `recess_m`, `opening_m`: diameters and depth in metres;
    defaults: 0.8 x the bore, 1 mm, 0.8 x the bore), `dtype`, the absorbing layer `pml_cells`,
    the surface's gap `surface_gap` (cells), the lattice `stencil` and the geometry held `fixed`
    at the given values (names in `FIXABLE`: "diaphragm", "recess", "opening"); the initial cone
    depth `cone_m` (m, signed) and bending `bend` (q) of those families (`fit.housed_profiles`)."""

    housing: Housing
    frequency_hz: float
    c_m_s: float = 343.2
    cells_per_wavelength: float = 10.0
    family: str = "recessed"
    diaphragm_m: float | None = None
    recess_m: float | None = None
    opening_m: float | None = None
    dtype: Literal["float32", "float64"] = "float64"
    pml_cells: int = 12
    surface_gap: int = 2
    cycles: float = 4.0
    stencil: Literal["standard", "isotropic"] = "standard"
    fixed: tuple[str, ...] = ()
    cone_m: float | None = None
    bend: float | None = None

    def __post_init__(self):
        if self.family not in FAMILIES:
            raise ValueError(f"housed family = {self.family!r}; allowed: {', '.join(FAMILIES)}")
        if not (self.frequency_hz > 0 and self.c_m_s > 0 and self.cells_per_wavelength >= 4):
            raise ValueError(
                f"frequency_hz = {self.frequency_hz}, c_m_s = {self.c_m_s} must be > 0 and "
                f"cells_per_wavelength = {self.cells_per_wavelength} >= 4"
            )
        h = self.housing
        if self.diaphragm_m is not None and not 0 < self.diaphragm_m <= 2 * h.bore_radius_m:
            raise ValueError(
                f"diaphragm_m = {self.diaphragm_m} m must be in (0, {2 * h.bore_radius_m:.6g}] m (the bore: "
                "the can's outer diameter less two walls); nothing is larger than the can"
            )
        if self.recess_m is not None and not 0 <= self.recess_m <= self.recess_max_m:
            raise ValueError(
                f"recess_m = {self.recess_m} m must be in [0, {self.recess_max_m:.6g}] m (the can's length less "
                "one cell of back)"
            )
        if self.opening_m is not None and not 0 < self.opening_m <= 2 * h.bore_radius_m:
            raise ValueError(f"opening_m = {self.opening_m} m must be in (0, {2 * h.bore_radius_m:.6g}] m (the bore)")
        if self.family == "opening" and h.plate_m < 2 * self.dx_m:
            need = 2 * self.c_m_s / (self.frequency_hz * h.plate_m)
            raise ValueError(
                f"the front plate ({h.plate_m * 1e3:.3g} mm) is {h.plate_m / self.dx_m:.2f} cells of "
                f"{self.dx_m * 1e3:.3g} mm; a cut-cell plate needs >= 2 cells to be sealed: raise "
                f"cells_per_wavelength to >= {need:.1f}, or model a thicker plate (housing plate_m)"
            )
        for name in self.fixed:
            if name not in FIXABLE.values():
                raise ValueError(
                    f"fixed = {self.fixed!r}: {name!r} is not a geometry parameter; allowed: diaphragm, recess, opening"
                )
            if getattr(self, f"{name}_m") is None:
                raise ValueError(f"fixed {name!r} needs its value: give {name}_m (e.g. from the outline drawing)")
        if self.cone_m is not None and not abs(self.cone_m) < h.length_m:
            raise ValueError(
                f"cone_m = {self.cone_m} m must be inside (-{h.length_m}, {h.length_m}) m (the can's length)"
            )
        if self.bend is not None:
            bend_to_raw(self.bend)  # refuses a q outside its bounds
        if self.n_rings < 2:
            raise ValueError(
                f"the bore ({2 * h.bore_radius_m * 1e3:.3g} mm) is {self.n_rings} rings of {self.dx_m * 1e3:.3g} mm: "
                "raise cells_per_wavelength"
            )

    # -- sizes ---------------------------------------------------------------------------
    @property
    def dx_m(self) -> float:
        return self.c_m_s / (self.frequency_hz * self.cells_per_wavelength)

    @property
    def n_rings(self) -> int:
        """Source rings: every ring the bore touches."""
        return int(math.ceil(self.housing.bore_radius_m / self.dx_m - 1e-9))

    @property
    def recess_max_m(self) -> float:
        return self.housing.length_m - self.dx_m

    @property
    def recess_min_m(self) -> float:
        """The opening family keeps its plate in front of the diaphragm (d >= plate)."""
        return self.housing.plate_m if self.family == "opening" else 0.0

    @property
    def period_s(self) -> float:
        return 1.0 / self.frequency_hz

    def layout(self) -> HousedLayout:
        """Rows: PML, margin, the cylinder's lower cap, the can at its deepest (d = 0: back at
        z_d - L), the diaphragm, the bore at its deepest (front at z_d + d_max), the upper cap,
        margin, PML."""
        dx, g, pml = self.dx_m, self.surface_gap, self.pml_cells
        below = int(math.ceil(self.housing.length_m / dx))
        above = int(math.ceil(self.recess_max_m / dx))
        # 4 cells of margin and the cylinder's 2 outer stencil cells between it and the PML
        span_z = Span.open(gap=g, layer=pml, pad=6, back=1 + below, fwd=above)
        span_r = Span.closed(gap=g, layer=pml, pad=6, fwd=int(math.ceil(self.housing.outer_radius_m / dx - 1e-9)))
        (nz, nr), zd = (span_z.n, span_r.n), span_z.source
        (iz0, iz1), jr = (span_z.contour_lo, span_z.contour_hi), span_r.contour_hi
        courant = 0.5  # lattice default of the rz kind is read from the grid below
        n_steps = int(math.hypot(nz, nr) / courant + 8 * self.cells_per_wavelength / courant)
        return HousedLayout((nz, nr), zd, iz0, iz1, jr, n_steps, dx)

    # -- parameters ------------------------------------------------------------------------
    def param_names(self) -> tuple[str, ...]:
        """The family's raw parameters, less those held `fixed` at the spec's values."""
        return tuple(k for k in FAMILY_PARAMS[self.family] if FIXABLE.get(k) not in self.fixed)

    def init_params(self) -> HousedParams:
        """Initial raw parameters of the family (defaults from the housing)."""
        h = self.housing
        rb = h.bore_radius_m
        out: dict = {}
        for key in self.param_names():
            if key == "diam":
                out[key] = jnp.asarray(logit(_inside(0.5 * (self.diaphragm_m or 1.6 * rb) / rb)))
            elif key == "recess":
                lo, hi = self.recess_min_m, self.recess_max_m
                d0 = self.recess_m if self.recess_m is not None else max(1e-3, lo + 0.2 * (hi - lo))
                out[key] = jnp.asarray(logit(_inside((d0 - lo) / (hi - lo))))
            elif key == "opening":
                out[key] = jnp.asarray(logit(_inside(0.5 * (self.opening_m or 1.6 * rb) / rb)))
            elif key == "gain_db":
                out[key] = jnp.asarray(0.0)
            elif key == "cone":  # not 0: the lobe is even in h, its slope vanishes there
                h0 = self.cone_m if self.cone_m is not None else 1e-3
                out[key] = jnp.asarray(math.atanh(h0 / h.length_m))
            elif key == "bend":
                out[key] = jnp.asarray(bend_to_raw(self.bend if self.bend is not None else 0.3))
            else:  # w, lag: the free profile, rings 1 .. n-1
                out[key] = jnp.zeros(self.n_rings - 1)
        return HousedParams(**out)

    def physical(self, params: HousedParams) -> dict:
        """Raw -> physical: `diaphragm_m`, `recess_m`, `opening_m` (None where the family has no
        plate), `cone_m`, `bend` (None outside their families), `gain_db`, per-ring `weights` and
        `lags_s` (the profile; 1 and 0 for a piston)."""
        h = self.housing
        rb = h.bore_radius_m
        s = jax.nn.sigmoid
        a = rb * s(params.diam) if params.diam is not None else jnp.asarray(0.5 * (self.diaphragm_m or 1.6 * rb))
        if params.recess is not None:
            lo, hi = self.recess_min_m, self.recess_max_m
            d = lo + (hi - lo) * s(params.recess)
        else:
            d = jnp.asarray(self.recess_m or 0.0)
        if params.opening is not None:
            b = rb * s(params.opening)
        elif self.family == "opening" and self.opening_m is not None:  # held fixed
            b = jnp.asarray(0.5 * self.opening_m)
        else:
            b = None
        n = self.n_rings
        w = jnp.ones(n)
        lag = jnp.zeros(n)
        if params.w is not None:
            w = jnp.exp(jnp.concatenate([jnp.zeros(1), params.w]))
        if params.lag is not None:
            lag = 0.5 * self.period_s * jnp.tanh(jnp.concatenate([jnp.zeros(1), params.lag]))
        cone = None if params.cone is None else h.length_m * jnp.tanh(params.cone)
        if params.cone is not None or params.bend is not None:
            s_ring = ring_centroid_s(a / self.dx_m, n, jnp.result_type(float))
            if cone is not None:
                lag = cone_lags_s(s_ring, cone, self.c_m_s)
            if params.bend is not None:
                w = bending_weights(s_ring, bend_from_raw(params.bend))
        return {
            "cone_m": cone,
            "bend": None if params.bend is None else bend_from_raw(params.bend),
            "diaphragm_m": 2 * a,
            "recess_m": d,
            "opening_m": None if b is None else 2 * b,
            "gain_db": jnp.asarray(0.0) if params.gain_db is None else params.gain_db,
            "weights": w,
            "lags_s": lag,
        }

    def truth_params(
        self,
        *,
        diaphragm_m: float,
        recess_m: float | None = None,
        opening_m: float | None = None,
        cone_m: float | None = None,
        bend: float | None = None,
    ) -> HousedParams:
        """Raw parameters of a given geometry (for synthetic data and warm starts); a recess,
        opening, cone depth or bending q not given keeps its initial value (`init_params`)."""
        rb = self.housing.bore_radius_m
        p = self.init_params()
        if p.diam is not None:
            p = dataclasses.replace(p, diam=jnp.asarray(logit(_inside(0.5 * diaphragm_m / rb))))
        if p.recess is not None and recess_m is not None:
            lo, hi = self.recess_min_m, self.recess_max_m
            p = dataclasses.replace(p, recess=jnp.asarray(logit(_inside((recess_m - lo) / (hi - lo)))))
        if p.opening is not None and opening_m is not None:
            p = dataclasses.replace(p, opening=jnp.asarray(logit(_inside(0.5 * opening_m / rb))))
        if p.cone is not None and cone_m is not None:
            p = dataclasses.replace(
                p, cone=jnp.asarray(math.atanh(_inside(0.5 + 0.5 * cone_m / self.housing.length_m) * 2 - 1))
            )
        if p.bend is not None and bend is not None:
            p = dataclasses.replace(p, bend=jnp.asarray(bend_to_raw(bend)))
        return p

    def bounds_mm(self) -> dict:
        """Physical bounds (mm) the parameterisation imposes (from the can)."""
        rb = self.housing.bore_radius_m
        return {
            "diaphragm_mm": (0.0, 2e3 * rb),
            "recess_mm": (1e3 * self.recess_min_m, 1e3 * self.recess_max_m),
            "opening_mm": (0.0, 2e3 * rb),
            "cone_mm": (-1e3 * self.housing.length_m, 1e3 * self.housing.length_m),
        }

    # -- the lattice -------------------------------------------------------------------------
    def rigid(self, phys: dict, lay: HousedLayout, dtype):
        """Rigid occupancy (rows, rings) of the can, its bore and plate, in exact cut-cell
        fractions (differentiable in the recess, the opening and, through nothing else, fixed
        in the outline)."""
        nz, nr = lay.shape
        h = self.housing
        dx = lay.dx_m
        R, Rb = h.outer_radius_m / dx, h.bore_radius_m / dx
        zd = float(lay.diaphragm_row)
        zf = zd + phys["recess_m"] / dx
        zb = zf - h.length_m / dx
        # a wall thinner than the lattice resolves would leak (two part-filled cut cells pass sound):
        # the bore's face is a cut cell at R_in, then at least one whole rigid ring (see `sealed_outer_cells`)
        Rw = max(R, sealed_outer_cells(Rb))
        if h.back == "closed":  # solid from the back to the diaphragm, the bore's wall in front
            body = row_fractions(zb, zd, nz, dtype)[:, None] * ring_volume_fractions(0.0, R, nr, dtype)[None, :]
            wall = row_fractions(zd, zf, nz, dtype)[:, None] * ring_volume_fractions(Rb, Rw, nr, dtype)[None, :]
        else:  # a tube, and the diaphragm's plate (one row, across the bore) at the diaphragm's row - 1
            body = row_fractions(zd - 1, zd, nz, dtype)[:, None] * ring_volume_fractions(0.0, Rb, nr, dtype)[None, :]
            wall = row_fractions(zb, zf, nz, dtype)[:, None] * ring_volume_fractions(Rb, Rw, nr, dtype)[None, :]
        occ = body + wall
        if phys["opening_m"] is not None:
            zp = zf - h.plate_m / dx
            zp = jnp.where(zp >= zd, zp, zd)
            b = 0.5 * phys["opening_m"] / dx
            occ = occ + row_fractions(zp, zf, nz, dtype)[:, None] * ring_volume_fractions(b, Rb, nr, dtype)[None, :]
        return _select_clip01(occ).astype(dtype)


def sealed_outer_cells(bore_cells: float) -> float:
    """Outer radius (cells) of the model's can wall: the datasheet's, or where that would leave no
    whole rigid ring behind the bore's cut cell, the outer face of the first whole ring
    (floor(R_in) + 2): a sub-cell wall is thickened outwards, never into the bore."""
    return float(math.floor(bore_cells) + 2)


def _inside(frac: float) -> float:
    return min(max(float(frac), 1e-6), 1 - 1e-6)


def lagrange4(t, n_nodes: int):
    """(start, weights): the cubic Lagrange interpolant at `t` (traced; in node spacings) over the
    four nodes start..start + 3 of 0..n_nodes - 1 round it (error O(h^4) in a smooth function;
    continuous in t, exact at the nodes)."""
    start = jnp.clip(jnp.floor(t).astype(jnp.int32) - 1, 0, n_nodes - 4)
    x = t - start
    w = [jnp.prod(jnp.stack([(x - j) / (k - j) for j in range(4) if j != k])) for k in range(4)]
    return start, jnp.stack(w)


WAVE_LINE_STEP = 0.25
"""Spacing (cells) of the free can's precomputed scan-line kernels, interpolated to the fitted
front face (`lagrange4`): relative error <= (k h)^4 x 9/16 / 24, 1.4e-5 (0.001 deg) at 10 cells
per wavelength."""


class HousedForward:
    """The housed model's lobe on its lattice: `lobe_db(params)` (jnp, differentiable in every
    raw parameter, the geometry included) at the far-field angles `angle_deg` (from the axis),
    and with a scan line (`wave_x_m` lateral positions at `wave_z_m` in front of the front face,
    the face where the parameters put it) the wavefront `near_field(params)`.

    A free can ("free" front): one run, the can's rigid body in cut cells, the far field from a
    closed Kirchhoff-Helmholtz cylinder round the can; the scan line's kernels are precomputed on
    lines `WAVE_LINE_STEP` cells apart and interpolated to the front face the recess puts it at.

    A flanged can ("flange" front: the front face an infinite rigid baffle): the grid's z_lo face
    is the diaphragm's rigid plane, the flange a rigid block filling the rows from it to the front
    face outside the bore (and through the radial absorbing layer), the far field the
    Kirchhoff-Helmholtz transform over the baffled cylinder standing on the flange (its image
    plane the front face). The front face lies on whole rows: the lattice resolves a flange between
    rows only through cut cells, which would move the transform's image plane off the face. A
    depth between rows is continued by cubic Lagrange interpolation (`lagrange4`) of the surface
    phasors over the four whole-row depths round it (four runs, one program: the phasors are
    recorded on a box covering every depth, and the cylinder's cells gathered at the depth's
    offset). The scan line's points are relative to the front face: it follows the fitted face."""

    def __init__(self, spec: HousedSpec, angle_deg, *, wave_x_m=None, wave_z_m: float | None = None):
        from ..lattice.coefficients import Edges
        from ..lattice.grid import make_grid
        from ..observe.farfield_rz import CylinderSurface, far_field_rz
        from .transfer_disc import surface_cells, surface_pairs

        self.spec = spec
        self.flanged = spec.housing.front == "flange"
        dx, g, pml = spec.dx_m, spec.surface_gap, spec.pml_cells
        if self.flanged:
            self.max_rows = max(int(math.ceil(spec.recess_max_m / dx)) + 2, 4)  # the interpolant's 4 nodes
            surface = CylinderSurface(0, g, spec.n_rings + g, baffled=True)
            box_z, box_r = self.max_rows + g + 3, surface.jr + 3
            shape = (box_z + 6 + pml, box_r + 6 + pml)
        else:
            lay = spec.layout()
            surface = CylinderSurface(lay.iz0, lay.iz1, lay.jr, baffled=False)
            shape = lay.shape
        grid = make_grid(
            frequency_hz=spec.frequency_hz,
            cells_per_wavelength=spec.cells_per_wavelength,
            c_max_m_s=spec.c_m_s,
            shape=shape,
            dtype=spec.dtype,
            kind="rz",
            stencil=spec.stencil,
        )
        nz, nr = shape
        n_steps = int(math.hypot(nz, nr) / grid.courant + (spec.cycles + 6) * grid.steps_per_period)
        self.grid, self.n_steps, self.surface = grid, n_steps, surface
        zd = 0 if self.flanged else lay.diaphragm_row
        self.layout = HousedLayout(shape, zd, surface.iz0, surface.iz1, surface.jr, n_steps, dx)
        self.angle_deg = np.asarray(angle_deg, float)
        self.cells = surface_cells(surface, 4)
        pairs = np.asarray(surface_pairs(np.eye(len(self.cells)), 4))  # (4M, 2M): recorded -> pairs
        kern = np.asarray(far_field_rz(np.eye(pairs.shape[1]), surface, grid, self.angle_deg))  # (2M, A)
        self.operator = jnp.asarray(pairs @ kern)  # (4M, A): recorded phasors -> far field
        if self.flanged:
            self.box = np.stack(np.meshgrid(np.arange(box_z), np.arange(box_r), indexing="ij"), -1).reshape(-1, 2)
            self.index = jnp.asarray(self.cells[:, 0] * box_r + self.cells[:, 1])
            self.row_stride = box_r
            self.flange = ring_volume_fractions(
                spec.housing.bore_radius_m / dx, float(nr + 1), nr, np.dtype(spec.dtype)
            )
            self.edges = Edges.axisymmetric("rigid", "pml", "pml", thickness_cells=pml)
        else:
            self.edges = Edges.axisymmetric("pml", "pml", "pml", thickness_cells=pml)
        self.wave_operator = None
        if wave_x_m is not None:
            self.wave_operator = jnp.asarray(np.einsum("ij,ljk->lik", pairs, self._wave_kernels(wave_x_m, wave_z_m)))

    def _wave_kernels(self, wave_x_m, wave_z_m):
        """(lines, 2M, J) Kirchhoff-Helmholtz kernels to the scan line `wave_z_m` in front of the
        front face at lateral positions `wave_x_m` (p(x) = p(|x|)): one line relative to a flange's
        face; for a free can one line per `WAVE_LINE_STEP` of the front face's admissible range."""
        from ..observe.farfield_rz import field_at_rz

        spec, lay, dx = self.spec, self.layout, self.layout.dx_m
        if wave_z_m is None or not wave_z_m > 0:
            raise ValueError(
                f"wave_z_m = {wave_z_m} must be > 0 m (the scan line's distance in front of the front face)"
            )
        x = np.abs(np.asarray(wave_x_m, float).reshape(-1)) / dx
        if self.flanged:
            z_lines = np.array([wave_z_m / dx])
            self.wave_u0 = 0
        else:  # the front face at zd + d / dx; lines every h cells over d in [d_min, d_max] (+- 2 lines)
            h = WAVE_LINE_STEP
            self.wave_u0 = int(math.floor(spec.recess_min_m / dx / h)) - 2
            u1 = int(math.ceil(spec.recess_max_m / dx / h)) + 2
            z_lines = lay.diaphragm_row + wave_z_m / dx + h * np.arange(self.wave_u0, u1 + 1)
        if z_lines[0] <= lay.iz1 + 2:
            face = z_lines[0] - wave_z_m / dx
            need = (lay.iz1 + 2 - face) * dx
            raise ValueError(
                f"wave_z_m = {wave_z_m} m puts the scan line inside the surface round the "
                f"{'flange' if self.flanged else 'can (which clears the deepest recess)'}; give wave_z_m > {need:.4g} m"
            )
        k = 2 * math.pi / spec.cells_per_wavelength
        r_src = lay.jr + 1.0
        d_min = max(z_lines[0] - lay.iz1 - 1, 1.0)
        n_phi = 2 * int(
            math.ceil(k * (r_src + x.max()) + 12 * r_src / d_min + 32)
        )  # as `transfer_disc` for near points
        m = self.operator.shape[0] // 2
        out = []
        for z in z_lines:
            pts = np.stack([np.full_like(x, z), x], 1)
            out.append(field_at_rz(np.eye(m), self.surface, self.grid, pts, dispersion="continuum", n_phi=n_phi))
        return np.asarray(out)

    def near_field(self, params: HousedParams):
        """Complex pressure on the scan line given at construction (same units as `far_field`);
        the observer's carrier phase in the rig's convention is -arg of it."""
        return self.fields(params)[1]

    def far_field(self, params: HousedParams):
        """Complex far field F at `angle_deg` (arbitrary units: the drive's spectrum is not divided out)."""
        return self.phasors(params) @ self.operator

    def fields(self, params: HousedParams):
        """(far field, near field on the scan line) from one lattice run (see `near_field`)."""
        if self.wave_operator is None:
            raise ValueError("no scan line: construct HousedForward(..., wave_x_m=..., wave_z_m=...)")
        ph = self.phasors(params)
        far = ph @ self.operator
        if self.flanged:
            return far, ph @ self.wave_operator[0]
        t = self.spec.physical(params)["recess_m"] / (self.layout.dx_m * WAVE_LINE_STEP) - self.wave_u0
        start, w = lagrange4(t, self.wave_operator.shape[0])
        ker = jax.lax.dynamic_slice_in_dim(self.wave_operator, start, 4)  # (4, 4M, J)
        return far, w @ jnp.einsum("i,lij->lj", ph, ker)

    def phasors(self, params: HousedParams):
        """The lattice run: phasors at the drive frequency of the surface's recorded cells (a
        flanged can: interpolated to the recess from the four whole-row depths round it)."""
        ph = self.spec.physical(params)
        if not self.flanged:
            return self._run(ph, self.spec.rigid(ph, self.layout, self.grid.jnp_dtype), self.cells, "can")
        start, w = lagrange4(ph["recess_m"] / self.layout.dx_m, self.max_rows)
        rows = jax.vmap(lambda m: self.flanged_phasors(ph, start + m))(jnp.arange(4))
        return w @ rows

    def flanged_phasors(self, ph: dict, rows):
        """A flanged can's surface phasors for a front face `rows` whole rows in front of the
        diaphragm (`ph`: `HousedSpec.physical`'s dict; the plate, if any, `plate_m` thick below
        the front face)."""
        nz, nr = self.layout.shape
        dt, dx, h = self.grid.jnp_dtype, self.layout.dx_m, self.spec.housing
        zf = jnp.asarray(rows, dt)
        occ = row_fractions(0.0, zf, nz, dt)[:, None] * self.flange[None, :]
        if ph["opening_m"] is not None:
            zp = jnp.where(zf - h.plate_m / dx >= 0, zf - h.plate_m / dx, 0.0)
            b, rb = 0.5 * ph["opening_m"] / dx, h.bore_radius_m / dx
            occ = occ + row_fractions(zp, zf, nz, dt)[:, None] * ring_volume_fractions(b, rb, nr, dt)[None, :]
        rec = self._run(ph, _select_clip01(occ).astype(dt), self.box, "rigid")
        return jnp.take(rec, self.index + jnp.asarray(rows) * self.row_stride)

    def _run(self, ph: dict, occ, cells, baffle):
        """One lattice run of the geometry `occ`; phasors at `cells`."""
        from ..air import density_kg_m3
        from ..lattice.medium import Medium
        from ..solver.loop import simulate
        from ..solver.sensors import Sensors
        from ..solver.sources import PointSources, ToneBurst, disc_transducer

        spec, grid = self.spec, self.grid
        src = disc_transducer(
            grid,
            radius_m=0.5 * ph["diaphragm_m"],
            z_m=self.layout.diaphragm_row * grid.dx_m,
            n_rings=spec.n_rings,
            weights=ph["weights"],
            lags_s=ph["lags_s"],
            signal=ToneBurst(spec.frequency_hz, spec.cycles),
            baffle=baffle,
        )
        sources = [src]
        if spec.housing.back == "open":  # the rear face: the same flux out of the cell behind the plate
            rear = np.asarray(src.cells_array).copy()
            rear[:, 0] -= 2
            sources.append(
                PointSources(
                    cells=rear, signal=src.signal, weights=-src.weights, lags_s=src.lags_s, injection="velocity"
                )
            )
        r = simulate(
            grid,
            Medium(spec.c_m_s, density_kg_m3(20.0), rigid=occ),
            sources,
            Sensors(phasor_cells=cells),
            n_steps=self.n_steps,
            edges=self.edges,
            backend="jax",
            preflight="off",
            throw=False,
        )
        assert r.phasors is not None  # recorded: the sensors ask for them
        return r.phasors

    def lobe_db(self, params: HousedParams):
        """Model levels, dB: 20 log10 |F| plus the fitted gain."""
        return level_db(self.far_field(params), params)


def level_db(far, params: HousedParams):
    """20 log10 |F| plus the fitted gain (dB)."""
    return 10 * jnp.log10(jnp.abs(far) ** 2 + 1e-300) + (0.0 if params.gain_db is None else params.gain_db)
