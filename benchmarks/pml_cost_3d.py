"""What absorbing layers cost a 3-D scene: a homogeneous N^3 cube of air with rigid, sponge or PML
edges (`--thickness` cells), for each stencil, each variant in its own process, interleaved over
rounds, on `--backend` ("auto": the native kernels where they run, i.e. the 7-point stencil in
air, else the JAX loop; "jax": the JAX loop for every stencil).

    python3 benchmarks/pml_cost_3d.py [--n 96] [--steps 60] [--rounds 3] [--backend auto] [--out DIR]

Prints one JSON line per run and the medians (MLUPS = N^3 x steps / median seconds), with each
edge's cost re the rigid cube of the same stencil; with `--out`, writes pml_cost_3d.json and
pml_cost_3d.md. The layer cells are 1 - ((N - 2 L) / N)^3 of the cube (50 % for N = 96, L = 10):
a layer form that costs only where it is adds at most that share times its per-cell cost
(issue 30: the wide and isotropic stencils' PML take their face values from whole-grid arrays).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

EDGES = ("rigid", "sponge", "pml")
STENCILS = ("standard", "wide")


def child(stencil: str, edge: str, n: int, steps: int, thickness: int, repeats: int, backend: str) -> dict:
    import jax
    import numpy as np

    from difflattice.apps import bench
    from difflattice.lattice import Edges
    from difflattice.lattice.grid import make_grid
    from difflattice.lattice.medium import Medium
    from difflattice.solver import Stepper
    from difflattice.solver.sensors import Sensors
    from difflattice.solver.sources import PointSources, ToneBurst

    g = make_grid(
        frequency_hz=40e3, cells_per_wavelength=10.0, c_max_m_s=343.0, shape=(n, n, n), kind="3d", stencil=stencil
    )
    src = PointSources(
        cells=np.array([[n // 2, n // 2, n // 2]]),
        signal=ToneBurst(40e3, 4),
        weights=jax.numpy.ones(1),
        lags_s=jax.numpy.zeros(1),
    )
    edges = Edges.all(edge, thickness_cells=thickness)
    t0 = time.perf_counter()
    stepper = Stepper.build(g, Medium(343.0, 1.2), src, Sensors(), edges)
    build_s = time.perf_counter() - t0
    compile_s, times = bench.time_run(stepper, steps, backend, repeats)
    return {
        "stencil": stencil,
        "edge": edge,
        "backend": backend,
        "n": n,
        "steps": steps,
        "thickness_cells": thickness,
        "mlups": n**3 * steps / statistics.median(times) / 1e6,
        "times_s": times,
        "build_s": build_s,
        "first_run_s": compile_s,  # compilation included
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=96)
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--thickness", type=int, default=10)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per process (median)")
    ap.add_argument("--backend", choices=("auto", "jax"), default="auto")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--child", nargs=2, metavar=("STENCIL", "EDGE"), default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(*args.child, args.n, args.steps, args.thickness, args.repeats, args.backend)))
        return
    rows: list[dict] = []
    for r in range(args.rounds):
        for s in STENCILS:
            for e in EDGES:
                load = os.getloadavg()[0]
                cmd = [sys.executable, __file__, "--child", s, e, "--n", str(args.n), "--steps", str(args.steps)]
                cmd += ["--thickness", str(args.thickness), "--repeats", str(args.repeats), "--backend", args.backend]
                out = subprocess.run(cmd, capture_output=True, text=True, check=True)
                row = json.loads(out.stdout.strip().splitlines()[-1]) | {"round": r, "load_avg": load}
                print(json.dumps(row), flush=True)
                rows.append(row)
    med = {
        f"{s}/{e}": statistics.median(x["mlups"] for x in rows if x["stencil"] == s and x["edge"] == e)
        for s in STENCILS
        for e in EDGES
    }
    layer_share = 1 - ((args.n - 2 * args.thickness) / args.n) ** 3
    summary = {
        "n": args.n,
        "steps": args.steps,
        "thickness_cells": args.thickness,
        "layer_cell_share": layer_share,
        "rounds": args.rounds,
        "backend": args.backend,
        "cpus": os.cpu_count(),
        "median_mlups": med,
        "time_re_rigid": {k: med[f"{k.split('/')[0]}/rigid"] / v for k, v in med.items()},
        "rows": rows,
    }
    print(json.dumps({k: v for k, v in summary.items() if k != "rows"}))
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "pml_cost_3d.json").write_text(json.dumps(summary, indent=2))
        lines = [
            f"3-D homogeneous {args.n}^3 cube, {args.steps} steps, {args.thickness}-cell layers "
            f"({100 * layer_share:.0f} % of the cells), backend {args.backend}, float32, {os.cpu_count()} CPUs; "
            f"medians of {args.rounds} interleaved rounds (`benchmarks/pml_cost_3d.py`; loads in the JSON)",
            "",
            "| stencil | edges | MLUPS | time re rigid |",
            "|---|---|---:|---:|",
        ]
        lines += [
            f"| {k.split('/')[0]} | {k.split('/')[1]} | {v:.0f} | {summary['time_re_rigid'][k]:.2f} |"
            for k, v in med.items()
        ]
        (args.out / "pml_cost_3d.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
