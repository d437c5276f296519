"""Speed of the axisymmetric (rz) stepper against the 2-D stepper on the same grid (issue 12:
rz >= 0.8 x 2-D), for both stencils (standard 5-point, isotropic 9-point), the bare leapfrog
(rigid window, no sensors) and the split-field PML step (20 cells on z_hi and the outer radius;
the 2-D run has PML on the same two sides, rigid on the others).

Each case runs in its own process (compile, then the median of `--inner` timed runs); the cases
are interleaved round by round (`--rounds`), and a case's figure is the median over rounds. The
load average is recorded before and after. Every case runs at the grid's default courant 0.707,
so MLUPS compare directly; in air the isotropic stencil may also run at up to sqrt(3)/2 (17 % fewer
steps at 20 cells per wavelength), which this benchmark does not count. Writes JSON and a
Markdown table.

    .venv/bin/python benchmarks/axisym_speed.py [--shape 1024 512] [--steps 2000] [--rounds 3]
        [--inner 3] [--backend auto] [--dtype float32] [--out docs/benchmarks/axisym_speed_native]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

EDGES = ("rigid", "pml")
KINDS = ("2d", "rz")
STENCILS = ("standard", "isotropic")


def one_case(args) -> dict:
    """Compile and time one case in this process; returns its times."""
    import jax

    if args.dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    from difflattice.lattice import Edges
    from difflattice.lattice.grid import make_grid
    from difflattice.lattice.medium import Medium
    from difflattice.solver.loop import run
    from difflattice.solver.native import why_not
    from difflattice.solver.stepper import Stepper

    edge, kind, stencil = args.case
    nx, ny = args.shape
    g = make_grid(
        frequency_hz=50e3,
        cells_per_wavelength=20,
        c_max_m_s=343.0,
        shape=(nx, ny),
        dtype=args.dtype,
        kind=kind,
        stencil=stencil,
    )
    if edge == "rigid":
        e = Edges.axisymmetric("rigid", "rigid", "rigid") if kind == "rz" else Edges.all("rigid")
    else:
        e = (
            Edges.axisymmetric("rigid", "pml", "pml", thickness_cells=20)
            if kind == "rz"
            else Edges(x_lo="rigid", x_hi="pml", y_lo="rigid", y_hi="pml", thickness_cells=20)
        )
    st = Stepper.build(g, Medium(343.0, 1.2), (), edges=e)
    f = jax.jit(lambda s: run(s, args.steps, backend=args.backend).final.pressure)
    t0 = time.perf_counter()
    jax.block_until_ready(f(st))
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(args.inner):
        t0 = time.perf_counter()
        jax.block_until_ready(f(st))
        times.append(time.perf_counter() - t0)
    native = why_not(st)
    return {
        "compile_s": compile_s,
        "times_s": times,
        "path": "native" if (native is None and args.backend != "jax") else f"jax ({native or 'backend jax'})",
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--shape", type=int, nargs=2, default=[1024, 512])
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--inner", type=int, default=3)
    ap.add_argument("--dtype", default="float32", choices=["float32", "float64"])
    ap.add_argument("--backend", default="auto", choices=["jax", "auto", "native"])
    ap.add_argument("--out", type=Path, default=Path("out/axisym_speed"))
    ap.add_argument("--case", nargs=3, metavar=("EDGE", "KIND", "STENCIL"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.case:  # a child process: one case, JSON on stdout
        print(json.dumps(one_case(args)))
        return 0

    nx, ny = args.shape
    cases = [(e, k, s) for e in EDGES for s in STENCILS for k in KINDS]
    load0 = os.getloadavg()
    runs: dict[tuple, list] = {c: [] for c in cases}
    common = [
        "--shape", str(nx), str(ny), "--steps", str(args.steps), "--inner", str(args.inner),
        "--dtype", args.dtype, "--backend", args.backend,
    ]  # fmt: skip
    for r in range(args.rounds):  # interleaved: every case once per round, each in a fresh process
        for c in cases:
            out = subprocess.run(
                [sys.executable, __file__, *common, "--case", *c], capture_output=True, text=True, check=True
            )
            res = json.loads(out.stdout.strip().splitlines()[-1])
            res["load_avg"] = os.getloadavg()[0]
            runs[c].append(res)
            print(f"round {r + 1}: {c}: median {statistics.median(res['times_s']):.3f} s ({res['path']})", flush=True)
    load1 = os.getloadavg()
    rows = []
    mlups = {}
    for c in cases:
        per_round = [statistics.median(x["times_s"]) for x in runs[c]]
        t = statistics.median(per_round)
        mlups[c] = nx * ny * args.steps / t / 1e6
        rows.append(
            {
                "edges": c[0],
                "kind": c[1],
                "stencil": c[2],
                "median_s": t,
                "round_medians_s": per_round,
                "mlups": mlups[c],
                "compile_s": statistics.median(x["compile_s"] for x in runs[c]),
                "path": runs[c][0]["path"],
                "load_avg": [x["load_avg"] for x in runs[c]],
            }
        )
    res = {
        "shape": [nx, ny],
        "steps": args.steps,
        "rounds": args.rounds,
        "inner": args.inner,
        "dtype": args.dtype,
        "backend": args.backend,
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
        "loadavg_before": load0,
        "loadavg_after": load1,
        "rows": rows,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "axisym_speed.json").write_text(json.dumps(res, indent=2))
    lines = [
        f"rz vs 2-D stepper, {nx} x {ny} cells, {args.steps} steps, {args.dtype}, backend {args.backend}, courant "
        f"0.707; median over {args.rounds} interleaved rounds of the median of {args.inner} runs, each case in its "
        f"own process; load average {load0[0]:.2f} -> {load1[0]:.2f} on {os.cpu_count()} CPUs",
        "",
        "| edges | stencil | 2-D MLUPS | rz MLUPS | rz / 2-D | path (rz) |",
        "|---|---|---|---|---|---|",
    ]
    for e in EDGES:
        for s in STENCILS:
            a, b = mlups[(e, "2d", s)], mlups[(e, "rz", s)]
            path = runs[(e, "rz", s)][0]["path"]
            lines.append(f"| {e} | {s} | {a:.1f} | {b:.1f} | {b / a:.3f} | {path} |")
    (args.out / "axisym_speed.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
