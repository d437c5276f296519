"""difflattice: a JAX differentiable lattice-gas simulator of ultrasonic waves in air.

``import difflattice as dl`` gives the handful of names a user needs; they are loaded on first
use, so ``import difflattice.capture`` (the serial host) never imports JAX and the capture tools
start fast on a lab laptop. The layers, bottom up: `lattice` (units, grid, media, geometry,
coefficients, operator) -> `solver` (sources, sensors, stepper, `simulate`) -> `observe` (far
field, metrics, analytic references) -> `scene` (scene files) -> `fit`, `design` -> `capture`
(rig protocol and files, no JAX) -> `plots` -> `apps` -> `cli`.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_LAZY = {
    # units / grid / media
    "Grid": "difflattice.lattice.grid",
    "make_grid": "difflattice.lattice.grid",
    "Material": "difflattice.lattice.medium",
    "MATERIALS": "difflattice.lattice.medium",
    "air": "difflattice.lattice.medium",
    "Medium": "difflattice.lattice.medium",
    "Edges": "difflattice.lattice.coefficients",
    # sources and sensors
    "PointSources": "difflattice.solver.sources",
    "line_transducer": "difflattice.solver.sources",
    "ToneBurst": "difflattice.solver.sources",
    "ContinuousWave": "difflattice.solver.sources",
    "Sensors": "difflattice.solver.sensors",
    # time loop
    "Stepper": "difflattice.solver.stepper",
    "simulate": "difflattice.solver.loop",
    "run": "difflattice.solver.loop",
    # scene files
    "load_scene": "difflattice.scene.model",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'difflattice' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)


def __dir__() -> list[str]:
    return sorted(list(globals()) + list(_LAZY))


__all__ = sorted(_LAZY) + ["__version__"]
