"""Work-precision, case "piston" (`difflattice accuracy --case piston`): a circular piston in a
rigid baffle on the axisymmetric lattice against the exact on-axis field, the far-field lobe and a
Rayleigh-integral quadrature (`run_piston`, `piston_sweep`). The shared table printer and
constants are `apps.accuracy`'s."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .accuracy import C_M_S, F_HZ, Backend, Dtype, RowPrinter, _need_x64

if TYPE_CHECKING:
    from ..lattice.grid import StencilKind


# ==========================================================================================
# Case "piston" (issue 12): a circular piston in a rigid baffle on the axisymmetric (rz)
# lattice, continuous wave, against the exact on-axis field, the far-field lobe 2 J1(x)/x and a
# Rayleigh-integral quadrature on the scan line (all in `observe.analytic`, independent of the
# lattice).
# ==========================================================================================

PISTON_RADIUS_M = 0.0192
"""The Polaroid's 38.4 mm face."""
PISTON_LINE_Z_M = 0.0165
"""The rig's scan line, metres in front of the face."""
PISTON_LINE_X_M = np.round(np.arange(-0.030, 0.030001, 0.0005), 6)
PISTON_LINE_HALF_M = 0.020
"""Line metrics over |x| <= this (the scan the fits use)."""
PISTON_RHO_KG_M3 = 1.2
PISTON_R_MARGIN_WAVELENGTHS = 4.0
PISTON_SETTLE_PERIODS = 20
PISTON_RECORD_PERIODS = 10

_PISTON_COLUMNS = [
    ("stencil", "stencil", "s"),
    ("cells_per_wavelength", "cells/λ", "g"),
    ("frequency_khz", "kHz", "g"),
    ("wall_time_s", "time (s)", ".2f"),
    ("axis_rms_error", "axis RMS", ".4f"),
    ("axis_extrema_error_cells", "extrema (cells)", ".2f"),
    ("null_error_deg", "null (deg)", ".4f"),
    ("sidelobe_error_db", "side lobe (dB)", ".3f"),
    ("line_phase_rms_deg", "line phase (deg)", ".2f"),
    ("line_amp_rms_db", "line amp (dB)", ".3f"),
]


def piston_courant(cells_per_wavelength: float, stencil: StencilKind = "standard") -> float:
    """The lattice speed giving a whole number of steps per period just below the stability limit
    of `stencil` (cells/step): the steady-state phasors then have no DFT leakage."""
    from ..lattice.grid import stability_limit

    limit = stability_limit("rz", stencil)
    return cells_per_wavelength / math.ceil(cells_per_wavelength / limit - 1e-9)


def _timed_runs(stepper, n_steps: int, backend, repeats: int):
    """The run's result and the wall times of `repeats` + 1 runs (the first compiles)."""
    import jax

    from ..solver.loop import run

    f = jax.jit(lambda s: run(s, n_steps, backend=backend))
    times = []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        res = f(stepper)
        jax.block_until_ready(res.phasors)
        times.append(time.perf_counter() - t0)
    return res, times


def run_piston(
    cells_per_wavelength: float,
    *,
    frequency_hz: float = F_HZ,
    radius_m: float = PISTON_RADIUS_M,
    c_m_s: float = C_M_S,
    on_axis: bool = True,
    line_z_m: float = PISTON_LINE_Z_M,
    line_x_m=PISTON_LINE_X_M,
    dtype: Dtype = "float64",
    pml_cells: int = 20,
    repeats: int = 1,
    stencil: StencilKind = "standard",
    backend: Backend = "auto",
) -> dict:
    """One continuous-wave run of a baffled piston (face at z = 0 on the rigid z_lo window face,
    PML on the outer radius and z_hi) until steady, then phasors over whole periods. Returns the
    complex amplitudes (per rho c u0: the drive's amplitude is rho c u0 = 1 Pa) on the axis (row
    centres from 0 to 5 a^2 / lambda, if `on_axis`), on the scan line and the far-field patterns
    (both transforms), the layout and the run time (median of `repeats` after a compiling run)."""
    import jax.numpy as jnp

    from ..lattice.coefficients import Edges
    from ..lattice.grid import make_grid
    from ..lattice.medium import Medium
    from ..lattice.window import Span, Window
    from ..observe.farfield_rz import CylinderSurface, axis_line, far_field_rz, scan_line
    from ..solver.sensors import Sensors
    from ..solver.sources import ContinuousWave, disc_transducer
    from ..solver.stepper import Stepper

    _need_x64([dtype])
    ppw = float(cells_per_wavelength)
    lam = c_m_s / frequency_hz
    dx = lam / ppw
    a_cells = radius_m / dx
    courant = piston_courant(ppw, stencil)
    spp = int(round(ppw / courant))
    gap = max(3, math.ceil(ppw / 2))  # the far-field cylinder: half a wavelength around the face
    z_far = 5 * radius_m**2 / lam if on_axis else line_z_m
    # the baffle and the axis close the window; its interior reaches past the range and the line
    win = Window(
        (
            Span.closed(gap=gap, layer=pml_cells, pad=1).with_reach(
                math.ceil(max(z_far, line_z_m, (gap + 2) * dx) / dx + 2 * ppw)
            ),
            Span.closed(gap=gap, layer=pml_cells, pad=1, fwd=math.ceil(a_cells)).with_reach(
                math.ceil(max(a_cells, np.abs(line_x_m).max() / dx) + PISTON_R_MARGIN_WAVELENGTHS * ppw)
            ),
        )
    )
    nz, nr = win.shape
    grid = make_grid(
        frequency_hz=frequency_hz,
        cells_per_wavelength=ppw,
        c_max_m_s=c_m_s,
        shape=(nz, nr),
        courant=courant,
        dtype=dtype,
        kind="rz",
        stencil=stencil,
    )
    src = disc_transducer(grid, radius_m=radius_m, signal=ContinuousWave(frequency_hz, 3.0, 1.0))
    (z0, z1), (_, jr) = win.box
    surface = CylinderSurface(z0, z1, jr, baffled=True)
    surface.check_inside(grid, margin=pml_cells)
    line = scan_line(grid, line_x_m, line_z_m)
    groups = [("surface", surface.cells), ("line", line.cells)]
    axis = None
    if on_axis:
        z_axis = (np.arange(nz - pml_cells - 2) + 0.5) * dx  # row centres (sampled exactly)
        z_axis = z_axis[z_axis >= 2 * dx]
        axis = axis_line(grid, z_axis)
        groups.append(("axis", axis.cells))
    cells = np.concatenate([c for _, c in groups])
    n_settle = math.ceil((math.hypot(nz, nr) / courant + PISTON_SETTLE_PERIODS * spp) / spp) * spp
    n_steps = n_settle + PISTON_RECORD_PERIODS * spp
    sensors = Sensors(phasor_cells=cells, phasor_from_step=n_settle)
    stepper = Stepper.build(
        grid,
        Medium(c_m_s, PISTON_RHO_KG_M3),
        src,
        sensors,
        Edges.axisymmetric("rigid", "pml", "pml", thickness_cells=pml_cells),
    )
    res, times = _timed_runs(stepper, n_steps, backend, repeats)
    amp = np.asarray(res.phasors) * 2 / (n_steps - n_settle)  # complex amplitude, p = Re(A exp(-i omega t))
    parts, start = {}, 0
    for name, c in groups:
        parts[name] = jnp.asarray(amp[start : start + len(c)])
        start += len(c)
    out = {
        "cells_per_wavelength": ppw,
        "stencil": stencil,
        "frequency_hz": frequency_hz,
        "radius_m": radius_m,
        "c_m_s": c_m_s,
        "dx_m": dx,
        "courant": courant,
        "steps_per_period": spp,
        "grid_shape": [nz, nr],
        "n_steps": n_steps,
        "wall_time_s": float(np.median(times[1:] or times)),
        "compile_and_run_s": times[0],
        "line_x_m": np.asarray(line_x_m, float),
        "line_z_m": line_z_m,
        "line": np.asarray(line(parts["line"])),
    }
    angles = np.arange(0.0, min(89.0, math.degrees(math.asin(min(1.0, 7.0 / (2 * math.pi / lam * radius_m))))), 0.005)
    out["angles_deg"] = angles
    for disp in ("continuum", "lattice"):
        out[f"far_{disp}"] = np.asarray(far_field_rz(parts["surface"], surface, grid, angles, dispersion=disp))
    if axis is not None:
        out["axis_z_m"] = z_axis
        out["axis"] = np.asarray(axis(parts["axis"]))
    return out


def _extrema(z, y, lo, hi):
    """Positions of the local extrema of y(z) inside (lo, hi), parabola-refined, with their kind."""
    out = []
    for i in range(1, len(y) - 1):
        if lo < z[i] < hi and ((y[i] > y[i - 1] and y[i] >= y[i + 1]) or (y[i] < y[i - 1] and y[i] <= y[i + 1])):
            d = 0.5 * (y[i - 1] - y[i + 1]) / (y[i - 1] - 2 * y[i] + y[i + 1])
            out.append((z[i] + d * (z[1] - z[0]), "max" if y[i] > y[i - 1] else "min"))
    return out


def _refine(x, y, i):
    """Parabola through (x, y)[i-1 .. i+1]: vertex position and value."""
    y0, y1, y2 = y[i - 1], y[i], y[i + 1]
    d = 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)
    return x[i] + d * (x[1] - x[0]), y1 - 0.25 * (y0 - y2) * d


def piston_errors(raw: dict, *, line_half_m: float = PISTON_LINE_HALF_M) -> dict:
    """Errors of a `run_piston` result against the references (exp(-i omega t); the drive is
    u(t) = u0 sin(omega t), complex velocity i u0):

    - on axis, z from a^2 / (4 lambda) to 5 a^2 / lambda: RMS of (|p| - |p_exact|) / (2 rho c u0)
      with the physical k ("axis_rms_error") and against the same two-ray form with the lattice's
      own wavenumbers (`analytic.piston_on_axis_lattice`, "axis_rms_error_lattice_k"); maxima and
      minima positions (cells) against both;
    - far field (continuum and lattice transforms): first null (deg) and first side lobe (dB)
      against 2 J1(ka sin t) / (ka sin t), max |dB| error where the lobe is above -20 dB;
    - the scan line: phase error RMS (deg; absolute, and after removing the mean phase, which
      only shifts the time origin) and amplitude error RMS (dB; over points within 10 dB of the
      line's maximum, and over all points: near a deep null a dB error means little) against
      `analytic.rayleigh_piston`, within |x| <= `line_half_m`; and the largest complex error
      relative to the line's maximum."""
    from ..observe import analytic as an

    k = 2 * math.pi * raw["frequency_hz"] / raw["c_m_s"]
    a = raw["radius_m"]
    lam = 2 * math.pi / k
    dx = raw["dx_m"]
    row = {
        "stencil": raw.get("stencil", "standard"),
        "cells_per_wavelength": raw["cells_per_wavelength"],
        "courant": raw["courant"],
        "frequency_khz": raw["frequency_hz"] / 1e3,
        "grid_shape": raw["grid_shape"],
        "n_steps": raw["n_steps"],
        "wall_time_s": raw["wall_time_s"],
        "mlups": raw["grid_shape"][0] * raw["grid_shape"][1] * raw["n_steps"] / raw["wall_time_s"] / 1e6,
    }
    if "axis" in raw:
        z, p = raw["axis_z_m"], raw["axis"]
        lo, hi = a * a / (4 * lam), 5 * a * a / lam
        sel = (z >= lo) & (z <= hi)
        omega = 2 * math.pi / raw["steps_per_period"]
        ex = np.abs(an.piston_on_axis(z, a, k))
        lk = np.abs(an.piston_on_axis_lattice(z, a, omega, raw["courant"], dx, raw.get("stencil", "standard")))
        row["axis_rms_error"] = float(np.sqrt(np.mean(((np.abs(p) - ex)[sel] / 2) ** 2)))
        row["axis_max_error"] = float(np.abs((np.abs(p) - ex)[sel] / 2).max())
        row["axis_rms_error_lattice_k"] = float(np.sqrt(np.mean(((np.abs(p) - lk)[sel] / 2) ** 2)))
        zf = np.linspace(lo, hi, 400_001)
        sim = _extrema(z, np.abs(p), lo, hi)
        for key, ref_curve in (
            ("", np.abs(an.piston_on_axis(zf, a, k))),
            (
                "_lattice_k",
                np.abs(an.piston_on_axis_lattice(zf, a, omega, raw["courant"], dx, raw.get("stencil", "standard"))),
            ),
        ):
            ref = _extrema(zf, ref_curve, lo, hi)
            errs = []
            for zr, kind in ref:
                cand = [zs for zs, ks in sim if ks == kind]
                errs.append(min((abs(zs - zr) for zs in cand), default=float("inf")) / dx)
            row["axis_extrema_error_cells" + key] = float(max(errs)) if errs else None
            row["axis_extrema" + key] = [
                {"z_mm": zr * 1e3, "kind": kind, "error_cells": e} for (zr, kind), e in zip(ref, errs)
            ]
    ang = raw["angles_deg"]
    ka = k * a
    th_null = math.degrees(math.asin(an.PISTON_FIRST_NULL_KA_SIN / ka))
    th_sl = math.degrees(math.asin(an.PISTON_FIRST_SIDELOBE_KA_SIN / ka))
    ref_db = 20 * np.log10(np.maximum(np.abs(an.piston_directivity(np.radians(ang), ka)), 1e-30))
    for disp in ("continuum", "lattice"):
        F = raw[f"far_{disp}"]
        power = np.abs(F / F[0]) ** 2
        near = np.abs(ang - th_null) < 2.0
        i = int(np.argmin(np.where(near, power, np.inf)))
        tn, _ = _refine(ang, power, i)  # |F|^2 is a parabola at a null
        db = 10 * np.log10(np.maximum(power, 1e-30))
        j = int(np.argmax(np.where(np.abs(ang - th_sl) < 2.0, db, -np.inf)))
        ts, ls = _refine(ang, db, j)
        sfx = "" if disp == "continuum" else "_lattice_k"
        row["null_error_deg" + sfx] = float(tn - th_null)
        row["sidelobe_error_db" + sfx] = float(ls - an.PISTON_FIRST_SIDELOBE_DB)
        row["sidelobe_angle_error_deg" + sfx] = float(ts - th_sl)
        row["lobe_db_max_error" + sfx] = float(np.abs(db - ref_db)[ref_db > -20].max())
    x = raw["line_x_m"]
    ref = 1j * an.rayleigh_piston(np.stack([x, np.full_like(x, raw["line_z_m"])], 1), a, k)
    s = np.abs(x) <= line_half_m + 1e-12
    dph = np.angle(raw["line"][s] / ref[s])
    dph_c = np.angle(np.exp(1j * (dph - np.angle(np.mean(np.exp(1j * dph))))))
    amp = 20 * np.log10(np.abs(raw["line"][s]) / np.abs(ref[s]))
    loud = 20 * np.log10(np.abs(ref[s]) / np.abs(ref[s]).max()) > -10
    row["line_phase_rms_deg"] = float(np.degrees(np.sqrt(np.mean(dph**2))))
    row["line_phase_rms_deg_centred"] = float(np.degrees(np.sqrt(np.mean(dph_c**2))))
    row["line_amp_rms_db"] = float(np.sqrt(np.mean(amp[loud] ** 2)))
    row["line_amp_rms_db_all"] = float(np.sqrt(np.mean(amp**2)))
    row["line_complex_error"] = float(np.abs(raw["line"][s] - ref[s]).max() / np.abs(ref[s]).max())
    return row


def piston_sweep(
    cells_per_wavelength=(6, 8, 10, 14, 20, 28, 40),
    frequencies_hz=(50e3, 40e3),
    *,
    dtype: Dtype = "float64",
    repeats: int = 1,
    stencils=("standard", "isotropic"),
    backend: Backend = "auto",
) -> dict:
    """The piston case over a sweep of resolutions and stencils: the on-axis field at the first
    frequency, the lobe and the scan line at each. `backend` "auto" (default) runs both stencils on
    the native CPU kernels where they apply (both have them: a like-for-like error-against-run-time
    comparison); "jax" times both on the XLA loop."""
    import os

    load_start = os.getloadavg()
    rows = []
    show = RowPrinter(_PISTON_COLUMNS)
    for stencil in stencils:
        for ppw in cells_per_wavelength:
            for i, f in enumerate(frequencies_hz):
                raw = run_piston(
                    float(ppw),
                    frequency_hz=f,
                    on_axis=(i == 0),
                    dtype=dtype,
                    repeats=repeats,
                    stencil=stencil,
                    backend=backend,
                )
                row = piston_errors(raw)
                row["dtype"] = dtype
                row["backend"] = backend
                rows.append(row)
                show(row)
    return {
        "case": f"baffled circular piston, {2e3 * PISTON_RADIUS_M:.1f} mm, continuous wave, rz lattice; references: "
        "exact on-axis field, 2 J1(x)/x, Rayleigh integral at z = 16.5 mm",
        "rows": rows,
        "loadavg_start": load_start,
        "loadavg_end": os.getloadavg(),
    }


def write_piston(results: dict, out_dir: str | Path) -> None:
    """accuracy_piston.json, accuracy_piston_table.md and accuracy_piston.png."""
    import matplotlib.pyplot as plt

    from .. import plots

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "accuracy_piston.json").write_text(json.dumps(results, indent=2))
    keys = [
        ("axis_rms_error", "on-axis RMS error (re 2ρcU)"),
        ("null_error_deg", "|first-null error| (deg)"),
        ("sidelobe_error_db", "|side-lobe error| (dB)"),
        ("line_phase_rms_deg", "line phase RMS (deg)"),
    ]
    fig, axes = plt.subplots(1, 5, figsize=(22, 4.2))
    keys.insert(1, ("axis_extrema_error_cells", "on-axis extrema error (cells)"))
    styles = {
        ("standard", 50.0): "-o",
        ("standard", 40.0): "--s",
        ("isotropic", 50.0): "-^",
        ("isotropic", 40.0): "--v",
    }
    for ax, (k, lab) in zip(axes, keys):
        for (st, f), style in styles.items():
            rs = [
                r
                for r in results["rows"]
                if r["frequency_khz"] == f and r.get("stencil", "standard") == st and r.get(k) is not None
            ]
            if rs:
                ax.loglog(
                    [r["wall_time_s"] for r in rs],
                    [max(abs(r[k]), 1e-6) for r in rs],
                    style,
                    label=f"{st}, {f:g} kHz",
                    ms=4,
                )
                for r in rs:
                    ax.annotate(
                        f"{r['cells_per_wavelength']:g}",
                        (r["wall_time_s"], max(abs(r[k]), 1e-6)),
                        textcoords="offset points",
                        xytext=(4, 4),
                        fontsize=7,
                    )
        ax.set_xlabel("wall time (s)")
        ax.set_ylabel(lab)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle("baffled circular piston on the rz lattice (labels: cells per wavelength)", fontsize=10)
    fig.tight_layout()
    plots.save(fig, out / "accuracy_piston.png")
    fmt = lambda v, f: "—" if v is None else format(v, f)
    lines = [
        "| stencil | cells/λ | courant | kHz | grid | steps | time (s) | axis RMS (re 2ρcU) | axis RMS, lattice k "
        "| extrema (cells) | extrema, lattice k | null (deg) | side lobe (dB) | line phase RMS (deg) | centred "
        "| line amp RMS (dB) | all points |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results["rows"]:
        lines.append(
            f"| {r.get('stencil', 'standard')} | {r['cells_per_wavelength']:g} | {r.get('courant', float('nan')):.3f} "
            f"| {r['frequency_khz']:g} | {r['grid_shape'][0]} x {r['grid_shape'][1]} "
            f"| {r['n_steps']} | {r['wall_time_s']:.2f} | {fmt(r.get('axis_rms_error'), '.4f')} "
            f"| {fmt(r.get('axis_rms_error_lattice_k'), '.4f')} | {fmt(r.get('axis_extrema_error_cells'), '.2f')} "
            f"| {fmt(r.get('axis_extrema_error_cells_lattice_k'), '.2f')} | {r['null_error_deg']:+.4f} "
            f"| {r['sidelobe_error_db']:+.3f} | {r['line_phase_rms_deg']:.2f} | {r['line_phase_rms_deg_centred']:.2f} "
            f"| {r['line_amp_rms_db']:.3f} | {r['line_amp_rms_db_all']:.3f} |"
        )
    (out / "accuracy_piston_table.md").write_text("\n".join(lines) + "\n")
