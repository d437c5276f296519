"""difflattice: a JAX differentiable lattice-gas simulator of ultrasonic waves in air.

The package is imported lazily: ``import difflattice.capture`` (the serial host) never imports
JAX, so the capture tools start fast on a lab laptop. The simulator API is re-exported here and
loaded on first use.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_LAZY = {
    # units / grid
    "Grid": "difflattice.grid",
    "make_grid": "difflattice.grid",
    # media and scene
    "Material": "difflattice.medium",
    "MATERIALS": "difflattice.medium",
    "air": "difflattice.medium",
    "Medium": "difflattice.medium",
    # sources
    "LineTransducer": "difflattice.source",
    "ToneBurst": "difflattice.source",
    "ContinuousWave": "difflattice.source",
    # sensors
    "Sensors": "difflattice.sensors",
    # solver
    "Simulation": "difflattice.solver",
    "simulate": "difflattice.solver",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'difflattice' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)


__all__ = sorted(_LAZY) + ["__version__"]
