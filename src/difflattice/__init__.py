"""difflattice: a JAX differentiable lattice-gas simulator of ultrasonic waves in air.

``import difflattice as dl`` gives the names a user needs; they are loaded on first use, so
``import difflattice.capture`` (the serial host) never imports JAX and the capture tools start
fast on a lab laptop. The layers, bottom up: `lattice` (units, grid, media, geometry,
coefficients, operator) -> `solver` (sources, sensors, stepper, `simulate`) -> `observe` (far
field, metrics, analytic references) -> `scene` (scene files) -> `fit`, `design` -> `capture`
(rig protocol and files, no JAX) -> `plots` -> `apps` -> `cli`.

Every name here means one thing whatever was imported before: the subpackages and modules
(`dl.air`, `dl.lattice`, `dl.observe`, ...) are always modules, and functions never share a
module's name (dry air as a `Material` is `dl.air_material`, the function
`difflattice.lattice.medium.air`).
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

# public name -> (module, attribute in it)
_LAZY: dict[str, tuple[str, str]] = {
    # units / grid / media
    "Grid": ("difflattice.lattice.grid", "Grid"),
    "make_grid": ("difflattice.lattice.grid", "make_grid"),
    "Material": ("difflattice.lattice.medium", "Material"),
    "MATERIALS": ("difflattice.lattice.medium", "MATERIALS"),
    "air_material": ("difflattice.lattice.medium", "air"),
    "Medium": ("difflattice.lattice.medium", "Medium"),
    "Edges": ("difflattice.lattice.coefficients", "Edges"),
    # sources and sensors
    "PointSources": ("difflattice.solver.sources", "PointSources"),
    "line_transducer": ("difflattice.solver.sources", "line_transducer"),
    "disc_transducer": ("difflattice.solver.sources", "disc_transducer"),
    "disc_housing": ("difflattice.solver.sources", "disc_housing"),
    "disc_transducer_3d": ("difflattice.solver.sources", "disc_transducer_3d"),
    "ToneBurst": ("difflattice.solver.sources", "ToneBurst"),
    "ContinuousWave": ("difflattice.solver.sources", "ContinuousWave"),
    "Sensors": ("difflattice.solver.sensors", "Sensors"),
    # time loop
    "Stepper": ("difflattice.solver.stepper", "Stepper"),
    "simulate": ("difflattice.solver.loop", "simulate"),
    "run": ("difflattice.solver.loop", "run"),
    # far field and metrics: each kind's surface (one protocol), and the 2-D (line), r-z (disc) and 3-D functions
    "FarFieldSurface": ("difflattice.observe.farfield_base", "FarFieldSurface"),
    "surface_for": ("difflattice.observe.surfaces", "surface_for"),
    "surface_around": ("difflattice.observe.surfaces", "surface_around"),
    "box_around": ("difflattice.observe.farfield", "box_around"),
    "far_field": ("difflattice.observe.farfield", "far_field"),
    "level_db": ("difflattice.observe.farfield", "level_db"),
    "cylinder_around": ("difflattice.observe.farfield_rz", "cylinder_around"),
    "far_field_rz": ("difflattice.observe.farfield_rz", "far_field_rz"),
    "box_around_3d": ("difflattice.observe.farfield3d", "box_around_3d"),
    "far_field_3d": ("difflattice.observe.farfield3d", "far_field"),
    "lobe_metrics": ("difflattice.observe.observables", "lobe_metrics"),
    "piston_directivity": ("difflattice.observe.analytic", "piston_directivity"),
    # scene files and scene runs (the `simulate` command)
    "load_scene": ("difflattice.scene.model", "load_scene"),
    "parse_scene": ("difflattice.scene.model", "parse_scene"),
    "Scene": ("difflattice.scene.model", "Scene"),
    "run_scene": ("difflattice.apps.scene_run", "run_scene"),
    "run_scene3d": ("difflattice.apps.scenes3d", "run_scene3d"),
    # fitting (the `fit` command) and design (the `design` command)
    "load_fit_config": ("difflattice.fit.config", "load_config"),
    "run_fit": ("difflattice.apps.fitting", "run_fit"),
    "design_horn": ("difflattice.design.presets", "design_horn"),
    "design_reflector": ("difflattice.design.presets", "design_reflector"),
}

# subpackages and modules reachable as attributes (always the module, whatever was imported first)
_MODULES = (
    "air",
    "apps",
    "capture",
    "config",
    "design",
    "fit",
    "lattice",
    "observe",
    "plots",
    "scene",
    "solver",
    "transforms",
)


def __getattr__(name: str) -> Any:
    if name in _MODULES:
        return importlib.import_module(f"difflattice.{name}")
    target = _LAZY.get(name)
    if target is None:
        raise AttributeError(f"module 'difflattice' has no attribute {name!r}")
    value = getattr(importlib.import_module(target[0]), target[1])
    globals()[name] = value  # later look-ups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY) | set(_MODULES))


__all__ = sorted(_LAZY) + ["__version__"]
