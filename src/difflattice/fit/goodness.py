"""How well a fit describes its data: chi-square per measured datum (per data set and joint,
with its probability), the runs test of residual signs, the variance factor of robust losses and
the outlier diagnostics (see docs/fitting.md, "Goodness of fit and exit codes")."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from .stats import chi2_sf, normal_cdf
from .verdict import GOODNESS_P_MIN

if TYPE_CHECKING:
    from .problem import Problem
    from .solve import FitOptions

OUTLIER_SIGMAS = 4.0


def outlier_diagnostics(data_residuals: dict) -> dict:
    """Per observable: RMS of the normalised residuals, a robust sigma (1.4826 MAD), their ratio
    and the points further than `OUTLIER_SIGMAS` robust sigmas (at least 1) from the median.
    `suspect` is set when at least 2 points and 1 % of them lie out there (a Gaussian sample of
    200 has one such point with probability ~1 %) or the RMS exceeds twice the robust sigma."""
    out = {}
    for name, r in data_residuals.items():
        r = np.asarray(r, float)
        n = len(r)
        if n < 8 or not np.all(np.isfinite(r)):
            continue
        med = float(np.median(r))
        mad = 1.4826 * float(np.median(np.abs(r - med)))
        rms = float(np.sqrt(np.mean(r**2)))
        s = max(mad, 1.0)
        far = np.abs(r - med) > OUTLIER_SIGMAS * s
        k = int(far.sum())
        ratio = rms / max(mad, 1e-12)
        out[name] = {
            "n": n,
            "n_outliers": k,
            "fraction": k / n,
            "rms": rms,
            "robust_sigma": mad,
            "rms_over_robust": ratio,
            "indices": np.flatnonzero(far).tolist(),
            "suspect": bool(k >= max(2, math.ceil(0.01 * n)) and (k / n >= 0.01 or ratio > 2.0)),
        }
    return out


def runs_test(r) -> tuple[int, float, float]:
    """(runs, expected runs, one-sided p of so few) of the signs of the residuals `r` in data
    order (Wald-Wolfowitz, normal approximation): a model that misses a structure leaves long
    runs of one sign, noise leaves about n/2 + 1. p = 1 where there are too few of either sign."""
    s = np.sign(np.asarray(r, float))
    s = s[s != 0]
    n1, n2 = int(np.sum(s > 0)), int(np.sum(s < 0))
    n = n1 + n2
    runs = 1 + int(np.sum(s[1:] != s[:-1])) if n else 0
    if n1 < 2 or n2 < 2:
        return runs, float(runs), 1.0
    mu = 2.0 * n1 * n2 / n + 1
    var = 2.0 * n1 * n2 * (2.0 * n1 * n2 - n) / (n * n * (n - 1))
    return runs, mu, normal_cdf((runs - mu + 0.5) / math.sqrt(var))


def _datum_weights(problem: Problem, arrays: dict) -> dict:
    """Per data set, the share of a datum each point's residual carries: its expected squared
    normalised residual from noise alone. 1 for a wavefront phase; for a lobe level L the soft
    floor F compresses the noise by its slope 1 / (1 + 10^((F - L)/10)), so a point far below
    the floor carries almost nothing (it says only "below the floor")."""
    out = {}
    if problem.lobe_floor is not None and arrays.get("lobe_db") is not None:
        level = np.asarray(arrays["lobe_db"], float)
        out["lobe"] = 1.0 / (1.0 + 10.0 ** ((problem.lobe_floor - level) / 10.0)) ** 2
    return out


def goodness_of_fit(
    data_res: dict, J_data: np.ndarray, cov_raw: np.ndarray | None, npar: int, datum_weights: dict | None = None
) -> dict:
    """Chi-square per data set and joint, counted per measured datum: a lobe point is one level,
    a wavefront point one phase (its residual: the chord 2 sin(d/2) / sigma, ~ d / sigma); a
    point's count is its `datum_weights` entry where given (a lobe level below the soft floor:
    less than one, `_datum_weights`), so `n_data` is the data's equivalent number of points. Each
    set's degrees of freedom are that number less its share of the fitted parameters, the sum of
    its rows' leverages (the hat matrix's diagonal; the joint sum is the effective number of
    parameters, `npar` without a smoothness prior). Per set: `chi2`, `n` (points), `n_data`,
    `dof`, `chi2_reduced`, `p` (`chi2_sf`: the probability of a chi-square this large
    from a correct model at the stated noise) and the runs test of the residual signs (`runs`,
    `runs_expected`, `runs_p`)."""
    if not data_res:
        return {}
    lev = None
    if cov_raw is not None and np.all(np.isfinite(cov_raw)) and np.all(np.isfinite(J_data)):
        lev = np.einsum("ij,jk,ik->i", J_data, cov_raw, J_data)
    out: dict = {}
    row = 0
    tot_chi2 = tot_n = tot_d = tot_h = 0.0
    for name, res in data_res.items():
        res = np.asarray(res, float)
        n = len(res)
        rows = n if name == "lobe" else 2 * n  # a wavefront point: the rows sin d and 1 - cos d
        h = float(np.sum(lev[row : row + rows])) if lev is not None else npar * n / max(len(J_data), 1)
        row += rows
        c2 = float(np.sum(res * res))
        w = (datum_weights or {}).get(name)
        n_data = float(np.sum(w)) if w is not None and len(w) == n else float(n)
        out[name] = _goodness_entry(c2, n, n_data, h)
        runs, mu, p_runs = runs_test(res)
        out[name].update(runs=runs, runs_expected=mu, runs_p=p_runs)
        tot_chi2, tot_n, tot_d, tot_h = tot_chi2 + c2, tot_n + n, tot_d + n_data, tot_h + h
    out["joint"] = _goodness_entry(tot_chi2, int(tot_n), tot_d, tot_h)
    out["joint"]["runs_p"] = min(v["runs_p"] for k, v in out.items() if k != "joint")
    out["p_min"] = GOODNESS_P_MIN
    return out


def _goodness_entry(c2: float, n: int, n_data: float, h: float) -> dict:
    dof = max(n_data - h, 1.0)
    return {
        "chi2": c2,
        "n": n,
        "n_data": n_data,
        "params_share": h,
        "dof": dof,
        "chi2_reduced": c2 / dof,
        "p": chi2_sf(c2, dof) if math.isfinite(c2) else 0.0,
    }


def _chi2_and_variance_factor(data_res: dict, options: FitOptions, npar: int, chi2_fit: float) -> tuple[float, float]:
    """(chi2_red of the data points, variance factor for the errors). For "l2" both are the
    reduced chi-square of the minimised residuals (the smoothness prior included). For a robust
    loss the factor is Huber's M-estimator one, sum psi(r)^2 / dof / (mean psi'(r))^2 with psi =
    rho' (Huber: the residual clipped at +-k; Cauchy: r / (1 + r^2/k^2)): outliers count by
    their bounded influence, not by their size, so a robust fit's errors are not blown up by the
    points it set aside."""
    r = np.concatenate([np.asarray(v, float) for v in data_res.values()]) if data_res else np.zeros(0)
    dof = max(len(r) - npar, 1)
    chi2_data = float(np.sum(r * r)) / dof
    if options.loss == "l2":
        return chi2_fit, chi2_fit
    k = options.loss_scale
    if options.loss == "huber":
        psi, dpsi = np.clip(r, -k, k), (np.abs(r) <= k).astype(float)
    else:
        u2 = (r / k) ** 2
        psi, dpsi = r / (1 + u2), (1 - u2) / (1 + u2) ** 2
    mean_dpsi = max(float(np.mean(dpsi)), 1e-3)
    return chi2_data, float(np.sum(psi * psi)) / dof / mean_dpsi**2
