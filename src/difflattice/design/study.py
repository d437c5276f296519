"""A whole design study in one call: gradient check at the start, optimisation, pictures, scene
files and a report (JSON + Markdown + PNGs) in a directory. Used by designs/design_*.py."""

from __future__ import annotations

import math
from pathlib import Path

import jax
import numpy as np

from .export import write_scene
from .objectives import Goal
from .optimise import gradient_check, optimise
from .parts import write_parts
from .problem import DesignProblem
from .report import (
    fields_plot,
    fmt_metrics,
    history_plot,
    machine_info,
    patterns_plot,
    resolution_note,
    shape_plot,
    write_json,
)


def run_study(
    problem: DesignProblem,
    start,
    goal: Goal,
    out: str | Path,
    *,
    title: str,
    free=None,
    max_steps: int = 20,
    check_gradients: bool = True,
    progress: bool = True,
    resolution_choice: str | None = None,
) -> dict:
    """Optimise `start` for `goal` and write the report to `out`; returns the summary dict."""
    from .. import plots

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    summary = {
        "title": title,
        "resolution": resolution_note(problem),
        "trust": trust_estimate(problem),
        "machine": machine_info(),
        "problem": {
            "kind": problem.kind,
            "wall": problem.wall,
            "grid_shape": list(problem.grid.shape),
            "dx_m": problem.grid.dx_m,
            "n_steps": problem.n_steps,
            "range_m": problem.range_m,
            "transducer_cells": problem.n_cells,
            "burst_cycles": problem.cycles,
        },
        "free": list(free or type(start).NAMES),
    }
    if resolution_choice:
        summary["resolution_choice"] = resolution_choice
    if problem.frequencies_hz:
        summary["band"] = {"frequencies_hz": list(problem.frequencies_hz), "weights": list(problem.band_weights)}
    if check_gradients:
        rows = gradient_check(problem, start, goal)
        summary["gradient_check"] = rows
    res = optimise(problem, start, goal, free=free, max_steps=max_steps, progress=progress)
    summary["optimisation"] = res.summary()
    summary["history"] = res.history
    designs = {"start": start, "optimised": res.best}
    pats = {"bare transducer": np.asarray(jax.jit(lambda: problem.pattern(None))())}
    for k, p in designs.items():
        pats[k] = np.asarray(jax.jit(problem.pattern)(p))
    plots.save(shape_plot(problem, designs), out / "shapes.png")
    plots.save(history_plot(res), out / "history.png")
    plots.save(patterns_plot(problem, pats, title=f"beam at {problem.range_m} m"), out / "patterns.png")
    plots.save(fields_plot(problem, {"bare transducer": None, **designs}), out / "fields.png")
    for k, p in designs.items():
        write_scene(problem, p, out / f"{k}.toml", title=f"{title}: {k} design")
    summary["part"] = write_parts(problem, res.best, out, name=f"optimised_{problem.kind}")
    write_json(out / "report.json", summary)
    (out / "report.md").write_text(markdown(summary, problem))
    return summary


def trust_line(t: dict) -> str:
    """One sentence on the design resolution's trust estimate."""
    verdict = (
        "within it"
        if t["trustworthy"]
        else "above it: beam figures at this resolution are not trustworthy; raise cells_per_wavelength"
    )
    return (
        f"expected phase error {t['expected_phase_error_periods']:.3f} periods "
        f"(trust threshold {t['threshold_periods']}: {verdict})"
    )


TRUST_PHASE_ERROR_PERIODS = 0.05
"""Above this expected phase error (worst direction, at the farthest distance a run's waves
travel) arrival times and interference patterns are not trustworthy (as `difflattice simulate`
says)."""


def trust_estimate(problem: DesignProblem) -> dict:
    """The design runs' expected phase error from the lattice's dispersion relation (worst
    direction, over the distance the waves travel in a run, at the highest design frequency)
    against the trust threshold."""
    from ..observe.analytic import phase_error_rad

    g = problem.grid
    f_top = max(problem.frequencies_hz or (g.frequency_hz,))
    cpw = g.cells_per_wavelength * g.frequency_hz / f_top  # a band is resolved worst at its top
    dist_wl = min(g.courant * problem.n_steps, math.hypot(*g.shape)) / cpw
    periods = phase_error_rad(cpw, g.courant, dist_wl, stencil=g.stencil) / (2 * math.pi)
    return {
        "expected_phase_error_periods": periods,
        "threshold_periods": TRUST_PHASE_ERROR_PERIODS,
        "trustworthy": bool(periods <= TRUST_PHASE_ERROR_PERIODS),
    }


def choose_resolution(build, lo: float, hi: float, step: float = 1.0) -> tuple[float, dict, str]:
    """The coarsest cells per wavelength in lo, lo + step, ..., hi whose problem (`build(cpw)`,
    built without simulating) has its trust estimate under the threshold; else `hi`, and a note
    that says so. Returns (cells per wavelength, trust estimate, note)."""
    if not (0 < lo <= hi):
        raise ValueError(f"resolution search needs 0 < {lo} <= {hi} cells per wavelength")
    cpw = lo
    while True:
        t = trust_estimate(build(cpw))
        if t["trustworthy"]:
            return cpw, t, f"resolution auto: {cpw:g} cells per wavelength, the coarsest under the trust threshold"
        if cpw >= hi:
            return (
                cpw,
                t,
                f"resolution auto: even {cpw:g} cells per wavelength (the maximum) is above the trust threshold; "
                "raise --max-cells-per-wavelength",
            )
        cpw = min(cpw + step, hi)


def markdown(s: dict, problem: DesignProblem) -> str:
    o = s["optimisation"]
    lines = [
        f"# {s['title']}",
        "",
        f"Resolution: {s['resolution']}." + (f" {s['resolution_choice']}." if "resolution_choice" in s else ""),
        "",
        f"Goal: {o['goal']} (free: {', '.join(s['free'])}).",
        "",
        "| design | " + " | ".join(o["start"]) + " |",
        "|---|" + "---|" * len(o["start"]),
    ]
    for k in ("start", "best"):
        lines.append(f"| {k} | " + " | ".join(f"{v:.5g}" for v in o[k].values()) + " |")
    lines += [
        "",
        f"- start: {fmt_metrics(o['metrics_start'], problem.sector_deg)} (loss {o['loss_start']:.4g})",
        f"- optimised: {fmt_metrics(o['metrics_best'], problem.sector_deg)} (loss {o['loss_best']:.4g})",
        f"- {o['optimiser_steps']} BFGS steps in {o['wall_s']:.1f} s (compilation included); converged: {o['converged']}",
        f"- {trust_line(s['trust'])}",
        "",
    ]
    if "gradient_check" in s:
        lines += [
            "Gradient of the loss at the start vs central differences (step h; truncation estimate "
            "|D(2h) - D(h)| / 3):",
            "",
            "| parameter | h | gradient | finite difference | |error| | truncation estimate |",
            "|---|---|---|---|---|---|",
        ]
        for r in s["gradient_check"]:
            lines.append(
                f"| {r['parameter']} | {r['step']:.3g} | {r['grad']:.8g} | {r['fd']:.8g} | {r['abs_error']:.2g} | "
                f"{r['fd_truncation_estimate']:.2g} |"
            )
        lines.append("")
    lines += [
        "![shapes](shapes.png)",
        "",
        "![history](history.png)",
        "",
        "![patterns](patterns.png)",
        "",
        "![fields](fields.png)",
        "",
        "Scene files: `start.toml`, `optimised.toml` (`difflattice simulate optimised.toml --out DIR`).",
        "",
    ]
    if "part" in s:
        part = s["part"]
        (x0, y0, z0), (x1, y1, z1) = part["bounds_mm"]
        lines += [
            f"Part: `{Path(part['stl']).name}` (STL, millimetres; watertight: {part['watertight']}, volume "
            f"{part['volume'] / 1e3:.2f} cm^3, extent {x1 - x0:.1f} x {y1 - y0:.1f} x {z1 - z0:.1f} mm) and its wall "
            f"outlines `{Path(part['profile_csv']).name}`.",
            "",
        ]
        lines += constraints_table(part.get("constraints", []))
    return "\n".join(lines)


def constraints_table(rows: list[dict]) -> list[str]:
    """Markdown rows: each maker constraint, its limit, the part's value, met / active."""
    if not rows:
        return []
    out = [
        "Constraints, measured on the exported part (active: the design sits on the optimiser's bound or penalty):",
        "",
        "| constraint | limit | part | met | active | enforced by |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        unit, s = ("deg", 1.0) if r["constraint"].endswith("_deg") else ("mm", 1e3)
        if r["constraint"] == "no_self_intersection":
            unit, s = ("mm^2", 1e6)
        op = "<=" if r["kind"] == "max" else ">="
        lim = "-" if r["limit"] is None else f"{op} {r['limit'] * s:.2f} {unit}"
        out.append(
            f"| {r['constraint']} | {lim} | {r['part'] * s:.2f} {unit} | {r['satisfied']} | {r['active']} | "
            f"{r['enforced_by']} |"
        )
    return out + [""]
