"""Model families of the error budget: the alternatives a fit is compared with (one more basis
function, free <-> symmetric profiles, a weak-prior per-cell shape test), their refits, and model
averaging's spread over the supported ones (Akaike weights on quasi-AIC)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from .data import LobeData, WaveData
from .family import ModelFamily
from .model import PROFILES
from .quantities import _implied_coefficients, _on_nominal, _quantities_and_jacobian, _stats, map_params
from .solve import FitOptions, FitResult, fit
from .transfer import Transfer

SUPPORTED_DELTA_QAIC = 10.0
"""Model families within this quasi-AIC of the best count in the family spread (Burnham and
Anderson: beyond 10, essentially no support)."""
FAMILY_KEYS = ("weights", "lags", "n_basis", "symmetric", "smoothness_sigma")


def default_families(spec: ModelFamily) -> list[dict]:
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


def shared_family(
    spec: ModelFamily, options: FitOptions, model_families: Sequence[str | Mapping[str, Any]] | None = None
) -> ModelFamily | None:
    """The error budget's family refit that `spec` nests in (one more basis function, the same
    settings) when the budget runs one (`model_families` as `error_budget` takes them), else None:
    the family to solve the nominal fit in (`fit`'s `solve_in`), so that in a fresh process the two
    fits compile their programs once (the refit is then the nominal model's structure)."""
    fams = default_families(spec) if model_families is None else [_family(spec, f) for f in model_families]
    for ov in fams:
        if ov and set(ov) <= set(FAMILY_KEYS):
            fspec, fopt = _check_family(spec, options, ov)
            if fopt == options and spec.nests_in(fspec):
                return fspec
    return None


def weak_smoothness_sigma(spec: ModelFamily) -> float:
    """The smoothness prior of a per-cell family that tests a smooth profile's shape: the weakest
    that still suppresses the non-radiating cell-to-cell oscillations, i.e. a Nyquist ripple of
    0.01 (1 % in weight, 0.01 rad in lag phase) on every cell costs at least one unit of chi2
    (second difference 4 x 0.01 per cell over n cells: sigma = 0.04 sqrt(n))."""
    return 0.04 * math.sqrt(spec.n_cells)


def _family(spec: ModelFamily, f: str | Mapping[str, Any]) -> dict:
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


def _check_family(spec: ModelFamily, options: FitOptions, ov: Mapping[str, Any]) -> tuple[ModelFamily, FitOptions]:
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


@dataclasses.dataclass
class FamilySpread:
    """The model-family part of a budget: per quantity the spread (`sys_family`, None when no family
    was compared), one row per family (`families`, the nominal first) and the notes it raises."""

    sys_family: dict[str, float] | None
    families: list[dict]
    notes: list[str]


def family_spread(
    fitted: FitResult,
    transfer: Transfer,
    lobe: LobeData | None,
    wave: WaveData | None,
    options: FitOptions,
    fams: Sequence[Mapping[str, Any]],
    names: Sequence[str],
    values: np.ndarray,
    stat: np.ndarray,
    active: np.ndarray,
    say: Callable[..., None],
) -> FamilySpread:
    """Refit `fitted` with each family (from the nominal solution mapped onto it) and return model
    averaging's unconditional spread about the nominal values (see `fit.uncertainty`)."""
    spec, params = fitted.spec, fitted.params
    fam_fits = []
    for ov in [f for f in fams if f]:
        fspec, fopt = _check_family(spec, options, ov)
        if fspec == spec and fopt == options:
            continue  # the nominal model itself (e.g. "symmetric" of a model that is symmetric anyway)
        say(f"[budget] refit with {_family_label(ov)} (model-family spread)")
        p0 = map_params(spec, params, fspec, physical=fitted.physical)
        fam_fits.append((ov, fspec, fit(fspec, transfer, lobe, wave, fopt, params0=p0)))
    if not fam_fits:
        return FamilySpread(None, [], [])
    vf = fitted.variance_factor
    allfits = [fitted] + [f for _, _, f in fam_fits]
    richest = max(allfits, key=lambda f: f.effective_params)
    c = max(richest.variance_factor, 1.0)
    q = [_qaic(f, c) for f in allfits]
    best = min(q)
    var_fam = {k: 0.0 for k in names}
    own = dict(zip(names, (stat * math.sqrt(max(vf, 1.0))).tolist()))
    used_all = [True] + [ff.converged and qf - best <= SUPPORTED_DELTA_QAIC for (_, _, ff), qf in zip(fam_fits, q[1:])]
    akaike = np.array([math.exp(-(qk - best) / 2) if u else 0.0 for qk, u in zip(q, used_all)])
    akaike /= akaike.sum()
    families = []
    for (ov, fspec, ff), qf, used, wk in zip(fam_fits, q[1:], used_all[1:], akaike[1:]):
        why = "" if used else ("did not converge" if not ff.converged else f"delta QAIC > {SUPPORTED_DELTA_QAIC:g}")
        # values (and, where used, their errors) from one program per family
        fv, fnames, _, _ = _quantities_and_jacobian(fspec, ff.params)
        other = _on_nominal(spec, fspec, dict(zip(fnames, np.asarray(fv).tolist())))
        if used:
            _add_family_variance(var_fam, spec, fspec, ff, other, own, names, values, active, float(wk))
        families.append(
            {
                "label": _family_label(ov),
                "overrides": dict(ov),
                "chi2_reduced": ff.chi2_reduced,
                "effective_params": ff.effective_params,
                "delta_qaic": qf - best,
                "akaike_weight": float(wk),
                "converged": ff.converged,
                "used": used,
                "why_not": why,
                "values": {k: other[k] for k in ("diameter_mm", "gain_db", "phase0_deg") if k in other},
            }
        )
    nominal = {
        "label": "nominal",
        "overrides": {},
        "chi2_reduced": fitted.chi2_reduced,
        "effective_params": fitted.effective_params,
        "delta_qaic": q[0] - best,
        "akaike_weight": float(akaike[0]),
        "converged": fitted.converged,
        "used": True,
        "why_not": "",
    }
    notes = []
    if q[0] - best > SUPPORTED_DELTA_QAIC:
        notes.append(
            f"an alternative model family fits much better (delta QAIC of the nominal {q[0] - best:+.1f}): "
            "consider it (see the families below)"
        )
    return FamilySpread({k: math.sqrt(x) for k, x in var_fam.items()}, [nominal, *families], notes)


def _add_family_variance(
    var_fam: dict[str, float],
    spec: ModelFamily,
    fspec: ModelFamily,
    ff: FitResult,
    other: dict,
    own: dict,
    names: Sequence[str],
    values: np.ndarray,
    active: np.ndarray,
    weight: float,
) -> None:
    """Model averaging's unconditional variance about the reported (nominal) value: the
    Akaike-weighted shift to this family's value plus the extra variance of a family that
    determines the quantity less well (added into `var_fam`)."""
    other_se = _on_nominal(spec, fspec, _stats(ff))
    if not any(k in other for k in names if k.startswith(("w.", "lag."))):  # another basis: implied coefficients
        imp, imp_se = _implied_coefficients(spec, active, ff)
        other.update(imp)
        other_se.update(imp_se)
    for k, val in zip(names, values):
        if k in other:
            extra = max(other_se.get(k, 0.0) ** 2 - own[k] ** 2, 0.0)
            var_fam[k] += weight * ((other[k] - val) ** 2 + extra)
