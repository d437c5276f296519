"""Speed of the axisymmetric (rz) stepper against the 2-D stepper on the same grid (issue 12:
rz >= 0.8 x 2-D), measured in one process, the two interleaved, median of repeats after a
compiling run, for the bare leapfrog (rigid window, no sensors) and the split-field PML step (20
cells on z_hi and the outer radius; the 2-D run has PML on the same two sides, rigid on the
others). Records the load average before and after. Writes JSON and a Markdown table.

    .venv/bin/python benchmarks/axisym_speed.py [--shape 1024 512] [--steps 400] [--repeats 3]
        [--backend jax] [--dtype float32] [--out docs/benchmarks/axisym_speed]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--shape", type=int, nargs=2, default=[1024, 512])
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--dtype", default="float32", choices=["float32", "float64"])
    ap.add_argument("--backend", default="jax", choices=["jax", "auto", "native"])
    ap.add_argument("--out", type=Path, default=Path("out/axisym_speed"))
    args = ap.parse_args(argv)

    import jax

    if args.dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    from difflattice.lattice import Edges
    from difflattice.lattice.grid import make_grid
    from difflattice.lattice.medium import Medium
    from difflattice.solver.loop import run
    from difflattice.solver.stepper import Stepper

    nx, ny = args.shape
    load0 = os.getloadavg()
    cases = {}
    for edge in ("rigid", "pml"):
        for kind in ("2d", "rz"):
            g = make_grid(
                frequency_hz=50e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(nx, ny), dtype=args.dtype, kind=kind
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
            f = jax.jit(lambda s, n=args.steps, b=args.backend: run(s, n, backend=b).final.pressure)
            t0 = time.perf_counter()
            jax.block_until_ready(f(st))
            cases[(edge, kind)] = {"f": f, "stepper": st, "compile_s": time.perf_counter() - t0, "times": []}
    for _ in range(args.repeats):  # interleaved: 2d, rz, 2d, rz, ...
        for c in cases.values():
            t0 = time.perf_counter()
            jax.block_until_ready(c["f"](c["stepper"]))
            c["times"].append(time.perf_counter() - t0)
    load1 = os.getloadavg()
    rows = []
    for edge in ("rigid", "pml"):
        m = {}
        for kind in ("2d", "rz"):
            c = cases[(edge, kind)]
            t = statistics.median(c["times"])
            m[kind] = nx * ny * args.steps / t / 1e6
            rows.append(
                {
                    "edges": edge,
                    "kind": kind,
                    "median_s": t,
                    "times_s": c["times"],
                    "mlups": m[kind],
                    "compile_s": c["compile_s"],
                }
            )
        rows.append({"edges": edge, "kind": "rz / 2d", "mlups_ratio": m["rz"] / m["2d"]})
        print(f"{edge:5s}: 2d {m['2d']:.1f} MLUPS, rz {m['rz']:.1f} MLUPS, ratio {m['rz'] / m['2d']:.3f}")
    res = {
        "shape": [nx, ny],
        "steps": args.steps,
        "repeats": args.repeats,
        "dtype": args.dtype,
        "backend": args.backend,
        "jax": jax.__version__,
        "devices": [str(d) for d in jax.devices()],
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
        "loadavg_before": load0,
        "loadavg_after": load1,
        "rows": rows,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "axisym_speed.json").write_text(json.dumps(res, indent=2))
    lines = [
        f"rz vs 2-D stepper, {nx} x {ny} cells, {args.steps} steps, {args.dtype}, backend {args.backend}, "
        f"median of {args.repeats} (interleaved), load average {load0[0]:.2f} -> {load1[0]:.2f} on {os.cpu_count()} CPUs",
        "",
        "| edges | 2-D MLUPS | rz MLUPS | rz / 2-D |",
        "|---|---|---|---|",
    ]
    for edge in ("rigid", "pml"):
        a = next(r for r in rows if r["edges"] == edge and r["kind"] == "2d")
        b = next(r for r in rows if r["edges"] == edge and r["kind"] == "rz")
        lines.append(f"| {edge} | {a['mlups']:.1f} | {b['mlups']:.1f} | {b['mlups'] / a['mlups']:.3f} |")
    (args.out / "axisym_speed.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
