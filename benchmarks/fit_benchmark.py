"""Benchmark: wall time of the Polaroid fit (lobe + wavefront) on this machine, per solver and
parameterisation; median of repeats, cold (first call, compiling) and warm. Writes
docs/benchmarks/fit.json and fit.md.

    .venv/bin/python benchmarks/fit_benchmark.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from difflattice.capture.files import load_capture  # noqa: E402
from difflattice.fit.data import lobe_from_capture, wave_from_capture  # noqa: E402
from difflattice.fit.model import ModelSpec  # noqa: E402
from difflattice.fit.solve import FitOptions, fit  # noqa: E402
from difflattice.fit.transfer import free_field_transfer  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "data" / "emulated" / "polaroid_like"


def cold(solver: str) -> None:
    """One full Polaroid fit (104 cells, free weights and lags, lobe + wavefront) in this fresh
    process; prints JSON timings."""
    t0 = time.perf_counter()
    lobe = lobe_from_capture(load_capture(DATA / "lobe.csv"))
    wave = wave_from_capture(load_capture(DATA / "wave.csv"), sigma_deg=0.1)
    c = 331.3 * math.sqrt(1 + lobe.temperature_c / 273.15)
    T = free_field_transfer(
        frequency_hz=50e3,
        c_m_s=c,
        n_cells=104,
        lobe_angle_deg=lobe.angle_deg,
        lobe_range_m=lobe.range_m,
        wave_x_m=wave.x_m,
        wave_z_m=wave.z_m,
    )
    t1 = time.perf_counter()
    r = fit(
        ModelSpec(104, c / (50e3 * 20), 50e3, weights="free", lags="free", fit_diameter=False),
        T,
        lobe,
        wave,
        FitOptions(solver=solver),
    )
    t2 = time.perf_counter()
    print(
        json.dumps(
            {
                "solver": solver,
                "transfer_s": t1 - t0,
                "fit_s": t2 - t1,
                "total_s": t2 - t0,
                "converged": bool(r.converged),
            }
        )
    )


def fresh_process_runs(solver: str, repeats: int, cache: bool) -> list[dict]:
    import subprocess
    import sys
    import tempfile

    env = dict(os.environ)
    tmp = tempfile.mkdtemp()
    env["DIFFLATTICE_CACHE_DIR"] = tmp if cache else "0"
    out = []
    for _ in range(repeats + (1 if cache else 0)):  # with the cache: the first run fills it
        r = subprocess.run(
            [sys.executable, __file__, "--cold", solver], capture_output=True, text=True, env=env, check=True
        )
        out.append(json.loads(r.stdout.strip().splitlines()[-1]))
    return out[1:] if cache else out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cold", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.cold:
        from difflattice.apps.jaxconfig import configure

        configure()
        return cold(args.cold)
    fresh = {}
    for solver in ("levenberg_marquardt", "dogleg"):
        for cache in (False, True):
            runs = fresh_process_runs(solver, args.repeats, cache)
            fresh[f"{solver}, {'with' if cache else 'without'} compilation cache"] = {
                "total_median_s": statistics.median(r["total_s"] for r in runs),
                "transfer_median_s": statistics.median(r["transfer_s"] for r in runs),
                "fit_median_s": statistics.median(r["fit_s"] for r in runs),
                "converged": all(r["converged"] for r in runs),
            }
            print(fresh)
    lobe = lobe_from_capture(load_capture(DATA / "lobe.csv"))
    wave = wave_from_capture(load_capture(DATA / "wave.csv"), sigma_deg=0.1)
    c = 331.3 * math.sqrt(1 + lobe.temperature_c / 273.15)
    ppw = 20.0
    dx = c / (50e3 * ppw)
    t_tr = []
    transfers = {}
    # the paper's Polaroid: 104 cells at 20 cells per wavelength; a 40 mm line (117 cells) when the
    # diameter is fitted, so the active aperture can grow past the nominal one
    for n in (104, 117):
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            transfers[n] = free_field_transfer(
                frequency_hz=50e3,
                c_m_s=c,
                n_cells=n,
                cells_per_wavelength=ppw,
                lobe_angle_deg=lobe.angle_deg,
                lobe_range_m=lobe.range_m,
                wave_x_m=wave.x_m,
                wave_z_m=wave.z_m,
            )
            if n == 104:
                t_tr.append(time.perf_counter() - t0)
    rows = []
    cases = [
        (
            "104 cells: free weights + free lags (207 parameters)",
            104,
            dict(weights="free", lags="free", fit_diameter=False),
        ),
        (
            "117 cells: smooth weights + lags + diameter (9 parameters)",
            117,
            dict(weights="smooth", lags="smooth", n_basis=3),
        ),
    ]
    for label, n, kw in cases:
        T = transfers[n]
        for solver in ("levenberg_marquardt", "dogleg", "bfgs"):
            spec = ModelSpec(n, dx, 50e3, **kw)
            times, res = [], None
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                res = fit(spec, T, lobe, wave, FitOptions(solver=solver, max_steps=300))
                times.append(time.perf_counter() - t0)
            rows.append(
                {
                    "model": label,
                    "solver": solver,
                    "cold_s": times[0],
                    "warm_median_s": statistics.median(times[1:] or times),
                    "converged": bool(res.converged),
                    "steps": res.n_steps,
                    "chi2_reduced": float(res.chi2_reduced),
                    "lobe_rms_db": res.rms["lobe_db"],
                    "wave_rms_deg": res.rms["wave_phase_deg"],
                }
            )
            print(rows[-1])
    out = {
        "machine": platform.machine(),
        "cpus": os.cpu_count(),
        "device": str(jax.devices()[0]),
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "repeats": args.repeats,
        "transfer_simulation_median_s": statistics.median(t_tr),
        "transfer_cold_s": t_tr[0],
        "fits": rows,
        "fresh_process_full_fit": fresh,
    }
    (ROOT / "docs" / "benchmarks").mkdir(parents=True, exist_ok=True)
    (ROOT / "docs" / "benchmarks" / "fit.json").write_text(json.dumps(out, indent=2))
    lines = [
        "# Fit benchmark (Polaroid: 104 cells, lobe 181 angles + wavefront 49 positions)",
        "",
        f"{out['date_utc']}, {out['machine']}, {out['cpus']} CPUs, {out['device']}, median of {args.repeats}.",
        "",
        f"Transfer simulation (one cell, 20 cells per wavelength): cold {t_tr[0]:.2f} s, median {out['transfer_simulation_median_s']:.2f} s.",
        "",
        "| model | solver | cold (s) | warm median (s) | converged | steps | chi2_red | lobe RMS dB | wave RMS deg |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['model']} | {r['solver']} | {r['cold_s']:.2f} | {r['warm_median_s']:.2f} | {r['converged']} | {r['steps']} | "
            f"{r['chi2_reduced']:.3g} | {r['lobe_rms_db']:.3f} | {r['wave_rms_deg']:.3f} |"
        )
    lines += [
        "",
        "Cold = first call in this process (includes tracing and compilation; later rows reuse some of it);",
        "warm = the same fit again in the same process (a fitting session, a sweep).",
        "",
        "## Full Polaroid fit in a fresh process (104 cells, free weights + lags, lobe + wavefront)",
        "",
        "Each run is a new Python process: data loading, transfer simulation and fit, excluding imports.",
        "",
        "| solver, cache | total median (s) | transfer (s) | fit (s) | converged |",
        "|---|---|---|---|---|",
    ]
    for k, v in fresh.items():
        lines.append(
            f"| {k} | {v['total_median_s']:.2f} | {v['transfer_median_s']:.2f} | {v['fit_median_s']:.2f} | {v['converged']} |"
        )
    lines.append("")
    (ROOT / "docs" / "benchmarks" / "fit.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
