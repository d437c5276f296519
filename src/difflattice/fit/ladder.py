"""Fitting housed transducers (`fit.housed`) by gradient, and the family ladder.

`fit_housed` fits one family to a lobe (`fit.data.LobeData`), and with it, where the rig measured
one, a near-field wavefront (`fit.data.WaveData`: the scan line `z_m` in front of the fitted
front face, a fitted phase offset), by Levenberg-Marquardt on the normalised residuals (model -
data) / sigma (a wavefront point as `fit.problem`: the rows sin d / sigma and (1 - cos d) / sigma
of its phase difference d), the Jacobian by forward-mode differentiation through
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

from .data import LobeData, WaveData
from .housed import FAMILIES, HousedForward, HousedParams, HousedSpec, level_db
from .model import soft_floor_db

COND_MAX = 1e8
"""Largest condition number of the column-scaled normal matrix (the parameters' correlation
matrix) for which a fit's errors are taken as meaning: beyond it some combination of parameters
is fixed only to 1e-4 of its marginal spread, the precision of "6.864 +- 0.000 mm"."""

BIC_TIE = 2.0
"""A richer family must lower the BIC by more than this to be chosen over a simpler one."""

AT_BOUND = 6.0
"""|logit| beyond which a geometry parameter is reported at a bound of its range (within 0.25 %)."""

FLOOR_BELOW_DB = 30.0
"""The model's soft floor lies this far below the lowest datum (it lifts the lowest datum's model level by
0.004 dB; a table does not resolve nulls deeper than that)."""


@dataclass
class HousedFit:
    """A fitted housed model: the spec, raw and physical parameters, errors (`errors`: physical
    name -> 1-sigma, mm or dB), residuals, chi-square, condition number, convergence."""

    spec: HousedSpec
    params: HousedParams
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
    errors_statistical: dict = dataclasses.field(default_factory=dict)
    errors_resolution: dict = dataclasses.field(default_factory=dict)
    wave_model_rad: np.ndarray | None = None
    wave_residual_deg: np.ndarray | None = None
    rms_wave_deg: float | None = None

    @property
    def aic(self) -> float:
        return self.chi2 + 2 * self.k

    @property
    def bic(self) -> float:
        return self.chi2 + self.k * math.log(self.n)

    @property
    def ill_conditioned(self) -> bool:
        return not self.condition <= COND_MAX

    @property
    def at_bound(self) -> list[str]:
        """Geometry parameters within `AT_BOUND` of a bound of their range (the logistic map's
        slope is < 0.25 % there): a diaphragm or opening the size of the bore, a recess of 0 or
        the can's length. Such a value is the model saying the data want more (or less) than the
        can allows; its error is not a spread."""
        out = []
        for key, label, lim in (
            ("diam", "diaphragm", AT_BOUND),
            ("recess", "recess", AT_BOUND),
            ("opening", "opening", AT_BOUND),
            ("cone", "cone", 0.5 * AT_BOUND),  # tanh(x) = 2 sigmoid(2x) - 1: the same slope criterion
            ("bend", "bending q", AT_BOUND),
        ):
            v = getattr(self.params, key)
            if v is not None and abs(float(v)) > lim:
                out.append(label)
        return out

    def summary(self) -> dict:
        """Plain values for reports and files (mm, dB)."""
        out = {
            "family": self.spec.family,
            "k": self.k,
            "n": self.n,
            "chi2": self.chi2,
            "chi2_reduced": self.chi2_reduced,
            "p": self.goodness.get("joint" if self.rms_wave_deg is not None else "lobe", {}).get("p", float("nan")),
            "aic": self.aic,
            "bic": self.bic,
            "rms_db": self.rms_db,
            "condition": self.condition,
            "ill_conditioned": self.ill_conditioned,
            "at_bound": self.at_bound,
            "converged": self.converged,
            "iterations": self.iterations,
        }
        if self.rms_wave_deg is not None:
            out["rms_wave_deg"] = self.rms_wave_deg
        for key, v in self.physical.items():
            out[key] = v
            if key in self.errors:
                out[key + "_err"] = self.errors[key]
        return out


def _physical_vector(spec: HousedSpec, params: HousedParams):
    """(names, jnp vector) of the reported physical quantities (mm and dB)."""
    ph = spec.physical(params)
    names, vals = [], []
    for key, scale, label in (
        ("diaphragm_m", 1e3, "diaphragm_mm"),
        ("recess_m", 1e3, "recess_mm"),
        ("opening_m", 1e3, "opening_mm"),
        ("cone_m", 1e3, "cone_mm"),
        ("bend", 1.0, "bend_q"),
        ("gain_db", 1.0, "gain_db"),
    ):
        v = ph[key]
        raw = {"diaphragm_m": "diam", "recess_m": "recess", "opening_m": "opening"}.get(key)
        if v is None or (raw is not None and not params.has(raw)):  # absent, or held fixed
            continue
        names.append(label)
        vals.append(jnp.asarray(v) * scale)
    return names, jnp.stack(vals)


def fit_housed(
    spec: HousedSpec,
    lobe: LobeData,
    *,
    wave: WaveData | None = None,
    init: HousedParams | None = None,
    max_iter: int = 60,
    forward: HousedForward | None = None,
    starts: int = 3,
    resolution_cpw: float | None = None,
    jacobian: str = "secant",
) -> HousedFit:
    """Fit `spec`'s family to `lobe` (levels in any dB reference: the gain is fitted) and, if
    given, the wavefront `wave` (phases in the models' convention, `fit.data`; its `z_m` is the
    scan line's distance in front of the front face, which moves with the fitted recess; a phase
    offset `phase0` is fitted), from `init` (raw parameters), or else from `starts` diaphragm
    diameters (the spec's, or the baffled piston's with the lobe's -6 dB angle,
    `piston_start_diameter_m`; then 0.8, 1.25, 0.65, 1.5 times it, below the bore; the recess and
    opening at their defaults); the best fit is returned. With `resolution_cpw` the fit is
    repeated from its result at that lattice resolution and the shift of each quantity is added
    to its error in quadrature (`errors_resolution`; the statistical part stays in
    `errors_statistical`): the lattice's discretisation is part of the quoted error.

    `jacobian`: "secant" (default) differentiates the geometry (diameter, recess, opening) by
    central secants one cell wide and everything else exactly; "exact" uses the forward-mode
    derivative throughout. Why: a cut cell's effect is not linear in its fill, so the lobe's
    exact derivative in a moving face ripples within each cell (+-25 % at 24 cells per
    wavelength, 30 deg, a 3 mm recess), and linearised errors built on it inherit the ripple
    (measured, a 9 mm piston 3 mm deep fitted at 24 cells per wavelength: the same fitted values
    within 0.01 mm either way, diameter error 0.13 mm by secants, 0.21 mm exact; at 16 cells
    0.12 and 0.10 mm). The cell-scale secant is the slope the lattice resolves. With a wavefront
    the steps use the exact derivative and only the errors the secants: its 0.1 deg phases make
    the cost so steep that steps on secants, which are not the local slope, creep (measured, a
    9 mm piston 3 mm deep at 12 cells per wavelength: chi2 still falling 1e-5 per step after 60
    steps; exact steps converge in 16, to a chi2 1e-3 lower, the geometry within 0.002 mm)."""
    if init is not None and not isinstance(init, HousedParams):
        raise TypeError(
            f"init is a {type(init).__name__}; give a HousedParams, e.g. spec.init_params() or spec.truth_params(...)"
        )
    if wave is not None and forward is None:
        fw = HousedForward(spec, lobe.angle_deg, wave_x_m=wave.x_m, wave_z_m=wave.z_m)
    else:
        fw = forward or HousedForward(spec, lobe.angle_deg)
    y = jnp.asarray(lobe.level_db, float)
    sig = jnp.asarray(lobe.sigma_db, float)
    floor = float(np.min(lobe.level_db)) - FLOOR_BELOW_DB
    p0 = _with_phase0(init if init is not None else spec.init_params(), wave)
    flat0, unravel = ravel_pytree(p0)
    wph = None if wave is None else jnp.asarray(wave.phase_rad, float)
    wsig = None if wave is None else jnp.asarray(wave.sigma_rad, float)

    def residual(u):
        p = unravel(u)
        if wave is None:
            return (soft_floor_db(fw.lobe_db(p), floor) - y) / sig
        far, near = fw.fields(p)
        d = -jnp.angle(near) + p.phase0 - wph
        r = (soft_floor_db(level_db(far, p), floor) - y) / sig
        return jnp.concatenate([r, jnp.sin(d) / wsig, (1 - jnp.cos(d)) / wsig])

    res_j = jax.jit(residual)
    exact_j = jax.jit(jax.jacfwd(residual))
    if jacobian == "exact":
        jac_j = exact_j
    elif jacobian == "secant":
        jac_j = _secant_jacobian(spec, p0, res_j, exact_j)
    else:
        raise ValueError(f"jacobian = {jacobian!r}; allowed: 'secant' (cell-scale secants of the geometry), 'exact'")
    step_j = exact_j if wave is not None else jac_j  # see the docstring: a wavefront's steps are exact
    inits = [np.asarray(flat0, float)]
    if init is None:
        rb = spec.housing.bore_radius_m
        d6 = spec.diaphragm_m or piston_start_diameter_m(lobe, spec.c_m_s, 2 * rb)
        inits = []
        for factor in (1.0, 0.8, 1.25, 0.65, 1.5)[: max(starts, 1)]:
            q = _with_phase0(spec.truth_params(diaphragm_m=min(factor * d6, 1.98 * rb)), wave)
            inits.append(np.asarray(ravel_pytree(q)[0], float))
    best = None
    for u0 in inits:
        u0 = _offsets_start(u0, res_j, unravel, sig, len(lobe.level_db), wsig)
        out = _levenberg_marquardt(res_j, step_j, u0, max_iter)
        if best is None or out[1] < best[1]:
            best = out
    assert best is not None
    u, cost, converged, it = best
    out = _finish(spec, lobe, wave, unravel, u, res_j, jac_j, converged, it)
    if resolution_cpw is not None:
        add_resolution_term(out, lobe, resolution_cpw, wave=wave, max_iter=max_iter)
    return out


def _with_phase0(p: HousedParams, wave: WaveData | None) -> HousedParams:
    """The parameters with a phase offset where a wavefront is fitted, without one where not."""
    if wave is None:
        return p.without("phase0") if p.has("phase0") else p
    return p if p.has("phase0") else dataclasses.replace(p, phase0=jnp.asarray(0.0))


def add_resolution_term(
    fit: HousedFit,
    lobe: LobeData,
    resolution_cpw: float,
    *,
    wave: WaveData | None = None,
    max_iter: int = 60,
) -> HousedFit:
    """Refit `fit` (to `lobe` and `wave`, the data it was fitted to) from its result at
    `resolution_cpw` cells per wavelength and add each geometric quantity's shift to its error in
    quadrature (in place; see `fit_housed`). The gain keeps its statistical error: it relates the
    data's dB reference to the far field in lattice units, which change with the cell size."""
    other = fit_housed(
        dataclasses.replace(fit.spec, cells_per_wavelength=resolution_cpw),
        lobe,
        wave=wave,
        init=fit.params,
        max_iter=max_iter,
    )
    fit.errors_statistical = dict(fit.errors)
    for key, err in fit.errors_statistical.items():
        if key == "gain_db":  # the data's dB reference against the far field's lattice units, which
            continue  # scale with the cell size: its shift between resolutions is a change of units (5-12 dB)
        shift = abs(other.physical[key] - fit.physical[key])
        fit.errors_resolution[key] = shift
        fit.errors[key] = math.hypot(err, shift)
    return fit


def piston_start_diameter_m(lobe: LobeData, c_m_s: float, d_max_m: float) -> float:
    """The diameter of the baffled piston whose lobe falls 6 dB at the data's -6 dB angle
    (2 J1(x) / x = 1/2 at x = k a sin t = 2.215), below `d_max_m`:
    a start the lobe itself suggests (the data's lobe is multimodal in the diameter)."""
    ang = np.abs(np.asarray(lobe.angle_deg, float))
    order = np.argsort(ang)
    ang, lev = ang[order], np.asarray(lobe.level_db, float)[order]
    rel = lev - lev[0]
    below = np.flatnonzero(rel <= -6.0)
    if len(below) == 0 or below[0] == 0:
        return 0.5 * d_max_m
    i = below[0]
    t = ang[i - 1] + (ang[i] - ang[i - 1]) * (-6.0 - rel[i - 1]) / (rel[i] - rel[i - 1])
    k = 2 * math.pi * lobe.frequency_hz / c_m_s
    return float(min(2 * 2.215 / (k * math.sin(math.radians(max(t, 1.0)))), 0.99 * d_max_m))


def _offsets_start(u0, res_j, unravel, sig, n_lobe: int, wsig=None):
    """Set the raw gain so the mean lobe residual is 0 (the gain is linear: one step) and the
    phase offset, where there is one, to the circular mean of the wavefront's phase differences."""
    p = unravel(jnp.asarray(u0))
    if p.has("phase0"):
        p = dataclasses.replace(p, phase0=jnp.asarray(0.0))
    r = np.asarray(res_j(ravel_pytree(p)[0]))
    s = np.asarray(sig, float)
    p = dataclasses.replace(p, gain_db=jnp.asarray(float(p.gain_db) - float(np.sum(r[:n_lobe] / s) / np.sum(1 / s**2))))
    if p.has("phase0"):
        w = np.asarray(wsig, float)
        sin_d, one_cos = (w * v for v in np.split(r[n_lobe:], 2))  # the rows are (sin d, 1 - cos d) / sigma
        p = dataclasses.replace(p, phase0=jnp.asarray(-float(np.angle(np.mean(1 - one_cos + 1j * sin_d)))))
    return np.asarray(ravel_pytree(p)[0], float)


def _secant_jacobian(spec: HousedSpec, template: HousedParams, res_j, exact_j):
    """J(u): exact columns, except the geometry's raw parameters, which get central secants of
    one lattice cell in the physical length (a radius, the recess), capped at 0.5 in the logit."""
    flat, unravel = ravel_pytree(template)
    geometry = {"diam": spec.housing.bore_radius_m, "opening": spec.housing.bore_radius_m}
    geometry["recess"] = spec.recess_max_m - spec.recess_min_m
    index = []  # (position in u, length scale of the logit)
    pos = 0
    for key in template.names():  # ravel_pytree's order
        size = int(np.size(getattr(template, key)))
        if key in geometry:
            index.append((pos, geometry[key]))
        pos += size

    def jac(u):
        J = np.array(exact_j(u))
        un = np.asarray(u, float)
        for i, scale in index:
            sg = 0.5 * (1.0 + math.tanh(0.5 * un[i]))  # the logistic function, without overflow
            h = min(spec.dx_m / max(scale * sg * (1 - sg), 1e-300), 0.5)
            up, dn = un.copy(), un.copy()
            up[i] += h
            dn[i] -= h
            J[:, i] = (np.asarray(res_j(jnp.asarray(up))) - np.asarray(res_j(jnp.asarray(dn)))) / (2 * h)
        return J

    return jac


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


def _finish(spec, lobe, wave, unravel, u, res_j, jac_j, converged, it) -> HousedFit:
    from .goodness import goodness_of_fit

    params = unravel(jnp.asarray(u))
    r = np.asarray(res_j(jnp.asarray(u)))
    J = np.asarray(jac_j(jnp.asarray(u)))
    n_lobe = len(lobe.level_db)
    n_wave = 0 if wave is None else len(wave.x_m)
    n, k = n_lobe + n_wave, J.shape[1]
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
    for name in spec.fixed:  # held at the given value: reported, without an error
        values[f"{name}_mm"] = 1e3 * float(getattr(spec, f"{name}_m"))
    sig = np.asarray(lobe.sigma_db, float)
    model = r[:n_lobe] * sig + np.asarray(lobe.level_db)  # the soft-floored model the fit saw
    data_res = {"lobe": r[:n_lobe]}
    extra: dict = {}
    if wave is not None:
        w = np.asarray(wave.sigma_rad, float)
        dphase = np.arctan2(w * r[n_lobe : n_lobe + n_wave], 1 - w * r[n_lobe + n_wave :])
        data_res["wave"] = 2 * np.sin(dphase / 2) / w
        extra = {
            "wave_model_rad": np.asarray(wave.phase_rad) + dphase,
            "wave_residual_deg": np.degrees(dphase),
            "rms_wave_deg": float(np.degrees(np.sqrt(np.mean(dphase**2)))),
        }
        values["phase0_rad"] = float(params.phase0)
    res_db = model - np.asarray(lobe.level_db)
    goodness = goodness_of_fit(data_res, J, cov, k)
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
        **extra,
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
        shaped = any(("cone_mm" in f.physical or "bend_q" in f.physical) for f in self.fits.values())
        if shaped:  # the one-parameter shapes (`fit.housed_profiles`)
            head += " shape |"
        rows = [head, "|" + "---|" * (13 if shaped else 12)]
        for name, f in self.fits.items():
            s = f.summary()
            mark = " (chosen)" if name == self.chosen else (" (ill-conditioned)" if f.ill_conditioned else "")
            mark += "".join(f" ({b} at bound)" for b in f.at_bound)
            rows.append(
                f"| {name}{mark} | {s['k']} | {s['chi2']:.1f} | {s['chi2_reduced']:.2f} | {s['p']:.2g} | "
                f"{s['aic']:.1f} | {s['bic']:.1f} | {s['rms_db']:.2f} | {s['condition']:.2g} | "
                f"{_pm(s, 'diaphragm_mm')} | {_pm(s, 'recess_mm')} | {_pm(s, 'opening_mm')} |"
                + (f" {_shape(s)} |" if shaped else "")
            )
        return "\n".join(rows) + f"\n\nChosen: **{self.chosen}**. {self.reason}\n"


def _pm(s: dict, key: str) -> str:
    if key not in s:
        return "-"
    if key + "_err" not in s:
        return f"{s[key]:.2f} (fixed)"
    return f"{s[key]:.2f} +- {s[key + '_err']:.2f}"


def _shape(s: dict) -> str:
    if "cone_mm" in s:
        return f"cone {_pm(s, 'cone_mm')} mm"
    if "bend_q" in s:
        return f"q {_pm(s, 'bend_q')}"
    return "-"


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


NESTED_IN = {"recessed": "flat", "opening": "recessed", "cone": "flat", "bending": "flat", "profile": "flat"}
"""The family each one reduces to (recess 0; no plate, i.e. an opening as wide as the bore; a cone
of depth 0; q = 0; a uniform profile): its fit seeds the richer family's, and the richer family's chi-square should
not exceed it."""


def _warm_starts(s: HousedSpec, parent: HousedFit) -> list[HousedParams]:
    """Raw starts of family `s.family` from its parent's fit: the parent's geometry with the new
    parameter (i) at its default and (ii) next to the value that reduces it to the parent (a
    recess of half a cell, an opening of 0.97 of the bore: at the bound itself the logit has no
    gradient)."""
    ph = parent.physical
    diam = ph["diaphragm_mm"] * 1e-3
    rec = ph.get("recess_mm")
    lo = s.recess_min_m
    near_rec = lo + 0.5 * s.dx_m
    rb = s.housing.bore_radius_m
    opening = ph.get("opening_mm")
    cases: list[tuple[float | None, float | None]] = [
        (None if rec is None else max(rec * 1e-3, lo + 0.05 * (s.recess_max_m - lo)), None)
    ]
    if s.family == "recessed":
        cases.append((near_rec, None))
    if s.family == "opening":
        cases.append((max(rec * 1e-3, lo + 0.5 * s.dx_m) if rec is not None else near_rec, 2 * 0.97 * rb))
    if s.family == "cone":  # the lobe is even in h (flat at 0): start off it, shallow and deep
        return [
            dataclasses.replace(s.truth_params(diaphragm_m=diam, cone_m=h), gain_db=jnp.asarray(ph["gain_db"]))
            for h in (0.5e-3, 2e-3)
        ]
    if s.family == "bending":
        return [
            dataclasses.replace(s.truth_params(diaphragm_m=diam, bend=q), gain_db=jnp.asarray(ph["gain_db"]))
            for q in (0.3, -0.3, 1.5)
        ]
    out = []
    for recess_m, opening_m in cases:
        q = s.truth_params(
            diaphragm_m=diam,
            recess_m=recess_m,
            opening_m=opening_m if opening_m is not None else (None if opening is None else opening * 1e-3),
        )
        out.append(dataclasses.replace(q, gain_db=jnp.asarray(ph["gain_db"])))
    return out


SHAPE_GRID = {
    "cone": (0.5e-3, 1e-3, 2e-3, 3e-3, 4e-3, 5e-3, 6e-3),
    "bending": (-0.9, -0.5, 0.5, 1.0, 1.5, 2.0, 2.5, 2.9),
}
"""Shape values (cone depth h in m, capped below the can's length; bending q) of the grid start
(`_grid_start`); h > 0 only: the lobe is even in h."""


def _grid_start(s: HousedSpec, lobe: LobeData) -> HousedParams:
    """The best point of a coarse grid (`SHAPE_GRID` x diaphragm 0.35-0.99 of the bore) by the
    sigma-weighted RMS after the best gain: the shape families' cost has separate minima (measured,
    the T4010A1 table: a bending fit from the flat piston's diameter went to q = -1 at 0.63 dB while
    q = 2.3 at a 3.5 mm diaphragm gives 0.58 dB), which starts next to the parent's fit miss."""
    fw = HousedForward(s, lobe.angle_deg)
    lob = jax.jit(fw.lobe_db)
    y, w = np.asarray(lobe.level_db, float), 1 / np.asarray(lobe.sigma_db, float) ** 2
    best: tuple[float, HousedParams | None] = (math.inf, None)
    for v in SHAPE_GRID[s.family]:
        if s.family == "cone" and v >= 0.95 * s.housing.length_m:
            continue
        for frac in (0.35, 0.45, 0.55, 0.65, 0.75, 0.87, 0.99):
            kw = {"cone_m": v} if s.family == "cone" else {"bend": v}
            q = s.truth_params(diaphragm_m=2 * frac * s.housing.bore_radius_m, **kw)
            r = np.asarray(lob(q)) - y
            gain = -float(np.sum(w * r) / np.sum(w))
            cost = float(np.sum(w * (r + gain) ** 2))
            if cost < best[0]:
                best = (cost, dataclasses.replace(q, gain_db=jnp.asarray(gain)))
    assert best[1] is not None
    return best[1]


def family_ladder(
    spec: HousedSpec,
    lobe: LobeData,
    *,
    wave: WaveData | None = None,
    families=FAMILIES,
    max_iter: int = 60,
    starts: int = 3,
    resolution_cpw: float | None = None,
) -> Ladder:
    """Fit each of `families` (a `HousedSpec` like `spec` with its family replaced) to `lobe`
    (and the wavefront `wave`, if given: `fit_housed`),
    from the fit of the family it reduces to (`NESTED_IN`, `_warm_starts`), a shape family also from
    its grid start (`_grid_start`), and, with `starts` > 1, from its own starts, keeping the best; then choose (`choose_family`). With `resolution_cpw`,
    the chosen fit's errors get the resolution term (`add_resolution_term`). A richer family whose
    chi-square stays above its parent's (a local minimum the starts did not escape) is named in
    the reason."""
    fits: dict = {}
    stuck = []
    for fam in families:
        s = dataclasses.replace(spec, family=fam)
        parent = fits.get(NESTED_IN.get(fam, ""))
        inits: list = [] if parent is None else _warm_starts(s, parent)
        if fam in SHAPE_GRID:
            inits.append(_grid_start(s, lobe))
        cands = [fit_housed(s, lobe, wave=wave, init=q, max_iter=max_iter) for q in inits]
        if not inits or starts > 1:
            cands.append(fit_housed(s, lobe, wave=wave, max_iter=max_iter, starts=starts))
        f = min(cands, key=lambda c: c.chi2)
        if parent is not None and f.chi2 > parent.chi2 + 1.0:
            stuck.append(f"{fam} (chi2 {f.chi2:.1f} above {NESTED_IN[fam]}'s {parent.chi2:.1f})")
        fits[fam] = f
    chosen, reason = choose_family(fits)
    if stuck:
        reason += " Local minima: " + ", ".join(stuck) + "; their comparison is not conclusive."
    if resolution_cpw is not None:
        add_resolution_term(fits[chosen], lobe, resolution_cpw, wave=wave, max_iter=max_iter)
        reason += f" Its errors include the shift of a refit at {resolution_cpw:g} cells per wavelength."
    return Ladder(fits, chosen, reason)
