"""What an error budget holds: one quantity's `Estimate` (value, statistical and systematic parts,
status) and the whole `ErrorBudget` with its tables; `fit.uncertainty.error_budget` builds them."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

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
