"""A fit's outcome in one of three classes, each with its own exit code and console line.

- **consistent** (exit 0): converged, every data set's chi-square probability (per measured
  datum, `goodness.goodness_of_fit`) at or above `GOODNESS_P_MIN`, and the residual-sign runs test
  too where the set's chi2_red is >= 1; no fitted parameter at a bound of its allowed range;
- **inadequate** (exit 4): converged, but the model does not describe the data: a chi-square
  probability below `GOODNESS_P_MIN`, a runs-test probability below it in a data set whose
  chi2_red is >= 1 (a structure below the stated noise is noted, not counted: at the stated
  sigmas the model describes the data), or a parameter pinned at a bound (the optimum lies
  outside what the model allows); the line names the failing test and suggests a model change;
- **not converged** (exit 3): the last iterate is not an optimum.

Configuration and data errors exit 2 before a fit starts (`difflattice fit --help`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # no JAX at import: `difflattice fit --help` shows the exit codes
    from .solve import FitResult

GOODNESS_P_MIN = 1e-3
"""A fit whose chi-square probability, or the runs test of a data set's residual signs, falls
below this is judged not to describe the data (a correct model at the stated noise fails one
fit in a thousand by each test)."""

EXIT_CONSISTENT = 0
EXIT_NOT_CONVERGED = 3
EXIT_INADEQUATE = 4
EXIT_CODES_HELP = f"""exit codes:
  0  converged and consistent with the data: per data set, the chi-square probability (one residual
     per measured datum) >= {GOODNESS_P_MIN:g}, and so is the residual-sign runs test where chi2_red >= 1;
     no parameter at a bound
  2  unusable config or data (one line naming the key or the file's column and the accepted units)
  3  the fit did not converge (the report holds the last iterate)
  4  converged, but the model does not describe the data (the line names the failed test and
     suggests a model change)"""
_SETS = {"lobe": "lobe", "wave": "wavefront"}
_HINTS = {
    "lobe": 'a richer weight profile (model.weights = "smooth" with a larger model.n_basis, or "free"), a '
    "baffle or directivity the model lacks, or the lobe sigmas too small (data.lobe_sigma_db of a plain table)",
    "wave": 'a richer lag profile (model.lags = "smooth" with a larger model.n_basis, or "free"), the '
    "wavefront's distance or the phase sigma (solver.wave_sigma_deg) too small",
    "lattice": "a finer lattice (model.cells_per_wavelength): the error budget's resolution term shows how far "
    "the discretisation moves the result",
}


def fit_outcome(result: FitResult, budget=None) -> dict:
    """{"outcome": "consistent" | "inadequate" | "not_converged", "exit_code", "line" (the
    console's one-line verdict), "reasons" (list), "suggestion"} for a fit and (optionally) its
    error budget (`fit.uncertainty.ErrorBudget`, whose at-bound parameters count against it)."""
    g = result.goodness
    chi = g.get("joint", {})
    stats = f"chi2_red {chi.get('chi2_reduced', result.chi2_reduced):.3g} (p = {chi.get('p', float('nan')):.2g})"
    if not result.converged:
        return {
            "outcome": "not_converged",
            "exit_code": EXIT_NOT_CONVERGED,
            "line": f"FIT DID NOT CONVERGE ({result.result_code} after {result.n_steps} steps): the result is the "
            "last iterate, not an optimum; raise solver.max_steps, give a start (model.diameter_m) or check "
            "the data",
            "reasons": [result.convergence.get("reason", result.result_code)],
            "suggestion": "raise solver.max_steps or check the model and the data",
        }
    reasons, hints, notes = [], [], []
    for key, name in _SETS.items():
        s = g.get(key)
        if not s:
            continue
        robust = result.loss != "l2"
        if not robust and s["p"] < GOODNESS_P_MIN:
            reasons.append(
                f"{name} chi2_red {s['chi2_reduced']:.3g} over {s['dof']:.1f} dof, p = {s['p']:.2g} < {GOODNESS_P_MIN:g}"
            )
            hints.append(_HINTS[key])
        elif s.get("runs_p", 1.0) < GOODNESS_P_MIN:
            runs = (
                f"{name} residuals structured: {s['runs']} sign runs where noise gives {s['runs_expected']:.0f} "
                f"(p = {s['runs_p']:.2g})"
            )
            if s["chi2_reduced"] >= 1.0:  # a structure at or above the stated noise
                reasons.append(runs)
                hints.append(_HINTS[key])
            else:  # smaller than the stated sigmas: the model describes the data at the stated noise
                notes.append(f"{runs}, below the stated noise (chi2_red {s['chi2_reduced']:.3g})")
    if result.loss != "l2" and chi and result.variance_factor > 1:
        from .stats import chi2_sf

        p = chi2_sf(result.variance_factor * chi["dof"], chi["dof"])
        if p < GOODNESS_P_MIN:
            reasons.append(f"{result.loss} variance factor {result.variance_factor:.3g}, p = {p:.2g}")
            hints.append("a richer model: the residuals exceed the noise beyond the outliers the loss sets aside")
    for e in [] if budget is None else budget.scalars:
        if e.status == "at_bound" or (e.status == "undetermined" and "bound" in e.note):
            reasons.insert(0, f"{e.name} at a bound ({e.limit or 'no useful limit'}): {e.note}")  # the root cause
            hints.insert(0, e.note.split(": ", 1)[-1] if ": " in e.note else "widen the parameter's allowed range")
    if not reasons:
        return {
            "outcome": "consistent",
            "exit_code": EXIT_CONSISTENT,
            "line": f"fit converged and consistent with the data: {stats}"
            + (f"; note: {'; '.join(notes)}" if notes else ""),
            "reasons": [],
            "notes": notes,
            "suggestion": "",
        }
    if any(k in ("lobe", "wave") for k in g) and hints and not any("bound" in r for r in reasons):
        hints.append(_HINTS["lattice"])
    suggestion = "; ".join(dict.fromkeys(hints))
    return {
        "outcome": "inadequate",
        "exit_code": EXIT_INADEQUATE,
        "line": f"FIT CONVERGED BUT THE MODEL DOES NOT DESCRIBE THE DATA: {'; '.join(reasons)}. Try: {suggestion}",
        "reasons": reasons,
        "notes": notes,
        "suggestion": suggestion,
    }
