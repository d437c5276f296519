"""Fitting housed transducers (`fit.housed`) by gradient, and the family ladder.

`fit_housed` fits one family to a lobe (`fit.data.LobeData`) by Levenberg-Marquardt on the
normalised residuals (model - data) / sigma, the Jacobian by forward-mode differentiation through
the lattice run (geometry included: a handful of tangents, one program). Its errors are the
linearised covariance at the stated sigma, scaled by chi2_red where that exceeds 1 (a model that
misses structure does not get tighter errors for it), mapped to physical units by the Jacobian
of the parameterisation; the condition number of the column-scaled normal matrix says whether
they mean anything.

`family_ladder` fits the families of `fit.housed.FAMILIES` (flat -> recessed -> opening -> free
profile) to the same data and compares them side by side by chi-square (`fit.goodness`), AIC =
chi2 + 2k and BIC = chi2 + k ln n. The chosen family is the one of least BIC among the
well-conditioned fits, replaced by a simpler one whose BIC is within `BIC_TIE` of it (evidence
below "positive", Kass & Raftery 1995: the data do not prefer the richer one); a family that
wins only with a condition number above `COND_MAX` is reported as winning by ill-conditioning,
never chosen.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from .data import LobeData
from .housed import FAMILIES, HousedForward, HousedSpec
from .model import soft_floor_db

COND_MAX = 1e8
"""Largest condition number of the column-scaled normal matrix (the parameters' correlation
matrix) for which a fit's errors are taken as meaning: beyond it some combination of parameters
is fixed only to 1e-4 of its marginal spread, the precision of "6.864 +- 0.000 mm"."""

BIC_TIE = 2.0
"""A richer family must lower the BIC by more than this to be chosen over a simpler one."""

FLOOR_BELOW_DB = 10.0
"""The model's soft floor lies this far below the lowest datum (a table does not resolve deeper nulls)."""


@dataclass
class HousedFit:
    """A fitted housed model: the spec, raw and physical parameters, errors (`errors`: physical
    name -> 1-sigma, mm or dB), residuals, chi-square, condition number, convergence."""

    spec: HousedSpec
    params: dict
    physical: dict
    errors: dict
    model_db: np.ndarray
    residual_db: np.ndarray
    chi2: float
    n: int
    k: int
    chi2_reduced: float
    goodness: dict
    condition: float
    converged: bool
    iterations: int
    rms_db: float

    @property
    def aic(self) -> float:
        return self.chi2 + 2 * self.k

    @property
    def bic(self) -> float:
        return self.chi2 + self.k * math.log(self.n)

    @property
    def ill_conditioned(self) -> bool:
        return not self.condition <= COND_MAX

    def summary(self) -> dict:
        """Plain values for reports and files (mm, dB)."""
        out = {
            "family": self.spec.family,
            "k": self.k,
            "n": self.n,
            "chi2": self.chi2,
            "chi2_reduced": self.chi2_reduced,
            "p": self.goodness.get("lobe", {}).get("p", float("nan")),
            "aic": self.aic,
            "bic": self.bic,
            "rms_db": self.rms_db,
            "condition": self.condition,
            "ill_conditioned": self.ill_conditioned,
            "converged": self.converged,
            "iterations": self.iterations,
        }
        for key, v in self.physical.items():
            out[key] = v
            if key in self.errors:
                out[key + "_err"] = self.errors[key]
        return out


def _physical_vector(spec: HousedSpec, params: dict):
    """(names, jnp vector) of the reported physical quantities (mm and dB)."""
    ph = spec.physical(params)
    names, vals = [], []
    for key, scale, label in (
        ("diaphragm_m", 1e3, "diaphragm_mm"),
        ("recess_m", 1e3, "recess_mm"),
        ("opening_m", 1e3, "opening_mm"),
        ("gain_db", 1.0, "gain_db"),
    ):
        v = ph[key]
        if v is None or (key == "recess_m" and "recess" not in params):
            continue
        names.append(label)
        vals.append(jnp.asarray(v) * scale)
    return names, jnp.stack(vals)


def fit_housed(
    spec: HousedSpec,
    lobe: LobeData,
    *,
    init: dict | None = None,
    max_iter: int = 60,
    forward: HousedForward | None = None,
    starts: int = 3,
) -> HousedFit:
    """Fit `spec`'s family to `lobe` (levels in any dB reference: the gain is fitted). `starts`
    initial diaphragm diameters (0.5, 0.7, 0.9 of the bore; the recess and opening at their
    defaults) unless `init` (raw parameters) is given; the best fit is returned."""
    fw = forward or HousedForward(spec, lobe.angle_deg)
    y = jnp.asarray(lobe.level_db, float)
    sig = jnp.asarray(lobe.sigma_db, float)
    floor = float(np.min(lobe.level_db)) - FLOOR_BELOW_DB
    p0 = init or spec.init_params()
    flat0, unravel = ravel_pytree(p0)

    def residual(u):
        m = soft_floor_db(fw.lobe_db(unravel(u)), floor)
        return (m - y) / sig

    res_j = jax.jit(residual)
    jac_j = jax.jit(jax.jacfwd(residual))
    inits = [np.asarray(flat0, float)]
    if init is None and starts > 1:
        rb = spec.housing.bore_radius_m
        inits = []
        for frac in np.linspace(0.5, 0.9, starts):
            q = spec.truth_params(
                diaphragm_m=2 * frac * rb, recess_m=spec.recess_m or 0.0, opening_m=spec.opening_m or 1.6 * rb
            )
            if "recess" in q and spec.recess_m is None:
                q["recess"] = p0["recess"]
            inits.append(np.asarray(ravel_pytree(q)[0], float))
    best = None
    for u0 in inits:
        u0 = _gain_start(u0, res_j, unravel, sig)
        out = _levenberg_marquardt(res_j, jac_j, u0, max_iter)
        if best is None or out[1] < best[1]:
            best = out
    assert best is not None
    u, cost, converged, it = best
    return _finish(spec, fw, lobe, unravel, u, res_j, jac_j, floor, converged, it)


def _gain_start(u0, res_j, unravel, sig):
    """Set the raw gain so the mean residual is 0 (the gain is linear: one step)."""
    p = unravel(jnp.asarray(u0))
    r = np.asarray(res_j(jnp.asarray(u0)))
    s = np.asarray(sig, float)
    p["gain_db"] = jnp.asarray(float(p["gain_db"]) - float(np.sum(r / s) / np.sum(1 / s**2)))
    return np.asarray(ravel_pytree(p)[0], float)


def _levenberg_marquardt(res_j, jac_j, u0, max_iter: int):
    """Minimise |r(u)|^2: returns (u, cost, converged, iterations)."""
    u = np.asarray(u0, float)
    r = np.asarray(res_j(jnp.asarray(u)))
    cost = float(r @ r)
    lam = 1e-3
    converged = False
    it = 0
    while it < max_iter:
        it += 1
        J = np.asarray(jac_j(jnp.asarray(u)))
        A, g = J.T @ J, J.T @ r
        improved = False
        for _ in range(12):
            step = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), -g)
            u_new = u + step
            r_new = np.asarray(res_j(jnp.asarray(u_new)))
            c_new = float(r_new @ r_new)
            if np.isfinite(c_new) and c_new < cost:
                improved = True
                lam = max(lam / 3, 1e-9)
                break
            lam *= 4
        if not improved:
            converged = True  # no descent direction left at this precision
            break
        rel = (cost - c_new) / max(cost, 1e-300)
        u, r, cost = u_new, r_new, c_new
        if rel < 1e-9 or np.max(np.abs(step)) < 1e-8:
            converged = True
            break
    return u, cost, converged, it


def _finish(spec, fw, lobe, unravel, u, res_j, jac_j, floor, converged, it) -> HousedFit:
    from .goodness import goodness_of_fit

    params = unravel(jnp.asarray(u))
    r = np.asarray(res_j(jnp.asarray(u)))
    J = np.asarray(jac_j(jnp.asarray(u)))
    n, k = len(r), J.shape[1]
    chi2 = float(r @ r)
    A = J.T @ J
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    corr = A / np.outer(d, d)
    ev = np.linalg.eigvalsh(corr)
    condition = float(ev[-1] / ev[0]) if ev[0] > 0 else math.inf
    cov = np.linalg.pinv(A)
    chi2_red = chi2 / max(n - k, 1)
    cov_scaled = cov * max(1.0, chi2_red)
    names, vec = _physical_vector(spec, params)

    def phys_vec(v):
        return _physical_vector(spec, unravel(v))[1]

    G = np.asarray(jax.jacfwd(phys_vec)(jnp.asarray(u)))
    cov_phys = G @ cov_scaled @ G.T
    errors = {nm: float(math.sqrt(max(cov_phys[i, i], 0.0))) for i, nm in enumerate(names)}
    values = {nm: float(v) for nm, v in zip(names, np.asarray(vec), strict=True)}
    model = np.asarray(soft_floor_db(fw.lobe_db(params), floor))
    res_db = model - np.asarray(lobe.level_db)
    goodness = goodness_of_fit({"lobe": r}, J, cov, k)
    ph = spec.physical(params)
    if spec.family == "profile":
        values["weights"] = np.asarray(ph["weights"]).tolist()
        values["lags_us"] = (np.asarray(ph["lags_s"]) * 1e6).tolist()
    return HousedFit(
        spec=spec,
        params=params,
        physical=values,
        errors=errors,
        model_db=model,
        residual_db=res_db,
        chi2=chi2,
        n=n,
        k=k,
        chi2_reduced=chi2_red,
        goodness=goodness,
        condition=condition,
        converged=converged,
        iterations=it,
        rms_db=float(np.sqrt(np.mean(res_db**2))),
    )


@dataclass
class Ladder:
    """The families fitted to one data set (`fits`, in `FAMILIES` order), the chosen family and
    why (`reason`)."""

    fits: dict
    chosen: str
    reason: str

    def table(self) -> list[dict]:
        return [f.summary() for f in self.fits.values()]

    def markdown(self) -> str:
        """The side-by-side comparison as a Markdown table."""
        head = (
            "| family | k | chi2 | chi2_red | p | AIC | BIC | RMS dB | cond | diaphragm mm | recess mm | opening mm |"
        )
        rows = [head, "|" + "---|" * 12]
        for name, f in self.fits.items():
            s = f.summary()
            mark = " (chosen)" if name == self.chosen else (" (ill-conditioned)" if f.ill_conditioned else "")
            rows.append(
                f"| {name}{mark} | {s['k']} | {s['chi2']:.1f} | {s['chi2_reduced']:.2f} | {s['p']:.2g} | "
                f"{s['aic']:.1f} | {s['bic']:.1f} | {s['rms_db']:.2f} | {s['condition']:.2g} | "
                f"{_pm(s, 'diaphragm_mm')} | {_pm(s, 'recess_mm')} | {_pm(s, 'opening_mm')} |"
            )
        return "\n".join(rows) + f"\n\nChosen: **{self.chosen}**. {self.reason}\n"


def _pm(s: dict, key: str) -> str:
    if key not in s:
        return "-"
    return f"{s[key]:.2f} +- {s.get(key + '_err', float('nan')):.2f}"


def choose_family(fits: dict) -> tuple[str, str]:
    """(chosen family, reason) by the rule of the module docstring."""
    ok = {k: f for k, f in fits.items() if f.converged and not f.ill_conditioned}
    if not ok:
        return next(iter(fits)), "no family converged with meaningful errors; the simplest is shown"
    best = min(ok, key=lambda k: ok[k].bic)
    order = [k for k in FAMILIES if k in ok]
    for k in order:  # simplest first
        if ok[k].bic <= ok[best].bic + BIC_TIE:
            chosen = k
            break
    reason = (
        f"least BIC among well-conditioned fits: {best} ({ok[best].bic:.1f})"
        + (f"; {chosen} is simpler and within {BIC_TIE:g} of it ({ok[chosen].bic:.1f})" if chosen != best else "")
        + "."
    )
    for k, f in fits.items():
        if f.ill_conditioned and f.bic < ok[chosen].bic - BIC_TIE:
            reason += (
                f" {k} has a lower BIC ({f.bic:.1f}) but only by ill-conditioning (condition number "
                f"{f.condition:.2g} > {COND_MAX:g}): its parameters are not determined, it is not chosen."
            )
    return chosen, reason


def family_ladder(
    spec: HousedSpec, lobe: LobeData, *, families=FAMILIES, max_iter: int = 60, starts: int = 3
) -> Ladder:
    """Fit each of `families` (a `HousedSpec` like `spec` with its family replaced) to `lobe`,
    warm-starting each family from the previous one's geometry, and choose (`choose_family`)."""
    fits: dict = {}
    prev = None
    for fam in families:
        s = dataclasses.replace(spec, family=fam)
        init = None
        if prev is not None:
            ph = prev.physical
            init = s.truth_params(
                diaphragm_m=ph["diaphragm_mm"] * 1e-3,
                recess_m=max(ph.get("recess_mm", 0.0) * 1e-3, s.recess_min_m + 1e-4),
                opening_m=ph.get("opening_mm", 1.6e3 * s.housing.bore_radius_m) * 1e-3,
            )
            init["gain_db"] = jnp.asarray(ph["gain_db"])
        f = fit_housed(s, lobe, init=init, max_iter=max_iter, starts=starts)
        if init is not None and starts > 1:  # also from the family's own starts: keep the better
            g = fit_housed(s, lobe, max_iter=max_iter, starts=starts)
            f = g if g.chi2 < f.chi2 else f
        fits[fam] = f
        prev = f
    chosen, reason = choose_family(fits)
    return Ladder(fits, chosen, reason)
