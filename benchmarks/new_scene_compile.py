"""Compile time of a new scene and reuse for a scene of the same shapes (issue 15), on the default
path (`backend="auto"`: the native kernels on a CPU): in a fresh process (no persistent compilation
cache: the library does not enable one), `simulate` of an 840x630 x 1000-step scene from the kernel
benchmark (homogeneous, and full-featured: density and speed maps, a rigid obstacle, PML, a probe
and phasors), then the same scene with the 104-cell line transducer moved (same shapes: must not
recompile), then moved again. Each case in its own process, `--rounds` rounds interleaved; the
1-minute load average recorded per run. first - moved = tracing + compilation.

    .venv/bin/python benchmarks/new_scene_compile.py [--rounds 3] [--out docs/benchmarks/new_scene_compile]
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

ROOT = Path(__file__).resolve().parent


def child(kind: str) -> dict:
    sys.path.insert(0, str(ROOT))
    import jax
    import jax.numpy as jnp
    import kernel_benchmark as kb

    from difflattice.solver import simulate
    from difflattice.solver.sources import ToneBurst, line_transducer

    g, medium, edges, sensors, c0 = kb._scene(kind, 840, 630, "float32")
    c0 = jnp.asarray(c0)

    def sim(y0):
        src = line_transducer(g, (40 * g.dx_m, y0 * g.dx_m), n_cells=104, signal=ToneBurst(50e3, 5))
        return simulate(g, medium(c0), src, sensors, n_steps=1000, edges=edges).final.pressure

    out = {"kind": kind, "persistent_cache": jax.config.jax_compilation_cache_dir}
    for name, y0 in (("first_s", 315), ("moved_s", 278), ("moved_again_s", 250)):
        t0 = time.perf_counter()
        jax.block_until_ready(sim(y0))
        out[name] = time.perf_counter() - t0
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT.parent / "docs" / "benchmarks" / "new_scene_compile"))
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.child)))
        return 0
    runs: dict[str, list[dict]] = {}
    for k in range(args.rounds):
        for kind in ("homogeneous", "full"):
            load = os.getloadavg()[0]
            r = subprocess.run([sys.executable, __file__, "--child", kind], capture_output=True, text=True, check=True)
            row = {**json.loads(r.stdout.strip().splitlines()[-1]), "load_avg": load, "round": k}
            print(json.dumps(row), flush=True)
            runs.setdefault(kind, []).append(row)
    table = {
        kind: {
            **{x: statistics.median(r[x] for r in rs) for x in ("first_s", "moved_s", "moved_again_s")},
            "trace_and_compile_s": statistics.median(r["first_s"] - r["moved_s"] for r in rs),
            "load_avg": [r["load_avg"] for r in rs],
        }
        for kind, rs in runs.items()
    }
    result = {
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "cpus": os.cpu_count(),
        "cases": table,
        "runs": runs,
    }
    dest = Path(args.out)
    dest.mkdir(parents=True, exist_ok=True)
    (dest / "new_scene_compile.json").write_text(json.dumps(result, indent=2))
    lines = [
        "# Compile time of a new scene (native kernels, no persistent cache)",
        "",
        f"{result['date_utc']}, {result['cpus']} CPUs; 840x630 x 1000 steps, float32; median of {args.rounds} "
        "fresh processes, interleaved.",
        "",
        "| scene | first call (s) | moved transducer (s) | moved again (s) | trace + compile (s) | load avg |",
        "|---|---|---|---|---|---|",
    ]
    for kind, v in table.items():
        lines.append(
            f"| {kind} | {v['first_s']:.2f} | {v['moved_s']:.2f} | {v['moved_again_s']:.2f} | "
            f"{v['trace_and_compile_s']:.2f} | {', '.join(f'{x:.2f}' for x in v['load_avg'])} |"
        )
    (dest / "new_scene_compile.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
