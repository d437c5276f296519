"""The fit's settings (`FitOptions`: solver, tolerances, loss, priors) and its stage names."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from .problem import LOSSES

Solver = Literal["levenberg_marquardt", "dogleg", "gauss_newton", "bfgs"]
SOLVERS = ("levenberg_marquardt", "dogleg", "gauss_newton", "bfgs")
Loss = Literal["l2", "huber", "cauchy"]

CONVERGENCE_WINDOW = 5
"""Accepted steps over which the relative cost change and the step are measured."""
STAGE_NAMES = {
    1: "diameter and offsets (profiles held uniform)",
    2: "all parameters, sigmas floored at 1 dB and 5 deg",
    3: "all parameters, measured sigmas",
}


@dataclass(frozen=True)
class FitOptions:
    """Solver settings: `solver` (levenberg_marquardt, dogleg, gauss_newton, bfgs), optimistix's
    tolerances `rtol`/`atol`, `max_steps` per stage, the lobe floor `floor_db` below the measured
    peak (dB), observable weights, the smoothness prior of per-cell profiles (second difference
    per cell), the residual `loss` ("l2", "huber", "cauchy") with its `loss_scale` (units of the
    data's 1-sigma), and the convergence tolerances `rtol_cost` (relative cost change over the
    last accepted steps) and `rtol_step` (step in standard errors)."""

    solver: Solver = "levenberg_marquardt"
    rtol: float = 1e-7
    atol: float = 1e-7
    max_steps: int = 200
    floor_db: float = 40.0  # below the measured peak
    lobe_weight: float = 1.0
    wave_weight: float = 1.0
    smoothness_sigma: float = 0.05  # free/symmetric profiles: allowed second difference per cell
    loss: Loss = "l2"
    loss_scale: float = 3.0  # sigma units
    rtol_cost: float = 1e-6
    rtol_step: float = 0.05

    def __post_init__(self):
        if self.solver not in SOLVERS:
            raise ValueError(f"solver = {self.solver!r}; allowed: {', '.join(SOLVERS)}")
        if self.max_steps < 1:
            raise ValueError(f"max_steps = {self.max_steps} must be >= 1")
        if self.loss not in LOSSES:
            raise ValueError(f"loss = {self.loss!r}; allowed: {', '.join(LOSSES)}")
        if not (isinstance(self.loss_scale, (int, float)) and math.isfinite(self.loss_scale) and self.loss_scale > 0):
            raise ValueError(
                f"loss_scale = {self.loss_scale!r} must be a number > 0, in units of the data's "
                "1-sigma (e.g. 3: residuals beyond 3 sigma count less)"
            )
        if not (isinstance(self.rtol_cost, (int, float)) and 0 < self.rtol_cost < 1):
            raise ValueError(f"rtol_cost = {self.rtol_cost!r} must lie in (0, 1) (e.g. 1e-6)")
        if not (isinstance(self.rtol_step, (int, float)) and math.isfinite(self.rtol_step) and self.rtol_step > 0):
            raise ValueError(f"rtol_step = {self.rtol_step!r} must be > 0, in standard errors (e.g. 0.05)")
