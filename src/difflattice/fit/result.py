"""A fit's outcome (`FitResult`, its `FitTrace`) assembled from the solver's stages in named
steps: the statistical covariance and conditioning, goodness of fit and its warnings, residual
RMS and model curves, the convergence record."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import jax
import numpy as np

from .data import LobeData, WaveData
from .family import FamilyParams, ModelFamily
from .goodness import (
    OUTLIER_SIGMAS,
    _chi2_and_variance_factor,
    _datum_weights,
    goodness_of_fit,
    outlier_diagnostics,
)
from .model import soft_floor_db
from .options import CONVERGENCE_WINDOW, STAGE_NAMES, FitOptions
from .problem import (
    Problem,
    _evaluate,
    _flat_jacobian,
    _physical_jacobian_of,
    _physical_values,
    _residuals,
)
from .programs import small_jit


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

    spec: ModelFamily
    params: FamilyParams
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
    solved_in: ModelFamily | None = None  # the richer family it was solved in (`fit`'s `solve_in`), for refits from it


@dataclass
class _Stage:
    y: FamilyParams
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


@small_jit
def _jacobian(problem: Problem, fixed: FamilyParams | None, params: FamilyParams):
    """Jacobian of the residuals w.r.t. the free parameters `params` (those present in `fixed`
    held there), (m, n) in `ravel_pytree` order."""
    jac = jax.jacfwd(lambda p: problem.residuals(p.merged(fixed)))(params)
    return _flat_jacobian(jac, params)


_physical_jacobian = small_jit(_physical_jacobian_of)


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


def _result(
    problem: Problem,
    spec: ModelFamily,
    stages: list[tuple[int, _Stage]],
    options: FitOptions,
    lobe: LobeData | None,
    wave: WaveData | None,
    wall: float,
    *,
    solved_in: ModelFamily | None = None,
) -> FitResult:
    """Assemble the `FitResult` of a solve from its stages (the last one's point is the solution).
    With `solved_in` (the richer family `problem` is of, see `fit`'s `solve_in`) every array is
    computed there and the extra coefficients' columns dropped: the same numbers as `spec`'s own
    programs give, from the programs that family's fits compile anyway."""
    last = stages[-1][1]
    y = jax.block_until_ready(last.y)  # in the family `problem` is of
    keep = slice(None) if solved_in is None else spec.kept_in(y, solved_in)
    params = y if solved_in is None else spec.unpad_params(y, solved_in)
    warnings = []
    finite = all(bool(np.all(np.isfinite(np.asarray(v)))) for v in jax.tree_util.tree_leaves(params))
    arrays = jax.tree_util.tree_map(np.asarray, _evaluate(problem, y))
    r = arrays["r"]
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
    J = arrays["J"][:, keep]
    m, npar = J.shape
    cost = 0.5 * float(np.sum(r * r))
    cv = _Covariance.of(J, spec, params, finite and bool(np.all(np.isfinite(J))))
    if cv.rank_deficient:
        warnings.append(
            f"ill-conditioned: Jacobian condition number {cv.condition_number:.3g}; some parameters are not "
            "determined by the data: the error budget names them"
        )
    arrays["G"] = arrays["G"][:, keep]
    # residual statistics: RMS per observable, outliers, chi2 of all data points
    data_res = arrays["data_res"]
    goodness = goodness_of_fit(
        data_res, J[cv.n_prior :], cv.cov_raw if cv.finite else None, npar, _datum_weights(problem, arrays)
    )
    # degrees of freedom per measured datum (a wavefront point is one phase, whose chord residual
    # is minimised as the pair (sin d, 1 - cos d) of the same squared norm; a lobe level below
    # the soft floor counts as the share of a datum its residual carries) and per prior row
    n_data = goodness["joint"]["n_data"] if goodness else float(m - cv.n_prior)
    dof = max(int(round(n_data)) + cv.n_prior - npar, 1)
    chi2 = 2 * cost / max(n_data + cv.n_prior - npar, 1.0)
    chi2_data, var_factor = _chi2_and_variance_factor(data_res, options, npar, chi2)
    if options.loss == "l2" and "joint" in goodness:
        chi2_data = goodness["joint"]["chi2_reduced"]
    G = arrays["G"]
    se = np.sqrt(np.clip(np.diag(G @ cv.cov_raw @ G.T), 0, None) * max(var_factor, 1.0))
    outliers = outlier_diagnostics(data_res)
    warnings += _residual_warnings(outliers, options, chi2_data, var_factor, dof)
    rms, curves = _rms_and_curves(problem, arrays, lobe, wave)
    return FitResult(
        spec=spec,
        params=params,
        physical=arrays["phys"],
        converged=converged,
        result_code=last.code,
        n_steps=n_steps,
        wall_time_s=wall,
        cost=cost,
        chi2_reduced=chi2_data,
        rms=rms,
        stderr={lab: float(v) for lab, v in zip(_physical_labels(spec), se)},
        correlation=cv.correlation,
        correlation_labels=cv.labels,
        condition_number=cv.condition_number,
        rank_deficient=cv.rank_deficient,
        trace=_trace(stages),
        model_curves=curves,
        warnings=warnings,
        convergence=_convergence_record(stages, converged, options),
        covariance_raw=cv.cov_raw,
        raw_labels=cv.labels,
        null_space=cv.null_space,
        dof=dof,
        goodness=goodness,
        outliers=outliers,
        loss=options.loss,
        variance_factor=var_factor,
        effective_params=cv.effective_params,
        options=options,
        solved_in=solved_in,
    )


@dataclass(frozen=True)
class _Covariance:
    """The statistical covariance (not inflated) of the raw parameters at the solution, with the
    conditioning, the null space, the correlations and the effective number of parameters."""

    finite: bool
    cov_raw: np.ndarray
    condition_number: float
    rank_deficient: bool
    null_space: np.ndarray
    n_prior: int
    effective_params: float
    correlation: np.ndarray
    labels: list

    @classmethod
    def of(cls, J: np.ndarray, spec: ModelFamily, params: FamilyParams, finite: bool) -> _Covariance:
        npar = J.shape[1]
        if finite:
            _, s, vt = np.linalg.svd(J, full_matrices=False)
        else:
            s, vt = np.array([1.0, 0.0]), np.eye(npar)
        cond = float(s[0] / s[-1]) if s[-1] > 0 else math.inf
        null = vt[s < s[0] * 1e-6].T if finite else np.eye(npar)
        cov_raw = np.linalg.pinv(J.T @ J, rcond=1e-12, hermitian=True) if finite else np.full((npar, npar), np.nan)
        # effective number of parameters: trace of the hat matrix of the data rows (the smoothness
        # prior's rows come first): what the data pay for, for model comparison
        n_prior = sum(
            spec.n_cells - 2
            for key, prof in (("w", spec.weights), ("lag", spec.lags))
            if params.has(key) and prof in ("free", "symmetric")
        )
        Jd = J[n_prior:]
        edf = float(np.trace(Jd @ cov_raw @ Jd.T)) if finite else float(npar)
        se_raw = np.sqrt(np.clip(np.diag(cov_raw), 0, None))
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = cov_raw / np.outer(se_raw, se_raw)
        return cls(
            finite=finite,
            cov_raw=cov_raw,
            condition_number=cond,
            rank_deficient=not (cond < 1e8),
            null_space=null,
            n_prior=n_prior,
            effective_params=edf,
            correlation=corr,
            labels=spec.raw_labels(params),
        )


def _residual_warnings(outliers: dict, options: FitOptions, chi2_data: float, var_factor: float, dof: int) -> list:
    """Warnings about outliers and residuals above the stated noise."""
    warnings = []
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
    return warnings


def _rms_and_curves(problem: Problem, arrays: dict, lobe: LobeData | None, wave: WaveData | None) -> tuple:
    """(RMS residual per observable, the model curves at the data points)."""
    rms: dict = {}
    curves: dict = {}
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
    return rms, curves


def _convergence_record(stages: list[tuple[int, _Stage]], converged: bool, options: FitOptions) -> dict:
    last = stages[-1][1]
    return {
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


def physical_vector(spec: ModelFamily, params: FamilyParams):
    """(vector, labels) of the physical quantities: per-cell weights `w[k]` (aperture applied),
    lags `lag_us[k]` (µs), `diameter_mm`, `gain_db`, `phase0_deg`."""
    return _physical_vector(spec, params)


def _physical_vector(spec: ModelFamily, params: FamilyParams):
    return _physical_array(spec, params), _physical_labels(spec)


def _physical_labels(spec: ModelFamily) -> list[str]:
    return (
        [f"w[{k}]" for k in range(spec.n_cells)]
        + [f"lag_us[{k}]" for k in range(spec.n_cells)]
        + ["diameter_mm", "gain_db", "phase0_deg"]
    )


@small_jit
def _physical_array(spec: ModelFamily, params: FamilyParams):
    return _physical_values(spec, params)


def physical_jacobian(spec: ModelFamily, params: FamilyParams) -> np.ndarray:
    """d physical_vector / d raw parameters, (n_physical, n_raw) in `ravel_pytree` order."""
    return np.asarray(_physical_jacobian(spec, params))


def residual_jacobian(problem: Problem, params: FamilyParams) -> np.ndarray:
    """Jacobian of the minimised residuals w.r.t. the raw parameters (`ravel_pytree` order)."""
    return np.asarray(_jacobian(problem, None, params))


def residual_vector(problem: Problem, params: FamilyParams) -> np.ndarray:
    return np.asarray(_residuals(problem, params))
