"""A design problem: a line transducer, a shape in front of (or around) it, and its far-field beam.

`DesignProblem` holds only static set-up (grid, transducer, far-field contour, run length, wall
material, angles, limits); the differentiable design is passed to its methods (`HornParams` or
`ReflectorParams`). The chain params -> signed distance -> smooth occupancy -> medium ->
checkpointed simulation -> contour phasors -> Kirchhoff-Helmholtz far field -> beam measures is
differentiable end to end. The grid and contour are sized from the limits, so every admissible
design fits inside the contour, away from the absorbing layer.

Build problems with `horn_design` and `reflector_design` (`stencil`: the grid's spatial stencil,
`Grid.stencil`; rigid walls keep the standard stability limit). With ``lattice="rz"`` they build the
axisymmetric counterpart (issue 12): the transducer is a transparent disc of the same diameter
(soft ring sources, each ring weighted by its covered face fraction, as the 2-D line is a
transparent soft line), the walls are bodies of revolution (the meridian-plane shape rasterised on
the rz grid, cell centres r = (j + 1/2) dx: occupancy is the meridian-area fraction, not the
ring-volume fraction, an O(dx / r) difference that matters only for walls within a few cells of
the axis, and the horn and dish walls lie at r >= 18 mm), and the beam is the 3-D
Kirchhoff-Helmholtz transform (`field_at_rz`) of the phasors on a closed cylinder around
transducer and walls.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..lattice.coefficients import Edges
from ..lattice.geometry import rasterise
from ..lattice.grid import Grid, make_grid
from ..lattice.kinds import AXISYMMETRIC, PLANE, LatticeKind, as_kind
from ..lattice.medium import Medium, air, material
from ..lattice.window import Window
from ..observe.farfield_base import FarFieldSurface
from ..observe.surfaces import surface_for
from ..solver.loop import simulate
from ..solver.sensors import Sensors
from ..solver.sources import PointSources, ToneBurst, line_transducer, ring_fractions
from .constraints import MakerConstraints, penalty
from .objectives import Goal, pattern_metrics
from .shapes import HornLimits, ReflectorLimits

LATTICES = (PLANE, AXISYMMETRIC)
"""Lattice kinds of a design problem: the 2-D plane (wedges, troughs) or axisymmetric (cones, dishes)."""

WALLS = ("rigid", "soft")
"""Ideal wall kinds; any fluid material of `medium.MATERIALS` (e.g. "pine") is also accepted."""


class DesignProblem(eqx.Module):
    """Static set-up of a design (see the module docstring). `kind` is "horn" or "reflector"."""

    kind: str = eqx.field(static=True)
    grid: Grid
    limits: HornLimits | ReflectorLimits
    anchor_m: tuple[float, float] = eqx.field(static=True)
    n_cells: int = eqx.field(static=True)
    direction_deg: float = eqx.field(static=True)
    cycles: float = eqx.field(static=True)
    wall: str = eqx.field(static=True)
    contour: FarFieldSurface
    pml_cells: int = eqx.field(static=True)
    n_steps: int = eqx.field(static=True)
    range_m: float = eqx.field(static=True)
    angles_deg: tuple[float, ...] = eqx.field(static=True)
    field_of_view_deg: float = eqx.field(static=True)
    sector_deg: float = eqx.field(static=True)
    reference_on_axis: float | None = eqx.field(static=True, default=None)
    ramp_cells: float = eqx.field(static=True, default=1.0)
    lattice: LatticeKind = eqx.field(static=True, default=PLANE, converter=as_kind)
    face_m: float = eqx.field(static=True, default=0.0)
    constraints: MakerConstraints | None = eqx.field(static=True, default=None)
    frequencies_hz: tuple[float, ...] = eqx.field(static=True, default=())
    band_weights: tuple[float, ...] = eqx.field(static=True, default=())

    # -- pieces --------------------------------------------------------------------------------
    def source(self):
        g = self.grid
        sig = ToneBurst(g.frequency_hz, self.cycles)
        if self.lattice.ring_metric:  # a transparent disc of ring cells (n_cells rings), the 2-D line's counterpart
            i_s = int(round(self.anchor_m[0] / g.dx_m - 0.5))
            cells = np.stack([np.full(self.n_cells, i_s), np.arange(self.n_cells)], 1)
            w = ring_fractions(jnp.asarray(0.5 * self.face_m / g.dx_m, g.jnp_dtype), self.n_cells).astype(g.jnp_dtype)
            return PointSources(
                cells=cells, signal=sig, weights=w, lags_s=jnp.zeros(self.n_cells, g.jnp_dtype), injection="soft"
            )
        return line_transducer(g, self.anchor_m, n_cells=self.n_cells, direction_deg=self.direction_deg, signal=sig)

    @property
    def edges(self) -> Edges:
        if self.lattice.has_axis_edge:
            return Edges.axisymmetric(thickness_cells=self.pml_cells)
        return Edges(thickness_cells=self.pml_cells)

    def occupancy(self, params):
        """Smooth occupancy of the design's walls (None for no shape)."""
        if params is None:
            return None
        return rasterise(params.shape(self.anchor_m), self.grid, "smooth", ramp_cells=self.ramp_cells)

    def medium(self, params) -> Medium:
        """Air with the design's walls: rigid (R = +1, conservative model), soft (R = -1: the paper's
        speed-zero walls; the conservative model's soft walls are not stable with fractional
        occupancy) or a fluid material (speed and density blended by occupancy)."""
        a = air(20.0)
        occ = self.occupancy(params)
        if occ is None:
            return Medium(a.speed_m_s, a.density_kg_m3)
        if self.wall == "rigid":
            return Medium(a.speed_m_s, a.density_kg_m3, rigid=occ)
        if self.wall == "soft":  # the paper's walls (Figs. 6-10): speed zero inside, R = -1
            return Medium(a.speed_m_s, a.density_kg_m3, soft=occ, boundary_model="speed_zero")
        m = material(self.wall)
        return Medium(a.speed_m_s * (1 - occ) + m.speed_m_s * occ, a.density_kg_m3 * (1 - occ) + m.density_kg_m3 * occ)

    def check(self, params):
        """Validate explicit design parameters (ValueError naming the parameter)."""
        return self.limits.check(params)

    # -- the beam ------------------------------------------------------------------------------
    def _phasors(self, params):
        """Contour phasors of one run, (K, m): the carrier's running DFT (K = 1), or, for a band,
        the DFT of the recorded contour pressures at each of `frequencies_hz` (the same sum,
        sum_n p(n) exp(i omega n), taken after the run)."""
        g = self.grid
        band = bool(self.frequencies_hz)
        cells = self.contour.cells
        r = simulate(
            g,
            self.medium(params),
            self.source(),
            Sensors(probes=cells) if band else Sensors(phasor_cells=cells),
            n_steps=self.n_steps,
            edges=self.edges,
            checkpoint="sqrt",
        )
        if not band:
            assert r.phasors is not None  # recorded: the sensors ask for them
            return r.phasors[None]
        n = np.arange(1, self.n_steps + 1)
        w = np.array([g.hz_to_lattice_omega(f) for f in self.frequencies_hz])
        ang = np.mod(w[:, None] * n[None, :], 2 * math.pi)
        kernel = jnp.asarray(np.exp(1j * ang), dtype=jnp.result_type(r.probes.dtype, jnp.complex64))
        return kernel @ r.probes

    def band_patterns(self, params, ranges_m: tuple[float, ...] | None = None):
        """Complex patterns per frequency, (K, angles) (or a tuple of them, one per range): the
        carrier alone (K = 1) or each of `frequencies_hz`."""
        phasors = self._phasors(params)
        freqs = self.frequencies_hz or (self.grid.frequency_hz,)
        rngs = (self.range_m,) if ranges_m is None else tuple(ranges_m)
        out = tuple(jnp.stack([self._beam(phasors[k], f, rng) for k, f in enumerate(freqs)]) for rng in rngs)
        return out[0] if ranges_m is None else out

    def pattern(self, params, ranges_m: tuple[float, ...] | None = None):
        """Pressure at `range_m` (or, given `ranges_m`, a tuple of patterns, one per range) from the
        transducer centre on `angles_deg` (0 = +x, the beam axis); params None = bare transducer.
        The carrier's complex pattern, or for a band the burst's energy pattern
        sqrt(sum_k w_k |p_k|^2) (real, >= 0: the beam of the burst's energy over its spectrum). A
        range must clear the contour by about a wavelength (k R > 30)."""
        pats = self.band_patterns(params, ranges_m)
        if not self.frequencies_hz:
            return pats[0] if ranges_m is None else tuple(p[0] for p in pats)
        w = jnp.asarray(self.band_weights)[:, None]
        energy = lambda p: jnp.sqrt(jnp.sum(w * jnp.abs(p) ** 2, axis=0))
        return energy(pats) if ranges_m is None else tuple(energy(p) for p in pats)

    def _beam(self, phasors, frequency_hz: float, rng: float):
        """One frequency's pattern at range `rng` from the transducer centre, from the surface's
        phasors (rz: at polar angle |angle| from +z; the pattern of a body of revolution is even in
        the angle, so the 2-D angle list is kept)."""
        g = self.grid
        centre = (self.anchor_m[0] / g.dx_m, self.anchor_m[1] / g.dx_m)
        angles = np.asarray(self.angles_deg)
        return self.contour.far_field(
            phasors, g, angles, range_m=rng, centre_cells=centre, dispersion="continuum", frequency_hz=frequency_hz
        )

    def metrics_of(self, pattern) -> dict:
        return pattern_metrics(
            pattern,
            self.angles_deg,
            reference_on_axis=self.reference_on_axis,
            field_of_view_deg=self.field_of_view_deg,
            sector_deg=self.sector_deg,
        )

    def metrics(self, params) -> dict:
        """Beam measures of a design (see `objectives.pattern_metrics`); on-axis gain re the bare transducer."""
        return self.metrics_of(self.pattern(params))

    def loss(self, params, goal: Goal):
        """The goal's loss plus the maker constraints' penalties (`constraints.penalty`)."""
        return goal.loss(self.metrics(params)) + self.penalty(params)

    def penalty(self, params):
        return penalty(self.constraints, params, ring_metric=self.lattice.ring_metric)

    def fields(self, params, snapshot_every: int):
        """A forward run for pictures: (snapshots, snapshot steps, p_max) as numpy arrays."""
        r = simulate(
            self.grid,
            self.medium(params),
            self.source(),
            Sensors(p_max=True, snapshot_every=snapshot_every),
            n_steps=self.n_steps,
            edges=self.edges,
        )
        return np.asarray(r.snapshots), np.asarray(r.snapshot_steps), np.asarray(r.p_max)


def _grid(
    frequency_hz, cells_per_wavelength, wall, shape, dtype, kind: LatticeKind = PLANE, stencil="standard"
) -> Grid:
    """A grid whose cell size resolves air at `cells_per_wavelength`, whatever the wall material."""
    c_air = air(20.0).speed_m_s
    c_max = c_air
    if wall not in WALLS:
        m = material(wall)
        if m.kind != "fluid":
            raise ValueError(f"wall = {wall!r}: give 'rigid', 'soft' or a fluid material name")
        c_max = max(c_air, m.speed_m_s)
    return make_grid(
        frequency_hz=frequency_hz,
        cells_per_wavelength=cells_per_wavelength * c_max / c_air,
        c_max_m_s=c_max,
        shape=shape,
        dtype=dtype,
        kind=kind,
        stencil=stencil,
    )


def _dx(frequency_hz, cells_per_wavelength) -> float:
    return air(20.0).speed_m_s / (frequency_hz * cells_per_wavelength)


def _finish(
    kind,
    grid,
    limits,
    anchor_cells,
    n_cells,
    direction_deg,
    cycles,
    wall,
    contour,
    pml,
    n_steps,
    range_m,
    angle_step_deg,
    field_of_view_deg,
    sector_deg,
    reference,
    lattice: LatticeKind = PLANE,
    face_m=0.0,
    constraints: MakerConstraints | None = None,
    band=None,
) -> DesignProblem:
    n_a = int(round(360.0 / angle_step_deg))
    if abs(n_a * angle_step_deg - 360.0) > 1e-9 or n_a % 2:
        raise ValueError(f"angle_step_deg = {angle_step_deg} must divide 180 deg")
    angles = tuple(float(a) for a in -180.0 + angle_step_deg * np.arange(n_a))
    # an even line is centred between two cells: put the anchor (throat / focus) there too
    if (
        lattice.ring_metric
    ):  # the disc centre: on the axis, at the source row's cell centre (rz cell centres are at + 1/2)
        anchor = ((anchor_cells[0] + 0.5) * grid.dx_m, 0.0)
    else:
        anchor = (anchor_cells[0] * grid.dx_m, (anchor_cells[1] + 0.5 * (n_cells % 2 == 0)) * grid.dx_m)
    contour.check_inside(grid, margin=pml)
    args = dict(
        kind=kind,
        grid=grid,
        limits=limits,
        anchor_m=anchor,
        n_cells=n_cells,
        direction_deg=direction_deg,
        cycles=cycles,
        wall=wall,
        contour=contour,
        pml_cells=pml,
        n_steps=n_steps,
        range_m=range_m,
        angles_deg=angles,
        field_of_view_deg=field_of_view_deg,
        sector_deg=sector_deg,
        lattice=lattice,
        face_m=face_m,
        constraints=constraints,
    )
    if band is not None:
        freqs, weights = band_frequencies(band, grid.frequency_hz, cycles)
        args.update(frequencies_hz=freqs, band_weights=weights)
    bare = DesignProblem(**args)
    if not reference:
        return bare
    p0 = bare.pattern(None)
    ref = float(jnp.abs(p0[angles.index(0.0)]))
    return DesignProblem(**args, reference_on_axis=ref)


def _n_steps(grid: Grid, contour, cycles: float, traversals: float) -> int:
    diag = math.hypot(*contour.span_cells)  # a cylinder's diameter plays the box's height
    return int(math.ceil(traversals * diag / grid.courant + (cycles + 6) * grid.steps_per_period))


def band_frequencies(
    band, frequency_hz: float, cycles: float, *, n: int = 5, drop_db: float = 6.0
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(frequencies, weights) of a design band. `band` = "burst": `n` frequencies evenly across
    the -`drop_db` band of the drive's Hann burst spectrum (`cycles` cycles at `frequency_hz`),
    weighted by its energy density |S(f)|^2 (normalised to sum 1); a sequence of frequencies
    (Hz): those, weighted equally."""
    if isinstance(band, str):
        if band != "burst":
            raise ValueError(f"band = {band!r}: give 'burst' or a list of frequencies in Hz")
        sig = ToneBurst(frequency_hz, cycles)
        t = np.linspace(0.0, sig.duration_s(), 4096)
        x = np.asarray(sig(jnp.asarray(t)))
        spec = lambda f: abs(np.trapezoid(x * np.exp(-2j * math.pi * np.asarray(f)[:, None] * t), t, axis=1)) ** 2
        fine = np.linspace(0.2 * frequency_hz, 1.8 * frequency_hz, 4001)
        e = spec(fine)
        inside = fine[e >= e.max() * 10 ** (-drop_db / 10)]
        grid_f = np.linspace(inside.min(), inside.max(), n)
        w = spec(grid_f)
        return tuple(float(f) for f in grid_f), tuple(float(v) for v in w / w.sum())
    listed = tuple(float(f) for f in band)
    if not listed or not all(math.isfinite(f) and f > 0 for f in listed):
        raise ValueError(f"band = {band!r}: give 'burst' or a non-empty list of positive frequencies in Hz")
    return listed, tuple(1.0 / len(listed) for _ in listed)


def _check_wall_resolved(wall_min_m: float, dx: float) -> None:
    if wall_min_m < dx - 1e-12:
        raise ValueError(
            f"wall_min_m = {wall_min_m:.6g} m is thinner than one cell ({dx:.6g} m): "
            "the grid cannot resolve the wall; raise wall_min_m or cells_per_wavelength"
        )


def _check_lattice(lattice: LatticeKind | str, wall: str) -> LatticeKind:
    """The design's lattice kind (plane or axisymmetric), refused with the reason otherwise."""
    kind = as_kind(lattice)
    if kind not in LATTICES:
        raise ValueError(
            f"lattice = {lattice!r}; allowed: {', '.join(repr(k.name) for k in LATTICES)} (2-D plane or axisymmetric)"
        )
    if "speed_zero" not in kind.boundary_models and wall == "soft":
        raise ValueError(
            "wall = 'soft' (the paper's speed-zero walls) has no ring-volume form on an rz lattice: "
            "use wall = 'rigid' or a fluid material with lattice = 'rz'"
        )
    return kind


def _layout(
    back: int,
    fwd: int,
    half: int,
    gap_cells: int,
    pml_cells: int,
    frequency_hz,
    cells_per_wavelength,
    wall,
    dtype,
    lattice: LatticeKind = PLANE,
    stencil="standard",
):
    """Grid and contour around a transducer anchored `back` cells behind and `fwd` cells before
    the walls' reach, `half` cells either side (rz: `half` rings out from the axis); returns
    (grid, contour, anchor cell)."""
    win = Window.around(lattice, gap=gap_cells, layer=pml_cells, pad=3, pad_hi=2, extent=((back, fwd), (half, half)))
    grid = _grid(frequency_hz, cells_per_wavelength, wall, win.shape, dtype, lattice, stencil)
    (i0, i1), (j0, j1) = win.box
    return grid, surface_for(lattice).from_box((i0, j0), (i1, j1)), win.source


def horn_design(
    *,
    limits: HornLimits,
    face_m: float,
    frequency_hz: float = 50e3,
    cells_per_wavelength: float = 8.0,
    wall: str = "soft",
    cycles: float = 5.0,
    range_m: float = 1.0,
    angle_step_deg: float = 0.5,
    field_of_view_deg: float = 90.0,
    sector_deg: float = 10.0,
    gap_cells: int = 4,
    pml_cells: int = 12,
    traversals: float = 1.5,
    dtype: str = "float64",
    reference: bool = True,
    lattice: LatticeKind | str = "2d",
    stencil: str = "standard",
    constraints: MakerConstraints | None = None,
    band=None,
) -> DesignProblem:
    """A horn problem: a line transducer of diameter `face_m` facing +x at the throat of any horn
    within `limits` (``lattice="rz"``: a disc of diameter `face_m` facing +z in a horn of
    revolution). The run lasts `traversals` crossings of the contour plus the burst and six
    periods, so the burst has left the contour when the phasors are read. `reference` runs the bare
    transducer once for the gain's reference (False skips it: `on_axis_db` is then 0 for every design)."""
    lattice = _check_lattice(lattice, wall)
    dx = _dx(frequency_hz, cells_per_wavelength)
    n_cells = max(1, int(round(face_m / dx)))
    if lattice.ring_metric and limits.throat_min_m < face_m - 1e-12:
        raise ValueError(
            f"throat_min_m = {limits.throat_min_m:.6g} m is narrower than the disc (face_m = {face_m:.6g} m): "
            "the walls would cover source rings"
        )
    if not lattice.ring_metric and limits.throat_min_m < n_cells * dx - 1e-12:
        raise ValueError(
            f"throat_min_m = {limits.throat_min_m:.6g} m is narrower than the transducer "
            f"({n_cells} cells = {n_cells * dx:.6g} m at this resolution): the walls would cover source cells"
        )
    _check_wall_resolved(limits.wall_min_m, dx)
    back = int(math.ceil(limits.wall_max_m / dx)) + 1
    fwd = int(math.ceil((limits.length_max_m + limits.wall_max_m) / dx)) + 1
    half = int(math.ceil((0.5 * limits.mouth_max_m + limits.wall_max_m) / dx)) + 1
    grid, contour, anchor = _layout(
        back, fwd, half, gap_cells, pml_cells, frequency_hz, cells_per_wavelength, wall, dtype, lattice, stencil
    )
    return _finish(
        "horn",
        grid,
        limits,
        anchor,
        _n_source(lattice, n_cells, face_m, dx),
        0.0,
        cycles,
        wall,
        contour,
        pml_cells,
        _n_steps(grid, contour, cycles, traversals),
        range_m,
        angle_step_deg,
        field_of_view_deg,
        sector_deg,
        reference,
        lattice,
        face_m,
        constraints,
        band,
    )


def reflector_design(
    *,
    limits: ReflectorLimits,
    face_m: float,
    frequency_hz: float = 50e3,
    cells_per_wavelength: float = 8.0,
    wall: str = "soft",
    cycles: float = 10.0,
    range_m: float = 1.0,
    angle_step_deg: float = 0.5,
    field_of_view_deg: float = 90.0,
    sector_deg: float = 10.0,
    gap_cells: int = 4,
    pml_cells: int = 12,
    traversals: float = 2.0,
    dtype: str = "float64",
    reference: bool = True,
    lattice: LatticeKind | str = "2d",
    stencil: str = "standard",
    constraints: MakerConstraints | None = None,
    band=None,
) -> DesignProblem:
    """A reflector problem: a line transducer of diameter `face_m` at the focus of a parabolic
    mirror opening towards +x, facing the vertex (as the paper's Fig. 10); ``lattice="rz"``: a disc
    of diameter `face_m` at the focus of a paraboloidal dish opening towards +z (a transparent disc
    radiates both ways, as the 2-D line does)."""
    lattice = _check_lattice(lattice, wall)
    dx = _dx(frequency_hz, cells_per_wavelength)
    n_cells = max(1, int(round(face_m / dx)))
    _check_wall_resolved(limits.wall_min_m, dx)
    half_face = 0.5 * n_cells * dx
    f = limits.focal_min_m
    if f - half_face**2 / (4 * f) < dx - 1e-12:
        need = 0.5 * (dx + math.sqrt(dx * dx + half_face**2))
        raise ValueError(
            f"focal_min_m = {f:.6g} m puts the mirror within a cell of the transducer's ends "
            f"(face {n_cells * dx:.6g} m): use focal_min_m >= {need:.6g} m"
        )
    rim = max(
        -ff + (a / 2) ** 2 / (4 * ff)
        for ff in (limits.focal_min_m, limits.focal_max_m)
        for a in (limits.aperture_min_m, limits.aperture_max_m)
    )
    back = int(math.ceil((limits.focal_max_m + limits.wall_max_m) / dx)) + 1
    fwd = max(int(math.ceil((rim + limits.wall_max_m) / dx)) + 1, 1)
    half = int(math.ceil((0.5 * max(limits.aperture_max_m, n_cells * dx) + limits.wall_max_m) / dx)) + 1
    grid, contour, anchor = _layout(
        back, fwd, half, gap_cells, pml_cells, frequency_hz, cells_per_wavelength, wall, dtype, lattice, stencil
    )
    return _finish(
        "reflector",
        grid,
        limits,
        anchor,
        _n_source(lattice, n_cells, face_m, dx),
        180.0,
        cycles,
        wall,
        contour,
        pml_cells,
        _n_steps(grid, contour, cycles, traversals),
        range_m,
        angle_step_deg,
        field_of_view_deg,
        sector_deg,
        reference,
        lattice,
        face_m,
        constraints,
        band,
    )


def _n_source(lattice: LatticeKind, n_cells: int, face_m: float, dx: float) -> int:
    """Source cells: the 2-D line's `n_cells`, or the rings a disc of diameter `face_m` touches."""
    return max(1, math.ceil(0.5 * face_m / dx - 1e-9)) if lattice.ring_metric else n_cells
