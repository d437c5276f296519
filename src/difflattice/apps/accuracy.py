"""Work-precision: error against run time over a sweep of resolutions, against analytic references.

Built-in cases (`difflattice accuracy --case ...`): "polaroid" (below, with the fit-vs-resolution
sweep), "wall" and "edges" (`apps.accuracy_wall`), "piston" (`apps.accuracy_piston`) and "air"
(`apps.accuracy_air`).

Case "polaroid": a uniform line source as long as the Polaroid's face (35.7 mm, 50 kHz,
air at 343 m/s), modelled as on the fitting path (one simulated cell + translation + far-field
transform / scan-line phasors). References, computed independently of the lattice:

- lobe at 1 m: the continuous uniform line, p(theta) = integral over the face of
  H0(k R) dy (scipy Hankel function, Gauss-Legendre quadrature, exact range);
- near-field wavefront at z = 16.5 mm: the same integral at the scan points; arrival time from the
  phase (fraction of a period).

Errors reported: max |dB| difference over the main lobe and first side lobes (reference above
-20 dB), first-null angle (deg), wavefront arrival (max over |x| <= 10 mm, in periods), and the
wall time of the transfer computation. The reference line has the modelled length (a whole number
of cells), so the errors do not include rounding the face length to cells. They do include
sampling the face by n point cells (a midpoint rule: about 0.11 dB x (6 / cells per wavelength)^2
of lobe error for any solver that models the face as n cells; measured against the discrete
array of the same n point sources in benchmarks/jwave_compare.py, which isolates the solver's
own error).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

if TYPE_CHECKING:
    pass

Dtype = Literal["float32", "float64"]
Backend = Literal["auto", "jax", "native"]

F_HZ, C_M_S, FACE_M, Z_M = 50e3, 343.0, 0.0357, 0.0165


class RowPrinter:
    """Prints result rows as an aligned console table (header once), not as dicts: `columns` are
    (key, header, format) triples; a missing or None value prints as "-"."""

    def __init__(self, columns):
        self.columns = columns
        self.widths = [max(len(h), 8) for _, h, _ in columns]
        self.started = False

    def __call__(self, row: dict) -> None:
        if not self.started:
            print("  ".join(h.rjust(w) for (_, h, _), w in zip(self.columns, self.widths)), flush=True)
            self.started = True
        cells = []
        for (k, _, fmt), w in zip(self.columns, self.widths):
            v = row.get(k)
            cells.append(("-" if v is None else format(v, fmt)).rjust(w))
        print("  ".join(cells), flush=True)


_POLAROID_COLUMNS = [
    ("cells_per_wavelength", "cells/λ", "g"),
    ("dtype", "dtype", "s"),
    ("farfield_dispersion", "far-field k", "s"),
    ("n_cells", "cells", "d"),
    ("wall_time_s", "time (s)", ".3f"),
    ("lobe_db_max_error", "lobe err (dB)", ".3f"),
    ("first_null_error_deg", "null err (deg)", ".3f"),
    ("arrival_error_periods", "arrival err (periods)", ".4f"),
]
_WALL_COLUMNS = [
    ("case", "case", "s"),
    ("cells_per_wavelength", "cells/λ", "g"),
    ("dtype", "dtype", "s"),
    ("wall_time_s", "time (s)", ".3f"),
    ("field_rel_l2_error", "field err (rel L2)", ".4f"),
    ("pattern_db_max_error", "pattern err (dB)", ".3f"),
    ("echo_arrival_error_periods", "echo arrival (periods)", ".4f"),
    ("echo_amplitude_db_error", "echo level (dB)", ".3f"),
]
_EDGE_COLUMNS = [
    ("cells_per_wavelength", "cells/λ", "g"),
    ("dtype", "dtype", "s"),
    ("edge", "edge", "s"),
    ("thickness_cells", "cells", "d"),
    ("wall_time_s", "time (s)", ".3f"),
    ("reflection_db_axis", "axis (dB)", ".1f"),
    ("reflection_db_corner", "corner (dB)", ".1f"),
]
_FIT_COLUMNS = [
    ("cells_per_wavelength", "cells/λ", "g"),
    ("wall_time_s", "time (s)", ".1f"),
    ("converged", "converged", ""),
    ("chi2_reduced", "chi2_red", ".3g"),
    ("diameter_mm", "D (mm)", ".3f"),
    ("diameter_stderr_mm", "± (mm)", ".3f"),
    ("edge_lag_us", "edge lag (µs)", ".3f"),
]


def reference(angles_deg, x_m, *, length_m: float = FACE_M, range_m: float = 1.0, n_quad: int = 4000):
    """Continuous uniform line source along y of length `length_m`: complex field at the lobe
    points and on the wavefront line (2-D Green's function (i/4) H0(kR), exp(-i omega t))."""
    from scipy.special import hankel1

    k = 2 * math.pi * F_HZ / C_M_S
    yq, wq = np.polynomial.legendre.leggauss(n_quad)
    yq, wq = yq * length_m / 2, wq * length_m / 2
    th = np.radians(angles_deg)
    ox, oy = range_m * np.cos(th), range_m * np.sin(th)
    R = np.hypot(ox[:, None], oy[:, None] - yq[None, :])
    lobe = (0.25j * hankel1(0, k * R)) @ wq
    R2 = np.hypot(Z_M, np.asarray(x_m)[:, None] - yq[None, :])
    wave = (0.25j * hankel1(0, k * R2)) @ wq
    return lobe, wave


def _present(block):
    """A transfer block the sweep asked for (the transfer returns None for blocks not requested)."""
    if block is None:
        raise ValueError("the transfer has no lobe or wavefront block: request both (lobe_range_m, wave_z_m)")
    return block


def _metrics(angles, x_m, lobe, wave, ref_lobe, ref_wave) -> dict:
    from ..observe.observables import lobe_metrics

    ld = 20 * np.log10(np.abs(lobe) / np.abs(lobe).max())
    rd = 20 * np.log10(np.abs(ref_lobe) / np.abs(ref_lobe).max())
    main = rd > -20
    m, r = lobe_metrics(angles, ld), lobe_metrics(angles, rd)
    if m["first_null_deg"] is None or r["first_null_deg"] is None:
        raise ValueError("no first null in the lobe or its reference: widen the angle range past the first null")
    ph = np.unwrap(np.angle(wave))
    rph = np.unwrap(np.angle(ref_wave))
    c = len(x_m) // 2
    inner = np.abs(x_m) <= 0.010
    arr = ((ph - ph[c]) - (rph - rph[c]))[inner] / (2 * math.pi)
    return {
        "lobe_db_max_error": float(np.abs(ld - rd)[main].max()),
        "first_null_error_deg": float(abs(m["first_null_deg"] - r["first_null_deg"])),
        "arrival_error_periods": float(np.abs(arr).max()),
    }


def _need_x64(dtypes) -> None:
    """Precision is the caller's (the CLI turns float64 on for the process): a float64 case without
    it would silently run in float32."""
    import jax

    if "float64" in tuple(dtypes) and not jax.config.read("jax_enable_x64"):
        raise ValueError(
            "dtype float64 needs 64-bit JAX: call jax.config.update('jax_enable_x64', True) at the start of "
            "the program (the `difflattice` command does), or use dtype float32"
        )


def sweep(cells_per_wavelength=(6, 8, 10, 14, 20, 28, 40), dtypes=("float32", "float64"), *, repeats: int = 1) -> dict:
    _need_x64(dtypes)
    from ..fit.transfer import free_field_transfer

    angles = np.arange(0, 60.001, 0.05)
    x_m = np.arange(-0.02, 0.02001, 0.0005)
    rows = []
    refs = {}
    show = RowPrinter(_POLAROID_COLUMNS)
    for dtype in dtypes:
        for ppw in cells_per_wavelength:
            dx = C_M_S / (F_HZ * ppw)
            n = max(2, int(round(FACE_M / dx)))
            # the reference is the continuous line of the modelled length n dx: the comparison
            # measures the scheme's error, not the rounding of the face to whole cells
            if n * dx not in refs:
                refs[n * dx] = reference(angles, x_m, length_m=n * dx)
            ref_lobe, ref_wave = refs[n * dx]
            for disp in ("continuum", "lattice"):
                times = []
                for _ in range(repeats + 1):  # the first run compiles
                    t0 = time.perf_counter()
                    T = free_field_transfer(
                        frequency_hz=F_HZ,
                        c_m_s=C_M_S,
                        n_cells=n,
                        cells_per_wavelength=ppw,
                        lobe_angle_deg=angles,
                        lobe_range_m=1.0,
                        wave_x_m=x_m,
                        wave_z_m=Z_M,
                        dtype=dtype,
                        dispersion=disp,
                    )
                    times.append(time.perf_counter() - t0)
                a = np.ones(n)
                row = {
                    "cells_per_wavelength": ppw,
                    "dtype": dtype,
                    "farfield_dispersion": disp,
                    "n_cells": n,
                    "wall_time_s": float(np.median(times[1:])),
                    "simulation_s": T.info["simulation_s"],
                    **_metrics(angles, x_m, _present(T.lobe) @ a, _present(T.wave) @ a, ref_lobe, ref_wave),
                }
                rows.append(row)
                show(row)
    return {"case": "polaroid uniform line, 35.7 mm, 50 kHz", "rows": rows}


def write(results: dict, out_dir: str | Path) -> None:
    import matplotlib.pyplot as plt

    from .. import plots  # noqa: F401  (sets the backend)

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "accuracy.json").write_text(json.dumps(results, indent=2))
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    keys = [
        ("lobe_db_max_error", "lobe error (dB)"),
        ("first_null_error_deg", "first-null error (deg)"),
        ("arrival_error_periods", "arrival error (periods)"),
    ]
    for ax, (k, lab) in zip(axes, keys):
        for dtype in ("float32", "float64"):
            for disp, style in (("continuum", "-o"), ("lattice", "--s")):
                rs = [r for r in results["rows"] if r["dtype"] == dtype and r["farfield_dispersion"] == disp]
                if rs:
                    ax.loglog(
                        [r["wall_time_s"] for r in rs], [max(r[k], 1e-6) for r in rs], style, label=f"{dtype}, {disp}"
                    )
        ax.set_xlabel("wall time (s)")
        ax.set_ylabel(lab)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    plots.save(fig, out / "accuracy.png")
    lines = [
        "| cells/λ | dtype | far-field k | cells | time (s) | lobe err (dB) | null err (deg) | arrival err (periods) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results["rows"]:
        lines.append(
            f"| {r['cells_per_wavelength']} | {r['dtype']} | {r['farfield_dispersion']} | {r['n_cells']} | {r['wall_time_s']:.2f} | "
            f"{r['lobe_db_max_error']:.3f} | {r['first_null_error_deg']:.3f} | {r['arrival_error_periods']:.4f} |"
        )
    (out / "accuracy_table.md").write_text("\n".join(lines) + "\n")


def fit_sweep(config_path, out_dir: str | Path, cells_per_wavelength=(8, 10, 14, 20, 28, 40)) -> dict:
    """Run one fit config at a sweep of resolutions: fitted parameters, residuals and time, so a
    user sees the cheapest resolution at which the answer stops changing. Each fit's report goes
    to `out_dir`/ppw<N>."""
    from dataclasses import replace

    from ..fit.config import load_config
    from .fitting import run_fit

    base = load_config(config_path)
    rows = []
    show = RowPrinter(_FIT_COLUMNS)
    for ppw in cells_per_wavelength:
        cfg = replace(
            base,
            model=replace(base.model, cells_per_wavelength=float(ppw)),
            output=replace(base.output, field_image=False),
        )
        t0 = time.perf_counter()
        rep = run_fit(cfg, out=Path(out_dir) / f"ppw{ppw}", verbose=False)
        f = rep["fit"]
        rows.append(
            {
                "cells_per_wavelength": ppw,
                "wall_time_s": time.perf_counter() - t0,
                "transfer_s": rep["provenance"]["timing_s"]["transfer_simulation"],
                "converged": f["converged"],
                "chi2_reduced": f["chi2_reduced"],
                "rms": f["rms"],
                "diameter_m": f["parameters"]["diameter_m"],
                "diameter_stderr_m": f["parameters"]["diameter_stderr_m"],
                "edge_lag_s": max(f["parameters"]["lags_s"], key=abs),
            }
        )
        r = rows[-1]
        show(
            {
                **r,
                "diameter_mm": r["diameter_m"] * 1e3,
                "diameter_stderr_mm": r["diameter_stderr_m"] * 1e3,
                "edge_lag_us": r["edge_lag_s"] * 1e6,
            }
        )
    return {"config": str(config_path), "rows": rows}
