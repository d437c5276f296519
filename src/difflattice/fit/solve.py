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
from types import MappingProxyType

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree

from .data import LobeData, WaveData
from .family import FamilyParams, ModelFamily
from .model import device_array
from .options import CONVERGENCE_WINDOW, SOLVERS, STAGE_NAMES, FitOptions, Loss, Solver
from .problem import Problem, _cost_aux, _residual_aux, _residuals, build_problem, initial_params
from .programs import small_jit
from .result import (
    FitResult,
    FitTrace,
    _jacobian,
    _result,
    _Stage,
    physical_jacobian,
    physical_vector,
    residual_jacobian,
    residual_vector,
)
from .transfer import Transfer

__all__ = [
    "CONVERGENCE_WINDOW",
    "SOLVERS",
    "STAGE_NAMES",
    "FitOptions",
    "FitResult",
    "FitTrace",
    "Loss",
    "Solver",
    "fit",
    "physical_jacobian",
    "physical_vector",
    "residual_jacobian",
    "residual_vector",
]


def _make_solver(o: FitOptions):
    if o.solver == "levenberg_marquardt":
        return optx.LevenbergMarquardt(rtol=o.rtol, atol=o.atol)
    if o.solver == "dogleg":
        return optx.Dogleg(rtol=o.rtol, atol=o.atol)
    if o.solver == "gauss_newton":
        return optx.GaussNewton(rtol=o.rtol, atol=o.atol)
    return optx.BFGS(rtol=o.rtol, atol=o.atol)


# -- the stepped solve ---------------------------------------------------------------------


def _solver_fn(solver):
    return _cost_aux if isinstance(solver, optx.AbstractMinimiser) else _residual_aux


# A materialised Jacobian (reverse mode): its operator holds arrays only, so the solver state can
# cross the jit boundary between steps (a linearised one holds a jaxpr whose constants differ
# between the traces of `init` and `step`). m x n is small here (hundreds x up to ~250).
_SOLVER_OPTIONS = MappingProxyType({"jac": "bwd"})


@small_jit
def _init_state(solver, y, args):
    fn = _solver_fn(solver)
    f_struct, aux_struct = jax.eval_shape(lambda: fn(y, args))
    return solver.init(fn, y, args, _SOLVER_OPTIONS, f_struct, aux_struct, frozenset())


@small_jit
def _step(solver, y, state, args):
    """One optimistix step; returns the accepted point, the state, optimistix's verdict and the
    residuals at the accepted point (for our convergence test and the trace)."""
    fn = _solver_fn(solver)
    y_new, state, _ = solver.step(fn, y, args, _SOLVER_OPTIONS, state, frozenset())
    done, result = solver.terminate(fn, y_new, args, _SOLVER_OPTIONS, state, frozenset())
    r, _ = _residual_aux(y_new, args)
    moved = jnp.any(ravel_pytree(y_new)[0] != ravel_pytree(y)[0])
    # optimistix's verdict as an index into _RESULT_NAMES, computed here: compared outside, each
    # `result == RESULTS.x` would be an eager program of its own in a fresh process
    codes = [getattr(optx.RESULTS, n) for n in _RESULT_NAMES]
    code = jnp.argmax(jnp.stack([result == c for c in codes] + [jnp.asarray(True)]))
    return y_new, state, done, code, r, moved


def _free_mask(y0: FamilyParams, hold: frozenset, keep: np.ndarray | None) -> np.ndarray:
    """(n_params,) bool in `ravel_pytree` order: the parameters a stage moves (not named in
    `hold`, and marked by `keep` where given: the extra coefficients of a richer family the fit is
    solved in stay at zero)."""
    flat = np.concatenate([np.full(np.size(getattr(y0, k)), k not in hold) for k in y0.names()])
    return flat if keep is None else flat & keep


def _per_leaf(y0: FamilyParams, flat: np.ndarray) -> FamilyParams:
    """A flat (n_params,) array in `ravel_pytree` order as arrays of `y0`'s structure."""
    out, i = {}, 0
    for k in y0.names():
        shape = np.shape(getattr(y0, k))
        n = int(np.prod(shape, dtype=int))
        out[k] = device_array(flat[i : i + n].reshape(shape))
        i += n
    return y0.replace(**out)


def _stationarity(problem: Problem, free: np.ndarray, y: FamilyParams, r: np.ndarray) -> tuple[float, float]:
    """(relative, in SE) further decrease the Gauss-Newton model predicts from `y` moving the
    parameters `free` marks: the predicted decrease 0.5 ||J dy||^2 over the cost, and
    ||J dy|| / sqrt(max(chi2_red, 1))."""
    J = np.asarray(_jacobian(problem, None, y))[:, free]
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(r))):
        return math.inf, math.inf
    dy = np.linalg.lstsq(J, r, rcond=None)[0]
    jd = J @ dy
    cost = 0.5 * float(r @ r)
    dof = max(len(r) - J.shape[1], 1)
    pred = 0.5 * float(jd @ jd)
    return pred / max(cost, 1e-300), math.sqrt(2 * pred / max(2 * cost / dof, 1.0))


def _run_stage(
    problem: Problem,
    y0: FamilyParams,
    options: FitOptions,
    *,
    hold: frozenset = frozenset(),
    keep: np.ndarray | None = None,
    stage: int,
    bar=None,
) -> _Stage:
    """Step the solver from `y0` (every parameter) until optimistix's test or ours says converged,
    or max_steps; the parameters named in `hold`, and those `keep` (flat, `ravel_pytree` order)
    marks False, keep their values in `y0`. Which parameters are held is data (a boolean per
    element): every stage, and every fit of one model structure, runs the same compiled programs."""
    solver = _make_solver(options)
    # strongly typed leaves: a weakly typed start would make the second step compile again
    y0 = jax.tree_util.tree_map(lambda v: device_array(np.asarray(v)), y0)
    free_flat = _free_mask(y0, hold, keep)
    free = _per_leaf(y0, free_flat)
    args = (problem, y0, free)
    w = CONVERGENCE_WINDOW
    r0 = np.asarray(_residuals(problem, y0))
    npar = int(free_flat.sum())
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
        y, state, done, result_index, r, moved = _step(solver, y, state, args)
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
            code = _result_name(int(result_index))
            conv = code == "successful"
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
            rc, se = _stationarity(problem, free_flat, _held(y, y0, free), r)
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
        y_held = _held(y, y0, free)
        rc, se = _stationarity(problem, free_flat, y_held, np.asarray(_residuals(problem, y_held)))
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
        y=_held(y, y0, free),  # the held parameters exactly as given (the solver never moves them)
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


def _held(y: FamilyParams, y0: FamilyParams, free: FamilyParams) -> FamilyParams:
    """`y` with the parameters `free` marks False exactly as in `y0` (on the host: no program)."""
    return jax.tree_util.tree_map(lambda a, b, f: device_array(np.where(np.asarray(f), a, b)), y, y0, free)


def _relaxed(problem: Problem, lobe_sigma_db: float = 1.0, wave_sigma_rad: float = math.radians(5.0)) -> Problem:
    """The same problem with sigmas floored: a smoother cost for the first stage of the fit."""
    out = problem
    # on the host (eager jnp.maximum would be a program of its own in every fresh process)
    if problem.lobe_sigma is not None:
        floored = device_array(np.maximum(np.asarray(problem.lobe_sigma), lobe_sigma_db))
        out = eqx.tree_at(lambda q: q.lobe_sigma, out, floored)
    if problem.wave_sigma is not None:
        floored = device_array(np.maximum(np.asarray(problem.wave_sigma), wave_sigma_rad))
        out = eqx.tree_at(lambda q: q.wave_sigma, out, floored)
    return out


def _finite(tree) -> bool:
    return all(bool(np.all(np.isfinite(np.asarray(v)))) for v in jax.tree_util.tree_leaves(tree))


def fit(
    spec: ModelFamily,
    transfer: Transfer,
    lobe: LobeData | None = None,
    wave: WaveData | None = None,
    options: FitOptions = FitOptions(),
    *,
    params0: FamilyParams | None = None,
    progress: bool = False,
    multistart: bool = False,
    solve_in: ModelFamily | None = None,
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
    from the truth (0.75 x, 1.3 x) would otherwise stay in one.

    `solve_in`: a richer family `spec` nests in (`spec.nests_in`: more basis functions), e.g. the
    error budget's refit with one more; the fit is solved there with the extra coefficients held
    at zero (the same optimum, to rounding), so that fit's compiled programs are this one's: in a
    fresh process they compile once for both. The result is `spec`'s (the extra columns dropped)
    and records the family in `solved_in`, for refits from it."""
    t_start = time.perf_counter()
    _check_params(spec, params0, "params0")
    if solve_in is not None and not spec.nests_in(solve_in):
        raise ValueError(
            f"solve_in must be the model with more basis functions for its smooth profile(s) (n_basis > "
            f"{spec.n_basis}, everything else equal); got {solve_in!r} for {spec!r}"
        )
    big = solve_in or spec
    problem = build_problem(big, transfer, lobe, wave, options)
    if solve_in is not None and params0 is not None:
        params0 = spec.pad_params(params0, solve_in)
    p0 = initial_params(problem, params0)
    keep = None if solve_in is None else spec.kept_in(p0, solve_in)
    starts = [p0]
    if multistart and params0 is not None and p0.has("diam"):
        starts.append(initial_params(problem, None))
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(desc="fit", unit="step")
    try:
        stages = _fit_stages(problem, starts, options, params0 is None, bar, keep)
    finally:
        if bar is not None:
            bar.close()
    return _result(problem, spec, stages, options, lobe, wave, time.perf_counter() - t_start, solved_in=solve_in)


def _check_params(spec: ModelFamily, params: object, name: str) -> None:
    """A start must be the family's parameter module (a dict, as before, is refused by name)."""
    if params is not None and not isinstance(params, FamilyParams):
        kind = type(spec.init_params()).__name__
        raise TypeError(
            f"{name} is a {type(params).__name__}; give the family's parameter module ({kind}), e.g. "
            f"spec.init_params() or dataclasses.replace(spec.init_params(), diam=...)"
        )


def _fit_stages(
    problem: Problem,
    starts: FamilyParams | list[FamilyParams],
    options: FitOptions,
    scan: bool,
    bar,
    keep: np.ndarray | None = None,
) -> list[tuple[int, _Stage]]:
    """The stages from one start or the first stage from each of several (a list), the rest from
    the best of those (`keep`: as for `_run_stage`)."""
    starts = [starts] if isinstance(starts, FamilyParams) else list(starts)
    out = []
    p0 = start = starts[0]
    profiles = frozenset(k for k in p0.names() if k in ("w", "lag"))
    if (profiles and scan and p0.has("diam")) or len(starts) > 1:
        firsts = [_run_stage(_relaxed(problem), p, options, hold=profiles, keep=keep, stage=1, bar=bar) for p in starts]
        ok = [s for s in firsts if _finite(s.y)]
        s1 = min(ok, key=lambda s: s.cost[-1] if s.cost else math.inf) if ok else firsts[0]
        out.append((1, s1))
        if _finite(s1.y):
            start = s1.y
    s2 = _run_stage(_relaxed(problem), start, options, keep=keep, stage=2, bar=bar)
    out.append((2, s2))
    start = s2.y if _finite(s2.y) else start
    out.append((3, _run_stage(problem, start, options, keep=keep, stage=3, bar=bar)))
    return out


_RESULT_NAMES = tuple(
    n
    for n in (
        "successful",
        "max_steps_reached",
        "nonlinear_max_steps_reached",
        "nonlinear_divergence",
        "singular",
        "breakdown",
        "nonfinite",
    )
    if getattr(optx.RESULTS, n, None) is not None
)


def _result_name(index: int) -> str:
    """The name of optimistix's verdict from `_step`'s index ("other" for one not listed)."""
    return _RESULT_NAMES[index] if index < len(_RESULT_NAMES) else "other"
