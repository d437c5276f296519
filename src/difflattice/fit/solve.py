"""Least-squares fitting with optimistix: residuals, solve, convergence trace, uncertainties.

Residuals (each divided by its 1-sigma, times sqrt(observable weight)):

- lobe: soft_floor(model dB) - soft_floor(measured dB), with the floor `floor_db` below the
  measured peak, so deep nulls (where a small angle error means tens of dB) do not dominate;
- wavefront: the pair (sin d, 1 - cos d) of the phase difference d, smooth and periodic (its
  squared norm is 4 sin^2(d/2) ~ d^2), so 2 pi wraps never jump.

Uncertainties come from the Jacobian J at the solution: cov = s^2 (J^T J)^+ with s^2 the reduced
chi-square (floored at 1), propagated to physical parameters through the reparameterisation.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree

from .data import LobeData, WaveData
from .model import ModelSpec, lobe_model_db, soft_floor_db, wave_model_phase
from .transfer import Transfer

Solver = Literal["levenberg_marquardt", "dogleg", "gauss_newton", "bfgs"]
SOLVERS = ("levenberg_marquardt", "dogleg", "gauss_newton", "bfgs")


@dataclass(frozen=True)
class FitOptions:
    """Solver settings: `solver` (levenberg_marquardt, dogleg, gauss_newton, bfgs), tolerances,
    `max_steps`, the lobe floor `floor_db` below the measured peak (dB), observable weights and the
    smoothness prior of per-cell profiles (second difference per cell)."""

    solver: Solver = "levenberg_marquardt"
    rtol: float = 1e-7
    atol: float = 1e-7
    max_steps: int = 200
    floor_db: float = 40.0  # below the measured peak
    lobe_weight: float = 1.0
    wave_weight: float = 1.0
    smoothness_sigma: float = 0.05  # free/symmetric profiles: allowed second difference per cell

    def __post_init__(self):
        if self.solver not in SOLVERS:
            raise ValueError(f"solver = {self.solver!r}; allowed: {', '.join(SOLVERS)}")
        if self.max_steps < 1:
            raise ValueError(f"max_steps = {self.max_steps} must be >= 1")


@dataclass
class FitResult:
    """A fit's outcome: raw and physical parameters, convergence (`converged`, `result_code`,
    `warnings`), residual statistics, standard errors and correlations, the convergence trace
    and the model curves at the solution."""

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
    trace: list = field(default_factory=list)
    model_curves: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)


def _make_solver(o: FitOptions):
    if o.solver == "levenberg_marquardt":
        return optx.LevenbergMarquardt(rtol=o.rtol, atol=o.atol)
    if o.solver == "dogleg":
        return optx.Dogleg(rtol=o.rtol, atol=o.atol)
    if o.solver == "gauss_newton":
        return optx.GaussNewton(rtol=o.rtol, atol=o.atol)
    return optx.BFGS(rtol=o.rtol, atol=o.atol)


class Problem(eqx.Module):
    """The residual function's data (arrays) and structure (static)."""

    spec: ModelSpec = eqx.field(static=True)
    lobe_T: jax.Array | None
    lobe_db: jax.Array | None
    lobe_sigma: jax.Array | None
    lobe_floor: float | None = eqx.field(static=True)
    wave_T: jax.Array | None
    wave_phase: jax.Array | None
    wave_sigma: jax.Array | None
    w_lobe: float = eqx.field(static=True)
    w_wave: float = eqx.field(static=True)
    smoothness_sigma: float = eqx.field(static=True, default=0.05)

    def residuals(self, params):
        parts = self._smoothness(params)
        if self.lobe_T is not None:
            m = lobe_model_db(self.spec, params, self.lobe_T)
            r = (soft_floor_db(m, self.lobe_floor) - soft_floor_db(self.lobe_db, self.lobe_floor)) / self.lobe_sigma
            parts.append(math.sqrt(self.w_lobe) * r)
        if self.wave_T is not None:
            d = wave_model_phase(self.spec, params, self.wave_T) - self.wave_phase
            parts.append(math.sqrt(self.w_wave) * jnp.sin(d) / self.wave_sigma)
            parts.append(math.sqrt(self.w_wave) * (1 - jnp.cos(d)) / self.wave_sigma)
        return jnp.concatenate(parts)

    def _smoothness(self, params) -> list:
        """Per-cell profiles have components that do not radiate (cell-to-cell oscillations
        beyond the wavenumber k): a weak prior on second differences of log-weight and lag phase
        (`smoothness_sigma` per cell) removes that null space, so free fits converge."""
        spec, out = self.spec, []
        for key, profile in (("w", spec.weights), ("lag", spec.lags)):
            if key in params and profile in ("free", "symmetric"):
                ph = spec.physical(params)
                v = jnp.log(ph["weights_raw"]) if key == "w" else 2 * math.pi * spec.frequency_hz * ph["lags_s"]
                out.append((v[2:] - 2 * v[1:-1] + v[:-2]) / self.smoothness_sigma)
        return out


def build_problem(spec: ModelSpec, transfer: Transfer, lobe: LobeData | None, wave: WaveData | None, o: FitOptions) -> Problem:
    """Bundle the data, transfer matrices and options into the residual function's `Problem`."""
    if lobe is None and wave is None:
        raise ValueError("nothing to fit: give lobe data, wavefront data or both")
    if transfer.n_cells != spec.n_cells:
        raise ValueError(f"transfer has {transfer.n_cells} cells but the model {spec.n_cells}")
    return Problem(
        spec=spec,
        lobe_T=None if lobe is None else jnp.asarray(transfer.lobe),
        lobe_db=None if lobe is None else jnp.asarray(lobe.level_db),
        lobe_sigma=None if lobe is None else jnp.asarray(lobe.sigma_db),
        lobe_floor=None if lobe is None else float(np.max(lobe.level_db) - o.floor_db),
        wave_T=None if wave is None else jnp.asarray(transfer.wave),
        wave_phase=None if wave is None else jnp.asarray(wave.phase_rad),
        wave_sigma=None if wave is None else jnp.asarray(wave.sigma_rad),
        w_lobe=o.lobe_weight,
        w_wave=o.wave_weight,
        smoothness_sigma=o.smoothness_sigma,
    )


@eqx.filter_jit
def _cost(problem: Problem, params: dict):
    r = problem.residuals(params)
    return jnp.sum(r * r)


def initial_params(problem: Problem, params=None) -> dict:
    """Start from the model's initial parameters with the gain and phase offset set in closed form,
    and (when it is fitted) the diameter chosen by a scan over 0.5-1 x the modelled line: the
    lobe's null angles scale with 1/D, so the cost in D has many local minima."""
    spec = problem.spec
    p = dict(spec.init_params() if params is None else params)
    # offsets the data cannot see are not parameters (they would make J singular)
    if problem.lobe_T is None:
        p.pop("gain_db", None)
    if problem.wave_T is None:
        p.pop("phase0", None)
    if "diam" in p and params is None:
        best = None
        for frac in np.linspace(0.5, 0.98, 25):
            q = _with_offsets(problem, {**p, "diam": jnp.asarray(math.log(frac / (1 - frac)))})
            c = float(_cost(problem, q))
            if np.isfinite(c) and (best is None or c < best[0]):
                best = (c, q)
        return best[1]
    return _with_offsets(problem, p)


def _with_offsets(problem: Problem, p: dict) -> dict:
    spec = problem.spec
    p = dict(p)
    if "gain_db" in p:
        m = np.asarray(lobe_model_db(spec, {**p, "gain_db": jnp.asarray(0.0)}, problem.lobe_T))
        data = np.asarray(problem.lobe_db)
        top = data > data.max() - 10
        p["gain_db"] = jnp.asarray(float(np.median(data[top] - m[top])))
    if "phase0" in p:
        m = np.asarray(wave_model_phase(spec, {**p, "phase0": jnp.asarray(0.0)}, problem.wave_T))
        d = np.asarray(problem.wave_phase) - m
        p["phase0"] = jnp.asarray(float(np.angle(np.mean(np.exp(1j * d)))))
    return p


_TRACE: list[tuple[float, float, int]] = []  # (wall time s, cost, stage)
_T0 = [0.0]
_STAGE = [0]
_BAR: list = [None]  # a tqdm bar while a fit with progress=True runs


def _record(cost) -> None:
    _TRACE.append((time.perf_counter() - _T0[0], float(cost), _STAGE[0]))
    bar = _BAR[0]
    if bar is not None:
        bar.update(1)
        bar.set_postfix(stage=_STAGE[0], cost=f"{float(cost):.4g}")


def _residual_fn(y, args):
    problem, fixed = args
    r = problem.residuals({**fixed, **y})
    jax.debug.callback(_record, 0.5 * jnp.sum(r * r))
    return r


def _solve(problem: Problem, y0: dict, options: FitOptions, fixed: dict | None = None, stage: int = 0):
    # module-level residual function and the problem as `args`: repeated fits of the same
    # structure reuse one compiled solver. `fixed`: parameters held at their values.
    _STAGE[0] = stage
    return optx.least_squares(_residual_fn, _make_solver(options), y0, args=(problem, fixed or {}),
                              max_steps=options.max_steps, throw=False)


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
) -> FitResult:
    """Fit `spec` to the data. Never raises on non-convergence: the result says so (`converged`,
    `result_code`, `warnings`). `progress` shows a bar of residual evaluations with the cost.

    Continuation in three stages, each from the previous one's result: (1) when the diameter is
    fitted, only the diameter and the offsets, the profiles held uniform; (2) everything, with the sigmas floored at 1 dB and
    5 deg (a smoother cost: with 0.05 dB sigmas the first long steps of a free profile can jump
    to a far local minimum, e.g. an aperture dominated by its edges); (3) everything with the
    measured sigmas. The reported convergence is that of the last stage."""
    problem = build_problem(spec, transfer, lobe, wave, options)
    p0 = initial_params(problem, params0)
    _TRACE.clear()
    _T0[0] = time.perf_counter()
    if progress:
        from tqdm import tqdm

        _BAR[0] = tqdm(desc="fit", unit="eval")
    try:
        return _fit_stages(problem, spec, p0, options, params0, lobe, wave)
    finally:
        if _BAR[0] is not None:
            _BAR[0].close()
            _BAR[0] = None


def _fit_stages(problem, spec, p0, options, params0, lobe, wave) -> FitResult:
    start = p0
    n_pre = 0
    profiles = {k: v for k, v in p0.items() if k in ("w", "lag")}
    if profiles and params0 is None and "diam" in p0:
        coarse = {k: v for k, v in p0.items() if k not in profiles}
        sol0 = _solve(_relaxed(problem), coarse, options, fixed=profiles, stage=1)
        n_pre += int(sol0.stats["num_steps"])
        if _finite(sol0.value):
            start = {**profiles, **sol0.value}
    sol1 = _solve(_relaxed(problem), start, options, stage=2)
    n_pre += int(sol1.stats["num_steps"])
    start = sol1.value if _finite(sol1.value) else start
    sol = _solve(problem, start, options, stage=3)
    params = jax.block_until_ready(sol.value)
    wall = time.perf_counter() - _T0[0]
    trace = list(_TRACE)
    y, unravel = ravel_pytree(params)
    result_code = _result_name(sol.result)
    warnings = []
    finite = bool(np.all(np.isfinite(np.asarray(y))))
    r = np.asarray(eqx.filter_jit(Problem.residuals)(problem, params))
    if not finite or not np.all(np.isfinite(r)):
        warnings.append("NON-FINITE parameters or residuals: the fit failed; check the data and the start point")
        converged = False
    else:
        converged = bool(sol.result == optx.RESULTS.successful)
    n_steps = n_pre + int(sol.stats["num_steps"])
    if not converged:
        warnings.append(f"FIT DID NOT CONVERGE ({result_code} after {n_steps} steps): "
                        "results below are the last iterate, not an optimum")

    # uncertainties
    J = np.asarray(_jacobian(problem, y, unravel))
    m, npar = J.shape
    cost = 0.5 * float(np.sum(r * r))
    dof = max(m - npar, 1)
    chi2 = 2 * cost / dof
    finite = finite and bool(np.all(np.isfinite(J)))
    s = np.linalg.svd(J, compute_uv=False) if finite else np.array([1.0, 0.0])
    cond = float(s[0] / s[-1]) if s[-1] > 0 else math.inf
    rank_def = not (cond < 1e8)
    if rank_def:
        warnings.append(f"ill-conditioned: Jacobian condition number {cond:.3g}; some parameters are not "
                        "determined by the data (e.g. mirror-symmetric pairs): their errors are unreliable")
    jtj_pinv = np.linalg.pinv(J.T @ J, rcond=1e-12) if finite else np.full((npar, npar), np.nan)
    cov_raw = max(chi2, 1.0) * jtj_pinv
    phys_vec, labels = _physical_vector(spec, params)
    G = np.asarray(_physical_jacobian(spec, y, unravel))
    cov = G @ cov_raw @ G.T
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(se, se)
    stderr = {lab: float(v) for lab, v in zip(labels, se)}

    phys = {k: np.asarray(v) for k, v in spec.physical(params).items()}
    rms = {}
    curves = {}
    if lobe is not None:
        mdb = np.asarray(lobe_model_db(spec, params, problem.lobe_T))
        curves["lobe_db"] = mdb
        above = lobe.level_db > problem.lobe_floor
        rms["lobe_db"] = float(np.sqrt(np.mean((mdb[above] - lobe.level_db[above]) ** 2)))
        rms["lobe_db_all_points_soft_floor"] = float(np.sqrt(np.mean(
            (np.asarray(soft_floor_db(mdb, problem.lobe_floor)) - np.asarray(soft_floor_db(lobe.level_db, problem.lobe_floor))) ** 2)))
        rms["lobe_normalised"] = float(np.sqrt(np.mean(((np.asarray(soft_floor_db(mdb, problem.lobe_floor)) - np.asarray(soft_floor_db(lobe.level_db, problem.lobe_floor))) / lobe.sigma_db) ** 2)))
    if wave is not None:
        mph = np.asarray(wave_model_phase(spec, params, problem.wave_T))
        curves["wave_phase_rad"] = mph
        d = np.angle(np.exp(1j * (mph - wave.phase_rad)))
        rms["wave_phase_deg"] = float(np.degrees(np.sqrt(np.mean(d**2))))
        rms["wave_normalised"] = float(np.sqrt(np.mean((d / wave.sigma_rad) ** 2)))
    return FitResult(
        spec=spec, params=params, physical=phys, converged=converged, result_code=result_code,
        n_steps=n_steps, wall_time_s=wall, cost=cost, chi2_reduced=chi2, rms=rms,
        stderr=stderr, correlation=corr, correlation_labels=labels, condition_number=cond,
        rank_deficient=rank_def, trace=trace, model_curves=curves, warnings=warnings,
    )


@eqx.filter_jit
def _jacobian(problem: Problem, y, unravel):
    return jax.jacfwd(lambda yy: problem.residuals(unravel(yy)))(y)


@eqx.filter_jit
def _physical_jacobian(spec: ModelSpec, y, unravel):
    return jax.jacfwd(lambda yy: _physical_vector(spec, unravel(yy))[0])(y)


def _physical_vector(spec: ModelSpec, params: dict):
    ph = spec.physical(params)
    n = spec.n_cells
    vec = jnp.concatenate([
        ph["weights"], ph["lags_s"] * 1e6, jnp.atleast_1d(ph["diameter_m"] * 1e3),
        jnp.atleast_1d(ph["gain_db"]), jnp.atleast_1d(jnp.degrees(ph["phase0_rad"])),
    ])
    labels = [f"w[{k}]" for k in range(n)] + [f"lag_us[{k}]" for k in range(n)] + ["diameter_mm", "gain_db", "phase0_deg"]
    return vec, labels


def _result_name(result) -> str:
    for name in ("successful", "max_steps_reached", "nonlinear_max_steps_reached", "nonlinear_divergence",
                 "singular", "breakdown", "nonfinite"):
        v = getattr(optx.RESULTS, name, None)
        if v is not None and result == v:
            return name
    return str(result)
