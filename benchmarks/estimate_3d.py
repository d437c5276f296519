"""Estimate against actual for a large 3-D run (issue 16): a 256^3 x 2000-step pulse-echo scene.

    .venv/bin/python benchmarks/estimate_3d.py [--n 256] [--steps 2000] [--no-refresh] [--no-write]

The scene: air at 40 kHz, 20 cells per wavelength (256^3 cells = 11 cm cube), a 12-cell PML on
every side, a 2-wavelength disc transducer (5-cycle burst) facing +x, a rigid wall at 20 deg
incidence 150 cells ahead (cut cells), the transducer's cells recorded every step (the A-scan),
float32. The estimate (`solver.estimate`: memory model, and run time from the MLUPS measured on
this machine now for the same kind of step, `measure_mlups(heterogeneous=True, refresh=True)` unless
`--no-refresh`) is printed before the run,
as `simulate(preflight="print")` does; then the run is timed (wall clock, compile included) and
its peak resident memory read (`resource.getrusage`, the whole process: Python, JAX, XLA and the
arrays). Writes `docs/benchmarks/estimate_3d.json` and `.md` with the load average at start and
end: figures taken at a load above the core count are provisional (the machine was shared).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=256)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--no-refresh", action="store_true", help="use the cached MLUPS figure")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()

    import jax
    import jax.numpy as jnp

    from difflattice.lattice import Edges, Medium
    from difflattice.lattice.geometry3d import HalfSpace, rasterise3d
    from difflattice.lattice.grid import make_grid
    from difflattice.solver import Sensors, ToneBurst, simulate
    from difflattice.solver.estimate import (
        RUNTIME_OVERHEAD_BYTES,
        available_memory_bytes,
        estimate_run,
        features_of,
        format_bytes,
        measure_mlups,
    )
    from difflattice.solver.sources import disc_transducer_3d
    from difflattice.solver.stepper import Stepper

    load0 = list(os.getloadavg())
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    n = args.n
    g = make_grid(frequency_hz=40e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(n, n, n), kind="3d")
    pml = 12
    x0 = pml + 8
    c = (x0, n / 2 - 0.5, n / 2 - 0.5)
    src = disc_transducer_3d(
        g, tuple(v * g.dx_m for v in c), (1, 0, 0), diameter_m=2 * 20 * g.dx_m, signal=ToneBurst(40e3, 5)
    )
    t = math.radians(20)
    wall = HalfSpace(
        jnp.array([x0 + min(150, n - x0 - pml - 30), c[1], c[2]]) * g.dx_m, jnp.array([-math.cos(t), math.sin(t), 0.0])
    )
    med = Medium(343.0, 1.2, rigid=rasterise3d(wall, g))
    edges = Edges.all("pml", thickness_cells=pml)
    sensors = Sensors(probes=src.cells_array)
    mlups = measure_mlups(3, "pml", "float32", heterogeneous=True, refresh=not args.no_refresh)
    stepper = Stepper.build(g, med, src, sensors, edges)
    feats = features_of(stepper, args.steps)
    est_bytes, est_s = estimate_run(g.shape, args.steps, "float32", feats)
    del stepper
    print(
        f"estimate at {mlups:.1f} MLUPS (measured now): memory {format_bytes(est_bytes)} + runtime "
        f"{format_bytes(RUNTIME_OVERHEAD_BYTES)}, time {est_s:.1f} s; available {format_bytes(available_memory_bytes())}",
        file=sys.stderr,
        flush=True,
    )
    t0 = time.perf_counter()
    r = simulate(g, med, src, sensors, n_steps=args.steps, edges=edges, preflight="print")
    jax.block_until_ready(r.probes)
    wall_s = time.perf_counter() - t0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    load1 = list(os.getloadavg())
    out = {
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "cpu_count": os.cpu_count(),
        "device": str(jax.devices()[0]),
        "shape": list(g.shape),
        "n_steps": args.steps,
        "dtype": "float32",
        "source_cells": src.n_cells,
        "mlups_measured": mlups,
        "estimate_bytes": est_bytes,
        "estimate_bytes_with_runtime": est_bytes + RUNTIME_OVERHEAD_BYTES,
        "estimate_s": est_s,
        "actual_s": wall_s,
        "actual_mlups": n**3 * args.steps / wall_s / 1e6,
        "peak_rss_bytes": rss,
        "rss_before_bytes": rss0,
        "load_average_at_start": load0,
        "load_average_at_end": load1,
        "provisional": max(load0[0], load1[0]) > (os.cpu_count() or 1),
        "within_time": wall_s <= est_s,
        "within_memory": rss <= est_bytes + RUNTIME_OVERHEAD_BYTES,
        "peak_history_finite": bool(jnp.all(jnp.isfinite(r.peak_history))),
    }
    print(json.dumps(out))
    if args.no_write:
        return
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "estimate_3d.json").write_text(json.dumps(out, indent=2) + "\n")
    md = [
        "# 3-D run: estimate against actual (issue 16)",
        "",
        f"{' x '.join(map(str, g.shape))} cells x {args.steps} steps, float32, PML, disc transducer, rigid wall "
        f"(cut cells), A-scan recorded; {out['date_utc']}, {os.cpu_count()} cores, load average "
        f"{load0[0]:.2f} at start, {load1[0]:.2f} at end"
        + (" (**provisional**: load above the core count)" if out["provisional"] else "")
        + ".",
        "",
        "| | estimate | actual |",
        "|---|---:|---:|",
        f"| time (s) | {est_s:.1f} (at {mlups:.1f} MLUPS measured now) | {wall_s:.1f} ({out['actual_mlups']:.1f} MLUPS) |",
        f"| memory | {format_bytes(est_bytes)} arrays + {format_bytes(RUNTIME_OVERHEAD_BYTES)} runtime = "
        f"{format_bytes(est_bytes + RUNTIME_OVERHEAD_BYTES)} | peak RSS {format_bytes(rss)} |",
        "",
        "Reproduce: `.venv/bin/python benchmarks/estimate_3d.py`.",
        "",
    ]
    (OUT / "estimate_3d.md").write_text("\n".join(md))


if __name__ == "__main__":
    main()
