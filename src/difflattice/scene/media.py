"""A scene's materials, grid and medium: the cell sized for the fastest fluid, the lattice kind's
courant default and limit, the air (temperature, humidity, absorption), and the medium maps the
objects make."""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING

import numpy as np

from .common import _fail, _material
from .schema import DiscTransducer

if TYPE_CHECKING:
    from ..lattice.grid import Grid, StencilKind
    from ..lattice.medium import Material, Medium
    from .model import Scene


def _materials(scene: Scene) -> tuple[Material, list[Material]]:
    """(background, [background, one material per object]); under speed_zero only the background
    (every object is a speed-zero region), warning about materials that are then ignored."""
    from ..lattice.medium import air, material

    p, med = scene.path, scene.medium
    if scene.air is not None:
        if med.background != "air":
            _fail(p, "air", f"describes the air, but [medium] background = {med.background!r}: remove [air]")
        if med.temperature_c is not None:
            _fail(p, "medium.temperature_c", "is given twice: [air] temperature_c sets it; remove this one")
        a = scene.air
        bg = air(a.temperature_c, a.pressure_pa, a.humidity_pct)
    elif med.background == "air":
        bg = air(med.air_temperature_c)
    else:
        bg = _material(p, "medium.background", med.background, material)
    if bg.kind != "fluid":
        _fail(p, "medium.background", f"must be a fluid material, got {bg.name} ({bg.kind})")
    mats = [bg] + [
        _material(p, f"objects[{i}].material", o.material_name, material) for i, o in enumerate(scene.objects)
    ]
    if med.boundary_model == "speed_zero":
        for i, m in enumerate(mats[1:]):
            given = scene.objects[i].material is not None
            if m.kind == "fluid" or (given and m.kind == "rigid"):
                warnings.warn(
                    f"{p}: [objects[{i}].material] = {m.name!r} is ignored under "
                    f'boundary_model = "speed_zero": every object is a speed-zero '
                    f"(pressure-release, R = -1) region, its speed "
                    f"{'and density ' if m.kind == 'fluid' else ''}not used. Use "
                    f'material = "soft" to say so, or boundary_model = "conservative" to '
                    f"simulate {m.name!r}.",
                    UserWarning,
                    stacklevel=3,
                )
        mats = [bg]
    return bg, mats


def _make_grid(scene: Scene, mats: list[Material]) -> Grid:
    """The grid, its cell sized for the fastest simulated fluid; the courant default and limit of
    the lattice kind (refused above it naming `[grid.courant]`); warns for every under-resolved
    fluid."""
    from ..lattice.grid import make_grid
    from ..lattice.medium import warn_if_under_resolved

    p, g = scene.path, scene.grid
    kind = scene.kind
    ndim = kind.ndim
    if (g.size_m is None) == (g.shape is None):
        axes = ", ".join(kind.axis_names)
        _fail(p, "grid", f"give exactly one of size_m = [{axes}] (m) or shape = [{axes}] (cells)")
    for key in ("size_m", "shape"):
        value = getattr(g, key)
        if value is not None and len(value) != ndim:
            _fail(p, f"grid.{key}", f"= {list(value)}: a {kind} grid needs {ndim} entries")
        for i, v in enumerate(value or ()):
            if not v > 0:
                _fail(p, f"grid.{key}", f"= {list(value)}: entry {i} ({kind.axis_names[i]}) must be > 0")
    if g.size_m is not None:  # each size must span cells at this resolution (make_grid would clamp it)
        dx = None
        try:
            fastest_c = max(m.speed_m_s for m in mats if m.kind == "fluid")
            dx = fastest_c / (g.frequency_hz * g.cells_per_wavelength)
        except ValueError:
            pass
        if dx is not None:
            small = [s for s in g.size_m if round(s / dx) < 3]
            if small:
                _fail(
                    p,
                    "grid.size_m",
                    f"= {list(g.size_m)} m: {small[0]:g} m is fewer than 3 cells of {dx * 1e3:.3g} mm at this "
                    "resolution; give each size in metres, at least a few wavelengths plus the edge layers",
                )
    air_cond = scene.air_conditions()
    # rz scenes in air (no objects, no housing, one fluid) default to the isotropic stencil: the
    # near field in place, on the native kernels; with obstacles the standard one (the native
    # kernels run the isotropic stencil on uniform faces only); 3-D scenes default to the wide
    # 25-point stencil (`kinds.Volume`: 0.24 % phase-speed error at 6 cells per wavelength)
    in_air = not scene.objects and all(
        not isinstance(t, DiscTransducer) or t.rz_baffle() == "rigid" for t in scene.transducers
    )
    stencil: StencilKind = g.stencil or ("isotropic" if kind.ring_metric and in_air else kind.default_stencil)
    try:
        kind.check_stencil(stencil)
    except ValueError as err:
        _fail(p, "grid.stencil", str(err))
    default = kind.default_courant_for(stencil)
    courant = default if g.courant is None else float(g.courant)
    limit = kind.stability_limit(stencil)
    if air_cond is not None:  # absorption stiffens the step: its own, lower limit (docs/air.md)
        from ..lattice.coefficients import absorbing_courant

        fast = max(m.speed_m_s for m in mats if m.kind == "fluid")
        c_air = absorbing_courant(g.frequency_hz, g.cells_per_wavelength, fast, air_cond, kind, stencil)
        if g.courant is None:
            courant = min(courant, c_air)
        elif courant > c_air / 0.9999:
            _fail(
                p,
                "grid.courant",
                f"= {courant:g} cells/step exceeds the limit with air absorption, {c_air / 0.9999:.5f} (the "
                f"relaxation and viscous terms stiffen the step): leave courant out (then {c_air:.5f}) or set "
                "it lower, or [air] absorption = false",
            )
    if courant > limit:
        _fail(
            p,
            "grid.courant",
            f"= {courant:g} cells/step exceeds the {kind.label} stability limit {kind.limit_formula(stencil)} = "
            f"{limit:.4f} (the leapfrog would grow without bound): set courant = {default} (the default) or less",
        )
    fluids = [m for m in mats if m.kind == "fluid"]
    fastest = max(fluids, key=lambda m: m.speed_m_s)
    try:
        grid = make_grid(
            frequency_hz=g.frequency_hz,
            cells_per_wavelength=g.cells_per_wavelength,
            c_max_m_s=fastest.speed_m_s,
            shape=tuple(g.shape) if g.shape else None,
            size_m=tuple(g.size_m) if g.size_m else None,
            courant=courant,
            dtype=g.dtype,
            kind=kind,
            stencil=stencil,
        )
    except ValueError as e:
        _fail(p, "grid", str(e))
    # every simulated fluid must be resolved: the cell is sized for the fastest one
    seen = set()
    for m in fluids:
        if m.name not in seen:
            seen.add(m.name)
            warn_if_under_resolved(
                m.name,
                m.speed_m_s,
                grid.frequency_hz,
                grid.dx_m,
                fastest=fastest.name,
                minimum=kind.resolved_cells_per_wavelength(stencil),
            )
    return grid


def _medium(scene: Scene, grid: Grid, bg: Material, mats: list[Material], occupancies, extra_rigid, union) -> Medium:
    """The `Medium`: each object's occupancy goes to the rigid or soft map or, for a fluid
    material, into the speed and density maps; `union` combines several occupancies."""
    import jax.numpy as jnp

    from ..lattice.medium import Medium

    p, med = scene.path, scene.medium
    speed_zero = med.boundary_model == "speed_zero"
    rigid, soft = list(extra_rigid), []
    speed = np.full(grid.shape, bg.speed_m_s)
    rho = np.full(grid.shape, bg.density_kg_m3)
    fluid_objects = False
    for i, occ in enumerate(occupancies):
        m = None if speed_zero else mats[1 + i]
        if m is None or m.kind == "soft":
            soft.append(occ)
        elif m.kind == "rigid":
            rigid.append(occ)
        else:
            fluid_objects = True
            o = np.asarray(occ)
            speed = speed * (1 - o) + m.speed_m_s * o
            rho = rho * (1 - o) + m.density_kg_m3 * o
    dt = grid.jnp_dtype

    def combined(occs):
        return None if not occs else jnp.asarray(union(occs), dt)

    try:
        return Medium(
            sound_speed_m_s=jnp.asarray(speed, dt) if fluid_objects else bg.speed_m_s,
            density_kg_m3=jnp.asarray(rho, dt) if fluid_objects else bg.density_kg_m3,
            rigid=combined(rigid),
            soft=combined(soft),
            boundary_model=med.boundary_model,
            absorption_db_per_m=float(med.absorption_db_per_m),
            air=scene.air_conditions(),
        )
    except ValueError as e:
        _fail(p, "medium", str(e))
