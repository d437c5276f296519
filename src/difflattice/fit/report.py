"""Fit reports: JSON (machine-readable), PNG figures and a Markdown page."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .data import LobeData, WaveData
from .solve import FitResult
from .transfer import Transfer


def _summary(r: FitResult) -> dict:
    ph = r.physical
    return {
        "converged": r.converged,
        "result_code": r.result_code,
        "n_steps": r.n_steps,
        "wall_time_s": r.wall_time_s,
        "cost": r.cost,
        "chi2_reduced": r.chi2_reduced,
        "rms": r.rms,
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
        },
        "correlation": {
            "labels": r.correlation_labels,
            "matrix": np.round(np.nan_to_num(r.correlation), 4).tolist(),
            "note": "from the Jacobian at the solution; |r| near 1 marks parameters the data cannot separate",
        },
        "model": {
            "n_cells": r.spec.n_cells, "dx_m": r.spec.dx_m, "weights": r.spec.weights, "lags": r.spec.lags,
            "n_basis": r.spec.n_basis, "symmetric": r.spec.symmetric, "fit_diameter": r.spec.fit_diameter,
        },
    }


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
) -> dict:
    """Write report.json, report.md and figures into `out_dir`; returns the report dict."""
    from .. import plots

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rep = {"fit": _summary(fitted), "provenance": provenance, "transfer": transfer.info}
    if uniform is not None:
        rep["untuned_uniform_model"] = {"rms": uniform.rms, "chi2_reduced": uniform.chi2_reduced, "converged": uniform.converged}
    rep["trace"] = [{"t_s": t, "cost": c, "stage": st} for t, c, st in fitted.trace]
    figs = {}
    if lobe is not None:
        ref = float(np.max(lobe.level_db))
        curves = {"measured": (lobe.level_db - ref, "o"), "fitted model": fitted.model_curves["lobe_db"] - ref}
        if uniform is not None:
            curves["uniform model"] = (uniform.model_curves["lobe_db"] - ref, "--")
        figs["lobe"] = plots.save(plots.lobe_plots(lobe.angle_deg, curves, title=f"lobe at {lobe.range_m:g} m"), out / "lobe.png")
    if wave is not None:
        to_us = 1e6 / (2 * math.pi * wave.frequency_hz)
        centre = int(np.argmin(np.abs(wave.x_m)))

        def arrival(phase):  # rig phase falls with delay: arrival = -unwrapped phase / omega
            u = -np.unwrap(np.asarray(phase))
            return (u - u[centre]) * to_us

        curves = {"measured": (arrival(wave.phase_rad), "o"), "fitted model": arrival(fitted.model_curves["wave_phase_rad"])}
        if uniform is not None:
            curves["uniform model"] = (arrival(uniform.model_curves["wave_phase_rad"]), "--")
        figs["wavefront"] = plots.save(
            plots.wavefront_plot(wave.x_m, curves, ylabel="arrival re centre (µs, from phase)",
                                 title=f"near-field wavefront at z = {wave.z_m * 1e3:.1f} mm"), out / "wavefront.png")
    ph = fitted.physical
    y = fitted.spec.y_m
    figs["aperture"] = plots.save(plots.aperture_plot(y, [ph["weights"]], [ph["lags_s"]], labels=["fitted"],
                                                      title=f"fitted aperture: D = {float(ph['diameter_m']) * 1e3:.2f} mm"), out / "aperture.png")
    figs["convergence"] = plots.save(_trace_plot(fitted.trace), out / "convergence.png")
    if field_image:
        figs["field"] = _field_figure(fitted, transfer, out / "field.png")
    rep["figures"] = {k: str(v) for k, v in figs.items()}
    (out / "report.json").write_text(json.dumps(rep, indent=2, default=_default))
    (out / "report.md").write_text(_markdown(rep, fitted, uniform))
    return rep


def _trace_plot(trace):
    """Cost against wall time and evaluation, per stage (1: diameter and offsets; 2: all, floored
    sigmas; 3: all, measured sigmas; costs of different stages are on different scales)."""
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.5))
    if trace:
        t, c, st = (np.array(v) for v in zip(*trace))
        k = np.arange(1, len(c) + 1)
        for s in np.unique(st):
            m = st == s
            best = np.minimum.accumulate(c[m])
            a1.semilogy(t[m], best, "-o", ms=3, label=f"stage {s}")
            a2.semilogy(k[m], c[m], ".", ms=3)
            a2.semilogy(k[m], best, "-", label=f"stage {s} best so far")
        a1.legend()
        a2.legend(fontsize=7)
    a1.set_xlabel("wall time (s)")
    a1.set_ylabel("cost (half sum of squared residuals)")
    a2.set_xlabel("residual evaluation")
    fig.suptitle("convergence")
    fig.tight_layout()
    return fig


def _field_figure(fitted: FitResult, transfer: Transfer, path: Path):
    """Simulate the fitted transducer (a burst) and render it like the paper's Fig. 2."""
    import jax.numpy as jnp

    from .. import plots
    from ..lattice.grid import make_grid
    from ..lattice.coefficients import Edges
    from ..lattice.medium import Medium
    from ..solver.sensors import Sensors
    from ..solver.loop import simulate
    from ..solver.sources import ToneBurst, line_transducer

    g0 = transfer.grid
    n = fitted.spec.n_cells
    nx, ny = int(5.5 * n), int(3.5 * n)
    grid = make_grid(frequency_hz=g0.frequency_hz, cells_per_wavelength=g0.cells_per_wavelength,
                     c_max_m_s=g0.c_max_m_s, shape=(nx, ny), dtype="float32")
    ph = fitted.physical
    src = line_transducer(grid, (30 * grid.dx_m, ny / 2 * grid.dx_m), n_cells=n, signal=ToneBurst(g0.frequency_hz, 8),
                          weights=jnp.asarray(ph["weights"], jnp.float32), lags_s=jnp.asarray(ph["lags_s"], jnp.float32))
    steps = int((nx - 60) / grid.courant)
    res = simulate(grid, Medium(g0.c_max_m_s, 1.2), src, Sensors(), n_steps=steps)
    fig = plots.field_image(res.final.pressure, grid.dx_m, step=steps, dt_s=grid.dt_s, sources=[src.cells_array],
                            title="fitted transducer (8-cycle burst)")
    return plots.save(fig, path)


def _markdown(rep: dict, fitted: FitResult, uniform: FitResult | None) -> str:
    f = rep["fit"]
    p = f["parameters"]
    lines = ["# Fit report", ""]
    if not f["converged"]:
        lines += ["> **WARNING: THE FIT DID NOT CONVERGE** (`" + f["result_code"] + "`). The numbers below are the last iterate.", ""]
    for w in f["warnings"]:
        lines += [f"> {w}", ""]
    lines += [
        f"- solver result: `{f['result_code']}` after {f['n_steps']} steps, {f['wall_time_s']:.2f} s",
        f"- reduced chi-square: {f['chi2_reduced']:.3g} (1 = residuals at the noise level)",
        f"- active diameter: {p['diameter_m'] * 1e3:.3f} ± {p['diameter_stderr_m'] * 1e3:.3f} mm",
        f"- Jacobian condition number: {f['condition_number']:.3g}",
        f"- strongest correlations: {_top_correlations(fitted)}",
        "",
        "| observable | fitted model RMS | untuned uniform model RMS |",
        "|---|---|---|",
    ]
    for k, v in f["rms"].items():
        u = uniform.rms.get(k) if uniform is not None else None
        lines.append(f"| {k} | {v:.4g} | {'' if u is None else f'{u:.4g}'} |")
    lines += ["", "## Figures", ""]
    for k, v in rep["figures"].items():
        lines += [f"### {k}", f"![{k}]({Path(v).name})", ""]
    prov = rep["provenance"]
    lines += ["## Provenance", "", "```json", json.dumps(prov, indent=2, default=_default), "```", ""]
    return "\n".join(lines)


def _top_correlations(r: FitResult, k: int = 3) -> str:
    c = np.nan_to_num(np.asarray(r.correlation))
    labels = r.correlation_labels
    pairs = [(abs(c[i, j]), labels[i], labels[j], c[i, j]) for i in range(len(labels)) for j in range(i + 1, len(labels))
             if np.isfinite(c[i, j]) and r.stderr.get(labels[i], 0) > 0 and r.stderr.get(labels[j], 0) > 0]
    pairs.sort(reverse=True)
    return ", ".join(f"{a}/{b} {v:+.2f}" for _, a, b, v in pairs[:k]) or "n/a"


def _default(o):
    if hasattr(o, "__array__") and not isinstance(o, np.ndarray):
        o = np.asarray(o)
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.item() if o.ndim == 0 else o.tolist()
    return str(o)
