"""The paper's Fig. 9 horn and Fig. 10 reflector as designs, and the two example studies (also
behind `difflattice design` and designs/design_*.py)."""

from __future__ import annotations

import math
from pathlib import Path

from .constraints import MakerConstraints, constraints_line, limits_for, project
from .objectives import Goal
from .problem import horn_design, reflector_design
from .shapes import HornLimits, HornParams, ReflectorLimits, ReflectorParams
from .study import trust_line

PAPER_FACE_M = 0.0357
"""The Polaroid-like line: 104 cells at 20 cells per wavelength, 50 kHz."""

FIG09_CONE = HornParams(
    throat_m=0.0367, mouth_m=0.0367 + 2 * 0.125 * math.tan(math.radians(5.0)), length_m=0.125, wall_m=0.003, flare=0.0
)
"""data/scenes/fig09_cone_horn.toml: inner faces 36.7 mm apart at the face, 5 deg half-angle, 125 mm, 3 mm walls."""

FIG10_PARABOLA = ReflectorParams(focal_m=0.050, aperture_m=0.190, wall_m=0.003)
"""data/scenes/fig10_parabolic_reflector.toml: focal length 50 mm, aperture 190 mm, 3 mm wall."""

HORN_LIMITS = HornLimits(
    throat_min_m=0.0365,
    throat_max_m=0.040,
    mouth_max_m=0.090,
    length_min_m=0.040,
    length_max_m=0.160,
    wall_min_m=0.002,
    wall_max_m=0.004,
)
REFLECTOR_LIMITS = ReflectorLimits(
    focal_min_m=0.025, focal_max_m=0.080, aperture_min_m=0.100, aperture_max_m=0.220, wall_min_m=0.002, wall_max_m=0.004
)

HORN_CONSTRAINTS = MakerConstraints(
    max_length_m=0.166, max_mouth_diameter_m=0.098, min_wall_m=0.002, max_overhang_deg=45.0
)
"""`difflattice design horn`'s default part limits: they reproduce HORN_LIMITS (length <= 160 mm
+ 1.5 walls, inner mouth <= 90 mm + 2 walls) and add the printing overhang."""

REFLECTOR_CONSTRAINTS = MakerConstraints(
    max_length_m=0.060, max_mouth_diameter_m=0.228, min_wall_m=0.002, max_overhang_deg=45.0
)
"""`difflattice design reflector`'s default part limits (aperture <= 220 mm + 2 walls, depth
<= 60 mm)."""


def _problem(kind: str, cells_per_wavelength, max_cells_per_wavelength: float, **kw):
    """The design problem at a resolution, or with "auto" the coarsest one whose trust estimate is
    under the threshold (`study.choose_resolution`); returns (problem, note or None)."""
    from .study import choose_resolution

    build = horn_design if kind == "horn" else reflector_design
    if cells_per_wavelength != "auto":
        return build(cells_per_wavelength=float(cells_per_wavelength), **kw), None
    # the wall must stay resolved: start where a cell is no thicker than the thinnest wall
    lo = max(4.0, math.ceil(343.0 / (50e3 * kw["limits"].wall_min_m)))
    cpw, _, note = choose_resolution(
        lambda n: build(cells_per_wavelength=n, **{**kw, "reference": False}), lo, max_cells_per_wavelength
    )
    return build(cells_per_wavelength=cpw, **kw), note


def design_horn(
    out: str | Path,
    *,
    cells_per_wavelength: float | str = 8.0,
    target_deg: float = 8.0,
    wall: str = "soft",
    steps: int = 15,
    check_gradients: bool = True,
    progress: bool = True,
    constraints: MakerConstraints | None = None,
    lattice: str = "2d",
    band=None,
    max_cells_per_wavelength: float = 24.0,
) -> dict:
    """Horn for a target -6 dB width at 1 m from the Fig. 9 cone; free: mouth, length, flare
    (the throat is fixed: the cone's, or the transducer can's of `constraints`). `band`: design
    over the burst's band ("burst") or a list of frequencies (Hz) instead of the carrier alone;
    `cells_per_wavelength="auto"`: see `_problem`."""
    from .study import run_study

    c = HORN_CONSTRAINTS if constraints is None else constraints
    limits = limits_for(c, HORN_LIMITS)
    pb, note = _problem(
        "horn",
        cells_per_wavelength,
        max_cells_per_wavelength,
        limits=limits,
        face_m=PAPER_FACE_M,
        wall=wall,
        cycles=5.0,
        constraints=c,
        lattice=lattice,
        band=band,
    )
    goal = Goal(width_target_deg=target_deg, width_weight=1.0, width_scale_deg=1.0)
    over = "" if band is None else " over the burst's band" if band == "burst" else " over the given frequencies"
    return run_study(
        pb,
        project(limits, FIG09_CONE),
        goal,
        out,
        title=f"Horn for a {target_deg:g} deg beam{over} (from the Fig. 9 cone, {wall} walls)",
        free=("mouth_m", "length_m", "flare"),
        max_steps=steps,
        check_gradients=check_gradients,
        progress=progress,
        resolution_choice=note,
    )


def design_reflector(
    out: str | Path,
    *,
    cells_per_wavelength: float | str = 8.0,
    wall: str = "soft",
    steps: int = 15,
    check_gradients: bool = True,
    progress: bool = True,
    constraints: MakerConstraints | None = None,
    lattice: str = "2d",
    band=None,
    max_cells_per_wavelength: float = 24.0,
) -> dict:
    """Reflector for on-axis gain at 1 m from the Fig. 10 parabola; free: focal length, aperture
    (`band`, `cells_per_wavelength`: as `design_horn`)."""
    from .study import run_study

    c = REFLECTOR_CONSTRAINTS if constraints is None else constraints
    limits = limits_for(c, REFLECTOR_LIMITS)
    pb, note = _problem(
        "reflector",
        cells_per_wavelength,
        max_cells_per_wavelength,
        limits=limits,
        face_m=PAPER_FACE_M,
        wall=wall,
        cycles=10.0,
        constraints=c,
        lattice=lattice,
        band=band,
    )
    return run_study(
        pb,
        project(limits, FIG10_PARABOLA),
        Goal(gain_weight=1.0),
        out,
        title=f"Reflector for on-axis gain (from the Fig. 10 parabola, {wall} walls)",
        free=("focal_m", "aperture_m"),
        max_steps=steps,
        check_gradients=check_gradients,
        progress=progress,
        resolution_choice=note,
    )


def one_line(summary: dict) -> str:
    o = summary["optimisation"]
    a, b = o["metrics_start"], o["metrics_best"]
    return (
        f"-6 dB width {a['beam_width_deg']:.2f} -> {b['beam_width_deg']:.2f} deg; on-axis gain {a['on_axis_db']:+.2f} -> "
        f"{b['on_axis_db']:+.2f} dB; loss {o['loss_start']:.4g} -> {o['loss_best']:.4g}; {o['optimiser_steps']} steps, "
        f"{o['wall_s']:.0f} s; converged: {o['converged']}; {trust_line(summary['trust'])}"
        + (f"\n{summary['resolution_choice']}" if "resolution_choice" in summary else "")
        + (f"\n{constraints_line(summary['part']['constraints'])}" if "part" in summary else "")
    )
