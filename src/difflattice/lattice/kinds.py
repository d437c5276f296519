"""Lattice kinds: what differs between the plane, axisymmetric (r-z) and volume lattices, owned
by one type so that nothing else in the package branches on a kind's name.

A kind holds no arrays: it is the static description of a lattice's geometry (rank, axis and
side names, where cell centres lie, whether ring cells carry a metric), its stability limit per
stencil and the messages that go with it. `Grid.kind` holds one; the strings "2d", "rz" and "3d"
are accepted where a user names a kind (`as_kind`) and compare equal to the kind they name.

A new lattice kind is one subclass here (see docs/architecture.md, "A new lattice kind"); the
stepper, loop, sensors and plots ask it instead of testing its name.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np

StencilKind = Literal["standard", "isotropic", "wide"]
STENCILS = ("standard", "isotropic", "wide")

MAX_COURANT = 1.0 / math.sqrt(2.0)
"""Stability limit of the 2-D five-point leapfrog in cells/step (also the r-z lattice's)."""

MAX_COURANT_3D = 1.0 / math.sqrt(3.0)
"""Stability limit of the 3-D seven-point leapfrog in cells/step."""

MAX_COURANT_ISOTROPIC = math.sqrt(3.0) / 2.0
"""Stability limit of the leapfrog with the isotropic (9-point) stencil, plane and rz grids."""

WIDE_PAIR_WEIGHT = 0.08
"""The 3-D wide stencil's compact pair weight a: ``L = L7 + a sum_(i<j) T_i T_j - (e/4) sum_i D_i W D_i``
(`operators._wide_3d`; the isotropic stencil is a = 1/6, e = 0)."""

WIDE_AXIS_WEIGHT = 0.25
"""The 3-D wide stencil's axis fourth-difference weight e (its second-neighbour term)."""

PAIR_WEIGHT = {"isotropic": 1.0 / 6.0, "wide": WIDE_PAIR_WEIGHT}
"""The compact pair weight a of each stencil with one (`operators._across_faces`)."""

MAX_COURANT_WIDE = 1.0 / math.sqrt(3.0 * (1.0 + WIDE_AXIS_WEIGHT) - 12.0 * WIDE_PAIR_WEIGHT)
"""Stability limit of the 3-D wide stencil, 1/sqrt(2.79) = 0.598684 cells/step: the leapfrog's
``sin^2(omega/2) = c^2 B(s)``, ``B = sum s_i + e sum s_i^2 - 4 a sum_(i<j) s_i s_j``, s_i =
sin^2(k_i/2) in [0, 1], is stable iff c^2 max B <= 1. B is convex along each s_i (d^2B/ds_i^2 = 2e
> 0), so its maximum over the cube [0, 1]^3 lies at a vertex; with n of the three s_i at 1,
B = n (1 + e) - 2 a n (n - 1): 1.25, 2.18, 2.79 for n = 1, 2, 3 (a = 0.08, e = 1/4), the
maximum at the body-diagonal checkerboard (pi, pi, pi): c <= 1/sqrt(3 + 3e - 12a). B >= 0 on
the cube (its minimum, 0, at s = 0), so -L is positive semi-definite."""

MAX_COURANT_WIDE_FACES = 1.0 / math.sqrt(3.0 * (1.0 + WIDE_AXIS_WEIGHT))
"""The wide stencil's bound for any face conductances of one speed, 1/sqrt(3.75) = 0.516: the
compact part is bounded by the 7-point operator (its filter M <= diag(b)), and each ``D W D`` by
``rho(K D) / c^2 (-D) <= 4 (-D)`` in the energy inner product, so ``-K L <= (1 + e) (-K L7)``.
Used only where the spectrum cannot be measured (traced obstacles); `spectrum.check_spectrum`
measures it otherwise."""

DEFAULT_COURANT_3D_WIDE = 0.595
"""The wide stencil's default courant: 0.6 % under its limit, a margin for obstacles (whose
operator spectrum is measured at build, `spectrum.check_spectrum`). Phase-speed error at 6
cells/wavelength: -0.24 % worst over every direction and every wavenumber up to it, group
velocity 0.74 % (`docs/three_d.md`)."""

PAPER_COURANT = 0.707
"""The paper's choice: just below the limit."""

DEFAULT_COURANT_3D = 0.577
"""The 3-D default courant: 0.06 % under 1/sqrt(3), as the paper's 0.707 is under 1/sqrt(2)."""

DEFAULT_COURANT_3D_ISOTROPIC = 0.86
"""The 3-D isotropic stencil's default courant: 0.7 % under sqrt(3)/2, a margin for the obstacles
whose measured spectral radius exceeds the whole-space bound by up to 1.4 % (posts, steps,
diagonal plates; `coefficients.build_lattice` measures it); phase-speed error 1.3 % at 6
cells/wavelength against 1.24 % at the limit."""


class LatticeKind:
    """A kind of lattice (abstract): rank, axis conventions, stability limit and labels.

    Subclasses set the class attributes and may override the methods; instances are stateless
    and compare equal to each other by class and to the string `name`.
    """

    name: ClassVar[str]
    """Short name used in scene files and summaries ("2d", "rz", "3d")."""
    label: ClassVar[str]
    """Name for messages ("2-D", "rz", "3-D")."""
    noun: ClassVar[str]
    """What a grid of this kind is called in a sentence ("plane", "rz", "3-D")."""
    ndim: ClassVar[int]
    axis_names: ClassVar[tuple[str, ...]]
    """Coordinate name of each array axis (e.g. ("z", "r") for rz)."""
    stencils: ClassVar[tuple[str, ...]] = ("standard",)
    """Spatial stencils implemented on this kind (`Grid.stencil`)."""
    default_stencil: ClassVar[StencilKind] = "standard"
    """The stencil a scene file gets when it names none (`scene.media`)."""
    default_courant: ClassVar[float] = PAPER_COURANT
    origin_cells: ClassVar[float] = 0.0
    """Offset of cell centres from the origin, in cells (0: the origin is the centre of cell 0)."""
    ring_metric: ClassVar[bool] = False
    """Whether axis 1 is a radius whose ring cells carry a volume/area metric (`AxisymMetric`)."""
    has_axis_edge: ClassVar[bool] = False
    """Whether the y_lo side is the symmetry axis r = 0 (an "axis" edge) rather than a window side."""
    boundary_models: ClassVar[tuple[str, ...]] = ("conservative",)
    """Boundary models (`Medium.boundary_model`) with a form on this kind: every kind has the
    finite-volume "conservative" one; the paper's eq. 10 models exist on the plane only."""
    mirrored_view: ClassVar[bool] = False
    """Whether images show the field mirrored about axis 1's low side (the whole meridian section)."""

    # --- identity -------------------------------------------------------------------------------
    def __eq__(self, other: object) -> bool:
        if isinstance(other, str):
            return other == self.name
        return type(other) is type(self)

    def __hash__(self) -> int:
        return hash(("LatticeKind", self.name))

    def __str__(self) -> str:
        return self.name

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"

    # --- shape and coordinates ------------------------------------------------------------------
    def check_shape(self, shape: tuple[int, ...]) -> None:
        """Refuse a grid shape this kind cannot have (rank, minimum cells)."""
        if len(shape) != self.ndim:
            names = ", ".join(f"n{a}" for a in self.axis_names)
            raise ValueError(
                f"a {self.label} grid needs shape ({names}), got {shape}"
                + ("" if self.ndim == 3 else " (for a 3-D grid set kind='3d')")
            )
        if shape[0] < 3 or min(shape) < self.min_cells:
            raise ValueError(
                f"grid shape {shape} is too small: a {self.label} grid needs at least 3 cells along "
                f"{self.axis_names[0]}" + (f" and {self.min_cells} along every axis" if self.min_cells > 1 else "")
            )

    min_cells: ClassVar[int] = 1

    def shape_for_size(self, size_m: tuple[float, ...], dx_m: float) -> tuple[int, ...]:
        """Cells per axis for a window of `size_m` metres (each axis at least its minimum)."""
        if len(size_m) != self.ndim:
            raise ValueError(f"a {self.label} grid's size_m has {self.ndim} lengths ({self.axis_names}), got {size_m}")
        return tuple(max(3 if i == 0 else self.min_cells, int(round(float(s) / dx_m))) for i, s in enumerate(size_m))

    def cells_of(self, points_m: np.ndarray, dx_m: float) -> np.ndarray:
        """Indices of the cells containing points (n, ndim) given in metres (nearest cell centre)."""
        return np.rint(np.asarray(points_m, dtype=float) / dx_m - self.origin_cells).astype(np.int64)

    def coordinates_m(self, shape: tuple[int, ...], dx_m: float) -> tuple[np.ndarray, ...]:
        """Cell-centre coordinates per axis, metres."""
        return tuple((np.arange(n) + self.origin_cells) * dx_m for n in shape)

    def axis_labels(self, unit: str = "mm") -> tuple[str, ...]:
        """Axis labels for plots, one per array axis (e.g. "z (mm)", "r (mm)")."""
        return tuple(f"{a} ({unit})" for a in self.axis_names)

    # --- stability ------------------------------------------------------------------------------
    def check_stencil(self, stencil: str) -> None:
        if stencil not in STENCILS:
            raise ValueError(f"stencil = {stencil!r}; allowed: {', '.join(map(repr, STENCILS))}")
        if stencil not in self.stencils:
            raise ValueError(
                f"stencil = {stencil!r} is implemented for {' and '.join(self._kinds_with(stencil))} grids only; "
                f"use stencil='standard' on a {self.label} grid"
            )

    @staticmethod
    def _kinds_with(stencil: str) -> list[str]:
        return [k.noun for k in KINDS.values() if stencil in k.stencils]

    def stability_limit(self, stencil: str = "standard") -> float:
        """Largest stable lattice speed (cells/step) of the leapfrog with `stencil`
        (derivations: `grid.stability_limit`)."""
        self.check_stencil(stencil)
        if stencil == "wide":
            return MAX_COURANT_WIDE
        return MAX_COURANT_ISOTROPIC if stencil == "isotropic" else self._standard_limit

    _standard_limit: ClassVar[float] = MAX_COURANT
    _standard_formula: ClassVar[str] = "1/sqrt(2)"

    def limit_formula(self, stencil: str = "standard") -> str:
        """The stability limit as a formula, for messages."""
        if stencil == "wide":
            return "1/sqrt(3 + 3e - 12a) = 1/sqrt(2.79)"
        return "sqrt(3)/2" if stencil == "isotropic" else self._standard_formula

    def limit_name(self, stencil: str = "standard") -> str:
        """E.g. "2-D", "rz isotropic-stencil": whose limit a message speaks of."""
        return self.label + (f" {stencil}-stencil" if stencil in ("isotropic", "wide") else "")

    def default_courant_for(self, stencil: str) -> float:
        """The courant a scene gets when it names none, for `stencil`."""
        return self.default_courant

    def resolved_cells_per_wavelength(self, stencil: str) -> float:
        """Cells per wavelength below which a medium counts as under-resolved with `stencil` (its
        worst phase-speed error above ~2 %; `medium.MIN_CELLS_PER_WAVELENGTH`)."""
        return 8.0

    @property
    def usual_courant(self) -> str:
        """The usual courant, for a fix hint."""
        return (
            f"the paper uses {PAPER_COURANT}"
            if self.default_courant == PAPER_COURANT
            else f"e.g. {self.default_courant}"
        )

    @property
    def speed_message(self) -> str:
        """The error raised when a (possibly traced) speed map exceeds the limit."""
        iso = ", sqrt(3)/2 with the isotropic stencil" if "isotropic" in self.stencils else ""
        if "wide" in self.stencils:
            iso += f", {self.limit_formula('wide')} with the wide one"
        return (
            f"difflattice: a medium speed exceeds the {self.label} stability limit ({self.limit_formula()} "
            f"cells/step{iso}): lower the grid courant or set c_max_m_s to the fastest medium's speed."
        )


class Plane(LatticeKind):
    """The paper's plane lattice of square cells: axis 0 is x, axis 1 is y; the origin is the
    centre of cell (0, 0). Five-point (or isotropic nine-point) stencil, limit 1/sqrt(2)."""

    name = "2d"
    label = "2-D"
    noun = "plane"
    ndim = 2
    axis_names = ("x", "y")
    stencils = ("standard", "isotropic")
    boundary_models = ("conservative", "paper", "speed_zero")


class Axisymmetric(LatticeKind):
    """The axisymmetric (r-z) lattice of ring cells: axis 0 is z (propagation), axis 1 is r. The
    axis r = 0 is the low face of ring 0 (cell centres at r = (j + 1/2) dx) and the origin is the
    low corner of cell (0, 0); the y_lo side is the axis. Limit 1/sqrt(2), as the plane's."""

    name = "rz"
    label = "rz"
    noun = "rz"
    ndim = 2
    axis_names = ("z", "r")
    stencils = ("standard", "isotropic")
    origin_cells = 0.5
    ring_metric = True
    has_axis_edge = True
    mirrored_view = True

    def cells_of(self, points_m: np.ndarray, dx_m: float) -> np.ndarray:
        # the cell containing the point: cells span [j, j + 1) dx from the axis and z = 0
        return np.floor(np.asarray(points_m, dtype=float) / dx_m).astype(np.int64)


class Volume(LatticeKind):
    """A volume of cubic cells, shape (nx, ny, nz); the origin is the centre of cell (0, 0, 0).
    Seven-point stencil, limit 1/sqrt(3), the 19-point isotropic one, limit sqrt(3)/2: 1.3 %
    phase-speed error at 6 cells/wavelength in every direction against the seven-point
    stencil's 3.4 % on the axes (`observe.analytic3d`), or the 25-point wide one (scenes'
    default), limit 1/sqrt(2.79): 0.24 % (`MAX_COURANT_WIDE`; docs/benchmarks/wide3d_work_precision.md)."""

    name = "3d"
    label = "3-D"
    noun = "3-D"
    ndim = 3
    axis_names = ("x", "y", "z")
    stencils = ("standard", "isotropic", "wide")
    default_stencil = "wide"
    default_courant = DEFAULT_COURANT_3D
    min_cells = 3
    _standard_limit = MAX_COURANT_3D
    _standard_formula = "1/sqrt(3)"

    def default_courant_for(self, stencil: str) -> float:
        if stencil == "wide":
            return DEFAULT_COURANT_3D_WIDE
        return DEFAULT_COURANT_3D_ISOTROPIC if stencil == "isotropic" else self.default_courant

    def resolved_cells_per_wavelength(self, stencil: str) -> float:
        # the isotropic stencil's 2 % point: 1.33 % at 6 cells/wavelength, error ~ 1/cpw^2; the
        # wide one's worst phase error is 1.04 % at 4 cells/wavelength (2 % near 3.5)
        if stencil == "wide":
            return 4.0
        return 5.0 if stencil == "isotropic" else 8.0


PLANE = Plane()
AXISYMMETRIC = Axisymmetric()
VOLUME = Volume()
KINDS: dict[str, LatticeKind] = {k.name: k for k in (PLANE, AXISYMMETRIC, VOLUME)}
"""The built-in kinds by name."""


def as_kind(kind: LatticeKind | str) -> LatticeKind:
    """The kind named by `kind` ("2d", "rz", "3d") or `kind` itself; a clear error otherwise."""
    if isinstance(kind, LatticeKind):
        return kind
    if isinstance(kind, str) and kind in KINDS:
        return KINDS[kind]
    raise ValueError(f"grid kind = {kind!r}; allowed: {', '.join(map(repr, KINDS))} (or a LatticeKind)")
