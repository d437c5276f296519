"""What air absorption costs the native kernels, and that lossless runs did not change: the bench's
840x630 homogeneous 2-D scene (a 104-cell line, float32, 1000 steps) with rigid edges (the
leapfrog kernel) or the default 20-cell PML (the split-field kernel), lossless or with humid air
(20 C, 50 % RH, ISO 9613-1 relaxation memory fields), each in its own process, interleaved over
rounds, the 1-minute load recorded per run.

    python3 benchmarks/air_cost.py [--rounds 3] [--threads 2] [--baseline TREE] [--out DIR]

Both variants of a pair use the same grid (the absorbing step's lower stability limit,
`coefficients.absorbing_courant`), so they differ by the absorption alone. `--baseline TREE`
(a checkout of another commit, e.g. a `git worktree` of the commit before the absorbing kernels)
adds its lossless runs, from its own `src`, to show that lossless speed did not change. Prints
one JSON line per run and the medians; with `--out`, writes air_cost.json and air_cost.md.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

NX, NY, STEPS = 840, 630, 1000
HERE = Path(__file__).resolve().parents[1]


def child(edges: str, air: bool, repeats: int) -> dict:
    from difflattice.apps import bench
    from difflattice.lattice import Edges
    from difflattice.lattice.grid import make_grid
    from difflattice.lattice.medium import Medium
    from difflattice.solver import Stepper
    from difflattice.solver.sensors import Sensors
    from difflattice.solver.sources import ToneBurst, line_transducer

    kw = {"frequency_hz": 50e3, "cells_per_wavelength": 20, "c_max_m_s": 343.0, "shape": (NX, NY), "dtype": "float32"}
    medium = Medium(343.0, 1.2)
    try:  # a tree with the absorbing kernels: both variants on the absorbing step's grid
        from difflattice.lattice.coefficients import absorbing_courant
        from difflattice.lattice.medium import AirConditions

        cond = AirConditions(20.0, 50.0)
        kw["courant"] = absorbing_courant(50e3, 20, 343.0, cond)
        if air:
            medium = Medium(343.0, 1.2, air=cond)
    except ImportError:  # the baseline tree: lossless only, its default courant
        assert not air
    g = make_grid(**kw)
    src = line_transducer(g, (40 * g.dx_m, NY / 2 * g.dx_m), n_cells=104, signal=ToneBurst(50e3, 5))
    e = Edges.all("rigid") if edges == "rigid" else Edges()
    stepper = Stepper.build(g, medium, src, Sensors(), e)
    from difflattice.solver.native import why_not

    assert why_not(stepper, None, None) is None, why_not(stepper, None, None)  # native, not the JAX loop
    _, times = bench.time_run(stepper, STEPS, "native", repeats)
    return {"mlups": NX * NY * STEPS / statistics.median(times) / 1e6, "times_s": times, "courant": g.courant}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per process (median)")
    ap.add_argument("--threads", type=int, default=2, help="DIFFLATTICE_NATIVE_THREADS of the children")
    ap.add_argument("--baseline", type=Path, default=None, help="another checkout: its lossless runs too")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--child", nargs=2, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child[0], args.child[1] == "air", args.repeats)))
        return
    variants = [("this", e, a) for e in ("rigid", "pml") for a in ("lossless", "air")]
    if args.baseline:
        variants += [("baseline", e, "lossless") for e in ("rigid", "pml")]
    rows: list[dict] = []
    for r in range(args.rounds):
        for tree, e, a in variants:
            src = (args.baseline if tree == "baseline" else HERE) / "src"
            env = dict(os.environ, DIFFLATTICE_NATIVE_THREADS=str(args.threads), PYTHONPATH=str(src))
            load = os.getloadavg()[0]
            cmd = [sys.executable, __file__, "--child", e, a, "--repeats", str(args.repeats)]
            out = subprocess.run(cmd, capture_output=True, text=True, env=env, check=True)
            row = json.loads(out.stdout.strip().splitlines()[-1])
            row |= {"tree": tree, "edges": e, "air": a, "round": r, "load_avg": load}
            print(json.dumps(row), flush=True)
            rows.append(row)
    med = {
        f"{t}/{e}/{a}": statistics.median(x["mlups"] for x in rows if (x["tree"], x["edges"], x["air"]) == (t, e, a))
        for t, e, a in variants
    }
    ratios = {f"{e}: air/lossless": med[f"this/{e}/air"] / med[f"this/{e}/lossless"] for e in ("rigid", "pml")}
    if args.baseline:
        ratios |= {
            f"{e}: lossless this/baseline": med[f"this/{e}/lossless"] / med[f"baseline/{e}/lossless"]
            for e in ("rigid", "pml")
        }
    summary = {"threads": args.threads, "rounds": args.rounds, "median_mlups": med, "ratios": ratios, "rows": rows}
    print(json.dumps({k: v for k, v in summary.items() if k != "rows"}))
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "air_cost.json").write_text(json.dumps(summary, indent=2))
        lines = [
            f"# Air absorption on the native kernels ({NX}x{NY}, {STEPS} steps, float32, {args.threads} threads)",
            "",
            "| variant | MLUPS (median) | per round | load avg |",
            "|---|---:|---|---|",
        ]
        for k, v in med.items():
            rs = [x for x in rows if f"{x['tree']}/{x['edges']}/{x['air']}" == k]
            per = ", ".join(f"{x['mlups']:.0f}" for x in rs)
            loads = ", ".join(f"{x['load_avg']:.2f}" for x in rs)
            lines.append(f"| {k} | {v:.0f} | {per} | {loads} |")
        lines += ["", *(f"- {k}: {v:.3f}" for k, v in ratios.items()), ""]
        (args.out / "air_cost.md").write_text("\n".join(lines))


if __name__ == "__main__":
    main()
