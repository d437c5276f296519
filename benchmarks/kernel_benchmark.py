"""Kernel benchmark (issue 5 baseline): MLUPS of the time step, gradient/JVP time ratios, peak
memory and compile times, with a NumPy in-place reference measured in the same run. Each case
runs in its own process (so peak RSS is per case); medians of repeats. Writes
docs/benchmarks/kernel.json and kernel.md.

    .venv/bin/python benchmarks/kernel_benchmark.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def numpy_case(nx, ny, steps, dtype):
    import numpy as np

    p = np.zeros((nx, ny), dtype)
    q = np.zeros((nx, ny), dtype)
    p[nx // 2, ny // 2] = 1
    c2 = dtype(0.5 * 0.707**2 / 0.5)
    t0 = time.perf_counter()
    for _ in range(steps):
        # q <- 2p - q + c2 lap(p), in place on the interior
        q[1:-1, 1:-1] *= -1
        q[1:-1, 1:-1] += (2 - 4 * c2) * p[1:-1, 1:-1]
        q[1:-1, 1:-1] += c2 * (p[2:, 1:-1] + p[:-2, 1:-1] + p[1:-1, 2:] + p[1:-1, :-2])
        p, q = q, p
    return time.perf_counter() - t0


def jax_case(kind, nx, ny, steps, dtype, mode):
    import jax

    if dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import equinox as eqx

    from difflattice.grid import make_grid
    from difflattice.lattice import Edges
    from difflattice.medium import Medium
    from difflattice.sensors import Sensors
    from difflattice.solver import Stepper, run
    from difflattice.source import ToneBurst, line_transducer

    g = make_grid(frequency_hz=50e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(nx, ny), dtype=dtype)
    dt = g.jnp_dtype
    x = jnp.arange(nx, dtype=dt)[:, None] * jnp.ones((1, ny), dt)
    if kind == "homogeneous":
        medium, edges, sensors = Medium(343.0, 1.2), Edges.all("rigid"), Sensors()
    elif kind == "homogeneous+pml":
        medium, edges, sensors = Medium(343.0, 1.2), Edges(), Sensors()
    else:  # full-featured: heterogeneous conservative medium, rigid obstacle, PML, sensors
        c = jnp.where(x > nx * 0.6, 300.0, 343.0).astype(dt)
        rho = jnp.where(x > nx * 0.6, 2.0, 1.2).astype(dt)
        rigid = ((x > nx * 0.8) & (x < nx * 0.82)).astype(dt)
        medium, edges = Medium(c, rho, rigid=rigid), Edges()
        sensors = Sensors(probes=[(nx // 2, ny // 2)], phasor_cells=[(nx // 2, j) for j in range(30, ny - 30, 10)])

    def make(weights):
        src = line_transducer(g, (40 * g.dx_m, ny / 2 * g.dx_m), n_cells=104, signal=ToneBurst(50e3, 5), weights=weights)
        return Stepper.build(g, medium, src, sensors, edges)

    w0 = jnp.ones(104, dt)

    def fwd(w):
        return run(make(w), steps, unroll=2).final.pressure

    def loss(w, checkpoint=None):
        r = run(make(w), steps, checkpoint=checkpoint, unroll=2)
        return jnp.sum(r.final.pressure ** 2)

    fns = {
        "forward": jax.jit(fwd),
        "grad": jax.jit(jax.grad(loss)),
        "grad_checkpointed": jax.jit(jax.grad(lambda w: loss(w, "sqrt"))),
        "jvp": jax.jit(lambda w: jax.jvp(loss, (w,), (jnp.ones_like(w),))[1]),
    }
    f = fns[mode]
    t0 = time.perf_counter()
    jax.block_until_ready(f(w0))
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        jax.block_until_ready(f(w0 * 1.01))
        times.append(time.perf_counter() - t0)
    return compile_s, statistics.median(times)


def child(args):
    spec = json.loads(args.child)
    if spec["impl"] == "numpy":
        import numpy as np

        ts = [numpy_case(spec["nx"], spec["ny"], spec["steps"], getattr(np, spec["dtype"])) for _ in range(3)]
        out = {"time_s": statistics.median(ts), "compile_s": 0.0}
    else:
        c, t = jax_case(spec["kind"], spec["nx"], spec["ny"], spec["steps"], spec["dtype"], spec["mode"])
        out = {"time_s": t, "compile_s": c}
    out["max_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps(out))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return child(args)
    sizes = [(840, 630, 1000)] + ([] if args.quick else [(2048, 2048, 200)])
    cases = []
    for nx, ny, steps in sizes:
        for dtype in ("float32", "float64"):
            cases.append({"impl": "numpy", "nx": nx, "ny": ny, "steps": steps, "dtype": dtype})
            for kind in ("homogeneous", "homogeneous+pml", "full"):
                cases.append({"impl": "jax", "kind": kind, "nx": nx, "ny": ny, "steps": steps, "dtype": dtype, "mode": "forward"})
    nx, ny, steps = 840, 630, 1000 if not args.quick else 300
    for mode in ("grad", "grad_checkpointed", "jvp"):
        cases.append({"impl": "jax", "kind": "homogeneous+pml", "nx": nx, "ny": ny, "steps": steps, "dtype": "float32", "mode": mode})
    rows = []
    for c in cases:
        r = subprocess.run([sys.executable, __file__, "--child", json.dumps(c)], capture_output=True, text=True)
        if r.returncode != 0:
            rows.append({**c, "error": r.stderr[-500:]})
            print(rows[-1])
            continue
        res = json.loads(r.stdout.strip().splitlines()[-1])
        row = {**c, **res, "mlups": c["nx"] * c["ny"] * c["steps"] / res["time_s"] / 1e6}
        rows.append(row)
        print(row)
    fwd = {(r["nx"], r.get("kind"), r["dtype"]): r for r in rows if r.get("mode") == "forward" and "time_s" in r}
    for r in rows:
        if r.get("mode") in ("grad", "grad_checkpointed", "jvp") and "time_s" in r:
            base = fwd.get((r["nx"], r["kind"], r["dtype"]))
            if base and base["steps"] == r["steps"]:
                r["ratio_to_forward"] = r["time_s"] / base["time_s"]
    out = {"date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "machine": platform.machine(), "cpus": os.cpu_count(),
           "python": sys.version.split()[0], "rows": rows,
           "note": "numba was not measured (not a dependency); NumPy in-place reference measured in the same run"}
    (ROOT / "docs" / "benchmarks").mkdir(parents=True, exist_ok=True)
    (ROOT / "docs" / "benchmarks" / "kernel.json").write_text(json.dumps(out, indent=2))
    lines = ["# Kernel benchmark (baseline)", "", f"{out['date_utc']}, {out['machine']}, {out['cpus']} CPUs; median of 3 after a compiling run;",
             "each case in its own process (peak RSS per case). Reproduce: `.venv/bin/python benchmarks/kernel_benchmark.py`.", "",
             "| impl | scene | size | steps | dtype | mode | time (s) | MLUPS | compile (s) | peak RSS (MB) | ratio to forward |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['impl']} | {r.get('kind', '-')} | {r['nx']}x{r['ny']} | {r['steps']} | {r['dtype']} | {r.get('mode', '-')} | error | | | | |")
            continue
        lines.append(f"| {r['impl']} | {r.get('kind', 'homogeneous')} | {r['nx']}x{r['ny']} | {r['steps']} | {r['dtype']} | {r.get('mode', 'forward')} | "
                     f"{r['time_s']:.3f} | {r['mlups']:.0f} | {r['compile_s']:.2f} | {r['max_rss_mb']:.0f} | {r.get('ratio_to_forward', float('nan')):.2f} |")
    (ROOT / "docs" / "benchmarks" / "kernel.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
