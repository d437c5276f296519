"""Identifiability and bounds of an error budget's estimates, decided by the data: reference and
inactive cells, quantities the model fixes, null directions of the Jacobian, symmetries of the data
(refits from the mapped solution), parameters at a bound, mirror aliases and non-finite errors.

Each step takes the estimates by name (`est`, updated in place) and returns the sentences it adds."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np

from ..transforms import sigmoid
from .data import LobeData, WaveData
from .estimates import Estimate
from .family import FamilyParams, ModelFamily
from .quantities import _values
from .solve import FitOptions, FitResult, fit
from .transfer import Transfer

EQUIVALENT_DELTA_CHI2 = 4.0
"""Two solutions whose costs differ by less than this (delta chi2, scaled by the variance factor)
are equally good fits: a 2-sigma distinction for one parameter."""


def mark_reference_and_inactive(est: dict[str, Estimate], spec: ModelFamily, window: np.ndarray) -> None:
    """Cells outside the active aperture (window < 1/2) are inactive; the reference (centre) cells
    are fixed by definition."""
    mid = list(spec.reference_cells)
    for k in range(spec.n_cells):
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


def mark_fixed(est: dict[str, Estimate], names: Sequence[str], values: np.ndarray, G: np.ndarray) -> None:
    """Per-cell quantities the fit does not move (a uniform profile's cells, a rim taper's flat part,
    a fixed diameter): fixed by the model, not determined by the data."""
    gnorm = np.linalg.norm(G, axis=1) if G.size else np.zeros(len(names))
    for i, k in enumerate(names):
        per_cell = k.startswith(("w[", "lag_us["))  # a scalar is listed only when it is fitted
        if per_cell and est[k].status == "determined" and gnorm[i] <= 1e-12 * max(abs(float(values[i])), 1.0):
            est[k] = dataclasses.replace(
                est[k],
                status="fixed",
                note="set by the model, not fitted",
                stat=0.0,
                sys_resolution=None,
                sys_chi2=0.0,
                sys_family=None,
            )


def mark_null_directions(est: dict[str, Estimate], fitted: FitResult, names: Sequence[str], G: np.ndarray) -> list[str]:
    """Quantities moved by a null direction of the Jacobian are undetermined."""
    N = fitted.null_space
    if N is None or not N.size:
        return []
    moved = np.linalg.norm(G @ N, axis=1) > 1e-3 * np.maximum(np.linalg.norm(G, axis=1), 1e-300)
    hit = [k for k, m in zip(names, moved) if m and est[k].status == "determined"]
    for k in hit:
        est[k] = dataclasses.replace(
            est[k], status="undetermined", note="the data do not constrain it (null direction of the Jacobian)"
        )
    if not hit:
        return []
    raw = fitted.spec.raw_labels(fitted.params)
    dirs = "; ".join(_direction_text(N[:, j], raw) for j in range(min(N.shape[1], 3)))
    return [
        f"{_describe(hit)}: along {N.shape[1]} direction(s) the data do not constrain the "
        f"parameters (Jacobian condition number {fitted.condition_number:.3g}; flat direction(s) {dirs}); "
        "the data determine only the combinations orthogonal to them"
    ]


def check_symmetries(
    est: dict[str, Estimate],
    fitted: FitResult,
    transfer: Transfer,
    lobe: LobeData | None,
    wave: WaveData | None,
    options: FitOptions,
    names: Sequence[str],
    values: np.ndarray,
    say: Callable[..., None],
) -> tuple[list[dict], list[str], list[str]]:
    """Refit from each candidate symmetry's image of the solution; where it fits as well, the
    quantities it changes beyond their errors are undetermined. Returns (one row per symmetry,
    undetermined sentences, notes)."""
    spec, params = fitted.spec, fitted.params
    vf = fitted.variance_factor
    sym_out: list[dict] = []
    undetermined: list[str] = []
    notes: list[str] = []
    for name, g in spec.symmetries().items():
        pg = g(params)
        vg = _values(spec, pg, fitted.solved_in)
        if max(abs(vg[k] - val) for k, val in zip(names, values)) < 1e-9 * max(1.0, float(np.max(np.abs(values)))):
            continue
        say(f"[budget] refit from the '{name}' image of the solution (identifiability)")
        fg = fit(spec, transfer, lobe, wave, options, params0=pg, solve_in=fitted.solved_in)
        d = 2 * (fg.cost - fitted.cost) / max(vf, 1.0)
        vals_g = _values(spec, fg.params, fg.solved_in)
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
    return sym_out, undetermined, notes


def mark_bounds(est: dict[str, Estimate], fitted: FitResult, names: Sequence[str], lags_s: np.ndarray, cov) -> None:
    """A diameter at its bound, or a lag within 2 inflated standard errors of +-T/2, is reported as
    a one-sided limit (see `_diameter_bound`)."""
    spec, params, vf = fitted.spec, fitted.params, fitted.variance_factor
    bounds = spec.bounds()
    soft_mm = spec.edge_softness_m * 1e3
    if "diameter_mm" in est and est["diameter_mm"].status in ("determined", "undetermined"):
        est["diameter_mm"] = _diameter_bound(est["diameter_mm"], bounds["diameter_mm"], soft_mm, spec, params, cov, vf)
    lo, hi = bounds["lag_us"]
    for k in names:
        if k.startswith("lag_us[") and est[k].status == "determined":
            e = est[k]
            lag_abs = abs(float(lags_s[int(k[7:-1])]) * 1e6)
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


def mirror_aliases(est: dict[str, Estimate], spec: ModelFamily) -> tuple[list[str], set[str]]:
    """Mirror duplicates, from the model's structure: cells at mirrored positions (y and -y) of a
    profile that is one parameter per mirror pair by construction (never from equal values: a
    disc's rings have no mirror, and a rim taper's flat rings are equal without being one).
    Returns (sentences, the names listed only once through their mirror)."""
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
    return aliases, drop


def mark_non_finite(est: dict[str, Estimate], names: Sequence[str]) -> None:
    """Never NaN, never a zero error for a quantity the fit moves: such a quantity is undetermined."""
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


def _diameter_bound(e: Estimate, bound: tuple, soft_mm: float, spec: ModelFamily, params: FamilyParams, cov, vf: float):
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
    diam = getattr(params, "diam", None)  # present: its label is
    assert diam is not None
    d_raw = float(diam)
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


def _mirror_pairs(spec: ModelFamily, profile: str) -> list[tuple[int, int]]:
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
