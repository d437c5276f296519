"""Gradient-based horn and reflector design.

- `shapes`: differentiable designs (`HornParams`, `ReflectorParams`) and their limits
  (`HornLimits`, `ReflectorLimits`: validation and the constraint-keeping reparameterisation);
- `objectives`: beam measures from a far-field pattern (gain, -6 dB width, side-lobe level,
  directivity, sector power) and weighted goals (`Goal`);
- `problem`: `horn_design` / `reflector_design` build a `DesignProblem` (grid, transducer,
  far-field contour) whose `metrics(params)` is differentiable through the whole simulation;
- `optimise`: BFGS (optimistix) over the reparameterised design with progress and history;
- `export`: a design as a scene TOML file for `difflattice simulate`.
"""

from .objectives import Goal, pattern_metrics
from .problem import DesignProblem, horn_design, reflector_design
from .shapes import HornLimits, HornParams, ReflectorLimits, ReflectorParams

__all__ = [
    "DesignProblem",
    "Goal",
    "HornLimits",
    "HornParams",
    "ReflectorLimits",
    "ReflectorParams",
    "horn_design",
    "pattern_metrics",
    "reflector_design",
]
