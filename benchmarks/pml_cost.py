"""What the split-field (PML) form costs the native kernels: the bench's 840x630 scene as three
variants, each in its own process, interleaved over rounds.

    python3 benchmarks/pml_cost.py [--rounds 3] [--threads 1] [--out DIR]

Variants: "rigid" (homogeneous air, rigid edges: the leapfrog kernel), "pml" (homogeneous air,
the default 20-cell PML: the leapfrog with the split-field form on the layer's cells only), "full" (the bench's full-featured
scene: maps, obstacle, PML, probes, phasors). Prints one JSON line per run and the medians; with
`--out`, writes pml_cost.json. For where the time goes inside a variant, run one child under a
sampling profiler, e.g.

    DIFFLATTICE_NATIVE_THREADS=1 perf record -e cpu-clock -F 2000 python3 benchmarks/pml_cost.py --child pml
    perf report --stdio --sort sym

(docs/performance.md, session 10: the staggered kernel's loops are vectorised and stream their rows
from L2, like the leapfrog's; the ratio follows the bytes moved per cell.)
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

VARIANTS = ("rigid", "pml", "full")
STEPS = 1000
NX, NY = 840, 630


def child(variant: str, repeats: int) -> dict:
    from difflattice.apps import bench
    from difflattice.lattice import Edges
    from difflattice.lattice.medium import Medium
    from difflattice.solver import Stepper
    from difflattice.solver.sensors import Sensors

    g, medium, src, sens, edges = bench.scene(bench.Case("full", NX, NY, STEPS, "float32"))
    if variant == "pml":
        medium, sens = Medium(343.0, 1.2), Sensors()
    elif variant == "rigid":
        medium, sens, edges = Medium(343.0, 1.2), Sensors(), Edges.all("rigid")
    _, times = bench.time_run(Stepper.build(g, medium, src, sens, edges), STEPS, "native", repeats)
    return {"variant": variant, "mlups": NX * NY * STEPS / statistics.median(times) / 1e6, "times_s": times}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per process (median)")
    ap.add_argument("--threads", type=int, default=1, help="DIFFLATTICE_NATIVE_THREADS of the children")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--child", choices=VARIANTS, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.repeats)))
        return
    env = dict(os.environ, DIFFLATTICE_NATIVE_THREADS=str(args.threads))
    rows: list[dict] = []
    for r in range(args.rounds):
        for v in VARIANTS:
            load = os.getloadavg()[0]
            cmd = [sys.executable, __file__, "--child", v, "--repeats", str(args.repeats)]
            out = subprocess.run(cmd, capture_output=True, text=True, env=env, check=True)
            row = json.loads(out.stdout.strip().splitlines()[-1]) | {"round": r, "load_avg": load}
            print(json.dumps(row), flush=True)
            rows.append(row)
    med = {v: statistics.median(x["mlups"] for x in rows if x["variant"] == v) for v in VARIANTS}
    summary = {
        "threads": args.threads,
        "rounds": args.rounds,
        "median_mlups": med,
        "pml/rigid": med["pml"] / med["rigid"],
        "full/rigid": med["full"] / med["rigid"],
        "rows": rows,
    }
    print(json.dumps({k: v for k, v in summary.items() if k != "rows"}))
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "pml_cost.json").write_text(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
