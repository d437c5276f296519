"""Least-squares fitting with optimistix: residuals, robust losses, a stepped solve that returns
its convergence trace, a convergence test that means something, and the statistical covariance.

Residuals (each divided by its 1-sigma, times sqrt(observable weight)):

- lobe: soft_floor(model dB) - soft_floor(measured dB), with the floor `floor_db` below the
  measured peak, so deep nulls (where a small angle error means tens of dB) do not dominate;
- wavefront: the pair (sin d, 1 - cos d) of the phase difference d, smooth and periodic (its
  squared norm is 4 sin^2(d/2) ~ d^2), so 2 pi wraps never jump.

Robust losses (`FitOptions.loss`: "l2", "huber", "cauchy"; `loss_scale` k in units of sigma).
Each data residual r is replaced by r phi(|r|) with phi(a) = sqrt(2 rho(a)) / a, so the sum of
squares that Levenberg-Marquardt minimises IS the robust cost sum rho(r_i) (Huber: r^2/2 inside
k, k|r| - k^2/2 outside; Cauchy: k^2/2 log(1 + r^2/k^2)). Why this "square root of rho"
transform rather than iteratively reweighted least squares: it keeps one optimistix least-squares
solve (its trust region and Jacobian, lineax's QR) on the true robust objective, with no outer
loop and no second stopping rule; both have the same stationary points (sum rho'(r_i) dr_i/dtheta
= 0) and the same Gauss-Newton Hessian up to the weight of the tails. phi is smooth at 0 (= 1)
and C1 at Huber's corner. The smoothness prior is not robustified.

The solve: optimistix's solver is stepped from Python (`init` / `step` / `terminate`, the step
jitted once per model structure and cached across fits), so the trace (cost per iteration, stage,
wall time without compilation) is returned with the result: no callbacks, no module state, fits
are re-entrant. Convergence, besides optimistix's own (strict) `rtol`/`atol` test, is ours:
over the last `CONVERGENCE_WINDOW` accepted steps the cost fell by less than `rtol_cost` (relative)
and the model's residuals moved by less than `rtol_step` standard errors (the norm of the change
of the normalised residual vector, ||J dy|| ~ the step in units of the parameters' statistical
uncertainty, sqrt(chi2_red)-inflated). A stage that runs out of steps is still judged converged
when it is stationary: the Gauss-Newton model predicts a further decrease below the same
tolerances. So a fit whose cost stopped changing says so, and "did not converge" means it.

Uncertainties: the statistical covariance (J^T J)^+ at the solution (Jacobian of the residuals
actually minimised); `stderr` inflates it by max(variance factor, 1) (chi2_red for l2; Huber's
M-estimator factor for robust losses) as a quick figure. The full budget
(resolution, model inadequacy, identifiability, bounds) is `fit.uncertainty.error_budget`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree

from .data import LobeData, WaveData
from .goodness import (
    OUTLIER_SIGMAS,
    _chi2_and_variance_factor,
    _datum_weights,
    goodness_of_fit,
    outlier_diagnostics,
)
from .model import ModelSpec, device_array, soft_floor_db
from .problem import (
    LOSSES,
    Problem,
    _cost_aux,
    _model_curves,
    _residual_aux,
    _residuals,
    build_problem,
    initial_params,
)
from .transfer import Transfer

Solver = Literal["levenberg_marquardt", "dogleg", "gauss_newton", "bfgs"]
SOLVERS = ("levenberg_marquardt", "dogleg", "gauss_newton", "bfgs")
Loss = Literal["l2", "huber", "cauchy"]

CONVERGENCE_WINDOW = 5
"""Accepted steps over which the relative cost change and the step are measured."""
"""A residual further than this many robust sigmas (MAD, at least the stated 1-sigma) from the
median is counted as an outlier (a Gaussian gives one in 16 000)."""
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


@dataclass(frozen=True)
class FitTrace:
    """The solve's history, one entry per solver step: `stage` (1-3, see `STAGE_NAMES`), `cost`
    (half the sum of squared residuals of that stage's problem at the accepted point),
    `accepted`, `step_s` (wall time of the step, compilation excluded) and per stage a summary
    (`stages`: name, first iteration, steps, compile time, convergence)."""

    stage: np.ndarray
    cost: np.ndarray
    accepted: np.ndarray
    step_s: np.ndarray
    stages: tuple = ()

    @property
    def iteration(self) -> np.ndarray:
        return np.arange(1, len(self.cost) + 1)

    @property
    def solve_s(self) -> np.ndarray:
        """Cumulative solve time (s) without compilation."""
        return np.cumsum(self.step_s)

    @property
    def compile_s(self) -> float:
        return float(sum(s["compile_s"] for s in self.stages))

    def to_dict(self) -> dict:
        return {
            "iteration": self.iteration.tolist(),
            "stage": self.stage.tolist(),
            "cost": self.cost.tolist(),
            "accepted": self.accepted.tolist(),
            "solve_s": self.solve_s.tolist(),
            "compile_s": self.compile_s,
            "stages": list(self.stages),
        }


@dataclass
class FitResult:
    """A fit's outcome: raw and physical parameters, convergence (`converged`, `result_code`,
    `convergence` with the reason and the measured tolerances, `warnings`), residual statistics
    (`chi2_reduced` of all data points, `variance_factor` for the errors, `rms`, `outliers`), the
    statistical covariance of the raw parameters
    (`covariance_raw`, not inflated) with `raw_labels`, standard errors of the physical parameters
    (`stderr`, inflated by max(variance_factor, 1)), correlations of the fitted (raw) parameters, the
    trace and the model curves at the solution."""

    spec: ModelSpec
    params: dict
    physical: dict
    converged: bool
    result_code: str
    n_steps: int
    wall_time_s: float
    cost: float
    chi2_reduced: float
    rms: dict
    stderr: dict
    correlation: np.ndarray
    correlation_labels: list
    condition_number: float
    rank_deficient: bool
    trace: FitTrace | None = None
    model_curves: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    convergence: dict = field(default_factory=dict)
    covariance_raw: np.ndarray | None = None
    raw_labels: list = field(default_factory=list)
    null_space: np.ndarray | None = None  # (n_params, k) directions the data do not constrain
    dof: int = 0  # minimised residuals counted per measured datum (prior rows included) - parameters
    goodness: dict = field(default_factory=dict)  # per data set and joint: chi2, dof, chi2_red, p (`goodness_of_fit`)
    outliers: dict = field(default_factory=dict)
    loss: str = "l2"
    variance_factor: float = 1.0  # multiplies the statistical covariance (chi2_red for l2, robust for others)
    effective_params: float = 0.0  # trace of the data rows' hat matrix (< n_params with the smoothness prior)
    options: FitOptions | None = None  # the settings it ran with (error budgets refit with them)


def _make_solver(o: FitOptions):
    if o.solver == "levenberg_marquardt":
        return optx.LevenbergMarquardt(rtol=o.rtol, atol=o.atol)
    if o.solver == "dogleg":
        return optx.Dogleg(rtol=o.rtol, atol=o.atol)
    if o.solver == "gauss_newton":
        return optx.GaussNewton(rtol=o.rtol, atol=o.atol)
    return optx.BFGS(rtol=o.rtol, atol=o.atol)


@eqx.filter_jit
def _result_arrays(problem: Problem, params: dict) -> dict:
    """What `_result` reports beyond the residuals and their Jacobian, as one program (five
    programs' tracing, lowering and cache reads would be Python work in every new process):
    the physical vector's Jacobian, the data residuals, the physical quantities and the
    models at the data points."""
    spec = problem.spec
    lobe, wave = _model_curves(problem, params)
    return {
        "G": _physical_jacobian_of(spec, params),
        "data_res": problem.data_residuals(params),
        "phys": spec.physical(params),
        "lobe_db": lobe,
        "wave_phase": wave,
    }


# -- the stepped solve ---------------------------------------------------------------------


def _solver_fn(solver):
    return _cost_aux if isinstance(solver, optx.AbstractMinimiser) else _residual_aux


# A materialised Jacobian (reverse mode): its operator holds arrays only, so the solver state can
# cross the jit boundary between steps (a linearised one holds a jaxpr whose constants differ
# between the traces of `init` and `step`). m x n is small here (hundreds x up to ~250).
_SOLVER_OPTIONS = MappingProxyType({"jac": "bwd"})


@eqx.filter_jit
def _init_state(solver, y, args):
    fn = _solver_fn(solver)
    f_struct, aux_struct = jax.eval_shape(lambda: fn(y, args))
    return solver.init(fn, y, args, _SOLVER_OPTIONS, f_struct, aux_struct, frozenset())


@eqx.filter_jit
def _step(solver, y, state, args):
    """One optimistix step; returns the accepted point, the state, optimistix's verdict and the
    residuals at the accepted point (for our convergence test and the trace)."""
    fn = _solver_fn(solver)
    y_new, state, _ = solver.step(fn, y, args, _SOLVER_OPTIONS, state, frozenset())
    done, result = solver.terminate(fn, y_new, args, _SOLVER_OPTIONS, state, frozenset())
    r, _ = _residual_aux(y_new, args)
    moved = jnp.any(ravel_pytree(y_new)[0] != ravel_pytree(y)[0])
    return y_new, state, done, result, r, moved


def _free(y: dict, hold: frozenset) -> dict:
    return {k: v for k, v in y.items() if k not in hold}


def _flat_jacobian(jac: dict, params: dict) -> jnp.ndarray:
    """A Jacobian computed w.r.t. a dict of parameters, as (m, n) in `ravel_pytree` order."""
    cols = []
    for k in sorted(params):
        j = jac[k]
        m = j.shape[0]
        cols.append(j.reshape(m, -1))
    return jnp.concatenate(cols, axis=1)


@eqx.filter_jit
def _jacobian(problem: Problem, fixed: dict, params: dict):
    """Jacobian of the residuals w.r.t. the free parameters, (m, n) in `ravel_pytree` order."""
    jac = jax.jacfwd(lambda p: problem.residuals({**fixed, **p}))(params)
    return _flat_jacobian(jac, params)


def _physical_jacobian_of(spec: ModelSpec, params: dict):
    jac = jax.jacfwd(lambda p: _physical_values(spec, p))(params)
    return _flat_jacobian(jac, params)


_physical_jacobian = eqx.filter_jit(_physical_jacobian_of)


def _stationarity(problem: Problem, fixed: dict, y: dict, r: np.ndarray) -> tuple[float, float]:
    """(relative, in SE) further decrease the Gauss-Newton model predicts from `y`: the
    predicted decrease 0.5 ||J dy||^2 over the cost, and ||J dy|| / sqrt(max(chi2_red, 1))."""
    J = np.asarray(_jacobian(problem, fixed, y))
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(r))):
        return math.inf, math.inf
    dy = np.linalg.lstsq(J, r, rcond=None)[0]
    jd = J @ dy
    cost = 0.5 * float(r @ r)
    dof = max(len(r) - J.shape[1], 1)
    pred = 0.5 * float(jd @ jd)
    return pred / max(cost, 1e-300), math.sqrt(2 * pred / max(2 * cost / dof, 1.0))


@dataclass
class _Stage:
    y: dict
    converged: bool
    code: str
    reason: str
    n_steps: int
    n_accepted: int
    rel_cost: float
    step_se: float
    compile_s: float
    cost: list
    accepted: list
    step_s: list


def _run_stage(
    problem: Problem, y0: dict, options: FitOptions, *, hold: frozenset = frozenset(), stage: int, bar=None
) -> _Stage:
    """Step the solver from `y0` (every parameter) until optimistix's test or ours says converged,
    or max_steps; the parameters named in `hold` keep their values in `y0`."""
    solver = _make_solver(options)
    # strongly typed leaves: a weakly typed start would make the second step compile again
    y0 = jax.tree_util.tree_map(lambda v: device_array(np.asarray(v)), y0)
    free = {k: device_array(np.asarray(k not in hold)) for k in y0}
    args = (problem, y0, free)
    fixed = {k: y0[k] for k in hold}  # for the stationarity test's Jacobian (the free ones only)
    w = CONVERGENCE_WINDOW
    r0 = np.asarray(_residuals(problem, y0))
    npar = int(sum(np.size(v) for k, v in y0.items() if k not in hold))
    dof = max(len(r0) - npar, 1)
    hist = [(0.5 * float(r0 @ r0), r0)]  # accepted iterates (cost, residuals), the start included
    costs, accepted, times = [], [], []
    state = _init_state(solver, y0, args)
    y = y0
    code, reason, conv = "max_steps_reached", "", False
    rel_cost = step_se = math.inf
    since = 0
    for k in range(1, options.max_steps + 1):
        t0 = time.perf_counter()
        y, state, done, result, r, moved = _step(solver, y, state, args)
        r = np.asarray(r)
        times.append(time.perf_counter() - t0)
        cost = 0.5 * float(r @ r)
        moved = bool(moved)
        costs.append(cost)
        accepted.append(moved)
        if bar is not None:
            bar.update(1)
            bar.set_postfix(stage=stage, cost=f"{cost:.4g}")
        if not np.isfinite(cost):
            code, reason = "nonfinite", f"non-finite cost at step {k}"
            break
        since = 0 if moved else since + 1
        if moved:
            hist.append((cost, r))
        if bool(done):
            conv = bool(result == optx.RESULTS.successful)
            code = _result_name(result)
            reason = "optimistix's rtol/atol test passed" if conv else f"optimistix stopped: {code}"
            break
        if len(hist) > w:
            (c_old, r_old), (c_new, r_new) = hist[-1 - w], hist[-1]
            rel_cost = (c_old - c_new) / max(c_new, 1e-300)
            step_se = float(np.linalg.norm(r_new - r_old)) / math.sqrt(max(2 * c_new / dof, 1.0))
            if moved and rel_cost <= options.rtol_cost and step_se <= options.rtol_step:
                conv, code = True, "converged"
                reason = (
                    f"cost changed by {rel_cost:.2g} (relative) and the residuals by {step_se:.2g} standard "
                    f"errors over the last {w} accepted steps (rtol_cost {options.rtol_cost:g}, "
                    f"rtol_step {options.rtol_step:g})"
                )
                break
        if since >= 2 * w:  # many rejections in a row: test for a stationary point
            rc, se = _stationarity(problem, fixed, _free(y, hold), r)
            if rc <= options.rtol_cost and se <= options.rtol_step:
                conv, code = True, "stationary"
                reason = (
                    f"stationary: after {since} rejected steps the Gauss-Newton model predicts a further "
                    f"relative decrease of {rc:.2g} ({se:.2g} standard errors)"
                )
                rel_cost, step_se = rc, se
                break
            since = 0
    else:
        rc, se = _stationarity(problem, fixed, _free(y, hold), np.asarray(_residuals(problem, {**y, **fixed})))
        if rc <= options.rtol_cost and se <= options.rtol_step:
            conv, code = True, "stationary"
            reason = (
                f"stationary at max_steps: the Gauss-Newton model predicts a further relative decrease "
                f"of {rc:.2g} ({se:.2g} standard errors)"
            )
        else:
            reason = (
                f"max_steps = {options.max_steps} reached: the cost still changes by {rel_cost:.2g} (relative) "
                f"over the last {w} accepted steps (rtol_cost {options.rtol_cost:g}) and the Gauss-Newton model "
                f"predicts a further decrease of {rc:.2g} ({se:.2g} standard errors, rtol_step "
                f"{options.rtol_step:g})"
            )
        rel_cost, step_se = min(rel_cost, rc), min(step_se, se)
    # the first call for a new model structure compiles the step (the second may too, where the
    # start's dtypes differ): take the typical step time for them, book the rest as compilation
    dt = np.asarray(times, float)
    compile_s = 0.0
    if len(dt) >= 3:
        typical = float(np.median(dt[2:]))
        extra = np.clip(dt[:2] - typical, 0, None)
        compile_s = float(extra.sum())
        dt[:2] -= extra
    n_acc = len(hist) - 1
    return _Stage(
        y={**y, **fixed},  # the held parameters exactly as given (the solver never moves them)
        converged=conv,
        code=code,
        reason=reason,
        n_steps=len(costs),
        n_accepted=n_acc,
        rel_cost=float(rel_cost),
        step_se=float(step_se),
        compile_s=compile_s,
        cost=costs,
        accepted=accepted,
        step_s=dt.tolist(),
    )


def _relaxed(problem: Problem, lobe_sigma_db: float = 1.0, wave_sigma_rad: float = math.radians(5.0)) -> Problem:
    """The same problem with sigmas floored: a smoother cost for the first stage of the fit."""
    out = problem
    if problem.lobe_sigma is not None:
        out = eqx.tree_at(lambda q: q.lobe_sigma, out, jnp.maximum(problem.lobe_sigma, lobe_sigma_db))
    if problem.wave_sigma is not None:
        out = eqx.tree_at(lambda q: q.wave_sigma, out, jnp.maximum(problem.wave_sigma, wave_sigma_rad))
    return out


def _finite(tree) -> bool:
    return bool(np.all(np.isfinite(np.asarray(ravel_pytree(tree)[0]))))


def fit(
    spec: ModelSpec,
    transfer: Transfer,
    lobe: LobeData | None = None,
    wave: WaveData | None = None,
    options: FitOptions = FitOptions(),
    *,
    params0: dict | None = None,
    progress: bool = False,
    multistart: bool = False,
) -> FitResult:
    """Fit `spec` to the data. Never raises on non-convergence: the result says so (`converged`,
    `result_code`, `convergence`, `warnings`). `progress` shows a bar of solver steps with the cost.

    Continuation in three stages, each from the previous one's result: (1) when the diameter is
    fitted and no start is given, only the diameter and the offsets, the profiles held uniform;
    (2) everything, with the sigmas floored at 1 dB and 5 deg (a smoother cost: with 0.05 dB
    sigmas the first long steps of a free profile can jump to a far local minimum, e.g. an
    aperture dominated by its edges); (3) everything with the measured sigmas. The reported
    convergence is that of the last stage.

    `multistart` (with a `params0` whose diameter is fitted, e.g. a user's start diameter): the
    first stage runs from `params0` and from the diameter scan's best start, and the fit goes on
    from the lower cost: a lobe's cost in D has a local minimum near every null, so a start far
    from the truth (0.75 x, 1.3 x) would otherwise stay in one."""
    t_start = time.perf_counter()
    problem = build_problem(spec, transfer, lobe, wave, options)
    p0 = initial_params(problem, params0)
    starts = [p0]
    if multistart and params0 is not None and "diam" in p0:
        starts.append(initial_params(problem, None))
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(desc="fit", unit="step")
    try:
        stages = _fit_stages(problem, starts, options, params0 is None, bar)
    finally:
        if bar is not None:
            bar.close()
    return _result(problem, spec, stages, options, lobe, wave, time.perf_counter() - t_start)


def _fit_stages(
    problem: Problem, starts: dict | list[dict], options: FitOptions, scan: bool, bar
) -> list[tuple[int, _Stage]]:
    """The stages from one start (a dict) or the first stage from each of several (a list), the
    rest from the best of those."""
    starts = [starts] if isinstance(starts, dict) else list(starts)
    out = []
    p0 = start = starts[0]
    profiles = frozenset(k for k in p0 if k in ("w", "lag"))
    if (profiles and scan and "diam" in p0) or len(starts) > 1:
        firsts = [_run_stage(_relaxed(problem), p, options, hold=profiles, stage=1, bar=bar) for p in starts]
        ok = [s for s in firsts if _finite(s.y)]
        s1 = min(ok, key=lambda s: s.cost[-1] if s.cost else math.inf) if ok else firsts[0]
        out.append((1, s1))
        if _finite(s1.y):
            start = s1.y
    s2 = _run_stage(_relaxed(problem), start, options, stage=2, bar=bar)
    out.append((2, s2))
    start = s2.y if _finite(s2.y) else start
    out.append((3, _run_stage(problem, start, options, stage=3, bar=bar)))
    return out


def _trace(stages: list[tuple[int, _Stage]]) -> FitTrace:
    st: list[int] = []
    cost: list[float] = []
    acc: list[bool] = []
    dt: list[float] = []
    summary: list[dict] = []
    for n, s in stages:
        summary.append(
            {
                "stage": n,
                "name": STAGE_NAMES[n],
                "first_iteration": len(cost) + 1,
                "n_steps": s.n_steps,
                "n_accepted": s.n_accepted,
                "compile_s": s.compile_s,
                "converged": s.converged,
                "result_code": s.code,
                "reason": s.reason,
            }
        )
        st += [n] * s.n_steps
        cost += s.cost
        acc += s.accepted
        dt += s.step_s
    return FitTrace(
        stage=np.asarray(st, int),
        cost=np.asarray(cost, float),
        accepted=np.asarray(acc, bool),
        step_s=np.asarray(dt, float),
        stages=tuple(summary),
    )


def _result(problem: Problem, spec: ModelSpec, stages, options: FitOptions, lobe, wave, wall: float) -> FitResult:
    last = stages[-1][1]
    params = jax.block_until_ready(last.y)
    y, _ = ravel_pytree(params)
    warnings = []
    finite = bool(np.all(np.isfinite(np.asarray(y))))
    r = np.asarray(_residuals(problem, params))
    converged = last.converged
    if not finite or not np.all(np.isfinite(r)):
        warnings.append("NON-FINITE parameters or residuals: the fit failed; check the data and the start point")
        converged = False
    n_steps = sum(s.n_steps for _, s in stages)
    if not converged:
        warnings.append(
            f"FIT DID NOT CONVERGE ({last.code} after {n_steps} steps): {last.reason}. The results below "
            "are the last iterate, not an optimum; raise solver.max_steps or check the model"
        )

    # statistical covariance (not inflated) and the quick inflated standard errors
    J = np.asarray(_jacobian(problem, {}, params))
    m, npar = J.shape
    cost = 0.5 * float(np.sum(r * r))
    finite = finite and bool(np.all(np.isfinite(J)))
    if finite:
        _, s, vt = np.linalg.svd(J, full_matrices=False)
    else:
        s, vt = np.array([1.0, 0.0]), np.eye(npar)
    cond = float(s[0] / s[-1]) if s[-1] > 0 else math.inf
    rank_def = not (cond < 1e8)
    if rank_def:
        warnings.append(
            f"ill-conditioned: Jacobian condition number {cond:.3g}; some parameters are not "
            "determined by the data: the error budget names them"
        )
    null = vt[s < s[0] * 1e-6].T if finite else np.eye(npar)
    cov_raw = np.linalg.pinv(J.T @ J, rcond=1e-12, hermitian=True) if finite else np.full((npar, npar), np.nan)
    # effective number of parameters: trace of the hat matrix of the data rows (the smoothness
    # prior's rows come first): what the data pay for, for model comparison
    n_prior = sum(
        spec.n_cells - 2
        for key, prof in (("w", spec.weights), ("lag", spec.lags))
        if key in params and prof in ("free", "symmetric")
    )
    Jd = J[n_prior:]
    edf = float(np.trace(Jd @ cov_raw @ Jd.T)) if finite else float(npar)
    labels = spec.raw_labels(params)
    se_raw = np.sqrt(np.clip(np.diag(cov_raw), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov_raw / np.outer(se_raw, se_raw)
    arrays = jax.tree_util.tree_map(np.asarray, _result_arrays(problem, params))
    phys_labels = _physical_labels(spec)
    G = arrays["G"]
    # residual statistics: RMS per observable, outliers, chi2 of all data points
    data_res = arrays["data_res"]
    goodness = goodness_of_fit(
        data_res, J[n_prior:], cov_raw if finite else None, npar, _datum_weights(problem, arrays)
    )
    # degrees of freedom per measured datum (a wavefront point is one phase, whose chord residual
    # is minimised as the pair (sin d, 1 - cos d) of the same squared norm; a lobe level below
    # the soft floor counts as the share of a datum its residual carries) and per prior row
    n_data = goodness["joint"]["n_data"] if goodness else float(m - n_prior)
    dof = max(int(round(n_data)) + n_prior - npar, 1)
    chi2 = 2 * cost / max(n_data + n_prior - npar, 1.0)
    chi2_data, var_factor = _chi2_and_variance_factor(data_res, options, npar, chi2)
    if options.loss == "l2" and "joint" in goodness:
        chi2_data = goodness["joint"]["chi2_reduced"]
    se = np.sqrt(np.clip(np.diag(G @ cov_raw @ G.T), 0, None) * max(var_factor, 1.0))
    stderr = {lab: float(v) for lab, v in zip(phys_labels, se)}
    outliers = outlier_diagnostics(data_res)
    for name, o in outliers.items():
        if not o["suspect"]:
            continue
        what = {"lobe": "lobe points", "wave": "wavefront points"}[name]
        if options.loss == "l2":
            warnings.append(
                f"OUTLIERS: {o['n_outliers']} of {o['n']} {what} lie more than {OUTLIER_SIGMAS:g} robust "
                f"sigmas from the model (residual RMS {o['rms']:.3g} vs robust sigma {o['robust_sigma']:.3g}; "
                f'chi2_red {chi2_data:.3g}): the l2 fit is pulled by them; use solver.loss = "huber" or '
                '"cauchy", or mask them out'
            )
        else:
            warnings.append(
                f"outliers: {o['n_outliers']} of {o['n']} {what} lie more than {OUTLIER_SIGMAS:g} robust "
                f"sigmas from the model; the {options.loss} loss (scale {options.loss_scale:g} sigma) "
                "down-weights them"
            )
    if var_factor > 1 + 4 * math.sqrt(2 / dof) + 0.1 and not any(o["suspect"] for o in outliers.values()):
        warnings.append(
            f"chi2_red = {chi2_data:.3g}: the residuals exceed the stated noise (model inadequacy or "
            "underestimated sigmas); the error budget's model term inflates the errors by sqrt(chi2_red)"
        )

    phys = arrays["phys"]
    rms = {}
    curves = {}
    if lobe is not None:
        mdb = arrays["lobe_db"]
        curves["lobe_db"] = mdb
        floor = problem.lobe_floor
        assert floor is not None  # set with the lobe data (build_problem)
        above = lobe.level_db > floor
        sm = soft_floor_db(mdb, floor)
        sd = soft_floor_db(lobe.level_db, floor)
        rms["lobe_db"] = float(np.sqrt(np.mean((mdb[above] - lobe.level_db[above]) ** 2)))
        rms["lobe_db_all_points_soft_floor"] = float(np.sqrt(np.mean((sm - sd) ** 2)))
        rms["lobe_normalised"] = float(np.sqrt(np.mean(((sm - sd) / lobe.sigma_db) ** 2)))
    if wave is not None:
        mph = arrays["wave_phase"]
        curves["wave_phase_rad"] = mph
        d = np.angle(np.exp(1j * (mph - wave.phase_rad)))
        rms["wave_phase_deg"] = float(np.degrees(np.sqrt(np.mean(d**2))))
        rms["wave_normalised"] = float(np.sqrt(np.mean((d / wave.sigma_rad) ** 2)))
    convergence = {
        "converged": converged,
        "result_code": last.code,
        "reason": last.reason,
        "rel_cost_change": last.rel_cost,
        "step_standard_errors": last.step_se,
        "rtol_cost": options.rtol_cost,
        "rtol_step": options.rtol_step,
        "window": CONVERGENCE_WINDOW,
        "stages": [
            {"stage": n, "converged": s.converged, "result_code": s.code, "n_steps": s.n_steps} for n, s in stages
        ],
    }
    return FitResult(
        spec=spec,
        params=params,
        physical=phys,
        converged=converged,
        result_code=last.code,
        n_steps=n_steps,
        wall_time_s=wall,
        cost=cost,
        chi2_reduced=chi2_data,
        rms=rms,
        stderr=stderr,
        correlation=corr,
        correlation_labels=labels,
        condition_number=cond,
        rank_deficient=rank_def,
        trace=_trace(stages),
        model_curves=curves,
        warnings=warnings,
        convergence=convergence,
        covariance_raw=cov_raw,
        raw_labels=labels,
        null_space=null,
        dof=dof,
        goodness=goodness,
        outliers=outliers,
        loss=options.loss,
        variance_factor=var_factor,
        effective_params=edf,
        options=options,
    )


def physical_vector(spec: ModelSpec, params: dict):
    """(vector, labels) of the physical quantities: per-cell weights `w[k]` (aperture applied),
    lags `lag_us[k]` (µs), `diameter_mm`, `gain_db`, `phase0_deg`."""
    return _physical_vector(spec, params)


def _physical_vector(spec: ModelSpec, params: dict):
    return _physical_array(spec, params), _physical_labels(spec)


def _physical_labels(spec: ModelSpec) -> list[str]:
    return (
        [f"w[{k}]" for k in range(spec.n_cells)]
        + [f"lag_us[{k}]" for k in range(spec.n_cells)]
        + ["diameter_mm", "gain_db", "phase0_deg"]
    )


@eqx.filter_jit
def _physical_array(spec: ModelSpec, params: dict):
    return _physical_values(spec, params)


def _physical_values(spec: ModelSpec, params: dict):
    ph = spec.physical(params)
    return jnp.concatenate(
        [
            ph["weights"],
            ph["lags_s"] * 1e6,
            jnp.atleast_1d(ph["diameter_m"] * 1e3),
            jnp.atleast_1d(ph["gain_db"]),
            jnp.atleast_1d(jnp.degrees(ph["phase0_rad"])),
        ]
    )


def physical_jacobian(spec: ModelSpec, params: dict) -> np.ndarray:
    """d physical_vector / d raw parameters, (n_physical, n_raw) in `ravel_pytree` order."""
    return np.asarray(_physical_jacobian(spec, params))


def residual_jacobian(problem: Problem, params: dict) -> np.ndarray:
    """Jacobian of the minimised residuals w.r.t. the raw parameters (`ravel_pytree` order)."""
    return np.asarray(_jacobian(problem, {}, params))


def residual_vector(problem: Problem, params: dict) -> np.ndarray:
    return np.asarray(_residuals(problem, params))


def _result_name(result) -> str:
    for name in (
        "successful",
        "max_steps_reached",
        "nonlinear_max_steps_reached",
        "nonlinear_divergence",
        "singular",
        "breakdown",
        "nonfinite",
    ):
        v = getattr(optx.RESULTS, name, None)
        if v is not None and result == v:
            return name
    return str(result)
