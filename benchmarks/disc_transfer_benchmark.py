"""Benchmark: how to batch the per-ring simulations of the disc transfer (fit.transfer_disc).

The rz lattice is linear but not translation invariant in r, so the disc's transfer needs one
response per ring. Ways to get them, each on the fit's problem (a 42 mm modelled disc, 61 rings
at 50 kHz and 20 cells per wavelength, 4-cycle burst, the Kirchhoff-Helmholtz surface recorded):

- ``vmap``: all rings in one `jax.vmap` over one-hot ring weights (one compiled program);
- ``vmap16``: the same in batches of 16 rings;
- ``loop``: one jitted single-ring simulation called per ring (weights are data: one compilation).

Each case runs in its own process (cold: compilation included), cases interleaved, `--repeats`
rounds; the warm time is a second call in the same process. Medians; the load average is recorded.
Writes docs/benchmarks/disc_transfer.json and .md.

    .venv/bin/python benchmarks/disc_transfer_benchmark.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CASES = ("vmap", "vmap16", "loop")


def run_case(case: str) -> dict:
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    from difflattice.air import density_kg_m3
    from difflattice.fit.transfer_disc import surface_cells
    from difflattice.lattice.coefficients import Edges
    from difflattice.lattice.grid import make_grid
    from difflattice.lattice.medium import Medium
    from difflattice.observe.farfield_rz import CylinderSurface
    from difflattice.solver.loop import simulate
    from difflattice.solver.sensors import Sensors
    from difflattice.solver.sources import ToneBurst, disc_transducer

    f, c, ppw = 50e3, 331.3 * math.sqrt(1 + 21 / 273.15), 20.0
    dx = c / f / ppw
    n = int(round(0.021 / dx))
    surf = CylinderSurface(0, 1, n, baffled=True)
    nz, nr = surf.iz1 + 26, surf.jr + 26
    grid = make_grid(frequency_hz=f, cells_per_wavelength=ppw, c_max_m_s=c, shape=(nz, nr), dtype="float64", kind="rz")
    sensors = Sensors(phasor_cells=surface_cells(surf, 4))
    sig = ToneBurst(f, 4.0)
    steps = int(math.hypot(nz, nr) / grid.courant + 10 * grid.steps_per_period)
    medium, edges = Medium(c, density_kg_m3(20.0)), Edges.axisymmetric("rigid", "pml", "pml", thickness_cells=20)

    def one(w):
        src = disc_transducer(grid, radius_m=n * dx, n_rings=n, weights=w, signal=sig)
        return simulate(grid, medium, src, sensors, n_steps=steps, edges=edges).phasors

    eye = jnp.eye(n)
    if case == "vmap":
        f_all = jax.jit(jax.vmap(one))
        go = lambda: np.asarray(f_all(eye))
    elif case == "vmap16":
        f_b = jax.jit(jax.vmap(one))
        go = lambda: np.concatenate([np.asarray(f_b(eye[s : s + 16])) for s in range(0, n, 16)])
    else:
        f_1 = jax.jit(one)
        go = lambda: np.stack([np.asarray(f_1(eye[i])) for i in range(n)])
    t0 = time.perf_counter()
    a = go()
    t1 = time.perf_counter()
    b = go()
    t2 = time.perf_counter()
    assert np.allclose(a, b)
    return {
        "case": case,
        "cold_s": t1 - t0,
        "warm_s": t2 - t1,
        "n_rings": n,
        "grid": [nz, nr],
        "n_steps": steps,
        "mlups_warm": n * nz * nr * steps / (t2 - t1) / 1e6,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--case", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    if args.case:
        print(json.dumps(run_case(args.case)))
        return
    runs: dict[str, list[dict]] = {c: [] for c in CASES}
    loads = []
    for _ in range(args.repeats):
        for case in CASES:  # interleaved, each in a fresh process
            loads.append(os.getloadavg()[0])
            out = subprocess.run(
                [sys.executable, __file__, "--case", case],
                capture_output=True,
                text=True,
                check=True,
                env=dict(os.environ),
            )
            runs[case].append(json.loads(out.stdout.strip().splitlines()[-1]))
    res = {
        "machine": platform.machine(),
        "cpus": os.cpu_count(),
        "load_average_1min": loads,
        "repeats": args.repeats,
        "cases": {
            c: {
                "cold_median_s": statistics.median(r["cold_s"] for r in v),
                "warm_median_s": statistics.median(r["warm_s"] for r in v),
                "mlups_warm_median": statistics.median(r["mlups_warm"] for r in v),
                "runs": v,
            }
            for c, v in runs.items()
        },
    }
    lines = [
        "# Disc transfer: batching the per-ring simulations",
        "",
        f"{res['cases']['vmap']['runs'][0]['n_rings']} rings, grid {res['cases']['vmap']['runs'][0]['grid']}, "
        f"{res['cases']['vmap']['runs'][0]['n_steps']} steps, float64; medians of {args.repeats} fresh processes; "
        f"load average {min(loads):.1f}-{max(loads):.1f} on {os.cpu_count()} cores.",
        "",
        "| case | cold (s, with compilation) | warm (s) | MLUPS (warm) |",
        "|---|---|---|---|",
    ]
    for c, v in res["cases"].items():
        lines.append(f"| {c} | {v['cold_median_s']:.2f} | {v['warm_median_s']:.2f} | {v['mlups_warm_median']:.0f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if not args.no_write:
        out = ROOT / "docs" / "benchmarks"
        out.mkdir(parents=True, exist_ok=True)
        (out / "disc_transfer.json").write_text(json.dumps(res, indent=1))
        (out / "disc_transfer.md").write_text(text)


if __name__ == "__main__":
    main()
