"""Error budgets of fitted transducer parameters: a statistical and a systematic part, the
parameters the data cannot determine named as such, and parameters at a bound reported as bounds.

    budget = error_budget(fitted, transfer, lobe, wave, options,
                          make_transfer=lambda m: <the same transfer at m cells per wavelength>,
                          second_cells_per_wavelength=None, model_families=None)

Quantities: the active diameter (mm), the gain (dB, referred to the centre cell's weight), the
wavefront phase offset (deg, referred to the centre cell's lag), the smooth profiles' Chebyshev
coefficients (every other raw profile parameter, e.g. a disc's rim taper), and per cell across the
face the weight relative to the reference (centre) cell and the lag
relative to the centre cell (µs): the overall scale and a common lag are the gain and the offset,
so only these are defined by the data and comparable between fits.

Per quantity, all 1-sigma-like, combined in quadrature into `total`:

- **statistical**: the Jacobian covariance (J^T J)^+ of the minimised residuals at the solution,
  propagated to the quantity: the noise alone, as if the model were exact;
- **systematic, resolution**: the fit repeated on a second lattice (`second_cells_per_wavelength`,
  default 1.5 x the fit's), the difference scaled to the discretisation error of the nominal
  fit assuming the lattice's second-order convergence: |q_1 - q_2| / |1 - (m_1 / m_2)^2|;
- **systematic, model**: (a) `sys_chi2` = stat * sqrt(max(v - 1, 0)), v the fit's variance factor
  (chi2_red for l2, Huber's M-estimator factor for robust losses): residuals above the noise are
  model error the covariance has to carry; (b) `sys_family`: model averaging's unconditional
  variance about the reported value over alternative model families (`model_families`; default
  n_basis + 1 for smooth profiles, free <-> symmetric for per-cell ones; "free"/"symmetric" asked
  for a smooth model test the taper's shape with a weak prior): each family weighted by its
  Akaike weight (quasi-AIC = chi2 / c + 2 x effective parameters, c the variance factor of the
  richest model; families beyond 10 of the best get none) contributes its shift squared plus the
  extra variance with which it determines the quantity (a family that pins the quantity less well
  says the nominal model's precision rests on its assumptions). Coefficients of another basis
  are the ones that family's per-cell profile implies (inverse-variance weighted projection).
- **total**: the quadrature sum (a 1-sigma-like figure).

Gain and phase offset refer to the lattice's unit source cell, so they get no resolution term.

Identifiability, decided by the data, not hard-coded:

- the model's candidate symmetries (`ModelSpec.symmetries`: time reversal of the lags, mirror
  across the face) are applied to the solution and refitted; when the mapped solution fits as
  well (scaled delta chi2 <= `EQUIVALENT_DELTA_CHI2`), every quantity it changes by more than
  twice its total uncertainty is NAMED undetermined, with the other solution's value (a lobe
  alone cannot tell a lead from a lag);
- directions of the Jacobian's null space make the quantities they move undetermined;
- quantities that are one parameter by construction (the mirror cells of a symmetric profile:
  identical rows of d quantity / d parameters) are listed once;
- cells outside the active aperture (window < 1/2) carry no determined lag or weight.

Bounds: a diameter within max(2 inflated standard errors, 2 edge softnesses) of 0 or of the modelled
line's length, or a lag that close to +-T/2, is pinned there: reported as a one-sided limit ("at
bound", ">= x") with the fix, not as a value +- 0.00.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from ..transforms import sigmoid
from .data import LobeData, WaveData
from .model import PROFILES, ModelSpec, device_array, physical_of
from .solve import FitOptions, FitResult, _flat_jacobian, fit
from .transfer import Transfer

EQUIVALENT_DELTA_CHI2 = 4.0
"""Two solutions whose costs differ by less than this (delta chi2, scaled by the variance factor)
are equally good fits: a 2-sigma distinction for one parameter."""
SUPPORTED_DELTA_QAIC = 10.0
"""Model families within this quasi-AIC of the best count in the family spread (Burnham and
Anderson: beyond 10, essentially no support)."""
FAMILY_KEYS = ("weights", "lags", "n_basis", "symmetric", "smoothness_sigma")
NUISANCE = ("gain_db", "phase0_deg")
OFFSET_LABELS = ("diameter.logit", "gain_db", "phase0_rad")
"""Raw parameters that are not profile coefficients (their physical forms are budget scalars)."""
"""Offsets whose meaning depends on the lattice's unit source cell (no resolution term)."""
STATUSES = ("determined", "reference", "fixed", "at_bound", "undetermined", "inactive")
_COEF_UNITS = {
    "w.rim_log": "ln(rim weight)",
    "lag.rim_atanh": "artanh(2 lag / T)",
}
_HUMAN = {
    "diameter_mm": "active diameter",
    "gain_db": "gain (re the centre cell)",
    "phase0_deg": "wavefront phase offset (re the centre cell)",
    "w.rim_log": "rim weight (log)",
    "lag.rim_atanh": "rim lag",
    "w.rim_width_logit": "weight taper's rim width (logit of its share of the radius)",
    "lag.rim_width_logit": "lag taper's rim width (logit of its share of the radius)",
}


def coefficient_unit(label: str) -> str:
    """The unit of a raw profile coefficient: smooth weight coefficients multiply Chebyshev
    polynomials of the log weight, lag coefficients those of artanh(2 lag / T)."""
    if label in _COEF_UNITS:
        return _COEF_UNITS[label]
    if label.endswith("_logit"):
        return "logit"
    return "ln(weight)" if label.startswith("w.") else "artanh(2 lag / T)"


def human_name(name: str) -> str:
    """A reader's name for a budget quantity ("" where the name says it)."""
    if name in _HUMAN:
        return _HUMAN[name]
    for prefix, what in (
        ("w.T", "weight profile, Chebyshev coefficient of degree "),
        ("lag.T", "lag profile, Chebyshev coefficient of degree "),
    ):
        if name.startswith(prefix):
            return f"{what}{name[len(prefix) :]}"
    return ""


@dataclass(frozen=True)
class Estimate:
    """One quantity's value and error budget (all in `unit`). `status`: "determined",
    "reference" (fixed by definition, e.g. the centre cell's relative weight), "at_bound"
    (`limit` holds the one-sided statement, `limit_value` its number), "undetermined" (`note`
    says why; `alternatives` holds equally good values) or "inactive" (outside the aperture).
    `sys_resolution` / `sys_family` are None when not measured."""

    name: str
    unit: str
    value: float
    stat: float
    sys_resolution: float | None = None
    sys_chi2: float = 0.0
    sys_family: float | None = None
    status: str = "determined"
    note: str = ""
    limit: str | None = None
    limit_value: float | None = None
    bound_side: str | None = None  # "upper" or "lower"
    alternatives: tuple = ()
    y_mm: float | None = None  # position across the face of a per-cell quantity

    @property
    def sys_model(self) -> float:
        return math.hypot(self.sys_chi2, self.sys_family or 0.0)

    @property
    def systematic(self) -> float:
        return math.hypot(self.sys_resolution or 0.0, self.sys_model)

    @property
    def total(self) -> float:
        return math.hypot(self.stat, self.systematic)

    def covers(self, true_value: float, k: float = 1.0) -> bool:
        """Whether `true_value` lies within k x total of the value (or of an equally good
        alternative), or beyond the one-sided limit of a parameter at its bound."""
        if self.status == "at_bound" and self.limit_value is not None:
            return true_value >= self.limit_value if self.bound_side == "upper" else true_value <= self.limit_value
        return any(abs(v - true_value) <= k * self.total for v in (self.value, *self.alternatives))

    def z(self, true_value: float) -> float:
        """Error in units of the total uncertainty (against the nearest equally good value)."""
        d = min(abs(v - true_value) for v in (self.value, *self.alternatives))
        return d / self.total if self.total > 0 else (0.0 if d == 0 else math.inf)  # exact by construction: 0

    def text(self, digits: int = 3) -> str:
        """'v ± stat (stat) ± sys (sys) = ± total', or the limit / status."""
        f = f".{digits}g"
        if self.status == "at_bound":
            return f"{self.limit} ({self.note})" if self.note else str(self.limit)
        if self.status in ("reference", "fixed"):
            return f"{self.value:{f}} ({self.status})"
        if self.status in ("undetermined", "inactive"):
            alt = f"; also {', '.join(format(a, f) for a in self.alternatives)}" if self.alternatives else ""
            return f"{self.value:{f}} (undetermined{alt})"
        return f"{self.value:{f}} ± {self.total:{f}}"

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d.update(sys_model=self.sys_model, systematic=self.systematic, total=self.total)
        d["alternatives"] = list(self.alternatives)
        return d


@dataclass
class ErrorBudget:
    """Error budget of a fit: `scalars` (diameter, gain, offset, profile coefficients) and per
    cell `weights` and `lags` (independent cells only), with what was measured to build it:
    `resolution` (the second fit), `families`, `symmetries`, and sentences naming what the data do
    not determine (`undetermined`), mirror `aliases` and `notes`."""

    scalars: list
    weights: list
    lags: list
    variance_factor: float
    resolution: dict = field(default_factory=dict)
    families: list = field(default_factory=list)
    symmetries: list = field(default_factory=list)
    undetermined: list = field(default_factory=list)
    aliases: list = field(default_factory=list)
    notes: list = field(default_factory=list)

    def all(self) -> list:
        return [*self.scalars, *self.weights, *self.lags]

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> ErrorBudget:
        """The budget back from `to_dict()` (e.g. report.json's "budget")."""
        names = {f.name for f in dataclasses.fields(Estimate)}

        def est(x):
            return Estimate(**{k: (tuple(v) if k == "alternatives" else v) for k, v in x.items() if k in names})

        return cls(
            scalars=[est(x) for x in d["scalars"]],
            weights=[est(x) for x in d["weights"]],
            lags=[est(x) for x in d["lags"]],
            variance_factor=d["variance_factor"],
            resolution=dict(d.get("resolution", {})),
            families=list(d.get("families", [])),
            symmetries=list(d.get("symmetries", [])),
            undetermined=list(d.get("undetermined", [])),
            aliases=list(d.get("aliases", [])),
            notes=list(d.get("notes", [])),
        )

    def get(self, name: str) -> Estimate:
        for e in self.all():
            if e.name == name:
                return e
        raise KeyError(
            f"no estimate named {name!r}; have {', '.join(e.name for e in self.scalars)} and per-cell w[k], lag_us[k]"
        )

    def to_dict(self) -> dict:
        return {
            "scalars": [e.to_dict() for e in self.scalars],
            "weights": [e.to_dict() for e in self.weights],
            "lags": [e.to_dict() for e in self.lags],
            "variance_factor": self.variance_factor,
            "resolution": self.resolution,
            "families": self.families,
            "symmetries": self.symmetries,
            "undetermined": self.undetermined,
            "aliases": self.aliases,
            "notes": self.notes,
            "method": "total = quadrature sum of stat (Jacobian covariance), sys_resolution (second lattice, "
            "Richardson-scaled), sys_chi2 (stat * sqrt(variance_factor - 1)) and sys_family (spread over "
            "supported model families); 1-sigma-like",
        }

    def compare(self, truth: Mapping[str, Any]) -> dict:
        """Fitted vs true values in units of the total uncertainty. `truth` may hold scalars by
        estimate name (e.g. `diameter_mm`) and per-cell profiles as `y_m` with `weights`
        (relative to the centre, or absolute: normalised here) and/or `lags_s` (relative to the
        centre here). Per-cell results are summarised over the active, determined cells."""
        out: dict = {}
        for e in self.scalars:
            if e.name in truth:
                t = float(truth[e.name])
                out[e.name] = {
                    "true": t,
                    "fitted": e.value,
                    "stat": e.stat,
                    "systematic": e.systematic,
                    "total": e.total,
                    "status": e.status,
                    "limit": e.limit,
                    "error_in_total": (e.value - t) / e.total if e.total > 0 else math.inf,
                    "error_in_stat": (e.value - t) / e.stat if e.stat > 0 else math.inf,
                    "within_total": e.covers(t),
                }
        if "y_m" in truth:
            y = np.asarray(truth["y_m"], float)
            for key, ests, conv in (("weights", self.weights, None), ("lags_s", self.lags, 1e6)):
                if key not in truth or not ests:
                    continue
                v = np.asarray(truth[key], float)
                ref = np.interp(0.0, y, v)
                v = v / ref if key == "weights" else (v - ref) * conv
                zs, within = [], []
                for e in ests:
                    if e.status not in ("determined", "undetermined", "at_bound") or e.y_mm is None:
                        continue
                    t = float(np.interp(e.y_mm * 1e-3, y, v))
                    zs.append(e.z(t))
                    within.append(e.covers(t))
                if zs:
                    za = np.asarray(zs)
                    out[f"{key}_per_cell"] = {
                        "n_cells": len(za),
                        "fraction_within_total": float(np.mean(within)),
                        "fraction_within_2_total": float(np.mean(za <= 2)),
                        "max_error_in_total": float(za.max()),
                        "median_error_in_total": float(np.median(za)),
                    }
        return out

    def markdown(self) -> list[str]:
        """Markdown lines: the scalar table, the per-cell tables (active cells) and the notes."""
        lines = [
            "## Parameters and their uncertainties",
            "",
            "Every fitted parameter with its uncertainty (1-sigma-like): statistical (Jacobian covariance: the "
            "noise, as if the model were exact), systematic = resolution (refit on a second lattice) ⊕ model "
            "(chi2_red inflation ⊕ spread over model families), total = statistical ⊕ systematic. '—' marks a "
            "part that was not measured.",
            "",
        ]
        lines += _table(self.scalars, first="parameter")
        for title, ests in (
            ("Weights across the face (relative to the centre cell)", self.weights),
            ("Lags across the face (µs, relative to the centre cell)", self.lags),
        ):
            if not ests:
                continue
            n_in = sum(e.status == "inactive" for e in ests)
            lines += ["", f"### {title}", ""]
            lines += _table(ests, first="y (mm)")
            if n_in:
                lines += [
                    "",
                    f"{n_in} cells outside the active aperture are listed as inactive: the data do not determine them.",
                ]
        if self.aliases:
            lines += ["", "One parameter by construction (listed once): " + "; ".join(self.aliases)]
        if self.undetermined:
            lines += ["", "### Not determined by the data", ""] + [f"- {u}" for u in self.undetermined]
        lines += ["", "### How the systematic parts were measured", ""]
        r = self.resolution
        if r.get("measured"):
            lines.append(
                f"- resolution: refit at {r['second_cells_per_wavelength']:g} cells per wavelength (nominal "
                f"{r['cells_per_wavelength']:g}); differences x {r['richardson_factor']:.3g} (second-order "
                f"Richardson scaling); second fit chi2_red {r['chi2_reduced']:.3g}, converged {r['converged']}"
            )
        else:
            lines.append(f"- resolution: not measured ({r.get('reason', 'no second resolution given')})")
        lines.append(
            f"- chi2 inflation: variance factor {self.variance_factor:.3g} (errors x "
            f"{math.sqrt(max(self.variance_factor, 1.0)):.3g})"
        )
        for fam in self.families:
            lines.append(
                f"- family {fam['label']}: chi2_red {fam['chi2_reduced']:.3g}, delta QAIC {fam['delta_qaic']:+.1f}, "
                f"weight {fam.get('akaike_weight', 0):.2f}, "
                f"{'used' if fam['used'] else 'not used (' + fam['why_not'] + ')'}"
            )
        if not self.families:
            lines.append("- model families: none compared")
        for s in self.symmetries:
            lines.append(f"- symmetry '{s['name']}': {s['verdict']}")
        lines += [f"- {n}" for n in self.notes]
        return lines


def _fmt(x: float | None, digits: int = 3) -> str:
    return "—" if x is None else f"{x:.{digits}g}"


def _table(ests: list, first: str) -> list[str]:
    lines = [
        f"| {first} | value | statistical | systematic | total | sys: resolution | sys: model | status |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for e in ests:
        label = (
            f"{e.y_mm:+.2f}"
            if e.y_mm is not None and first.startswith("y")
            else f"{e.name} ({e.unit}): {human_name(e.name)}".rstrip(": ")
        )
        status = e.status if not e.note else f"{e.status}: {e.note}"
        parts = f"{_fmt(e.sys_resolution)} | {_fmt(e.sys_model)}"
        if e.status == "at_bound":
            lines.append(f"| {label} | {e.limit} | — | — | — | — | — | {status} |")  # a limit, not a value ± error
            continue
        if e.status in ("reference", "fixed", "inactive") or (e.status == "undetermined" and not e.alternatives):
            lines.append(f"| {label} | {e.value:.5g} | — | — | — | — | — | {status} |")
            continue
        alt = f" (or {', '.join(f'{a:.4g}' for a in e.alternatives)})" if e.alternatives else ""
        lines.append(
            f"| {label} | {e.value:.5g}{alt} | {_fmt(e.stat)} | {_fmt(e.systematic)} | {_fmt(e.total)} | "
            f"{parts} | {status} |"
        )
    return lines


# -- quantities ---------------------------------------------------------------------------
def quantities(spec: ModelSpec, params: dict):
    """(vector, names, units) of the budget's quantities for `params` (differentiable)."""
    ph = spec.physical(params)
    n = spec.n_cells
    mid = list(spec.reference_cells)
    w = ph["weights"]
    wc = jnp.mean(w[jnp.asarray(mid)])
    lag = ph["lags_s"]
    lc = jnp.mean(lag[jnp.asarray(mid)])
    parts, names, units = [], [], []
    if spec.weights != "uniform" or spec.fit_diameter:
        parts.append(w / wc)
        names += [f"w[{k}]" for k in range(n)]
        units += ["re centre"] * n
    if spec.lags != "uniform":
        parts.append((lag - lc) * 1e6)
        names += [f"lag_us[{k}]" for k in range(n)]
        units += ["µs"] * n
    if "diam" in params:
        parts.append(jnp.atleast_1d(ph["diameter_m"] * 1e3))
        names.append("diameter_mm")
        units.append("mm")
    if "gain_db" in params:
        parts.append(jnp.atleast_1d(ph["gain_db"] + 20 * jnp.log10(wc)))
        names.append("gain_db")
        units.append("dB")
    if "phase0" in params:
        parts.append(jnp.atleast_1d(jnp.degrees(ph["phase0_rad"] - 2 * math.pi * spec.frequency_hz * lc)))
        names.append("phase0_deg")
        units.append("deg")
    labels = spec.raw_labels(params)
    flat = ravel_pytree(params)[0]
    coef = [i for i, lab in enumerate(labels) if "[" not in lab and lab not in OFFSET_LABELS]
    if coef:
        parts.append(flat[jnp.asarray(coef)])
        names += [labels[i] for i in coef]
        units += [coefficient_unit(labels[i]) for i in coef]
    return jnp.concatenate(parts), names, units


_quantities = eqx.filter_jit(quantities)
"""`quantities` as one compiled program (called eagerly, its ~40 operations each ran as its own)."""


@eqx.filter_jit
def _quantity_jacobian(spec: ModelSpec, params: dict):
    jac = jax.jacfwd(lambda p: quantities(spec, p)[0])(params)
    return _flat_jacobian(jac, params)


@eqx.filter_jit
def _quantities_and_jacobian(spec: ModelSpec, params: dict):
    """(values, names, units, d values / d raw parameters) as one program (two would each be
    traced, lowered and read from the cache in every new process)."""
    v, names, units = quantities(spec, params)
    return v, names, units, _quantity_jacobian(spec, params)


def _values(spec: ModelSpec, params: dict) -> dict:
    v, names, _ = _quantities(spec, params)
    return dict(zip(names, np.asarray(v).tolist()))


def _stats(r: FitResult) -> dict:
    """Statistical errors of a fit's quantities, inflated by its variance factor (its own total
    as far as the noise and its own chi2 go)."""
    v, names, _, G = _quantities_and_jacobian(r.spec, r.params)
    G = np.asarray(G)
    cov = np.asarray(r.covariance_raw)
    s = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", G, cov, G), 0, None) * max(r.variance_factor, 1.0))
    return dict(zip(names, s.tolist()))


def _on_nominal(spec: ModelSpec, other_spec: ModelSpec, other: dict) -> dict:
    """Another fit's quantities (`other`: name -> number) under the nominal fit's names: per-cell
    values interpolated at the nominal cells' positions, coefficients only where the basis is the
    same."""
    out = {k: v for k, v in other.items() if not k.startswith(("w[", "lag_us[", "w.", "lag."))}
    same_basis = spec.symmetric == other_spec.symmetric and spec.n_basis == other_spec.n_basis
    for key, profile in (("w", "weights"), ("lag", "lags")):
        # a coefficient is the same quantity only in the same basis (adding a term moves the others)
        if getattr(spec, profile) == getattr(other_spec, profile) and same_basis:
            out.update({k: v for k, v in other.items() if k.startswith(f"{key}.")})
    for prefix in ("w[", "lag_us["):
        arr = [other.get(f"{prefix}{k}]") for k in range(other_spec.n_cells)]
        if arr[0] is None:
            continue
        interp = np.interp(spec.y_m, other_spec.y_m, np.asarray(arr, float))
        out.update({f"{prefix}{k}]": float(interp[k]) for k in range(spec.n_cells)})
    return out


def _per_cell(ospec: ModelSpec, p: dict, y_nom, y_other, key: str):
    """A fit's per-cell raw profile (log weight, or artanh(2 lag / T)) interpolated at `y_nom`."""
    ph = ospec.physical(p)
    v = (
        jnp.log(ph["weights_raw"])
        if key == "w"
        else jnp.arctanh(jnp.clip(2 * ph["lags_s"] / ospec.period_s, -0.999999, 0.999999))
    )
    return jnp.interp(y_nom, y_other, v)


@eqx.filter_jit
def _per_cell_raw(ospec: ModelSpec, params: dict, y_nom, y_other, key: str):
    """`_per_cell` and its Jacobian w.r.t. the raw parameters (flat), as one compiled program."""
    jac = jax.jacfwd(lambda p: _per_cell(ospec, p, y_nom, y_other, key))(params)
    return _per_cell(ospec, params, y_nom, y_other, key), _flat_jacobian(jac, params)


def _implied_coefficients(spec: ModelSpec, active: np.ndarray, other: FitResult) -> tuple[dict, dict]:
    """The nominal smooth profiles' coefficients that another family's fit implies: its per-cell
    raw profiles (log weight, artanh(2 lag / T)) interpolated at the nominal's active cells and
    projected on the nominal basis by inverse-variance weighted least squares (a free constant
    column: the gain and the offset absorb it), so cells that family determines poorly (the edge)
    count little; with the projection's statistical errors (that fit's covariance, inflated by its
    variance factor)."""
    keys = [(k, p) for k, p in (("w", spec.weights), ("lag", spec.lags)) if p == "smooth"]
    if not keys or not active.any():
        return {}, {}
    ospec, y_nom, y_other = other.spec, device_array(spec.y_m[active]), device_array(other.spec.y_m)
    cov = np.asarray(other.covariance_raw) * max(other.variance_factor, 1.0)
    vals, ses = {}, {}
    step = 2 if spec.symmetric else 1
    for key, profile in keys:
        v, Gv = (np.asarray(a) for a in _per_cell_raw(ospec, other.params, y_nom, y_other, key))
        cv = Gv @ cov @ Gv.T
        var = np.clip(np.diag(cv), 1e-12 * max(float(np.max(np.diag(cv))), 1e-300), None)
        E = spec.expansion(profile)[active]
        A = np.concatenate([E, np.ones((E.shape[0], 1))], axis=1)
        W = 1.0 / var
        P = np.linalg.solve(A.T @ (A * W[:, None]), (A * W[:, None]).T)[:-1]
        c = P @ v
        se = np.sqrt(np.clip(np.diag(P @ cv @ P.T), 0, None))
        for i in range(E.shape[1]):
            vals[f"{key}.T{step * (i + 1)}"] = float(c[i])
            ses[f"{key}.T{step * (i + 1)}"] = float(se[i])
    return vals, ses


def map_params(spec_from: ModelSpec, params: dict, spec_to: ModelSpec) -> dict:
    """A warm start for `spec_to` from a fit of `spec_from` (another resolution or family): the
    per-cell log weights and lag arguments interpolated at the new cells and projected on the new
    parameterisation."""
    ph = physical_of(spec_from, params)
    logw = np.log(np.asarray(ph["weights_raw"]))
    arg = np.arctanh(np.clip(2 * np.asarray(ph["lags_s"]) / spec_from.period_s, -0.999999, 0.999999))
    y0, y1 = spec_from.y_m, spec_to.y_m
    return spec_to.params_from_profiles(
        np.interp(y1, y0, logw), np.interp(y1, y0, arg), float(ph["diameter_m"]), params
    )


def default_families(spec: ModelSpec) -> list[dict]:
    """Alternative model families compared by default: one more basis function for smooth
    profiles (n vs n + 1); for per-cell profiles, free <-> symmetric. A per-cell profile for a
    smooth one is not a default: it determines the aperture far less well, and its spread would
    dominate every error; ask for it (`model_families = ["symmetric"]`) where the smooth basis may
    miss the true shape (e.g. the square-root edge of a circular piston seen by a line model)."""
    out: list[dict] = []
    if "smooth" in (spec.weights, spec.lags):
        out.append({"n_basis": spec.n_basis + 1})
    swap = {"symmetric": "free", "free": "symmetric"}
    alt = {k: swap[getattr(spec, k)] for k in ("weights", "lags") if getattr(spec, k) in swap}
    if alt:
        out.append(alt)
    return out


def weak_smoothness_sigma(spec: ModelSpec) -> float:
    """The smoothness prior of a per-cell family that tests a smooth profile's shape: the weakest
    that still suppresses the non-radiating cell-to-cell oscillations, i.e. a Nyquist ripple of
    0.01 (1 % in weight, 0.01 rad in lag phase) on every cell costs at least one unit of chi2
    (second difference 4 x 0.01 per cell over n cells: sigma = 0.04 sqrt(n))."""
    return 0.04 * math.sqrt(spec.n_cells)


def _family(spec: ModelSpec, f: str | Mapping[str, Any]) -> dict:
    """A family given as overrides, or as a profile name applied to every fitted profile ("smooth"
    when the nominal is smooth means one more basis function; "free"/"symmetric" for a smooth
    nominal come with the weak prior `weak_smoothness_sigma`); {} when it is the nominal model."""
    if not isinstance(f, str):
        return dict(f)
    if f not in PROFILES:
        raise ValueError(
            f"model_families entry {f!r}: a profile family is one of {', '.join(PROFILES)}, or give "
            f"overrides such as {{'n_basis': {spec.n_basis + 1}}}"
        )
    ov: dict = {k: f for k in ("weights", "lags") if getattr(spec, k) != "uniform" and getattr(spec, k) != f}
    if not ov and f == "smooth":
        ov = {"n_basis": spec.n_basis + 1}
    if f in ("free", "symmetric") and any(getattr(spec, k) == "smooth" for k in ov):
        ov["smoothness_sigma"] = weak_smoothness_sigma(spec)  # a per-cell shape test of a smooth profile
    return ov


def _family_label(ov: Mapping[str, Any]) -> str:
    return ", ".join(
        f"{k} = {v!r}" if isinstance(v, str) else f"{k} = {v:.3g}" if isinstance(v, float) else f"{k} = {v}"
        for k, v in ov.items()
    )


def _check_family(spec: ModelSpec, options: FitOptions, ov: Mapping[str, Any]) -> tuple[ModelSpec, FitOptions]:
    bad = [k for k in ov if k not in FAMILY_KEYS]
    if bad:
        raise ValueError(
            f"model_families entry {dict(ov)}: unknown key(s) {', '.join(bad)}; allowed: {', '.join(FAMILY_KEYS)}"
        )
    for k in ("weights", "lags"):
        if k in ov and ov[k] not in PROFILES:
            raise ValueError(f"model_families entry {dict(ov)}: {k} = {ov[k]!r}; allowed: {', '.join(PROFILES)}")
    model = {k: v for k, v in ov.items() if k != "smoothness_sigma"}
    opts = options
    if "smoothness_sigma" in ov:
        sig = ov["smoothness_sigma"]
        if not (isinstance(sig, (int, float)) and sig > 0):
            raise ValueError(f"model_families entry {dict(ov)}: smoothness_sigma = {sig!r} must be > 0")
        opts = dataclasses.replace(options, smoothness_sigma=float(sig))
    return dataclasses.replace(spec, **model), opts


def _qaic(r: FitResult, c: float) -> float:
    return 2 * r.cost / c + 2 * r.effective_params


# -- the budget ----------------------------------------------------------------------------
def second_resolution(cells_per_wavelength: float, second: float | None = None) -> float:
    """The resolution (cells per wavelength) of the error budget's refit: `second`, else 1.5 x the
    fit's."""
    return float(second or 1.5 * cells_per_wavelength)


def error_budget(
    fitted: FitResult,
    transfer: Transfer,
    lobe: LobeData | None,
    wave: WaveData | None,
    options: FitOptions | None = None,
    *,
    make_transfer: Callable[[float], Transfer] | None = None,
    second_cells_per_wavelength: float | None = None,
    model_families: Sequence[str | Mapping[str, Any]] | None = None,
    symmetries: bool = True,
    progress: bool = False,
) -> ErrorBudget:
    """The error budget of `fitted` (the fit of `fitted.spec` to `lobe`/`wave` with `transfer`
    and `options`; see the module docstring for the method).

    - `make_transfer(cells_per_wavelength) -> Transfer`: the same transfer (same data points and
      modelled line length) at another resolution; None skips the resolution part (the budget
      says so).
    - `second_cells_per_wavelength`: that resolution; None: 1.5 x the fit's.
    - `model_families`: alternative families, each either `ModelSpec` overrides, e.g.
      `{"n_basis": 5}` or `{"weights": "symmetric", "smoothness_sigma": 0.3}` (keys: weights, lags,
      n_basis, symmetric, smoothness_sigma), or a profile name ("free", "symmetric", "smooth")
      applied to every fitted profile ("smooth" for a smooth nominal: n_basis + 1); None:
      `default_families`; [] compares none.
    - `symmetries`: test the model's candidate symmetries (one refit each; see the module).
    - `progress`: print one line per refit.
    - `options`: the fit's settings (default: those `fitted` ran with).

    Refits start from the nominal solution (mapped onto the other model) and use `options`.
    With `make_transfer=None, model_families=[], symmetries=False` no refit runs: the
    statistical part, chi2 inflation, bounds, null directions and mirror aliases only."""
    spec, params = fitted.spec, fitted.params
    options = options or fitted.options or FitOptions()
    say = print if progress else (lambda *a, **k: None)
    vf = fitted.variance_factor
    v, names, units, G = _quantities_and_jacobian(spec, params)
    v, G = np.asarray(v), np.asarray(G)
    cov = fitted.covariance_raw
    stat = (
        np.sqrt(np.clip(np.einsum("ij,jk,ik->i", G, cov, G), 0, None)) if cov is not None else np.full(len(v), np.nan)
    )
    sys_chi2 = stat * math.sqrt(max(vf - 1.0, 0.0))
    notes: list[str] = []
    ph = physical_of(spec, params)
    window = np.asarray(ph["weights"]) / np.asarray(ph["weights_raw"])
    active = window >= 0.5  # cells inside the active aperture

    # resolution: the refit at a second resolution runs in a background thread while the
    # model-family refits run here (XLA's compilation and the solver's steps release the GIL)
    sys_res: dict[str, float] | None = None
    resolution: dict = {"measured": False}
    m1 = float(transfer.info.get("cells_per_wavelength", transfer.grid.cells_per_wavelength))
    refit2 = None
    if make_transfer is None:
        resolution["reason"] = "no second transfer (make_transfer) given"
    else:
        m2 = second_resolution(m1, second_cells_per_wavelength)
        if not (m2 > 0 and math.isfinite(m2)) or abs(m2 - m1) < 1e-9:
            raise ValueError(
                f"second_cells_per_wavelength = {m2:g} must be > 0 and differ from the fit's {m1:g} "
                "(e.g. 1.5 x the fit's)"
            )
        say(f"[budget] refit at {m2:g} cells per wavelength (resolution error)")
        T2 = make_transfer(m2)
        spec2 = dataclasses.replace(spec, n_cells=T2.n_cells, dx_m=T2.grid.dx_m)
        pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="difflattice-budget")
        refit2 = pool.submit(fit, spec2, T2, lobe, wave, options, params0=map_params(spec, params, spec2))
        pool.shutdown(wait=False)
    notes_at = len(notes)  # the resolution's notes go before the families'

    # model families
    fams = default_families(spec) if model_families is None else [_family(spec, f) for f in model_families]
    fam_fits = []
    for ov in [f for f in fams if f]:
        fspec, fopt = _check_family(spec, options, ov)
        if fspec == spec and fopt == options:
            continue  # the nominal model itself (e.g. "symmetric" of a model that is symmetric anyway)
        say(f"[budget] refit with {_family_label(ov)} (model-family spread)")
        fam_fits.append((ov, fspec, fit(fspec, transfer, lobe, wave, fopt, params0=map_params(spec, params, fspec))))
    sys_fam: dict[str, float] | None = None
    families = []
    if fam_fits:
        allfits = [fitted] + [f for _, _, f in fam_fits]
        richest = max(allfits, key=lambda f: f.effective_params)
        c = max(richest.variance_factor, 1.0)
        q = [_qaic(f, c) for f in allfits]
        best = min(q)
        var_fam = {k: 0.0 for k in names}
        own = dict(zip(names, (stat * math.sqrt(max(vf, 1.0))).tolist()))
        used_all = [True] + [
            ff.converged and qf - best <= SUPPORTED_DELTA_QAIC for (_, _, ff), qf in zip(fam_fits, q[1:])
        ]
        akaike = np.array([math.exp(-(qk - best) / 2) if u else 0.0 for qk, u in zip(q, used_all)])
        akaike /= akaike.sum()
        for (ov, fspec, ff), qf, used, wk in zip(fam_fits, q[1:], used_all[1:], akaike[1:]):
            dq = qf - best
            why = "" if used else ("did not converge" if not ff.converged else f"delta QAIC > {SUPPORTED_DELTA_QAIC:g}")
            # values (and, where used, their errors) from one program per family
            fv, fnames, _, _ = _quantities_and_jacobian(fspec, ff.params)
            other = _on_nominal(spec, fspec, dict(zip(fnames, np.asarray(fv).tolist())))
            if used:
                # model averaging's unconditional variance about the reported (nominal) value:
                # the Akaike-weighted shift to each family's value plus the extra variance of a
                # family that determines the quantity less well
                other_se = _on_nominal(spec, fspec, _stats(ff))
                if not any(
                    k in other for k in names if k.startswith(("w.", "lag."))
                ):  # another basis: implied coefficients
                    imp, imp_se = _implied_coefficients(spec, active, ff)
                    other.update(imp)
                    other_se.update(imp_se)
                for k, val in zip(names, v):
                    if k in other:
                        extra = max(other_se.get(k, 0.0) ** 2 - own[k] ** 2, 0.0)
                        var_fam[k] += wk * ((other[k] - val) ** 2 + extra)
            families.append(
                {
                    "label": _family_label(ov),
                    "overrides": dict(ov),
                    "chi2_reduced": ff.chi2_reduced,
                    "effective_params": ff.effective_params,
                    "delta_qaic": dq,
                    "akaike_weight": float(wk),
                    "converged": ff.converged,
                    "used": used,
                    "why_not": why,
                    "values": {k: other[k] for k in ("diameter_mm", "gain_db", "phase0_deg") if k in other},
                }
            )
        sys_fam = {k: math.sqrt(x) for k, x in var_fam.items()}
        families.insert(
            0,
            {
                "label": "nominal",
                "overrides": {},
                "chi2_reduced": fitted.chi2_reduced,
                "effective_params": fitted.effective_params,
                "delta_qaic": q[0] - best,
                "akaike_weight": float(akaike[0]),
                "converged": fitted.converged,
                "used": True,
                "why_not": "",
            },
        )
        if q[0] - best > SUPPORTED_DELTA_QAIC:
            notes.append(
                f"an alternative model family fits much better (delta QAIC of the nominal {q[0] - best:+.1f}): "
                "consider it (see the families below)"
            )

    if refit2 is not None:
        f2 = refit2.result()
        factor = 1.0 / abs(1.0 - (m1 / m2) ** 2)
        other = _on_nominal(spec, spec2, _values(spec2, f2.params))
        # the gain and the phase offset refer to the lattice's unit source cell, whose strength and
        # phase change with the cell size: not a property of the transducer, so no resolution term
        sys_res = {k: factor * abs(other[k] - val) for k, val in zip(names, v) if k in other and k not in NUISANCE}
        resolution = {
            "measured": True,
            "cells_per_wavelength": m1,
            "second_cells_per_wavelength": m2,
            "richardson_factor": factor,
            "chi2_reduced": f2.chi2_reduced,
            "converged": f2.converged,
            "values": {k: other[k] for k in ("diameter_mm", "gain_db", "phase0_deg") if k in other},
        }
        if not f2.converged:
            notes.insert(
                notes_at,
                f"the refit at {m2:g} cells per wavelength did not converge ({f2.result_code}): its "
                "resolution estimate is uncertain",
            )

    # estimates before identifiability
    y_mm = spec.y_m * 1e3
    est: dict[str, Estimate] = {}
    for i, (k, u) in enumerate(zip(names, units)):
        pos = None
        if k.startswith(("w[", "lag_us[")):
            pos = float(y_mm[int(k[k.index("[") + 1 : -1])])
        est[k] = Estimate(
            name=k,
            unit=u,
            value=float(v[i]),
            stat=float(stat[i]),
            sys_resolution=None if sys_res is None else sys_res.get(k),
            sys_chi2=float(sys_chi2[i]),
            sys_family=None if sys_fam is None else sys_fam.get(k),
            y_mm=pos,
        )
    undetermined: list[str] = []

    # reference cells, inactive cells
    n = spec.n_cells
    mid = list(spec.reference_cells)
    for k in range(n):
        for key in (f"w[{k}]", f"lag_us[{k}]"):
            if key not in est:
                continue
            e = est[key]
            if window[k] < 0.5:
                est[key] = dataclasses.replace(e, status="inactive", note="outside the active aperture")
            elif k in mid and e.stat <= 1e-9 * max(abs(e.value), 1.0):
                est[key] = dataclasses.replace(
                    e,
                    status="reference",
                    note="relative to the centre: fixed by definition",
                    stat=0.0,
                    sys_resolution=0.0,
                    sys_chi2=0.0,
                    sys_family=0.0,
                )

    # quantities the fit does not move (a uniform profile's cells, a rim taper's flat part, a
    # fixed diameter): fixed by the model, not determined by the data
    gnorm = np.linalg.norm(G, axis=1) if G.size else np.zeros(len(names))
    for i, k in enumerate(names):
        per_cell = k.startswith(("w[", "lag_us["))  # a scalar is listed only when it is fitted
        if per_cell and est[k].status == "determined" and gnorm[i] <= 1e-12 * max(abs(float(v[i])), 1.0):
            est[k] = dataclasses.replace(
                est[k],
                status="fixed",
                note="set by the model, not fitted",
                stat=0.0,
                sys_resolution=None,
                sys_chi2=0.0,
                sys_family=None,
            )

    # null directions of the Jacobian
    N = fitted.null_space
    if N is not None and N.size:
        moved = np.linalg.norm(G @ N, axis=1) > 1e-3 * np.maximum(np.linalg.norm(G, axis=1), 1e-300)
        hit = [k for k, m in zip(names, moved) if m and est[k].status == "determined"]
        for k in hit:
            est[k] = dataclasses.replace(
                est[k], status="undetermined", note="the data do not constrain it (null direction of the Jacobian)"
            )
        if hit:
            raw = spec.raw_labels(params)
            dirs = "; ".join(_direction_text(N[:, j], raw) for j in range(min(N.shape[1], 3)))
            undetermined.append(
                f"{_describe(hit)}: along {N.shape[1]} direction(s) the data do not constrain the "
                f"parameters (Jacobian condition number {fitted.condition_number:.3g}; flat direction(s) {dirs}); "
                "the data determine only the combinations orthogonal to them"
            )

    # symmetries of the data
    sym_out = []
    for name, g in (spec.symmetries() if symmetries else {}).items():
        pg = g(params)
        vg = _values(spec, pg)
        if max(abs(vg[k] - val) for k, val in zip(names, v)) < 1e-9 * max(1.0, float(np.max(np.abs(v)))):
            continue
        say(f"[budget] refit from the '{name}' image of the solution (identifiability)")
        fg = fit(spec, transfer, lobe, wave, options, params0=pg)
        d = 2 * (fg.cost - fitted.cost) / max(vf, 1.0)
        vals_g = _values(spec, fg.params)
        changed = [
            k
            for k in names
            if est[k].status in ("determined", "undetermined")
            and abs(vals_g[k] - est[k].value) > 2 * max(est[k].total, 1e-12)
        ]
        entry = {"name": name, "delta_chi2": d, "converged": fg.converged, "changed": changed}
        if d <= EQUIVALENT_DELTA_CHI2 and fg.converged:
            for k in changed:
                e = est[k]
                est[k] = dataclasses.replace(
                    e, status="undetermined", alternatives=(*e.alternatives, vals_g[k]), note=f"{name} fits as well"
                )
            entry["verdict"] = (
                f"fits the data as well (delta chi2 {d:+.2f}): {_describe(changed)} not determined"
                if changed
                else f"fits as well (delta chi2 {d:+.2f}) and changes nothing beyond the errors"
            )
            if changed:
                undetermined.append(
                    f"{_describe(changed)}: the {name} of the solution fits the data as well (delta chi2 "
                    f"{d:+.2f}); {_symmetry_hint(name)}"
                )
            if d < -EQUIVALENT_DELTA_CHI2:
                notes.append(
                    f"the {name} of the solution fits better (delta chi2 {d:+.2f}): the reported solution is a "
                    "local minimum"
                )
        else:
            entry["verdict"] = (
                f"rejected by the data (delta chi2 {d:+.2f})"
                if fg.converged
                else f"refit did not converge ({fg.result_code}); not decided"
            )
        sym_out.append(entry)

    # bounds
    bounds = spec.bounds()
    soft_mm = spec.edge_softness_m * 1e3
    if "diameter_mm" in est and est["diameter_mm"].status in ("determined", "undetermined"):
        est["diameter_mm"] = _diameter_bound(est["diameter_mm"], bounds["diameter_mm"], soft_mm, spec, params, cov, vf)
    lo, hi = bounds["lag_us"]
    for k in names:
        if k.startswith("lag_us[") and est[k].status == "determined":
            e = est[k]
            lag_abs = abs(float(np.asarray(ph["lags_s"])[int(k[7:-1])]) * 1e6)
            if hi - lag_abs < max(2 * e.stat * math.sqrt(max(vf, 1.0)), 0.01 * hi):
                side = "upper" if e.value > 0 else "lower"
                lim = e.value - 2 * e.total if side == "upper" else e.value + 2 * e.total
                lim = min(max(lim, -(hi - lo)), hi - lo)  # a relative lag lies within one period
                est[k] = dataclasses.replace(
                    e,
                    status="at_bound",
                    bound_side=side,
                    limit_value=lim,
                    limit=f"{'>=' if side == 'upper' else '<='} {lim:.4g}",
                    note="the lag reaches +-T/2 (defined modulo the period)",
                )

    # mirror duplicates, from the model's structure: cells at mirrored positions (y and -y) of a
    # profile that is one parameter per mirror pair by construction (never from equal values: a
    # disc's rings have no mirror, and a rim taper's flat rings are equal without being one)
    aliases = []
    drop: set[str] = set()
    for prefix, profile in (("w[", spec.weights), ("lag_us[", spec.lags)):
        pairs = _mirror_pairs(spec, profile)
        pairs = [(a, b) for a, b in pairs if f"{prefix}{a}]" in est and f"{prefix}{b}]" in est]
        drop.update(f"{prefix}{a}]" for a, _ in pairs)
        if pairs:
            aliases.append(
                f"{len(pairs)} mirror pairs {prefix}k] = {prefix}n-1-k] ({profile} profile of a symmetric model: one "
                "parameter per pair): the cells at y >= 0 listed"
            )

    # never NaN, never a zero error for a quantity the fit moves
    for k in names:
        e = est[k]
        if e.status in ("determined", "undetermined") and not (math.isfinite(e.total) and math.isfinite(e.value)):
            est[k] = dataclasses.replace(
                e,
                status="undetermined",
                stat=0.0,
                sys_chi2=0.0,
                sys_resolution=None,
                sys_family=None,
                note="its uncertainty is not finite (singular covariance): the data do not determine it",
            )
        elif e.status == "determined" and not e.total > 1e-12 * max(abs(e.value), 1.0):
            est[k] = dataclasses.replace(
                e, status="undetermined", note="zero uncertainty for a fitted quantity: a flat or saturated direction"
            )

    scalars = [est[k] for k in names if not k.startswith(("w[", "lag_us["))]
    weights = [est[k] for k in names if k.startswith("w[") and k not in drop]
    lags = [est[k] for k in names if k.startswith("lag_us[") and k not in drop]
    for e in scalars:
        if e.status == "at_bound":
            undetermined.append(f"{e.name}: {e.note}; reported as the one-sided limit {e.limit}")
        elif e.status == "undetermined" and e.note and not any(e.name in u for u in undetermined):
            undetermined.append(f"{e.name}: {e.note}")
    return ErrorBudget(
        scalars=scalars,
        weights=weights,
        lags=lags,
        variance_factor=vf,
        resolution=resolution,
        families=families,
        symmetries=sym_out,
        undetermined=undetermined,
        aliases=aliases,
        notes=notes,
    )


def _diameter_bound(e: Estimate, bound: tuple, soft_mm: float, spec: ModelSpec, params: dict, cov, vf: float):
    """The diameter's estimate with its bound status. "at_bound" only when the value is AT the
    bound (within 2 edge softnesses, or 0.1 %, of it); its one-sided limit is the likelihood's:
    2 inflated standard errors of the raw (logit) parameter away from the bound, mapped into the
    allowed range (0, modelled line). Where that limit says nothing (the data do not bound the
    diameter away from the other end) the diameter is "undetermined", never a negative or
    vanishing limit."""
    lo, hi = bound
    at = max(2 * soft_mm, 1e-3 * hi)
    side = "upper" if hi - e.value < at else "lower" if e.value - lo < at else None
    if side is None:
        return e
    labels = spec.raw_labels(params)
    j = labels.index("diameter.logit")
    var = float(cov[j, j]) * max(vf, 1.0) if cov is not None else math.nan
    sd_raw = math.sqrt(var) if math.isfinite(var) and var > 0 else math.nan
    d_raw = float(params["diam"])
    lim = hi * sigmoid(d_raw - 2 * sd_raw) if side == "upper" else hi * sigmoid(d_raw + 2 * sd_raw)
    if not math.isfinite(lim):
        lim = e.value  # no curvature at all: the only statement is the bound itself
    fix = (
        "lengthen model.line_length_m (the optimum lies beyond the modelled face)"
        if side == "upper"
        else "the data see no active face: check the data's units and the model"
    )
    useful = lim > max(2 * soft_mm, 0.01 * hi) if side == "upper" else lim < hi - max(2 * soft_mm, 0.01 * hi)
    if not useful:
        return dataclasses.replace(
            e,
            status="undetermined",
            note=f"at the {side} bound {hi if side == 'upper' else lo:.4g} mm and the data set no useful limit: {fix}",
        )
    where = f"the modelled line's {hi:.4g} mm" if side == "upper" else f"{lo:g} mm"
    return dataclasses.replace(
        e,
        status="at_bound",
        bound_side=side,
        limit_value=lim,
        limit=f"{'>=' if side == 'upper' else '<='} {lim:.4g}",
        note=f"at the {side} bound, {where}: {fix}",
    )


def _mirror_pairs(spec: ModelSpec, profile: str) -> list[tuple[int, int]]:
    """(k, n-1-k) pairs that are one parameter by the model's construction: cells at mirrored
    positions (y_k = -y_(n-1-k)) of a profile that is even in y ("symmetric", "uniform", or
    "smooth" with even degrees only). A disc's rings (y >= 0) have none."""
    y = np.asarray(spec.y_m, float)
    n = len(y)
    even = profile in ("symmetric", "uniform") or (profile == "smooth" and bool(spec.symmetric))
    if not even or not np.any(y < 0):
        return []
    tol = 1e-9 * max(float(np.max(np.abs(y))), 1e-12)
    return [(k, n - 1 - k) for k in range(n // 2) if abs(y[k] + y[n - 1 - k]) <= tol]


def _direction_text(d: np.ndarray, labels: Sequence[str]) -> str:
    """'0.71 diameter.logit - 0.70 w.T2' for a unit direction in raw-parameter space (its
    components above 0.1)."""
    d = np.asarray(d, float)
    order = np.argsort(-np.abs(d))
    terms = [f"{d[i]:+.2f} {labels[i]}" for i in order if abs(d[i]) >= 0.1][:4]
    return " ".join(terms).lstrip("+") or "(spread over many parameters)"


def _describe(keys: Sequence[str]) -> str:
    """'lags (40 cells; lag.T2, lag.T4)' style summary of quantity names."""
    groups: dict[str, list[str]] = {}
    for k in keys:
        if k.startswith("w["):
            groups.setdefault("weights", []).append(k)
        elif k.startswith("lag_us["):
            groups.setdefault("lags", []).append(k)
        elif k.startswith("w."):
            groups.setdefault("weights", []).append(k)
        elif k.startswith("lag."):
            groups.setdefault("lags", []).append(k)
        else:
            groups.setdefault(k, []).append(k)
    parts = []
    for g, ks in groups.items():
        cells = [k for k in ks if "[" in k]
        coefs = [k for k in ks if "[" not in k and k != g]
        bits = ([f"{len(cells)} cells"] if cells else []) + coefs
        parts.append(f"{g} ({'; '.join(bits)})" if bits else g)
    return ", ".join(parts)


def _symmetry_hint(name: str) -> str:
    if name == "time reversal":
        return "a lead and a lag give the same lobe: the SIGN of the lags is not determined (a wavefront scan determines it)"
    if name == "mirror":
        return "the two halves of the face can be swapped: measure both sides or use a symmetric model"
    return "a mirrored aperture with reversed lags gives the same lobe: use a wavefront scan or a symmetric model"
