"""Benchmark: time and peak memory of one objective + gradient for the paper's Fig. 9 horn scene at
20 cells per wavelength (median of repeats, after a compiling call), and of a whole horn
optimisation (the designs/design_horn.py set-up). Each case runs in a fresh process so its peak
RSS is its own. Writes docs/benchmarks/design.json and design.md.

    .venv/bin/python benchmarks/design_benchmark.py [--repeats 3] [--cells-per-wavelength 20] [--opt-cells-per-wavelength 8] [--opt-steps 10]
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def case_gradient(cpw: float, repeats: int) -> dict:
    import equinox as eqx
    import jax

    jax.config.update("jax_enable_x64", True)
    sys.path.insert(0, str(ROOT / "designs"))
    from fig09_fig10_beams import CONE, CONE_LIMITS, FACE_M

    from difflattice.design import Goal, horn_design

    t0 = time.perf_counter()
    pb = horn_design(limits=CONE_LIMITS, face_m=FACE_M, cells_per_wavelength=cpw, cycles=5.0)
    t_build = time.perf_counter() - t0
    goal = Goal(width_target_deg=8.0, width_weight=1.0)
    vg = eqx.filter_jit(eqx.filter_value_and_grad(lambda p: pb.loss(p, goal)))
    t0 = time.perf_counter()
    jax.block_until_ready(vg(CONE))
    cold = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(vg(CONE))
        times.append(time.perf_counter() - t0)
    f = jax.jit(lambda p: pb.loss(p, goal))
    jax.block_until_ready(f(CONE))
    ftimes = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(f(CONE))
        ftimes.append(time.perf_counter() - t0)
    nx, ny = pb.grid.shape
    return {
        "case": "gradient",
        "cells_per_wavelength": cpw,
        "grid": [nx, ny],
        "n_steps": pb.n_steps,
        "problem_build_s": t_build,
        "value_and_grad_cold_s": cold,
        "value_and_grad_median_s": statistics.median(times),
        "value_and_grad_s": times,
        "value_median_s": statistics.median(ftimes),
        "grad_over_value": statistics.median(times) / statistics.median(ftimes),
        "mcell_updates_per_s_forward": nx * ny * pb.n_steps / statistics.median(ftimes) / 1e6,
        "peak_rss_mb": _peak_rss_mb(),
    }


def case_optimise(cpw: float, steps: int) -> dict:
    import jax

    jax.config.update("jax_enable_x64", True)
    from difflattice.design import Goal, horn_design
    from difflattice.design.optimise import optimise
    from difflattice.design.presets import FIG09_CONE as CONE
    from difflattice.design.presets import HORN_LIMITS as LIMITS

    t0 = time.perf_counter()
    pb = horn_design(limits=LIMITS, face_m=0.0357, cells_per_wavelength=cpw, cycles=5.0)
    res = optimise(
        pb,
        CONE,
        Goal(width_target_deg=8.0, width_weight=1.0),
        free=("mouth_m", "length_m", "flare"),
        max_steps=steps,
        progress=False,
    )
    total = time.perf_counter() - t0
    return {
        "case": "optimise",
        "cells_per_wavelength": cpw,
        "grid": list(pb.grid.shape),
        "n_steps": pb.n_steps,
        "bfgs_steps": res.n_steps,
        "total_s": total,
        "optimise_s": res.wall_s,
        "width_start_deg": res.metrics_start["beam_width_deg"],
        "width_best_deg": res.metrics_best["beam_width_deg"],
        "peak_rss_mb": _peak_rss_mb(),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cells-per-wavelength", type=float, default=20.0)
    ap.add_argument("--opt-cells-per-wavelength", type=float, default=8.0)
    ap.add_argument("--opt-steps", type=int, default=10)
    ap.add_argument("--case", choices=["gradient", "optimise"], help=argparse.SUPPRESS)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args(argv)
    if args.case == "gradient":
        print(json.dumps(case_gradient(args.cells_per_wavelength, args.repeats)))
        return 0
    if args.case == "optimise":
        print(json.dumps(case_optimise(args.opt_cells_per_wavelength, args.opt_steps)))
        return 0
    sys.path.insert(0, str(ROOT / "src"))
    from difflattice.design.report import machine_info

    rows = []
    for case in ("gradient", "optimise"):
        r = subprocess.run(
            [
                sys.executable,
                __file__,
                "--case",
                case,
                "--repeats",
                str(args.repeats),
                "--cells-per-wavelength",
                str(args.cells_per_wavelength),
                "--opt-cells-per-wavelength",
                str(args.opt_cells_per_wavelength),
                "--opt-steps",
                str(args.opt_steps),
            ],
            capture_output=True,
            text=True,
            check=True,
        )
        rows.append(json.loads(r.stdout.strip().splitlines()[-1]))
    data = {"machine": machine_info(), "results": rows}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "design.json").write_text(json.dumps(data, indent=2) + "\n")
    g, o = rows
    m = data["machine"]
    md = [
        "# Design benchmark (Fig. 9 horn: Polaroid-like line + 5-degree, 125 mm cone)",
        "",
        f"{m['date_utc']} UTC, {m['processor']}, {m['cpu_count']} CPUs, {', '.join(m['devices'])}, JAX {m['jax']}, float64. "
        "Each case in a fresh process (peak RSS of that process). Run: `.venv/bin/python benchmarks/design_benchmark.py`.",
        "",
        "## One objective + gradient",
        "",
        f"Goal: (-6 dB width at 1 m - 8 deg)^2; {g['cells_per_wavelength']:g} cells per wavelength, grid {g['grid'][0]} x {g['grid'][1]}, "
        f"{g['n_steps']} steps, checkpointed reverse mode (sqrt).",
        "",
        "| quantity | value |",
        "|---|---|",
        f"| value + gradient, median of {len(g['value_and_grad_s'])} (s) | {g['value_and_grad_median_s']:.2f} |",
        f"| value + gradient, first call incl. compilation (s) | {g['value_and_grad_cold_s']:.2f} |",
        f"| value only, median (s) | {g['value_median_s']:.2f} |",
        f"| gradient / value time | {g['grad_over_value']:.1f} |",
        f"| forward speed (million cell updates / s) | {g['mcell_updates_per_s_forward']:.0f} |",
        f"| peak RSS (MB) | {g['peak_rss_mb']:.0f} |",
        "",
        "## A whole optimisation",
        "",
        f"designs/design_horn.py set-up (free: mouth, length, flare; target 8 deg) at {o['cells_per_wavelength']:g} cells per "
        f"wavelength, grid {o['grid'][0]} x {o['grid'][1]}, {o['n_steps']} steps, {o['bfgs_steps']} BFGS steps.",
        "",
        "| quantity | value |",
        "|---|---|",
        f"| total incl. problem set-up and compilation (s) | {o['total_s']:.1f} |",
        f"| optimisation loop (s) | {o['optimise_s']:.1f} |",
        f"| -6 dB width start -> best (deg) | {o['width_start_deg']:.2f} -> {o['width_best_deg']:.2f} |",
        f"| peak RSS (MB) | {o['peak_rss_mb']:.0f} |",
        "",
    ]
    (args.out / "design.md").write_text("\n".join(md))
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
