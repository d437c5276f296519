"""Fit reports: JSON (machine-readable), PNG figures and a Markdown page.

report.json: the fit summary (convergence, chi2, RMS, outliers, every parameter with its standard
error), the error budget (`fit.uncertainty`), the model curves at the measured points (lobe dB
against angle, wavefront phase against x, for the fitted and the untuned uniform model), beam
metrics of each curve (null angles, side-lobe levels, -3/-6 dB widths), the per-cell aperture
with its uncertainty, correlations of the fitted parameters and the convergence trace.
report.md: the same for a reader, every fitted parameter with statistical, systematic and total
uncertainty, and the figures.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..observe.observables import lobe_metrics
from .data import LobeData, WaveData
from .family import FamilyParams
from .figures import (
    FigureWriter,
    _aperture_plot_args,
    model_family,
    start_figures,
)
from .result import FitResult
from .transfer import Transfer

NULL_PROMINENCE_DB = 3.0
"""A local minimum of a lobe is a null when it lies this far below the maxima on both sides."""


def beam_metrics(angle_deg, level_db) -> dict:
    """Beam metrics of a lobe (dB, any reference): peak angle, -3 and -6 dB full widths (deg),
    every null (local minimum at least `NULL_PROMINENCE_DB` below the maxima on both sides; angle
    and depth re peak) and every side lobe (the maximum between two nulls, or between a null and
    the scan's end; angle and level re peak), with the highest side lobe."""
    a = np.asarray(angle_deg, float)
    lv = np.asarray(level_db, float)
    lv = lv - lv.max()
    base = lobe_metrics(a, lv)
    out: dict[str, Any] = {
        "peak_angle_deg": base["peak_angle_deg"],
        "width_3db_deg": base["width_3db_deg"],
        "width_6db_deg": base["width_6db_deg"],
    }
    i0 = int(np.argmax(lv))
    mins = [i for i in range(1, len(lv) - 1) if lv[i] < lv[i - 1] and lv[i] <= lv[i + 1]]
    nulls = []
    for i in mins:  # prominence against the nearest maxima on each side
        if min(_nearest_max(lv, i, -1), _nearest_max(lv, i, +1)) - lv[i] >= NULL_PROMINENCE_DB:
            nulls.append(i)
    out["nulls"] = [{"angle_deg": float(a[i]), "level_db": float(lv[i])} for i in nulls]
    out["null_angles_deg"] = [float(a[i]) for i in nulls]
    bounds = sorted(set([0, *nulls, len(lv) - 1]))
    lobes = []
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        if lo <= i0 <= hi:
            continue  # the main lobe
        j = lo + int(np.argmax(lv[lo : hi + 1]))
        if j in nulls:
            continue
        lobes.append({"angle_deg": float(a[j]), "level_db": float(lv[j])})
    out["side_lobes"] = lobes
    out["highest_side_lobe_db"] = max((s["level_db"] for s in lobes), default=None)
    return out


def _nearest_max(lv: np.ndarray, i: int, step: int) -> float:
    """The level of the first local maximum (or the end) walking from i in direction `step`."""
    j = i
    while 0 <= j + step < len(lv) and lv[j + step] >= lv[j]:
        j += step
    return float(lv[j])


def _summary(r: FitResult) -> dict:
    ph = r.physical
    labels = r.correlation_labels
    return {
        "converged": r.converged,
        "result_code": r.result_code,
        "convergence": r.convergence,
        "n_steps": r.n_steps,
        "wall_time_s": r.wall_time_s,
        "compile_s": r.trace.compile_s if r.trace is not None else None,
        "cost": r.cost,
        "chi2_reduced": r.chi2_reduced,
        "goodness": r.goodness,
        "variance_factor": r.variance_factor,
        "effective_params": r.effective_params,
        "dof": r.dof,
        "loss": r.loss,
        "rms": r.rms,
        "outliers": r.outliers,
        "condition_number": r.condition_number,
        "rank_deficient": r.rank_deficient,
        "warnings": r.warnings,
        "parameters": {
            "diameter_m": float(ph["diameter_m"]),
            "diameter_stderr_m": r.stderr.get("diameter_mm", float("nan")) * 1e-3,
            "gain_db": float(ph["gain_db"]),
            "phase0_deg": float(np.degrees(ph["phase0_rad"])),
            "weights": ph["weights"].tolist(),
            "weights_stderr": [r.stderr[f"w[{k}]"] for k in range(len(ph["weights"]))],
            "lags_s": ph["lags_s"].tolist(),
            "lags_stderr_s": [r.stderr[f"lag_us[{k}]"] * 1e-6 for k in range(len(ph["lags_s"]))],
            "note": "stderr: statistical, inflated by max(variance_factor, 1); the full budget is in 'budget'",
        },
        "fitted_parameters": {lab: float(v) for lab, v in zip(labels, _flat(r.params))},
        "correlation": {
            "labels": labels,
            "matrix": np.round(np.nan_to_num(r.correlation), 4).tolist(),
            "strongest": _top_correlations(r, 5),
            "note": "of the fitted (raw) parameters, from the Jacobian at the solution; |r| near 1 marks "
            "parameters the data cannot separate",
        },
        "model": {
            "family": model_family(r.spec),
            "n_cells": r.spec.n_cells,
            "dx_m": r.spec.dx_m,
            "weights": r.spec.weights,
            "lags": r.spec.lags,
            "n_basis": r.spec.n_basis,
            "symmetric": r.spec.symmetric,
            "fit_diameter": r.spec.fit_diameter,
            "baffle": getattr(r.spec, "baffle", None),  # a disc's surround; None for the line model
        },
    }


def _flat(params: FamilyParams) -> np.ndarray:
    """The parameters as one vector, in `ravel_pytree`'s order (the leaves' order), built on the
    host (no eager XLA programs in a fresh process)."""
    from jax.tree_util import tree_leaves

    leaves = [np.ravel(np.asarray(x)) for x in tree_leaves(params)]
    return np.concatenate(leaves) if leaves else np.zeros(0)


def aperture_arrays(fitted: FitResult, budget) -> dict:
    """Per cell (every cell of the line): position, weight and lag relative to the centre cell,
    their total uncertainties (NaN where not determined) and, where a symmetry leaves them
    undetermined, the other solution's lags."""
    spec = fitted.spec
    n = spec.n_cells
    by = {e.name: e for e in budget.all()}
    out = {"y_m": spec.y_m.tolist()}
    for prefix, key, scale in (("w[", "weights_re_centre", 1.0), ("lag_us[", "lags_re_centre_s", 1e-6)):
        vals: list[float] = []
        errs: list[float] = []
        alts: list[float] = []
        complete = True
        for k in range(n):
            e = by.get(f"{prefix}{k}]") or by.get(f"{prefix}{n - 1 - k}]")
            if e is None:
                complete = False
                break
            vals.append(e.value * scale)
            ok = e.status in ("determined", "reference", "fixed", "at_bound")
            errs.append(e.total * scale if ok else float("nan"))
            alts.append(e.alternatives[0] * scale if e.alternatives else e.value * scale)
        if complete:
            out[key] = vals
            out[key.replace("_re_centre", "_total")] = errs
            if any(a != v for a, v in zip(alts, vals)):
                out[key.replace("_re_centre", "_alternative")] = alts
    return out


def write_report(
    out_dir: str | Path,
    fitted: FitResult,
    uniform: FitResult | None,
    transfer: Transfer,
    lobe: LobeData | None,
    wave: WaveData | None,
    *,
    provenance: dict,
    field_image: bool = True,
    budget=None,
    truth: dict | None = None,
    figures: FigureWriter | None = None,
) -> dict:
    """Write report.json, report.md and figures into `out_dir`; returns the report dict.
    `budget`: the `fit.uncertainty.ErrorBudget` (without one, the statistical part alone is
    reported and the report says the systematic parts were not measured). `truth` ({"y_m",
    "weights", "lags_s"}): overlaid on the aperture plot (emulated data). `figures`: the figures
    `start_figures` began (`field_image` then applies there); else they are drawn here."""
    from .uncertainty import error_budget
    from .verdict import fit_outcome

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if figures is None:
        figures = start_figures(out, fitted, uniform, transfer, lobe, wave, field_image=field_image, background=False)
    try:
        if budget is None:
            budget = error_budget(fitted, transfer, lobe, wave, make_transfer=None, model_families=[], symmetries=False)
            budget.notes.append(
                "systematic parts not measured: this report was written without an error budget "
                "(fit.uncertainty.error_budget); the totals are statistical (chi2-inflated) only"
            )
        rep = {"fit": _summary(fitted), "budget": budget.to_dict(), "provenance": provenance, "transfer": transfer.info}
        rep["fit"]["outcome"] = fit_outcome(fitted, budget)
        if uniform is not None:
            rep["untuned_uniform_model"] = {
                "rms": uniform.rms,
                "chi2_reduced": uniform.chi2_reduced,
                "converged": uniform.converged,
            }
        rep["trace"] = fitted.trace.to_dict() if fitted.trace is not None else {}
        curves, beam = _model_curves(fitted, uniform, lobe, wave)
        rep["model_curves"] = curves
        rep["beam"] = beam
        ap = aperture_arrays(fitted, budget)
        rep["aperture"] = ap
        d = budget.get("diameter_mm") if any(e.name == "diameter_mm" for e in budget.scalars) else None
        dtxt = (
            f"D = {d.text(4)} mm"
            if d is not None
            else f"D = {float(fitted.physical['diameter_m']) * 1e3:.2f} mm (fixed)"
        )
        args, kwargs = _aperture_plot_args(ap, truth=truth, title=f"fitted aperture: {dtxt}")
        figures.submit("aperture", "aperture_plot", out / "aperture.png", *args, **kwargs)
        figs = figures.results()
    finally:
        figures.close()
    order = ("lobe", "wavefront", "aperture", "convergence", "field")
    rep["figures"] = {k: str(figs[k]) for k in order if k in figs}
    (out / "report.json").write_text(json.dumps(_finite_or_null(rep), indent=2, default=_default, allow_nan=False))
    (out / "report.md").write_text(_markdown(rep, fitted, uniform, budget))
    return rep


def _model_curves(fitted: FitResult, uniform: FitResult | None, lobe, wave) -> tuple[dict, dict]:
    curves: dict = {}
    beam: dict = {}
    if lobe is not None:
        c = {
            "angle_deg": lobe.angle_deg.tolist(),
            "measured_db": lobe.level_db.tolist(),
            "sigma_db": lobe.sigma_db.tolist(),
            "model_db": np.asarray(fitted.model_curves["lobe_db"]).tolist(),
            "range_m": lobe.range_m,
        }
        beam["measured"] = beam_metrics(lobe.angle_deg, lobe.level_db)
        beam["fitted model"] = beam_metrics(lobe.angle_deg, fitted.model_curves["lobe_db"])
        if uniform is not None:
            c["uniform_model_db"] = np.asarray(uniform.model_curves["lobe_db"]).tolist()
            beam["uniform model"] = beam_metrics(lobe.angle_deg, uniform.model_curves["lobe_db"])
        curves["lobe"] = c
    if wave is not None:
        c = {
            "x_m": wave.x_m.tolist(),
            "z_m": wave.z_m,
            "measured_phase_deg": np.degrees(wave.phase_rad).tolist(),
            "sigma_deg": np.degrees(wave.sigma_rad).tolist(),
            "model_phase_deg": np.degrees(fitted.model_curves["wave_phase_rad"]).tolist(),
            "convention": "phase = -arg p with exp(-i omega t) (the models'); the rig's lag is -phase mod 360 deg",
        }
        if uniform is not None:
            c["uniform_model_phase_deg"] = np.degrees(uniform.model_curves["wave_phase_rad"]).tolist()
        curves["wavefront"] = c
    return curves, beam


def _fmt(x, f=".3g") -> str:
    return "—" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, f)


def _markdown(rep: dict, fitted: FitResult, uniform: FitResult | None, budget) -> str:
    f = rep["fit"]
    m = f["model"]
    lines = ["# Fit report", ""]
    verdict = f.get("outcome")
    if verdict is not None:
        lines += [
            f"**Outcome: {verdict['outcome'].replace('_', ' ')}** (exit code {verdict['exit_code']}): {verdict['line']}",
            "",
        ]
    if not f["converged"]:
        lines += [
            "> **WARNING: THE FIT DID NOT CONVERGE** (`"
            + f["result_code"]
            + "`): "
            + f["convergence"]["reason"]
            + ". The numbers below are the last iterate, not an optimum.",
            "",
        ]
    for w in f["warnings"]:
        lines += [f"> {w}", ""]
    prof = lambda p: (
        f"{p} (n_basis {m['n_basis']}, {'even' if m['symmetric'] else 'all'} degrees)" if p == "smooth" else p
    )  # noqa: E731
    c = f["convergence"]
    stages = ", ".join(f"stage {s['stage']} {s['result_code']} in {s['n_steps']}" for s in c["stages"])
    unit = "rings" if m["family"] == "disc" else "cells"
    lines += [
        f"- model: {m['family']} family, {m['n_cells']} {unit} of {m['dx_m'] * 1e3:.3f} mm; weights {prof(m['weights'])}; lags {prof(m['lags'])}; "
        f"diameter {'fitted' if m['fit_diameter'] else 'fixed'}"
        + (f"; baffle {m['baffle']}" if m.get("baffle") else "")
        + f"; loss {f['loss']}",
        f"- convergence: **{'converged' if f['converged'] else 'NOT CONVERGED'}** — {c['reason']} ({stages} steps; "
        f"{f['wall_time_s']:.2f} s, of which compilation {_fmt(f['compile_s'], '.2f')} s)",
        f"- reduced chi-square (all data points, one residual per measured datum): {f['chi2_reduced']:.3g}; "
        f"variance factor of the errors: {f['variance_factor']:.3g} (1 = residuals at the stated noise); "
        f"effective parameters {f['effective_params']:.1f}",
        f"- Jacobian condition number: {f['condition_number']:.3g}",
        "- strongest correlations of the fitted parameters: "
        + (", ".join(f"{a}/{b} {v:+.2f}" for a, b, v in f["correlation"]["strongest"]) or "n/a"),
    ]
    lines += _goodness_lines(f)
    for name, o in f["outliers"].items():
        lines.append(
            f"- {name} residuals: RMS {o['rms']:.3g} sigma, robust sigma (MAD) {o['robust_sigma']:.3g}; "
            f"{o['n_outliers']} of {o['n']} points beyond 4 robust sigmas" + (" — **outliers**" if o["suspect"] else "")
        )
    lines += ["", "| observable | fitted model RMS | untuned uniform model RMS |", "|---|---|---|"]
    for k, v in f["rms"].items():
        u = uniform.rms.get(k) if uniform is not None else None
        lines.append(f"| {k} | {v:.4g} | {'' if u is None else f'{u:.4g}'} |")
    lines += [""] + budget.markdown()
    if rep.get("beam"):
        lines += ["", "## Beam", "", "| metric | measured | fitted model | uniform model |", "|---|---|---|---|"]
        b = rep["beam"]

        def cell(src, key):
            v = b.get(src, {}).get(key)
            if isinstance(v, list):
                return ", ".join(f"{x:+.1f}" for x in v) or "none"
            return _fmt(v, ".4g")

        for key, label in (
            ("width_3db_deg", "-3 dB width (deg)"),
            ("width_6db_deg", "-6 dB width (deg)"),
            ("null_angles_deg", "null angles (deg)"),
            ("highest_side_lobe_db", "highest side lobe (dB re peak)"),
        ):
            lines.append(
                f"| {label} | {cell('measured', key)} | {cell('fitted model', key)} | {cell('uniform model', key)} |"
            )
    lines += ["", "## Figures", ""]
    captions = {
        "convergence": "cost per solver iteration; stage 1 fits the diameter and offsets with uniform profiles, "
        "stage 2 everything with the sigmas floored at 1 dB / 5 deg, stage 3 everything with the "
        "measured sigmas (so the cost jumps at the boundaries); compilation time is excluded",
        "aperture": "weights and lags relative to the centre cell; the band is ± the total uncertainty",
        "lobe": "rings: level in dB re the measured peak",
    }
    for k, v in rep["figures"].items():
        lines += [f"### {k}", f"![{k}]({Path(v).name})", ""]
        if k in captions:
            lines += [f"*{captions[k]}*", ""]
    prov = rep["provenance"]
    lines += ["## Provenance", "", "```json", json.dumps(prov, indent=2, default=_default), "```", ""]
    return "\n".join(lines)


def _goodness_lines(f: dict) -> list[str]:
    """The goodness-of-fit table: chi-square per data set and joint, counted per measured datum."""
    g = f.get("goodness") or {}
    if not g:
        return []
    lines = [
        "",
        "| data set | points | dof | chi2 | chi2_red | P(chi2 >= this) | sign runs (noise: expected) | P(runs <= this) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for key, name in (("lobe", "lobe"), ("wave", "wavefront"), ("joint", "joint")):
        s = g.get(key)
        if not s:
            continue
        runs = f"{s['runs']} ({s['runs_expected']:.1f})" if "runs" in s else "—"
        lines.append(
            f"| {name} | {s['n']} | {s['dof']:.1f} | {s['chi2']:.4g} | {s['chi2_reduced']:.3g} | {s['p']:.3g} | "
            f"{runs} | {s['runs_p']:.3g} |"
        )
    lines += [
        "",
        f"dof = points less the set's share of the fitted parameters (its leverages); a probability below "
        f"{g.get('p_min', 1e-3):g} means the model does not describe that data set at the stated noise.",
        "",
    ]
    return lines


def _top_correlations(r: FitResult, k: int = 3) -> list:
    """The k strongest correlations between the fitted (raw) parameters: distinct parameters
    only (a symmetric profile's mirror cells are one raw parameter, so never listed as a pair)."""
    c = np.asarray(r.correlation)
    labels = r.correlation_labels
    pairs = [
        (abs(c[i, j]), labels[i], labels[j], float(c[i, j]))
        for i in range(len(labels))
        for j in range(i + 1, len(labels))
        if np.isfinite(c[i, j])
    ]
    pairs.sort(key=lambda p: -p[0])
    return [(a, b, v) for _, a, b, v in pairs[:k]]


def _finite_or_null(o):
    """The report with every non-finite number (an error that is not determined, a convergence
    measure never taken) as JSON null: report.json holds no NaN or Infinity (not JSON)."""
    if isinstance(o, dict):
        return {k: _finite_or_null(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite_or_null(v) for v in o]
    if isinstance(o, np.ndarray):
        return _finite_or_null(o.tolist())
    if isinstance(o, (float, np.floating)) and not math.isfinite(float(o)):
        return None
    return o


def _default(o):
    if hasattr(o, "__array__") and not isinstance(o, np.ndarray):
        o = np.asarray(o)
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, np.ndarray):
        return o.item() if o.ndim == 0 else o.tolist()
    return str(o)
