"""Kernel benchmark (issue 5): forward MLUPS, the NumPy and numba references measured in the same
run, two host devices (both cores) through JAX sharding, gradient and JVP time ratios with peak
memory, compile and re-compile times, vmap batching. Each case runs in its own process (peak RSS
is per case); times are medians of repeats after a compiling run. Writes
docs/benchmarks/kernel.json and kernel.md.

    .venv/bin/python benchmarks/kernel_benchmark.py [--quick] [--skip-numba]

The numba reference runs in its own virtual environment (benchmarks/reference_kernels.py sets
up .venv-bench); numba is never a dependency of difflattice.
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
REPEATS = 3


def _median_time(f, *args):
    import jax

    t0 = time.perf_counter()
    jax.block_until_ready(f(*args))
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        jax.block_until_ready(f(*args))
        times.append(time.perf_counter() - t0)
    return compile_s, statistics.median(times), times


def _scene(kind, nx, ny, dtype):
    """(grid, medium factory c -> Medium, edges, sensors) for a benchmark scene kind."""
    import jax.numpy as jnp

    from difflattice.lattice import Edges
    from difflattice.lattice.grid import make_grid
    from difflattice.lattice.medium import Medium
    from difflattice.solver.sensors import Sensors

    g = make_grid(frequency_hz=50e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(nx, ny), dtype=dtype)
    dt = g.jnp_dtype
    x = jnp.arange(nx, dtype=dt)[:, None] * jnp.ones((1, ny), dt)
    probes = Sensors(probes=[(nx // 2 + 100, ny // 2 + k) for k in range(-50, 51, 10)])
    if kind == "homogeneous":  # rigid window, no sensors: the bare 5-point leapfrog
        return g, (lambda c: Medium(c, 1.2)), Edges.all("rigid"), Sensors(), 343.0
    if kind == "homogeneous+pml":
        return g, (lambda c: Medium(c, 1.2)), Edges(), Sensors(), 343.0
    if kind == "full":  # heterogeneous conservative medium, rigid obstacle, PML, probes + phasors
        rho = jnp.where(x > nx * 0.6, 2.0, 1.2).astype(dt)
        rigid = ((x > nx * 0.8) & (x < nx * 0.82)).astype(dt)
        sens = Sensors(probes=[(nx // 2, ny // 2)], phasor_cells=[(nx // 2, j) for j in range(30, ny - 30, 10)])
        c0 = jnp.where(x > nx * 0.6, 300.0, 343.0).astype(dt)
        return g, (lambda c: Medium(c, rho, rigid=rigid)), Edges(), sens, c0
    if kind == "gradient":  # heterogeneous medium map, rigid window (adjoint-supported), probes
        rho = jnp.where(x > nx * 0.6, 2.0, 1.2).astype(dt)
        c0 = jnp.full((nx, ny), 343.0, dt)
        return g, (lambda c: Medium(c, rho)), Edges.all("rigid"), probes, c0
    raise ValueError(kind)


def jax_case(spec):
    import jax

    if spec["dtype"] == "float64":
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    from difflattice.solver import Stepper, grid_sharding, run
    from difflattice.solver.sources import ToneBurst, line_transducer

    nx, ny, steps, mode = spec["nx"], spec["ny"], spec["steps"], spec["mode"]
    backend = spec.get("backend", "jax")  # the XLA loop; the native kernels: `difflattice bench`
    g, medium, edges, sensors, c0 = _scene(spec["kind"], nx, ny, spec["dtype"])
    dt = g.jnp_dtype
    sharding = grid_sharding() if spec.get("devices", 1) > 1 else None
    if sharding is not None:
        assert len(jax.devices()) == spec["devices"], jax.devices()

    def make(w, lag, c, y0=ny / 2):
        src = line_transducer(
            g, (40 * g.dx_m, y0 * g.dx_m), n_cells=104, signal=ToneBurst(50e3, 5), weights=w, lags_s=lag
        )
        return Stepper.build(g, medium(c), src, sensors, edges)

    w0, l0 = jnp.ones(104, dt), jnp.zeros(104, dt)
    c0 = jnp.asarray(c0, dt)

    def loss(w, lag, c, checkpoint=None, adjoint="autodiff"):
        r = run(make(w, lag, c), steps, checkpoint=checkpoint, adjoint=adjoint, backend=backend)
        return jnp.sum(r.probes**2)

    out = {}
    if mode == "forward":
        f = jax.jit(lambda w, l, c: run(make(w, l, c), steps, sharding=sharding, backend=backend).final.pressure)
        compile_s, t, ts = _median_time(f, w0, l0, c0)
        out.update(compile_s=compile_s, time_s=t, times_s=ts)
        if spec.get("recompile_check"):
            # a second scene with the same shapes (transducer moved by 37 cells): no recompile
            from difflattice.solver import simulate

            def sim(y0):
                src = line_transducer(g, (40 * g.dx_m, y0 * g.dx_m), n_cells=104, signal=ToneBurst(50e3, 5))
                return simulate(g, medium(c0), src, sensors, n_steps=steps, edges=edges, backend=backend).final.pressure

            t0 = time.perf_counter()
            jax.block_until_ready(sim(ny / 2))
            out["first_scene_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            jax.block_until_ready(sim(ny / 2 - 37))
            out["moved_transducer_s"] = time.perf_counter() - t0
    elif mode == "vmap":
        B = spec["batch"]
        ws = jnp.linspace(0.5, 1.5, B)[:, None] * w0[None]
        one = jax.jit(lambda w: run(make(w, l0, c0), steps, backend=backend).final.pressure)
        batched = jax.jit(jax.vmap(lambda w: run(make(w, l0, c0), steps, backend=backend).final.pressure))

        def loop(ws):
            return [one(w) for w in ws]

        c1, t1, _ = _median_time(loop, ws)
        c2, t2, ts = _median_time(batched, ws)
        out.update(compile_s=c2, time_s=t2, times_s=ts, loop_time_s=t1, batch=B)
    else:
        fns = {
            "loss": lambda w, l, c: loss(w, l, c),
            "grad_sources": jax.grad(loss, argnums=(0, 1)),
            "grad_sources_lattice": jax.grad(lambda w, l, c: loss(w, l, c, adjoint="lattice"), argnums=(0, 1)),
            "grad_medium": jax.grad(loss, argnums=2),
            "grad_medium_checkpointed": jax.grad(lambda w, l, c: loss(w, l, c, "sqrt"), argnums=2),
            "grad_medium_lattice": jax.grad(lambda w, l, c: loss(w, l, c, adjoint="lattice"), argnums=2),
            "jvp_sources": lambda w, l, c: jax.jvp(lambda w_: loss(w_, l, c), (w,), (jnp.ones_like(w),))[1],
        }
        f = jax.jit(fns[mode])
        compile_s, t, ts = _median_time(f, w0, l0, c0)
        out.update(compile_s=compile_s, time_s=t, times_s=ts)
    return out


def numpy_case(nx, ny, steps, dtype):
    import numpy as np

    p = np.zeros((nx, ny), dtype)
    q = np.zeros((nx, ny), dtype)
    p[nx // 2, ny // 2] = 1
    c2 = dtype(0.5)
    ts = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        for _ in range(steps):
            q[1:-1, 1:-1] *= -1
            q[1:-1, 1:-1] += (2 - 4 * c2) * p[1:-1, 1:-1]
            q[1:-1, 1:-1] += c2 * (p[2:, 1:-1] + p[:-2, 1:-1] + p[1:-1, 2:] + p[1:-1, :-2])
            p, q = q, p
        ts.append(time.perf_counter() - t0)
    return {"time_s": statistics.median(ts), "times_s": ts, "compile_s": 0.0}


def child(spec):
    if spec["impl"] == "numpy":
        import numpy as np

        out = numpy_case(spec["nx"], spec["ny"], spec["steps"], getattr(np, spec["dtype"]))
    else:
        out = jax_case(spec)
    out["max_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps(out))


def _run_child(spec):
    env = dict(os.environ)
    if spec.get("devices", 1) > 1:
        env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={spec['devices']}"
    r = subprocess.run([sys.executable, __file__, "--child", json.dumps(spec)], capture_output=True, text=True, env=env)
    if r.returncode != 0:
        return {**spec, "error": r.stderr[-800:]}
    res = json.loads(r.stdout.strip().splitlines()[-1])
    row = {**spec, **res}
    if "time_s" in res and spec["mode"] in ("forward", "vmap"):
        row["mlups"] = spec["nx"] * spec["ny"] * spec["steps"] * spec.get("batch", 1) / res["time_s"] / 1e6
    return row


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="840x630 only, fewer steps")
    ap.add_argument("--skip-numba", action="store_true", help="do not run the numba reference (needs PyPI once)")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return child(json.loads(args.child))
    sizes = [(840, 630, 1000 if not args.quick else 200)] + ([] if args.quick else [(2048, 2048, 200)])
    cases = []
    for nx, ny, steps in sizes:
        for dtype in ("float32", "float64"):
            cases.append(
                {
                    "impl": "numpy",
                    "mode": "forward",
                    "kind": "homogeneous",
                    "nx": nx,
                    "ny": ny,
                    "steps": steps,
                    "dtype": dtype,
                }
            )
            for kind in ("homogeneous", "homogeneous+pml", "full"):
                c = {"impl": "jax", "mode": "forward", "kind": kind, "nx": nx, "ny": ny, "steps": steps, "dtype": dtype}
                if kind == "full" and dtype == "float32":
                    c["recompile_check"] = True
                cases.append(c)
        for kind in ("homogeneous", "full"):
            cases.append(
                {
                    "impl": "jax",
                    "mode": "forward",
                    "kind": kind,
                    "nx": nx,
                    "ny": ny,
                    "steps": steps,
                    "dtype": "float32",
                    "devices": 2,
                }
            )
    nx, ny, steps = 840, 630, 1000 if not args.quick else 200
    for mode in (
        "loss",
        "grad_sources",
        "grad_sources_lattice",
        "grad_medium",
        "grad_medium_checkpointed",
        "grad_medium_lattice",
        "jvp_sources",
    ):
        cases.append(
            {"impl": "jax", "mode": mode, "kind": "gradient", "nx": nx, "ny": ny, "steps": steps, "dtype": "float32"}
        )
    for mode in ("loss", "grad_medium", "grad_medium_checkpointed", "grad_medium_lattice"):  # memory growth
        cases.append(
            {
                "impl": "jax",
                "mode": mode,
                "kind": "gradient",
                "nx": nx,
                "ny": ny,
                "steps": steps // 4,
                "dtype": "float32",
            }
        )
    cases.append(
        {
            "impl": "jax",
            "mode": "vmap",
            "kind": "homogeneous",
            "nx": nx,
            "ny": ny,
            "steps": steps // 4,
            "dtype": "float32",
            "batch": 4,
        }
    )

    rows = []
    for c in cases:
        row = _run_child(c)
        rows.append(row)
        print({k: v for k, v in row.items() if k != "times_s"}, flush=True)

    numba = None
    if not args.skip_numba:
        out_json = ROOT / "docs" / "benchmarks" / "reference_kernels.json"
        cmd = [sys.executable, str(ROOT / "benchmarks" / "reference_kernels.py"), "--json", str(out_json)] + (
            ["--quick"] if args.quick else []
        )
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode == 0:
            numba = json.loads(r.stdout.strip().splitlines()[-1])
        else:
            numba = {"error": r.stderr[-800:]}

    fwd = {
        (r["nx"], r["kind"], r["dtype"], r.get("devices", 1)): r
        for r in rows
        if r["mode"] == "forward" and r["impl"] == "jax" and "time_s" in r
    }
    loss = {(r["steps"]): r for r in rows if r["mode"] == "loss" and "time_s" in r}
    for r in rows:
        if r["mode"] not in ("forward", "vmap", "loss") and "time_s" in r and r["steps"] in loss:
            r["ratio_to_forward"] = r["time_s"] / loss[r["steps"]]["time_s"]
        if r["mode"] == "forward" and r["impl"] == "jax" and "time_s" in r:
            hom = fwd.get((r["nx"], "homogeneous", r["dtype"], r.get("devices", 1)))
            if hom:
                r["ratio_to_homogeneous"] = hom["time_s"] / r["time_s"]  # rate relative to homogeneous
            if r.get("devices", 1) > 1 and (one := fwd.get((r["nx"], r["kind"], r["dtype"], 1))):
                r["speedup_vs_one_device"] = one["time_s"] / r["time_s"]
        if r["mode"] == "vmap" and "time_s" in r:
            r["speedup_vs_loop"] = r["loop_time_s"] / r["time_s"]
    import jax

    out = {
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "machine": platform.machine(),
        "processor": platform.processor(),
        "cpus": os.cpu_count(),
        "python": sys.version.split()[0],
        "jax": jax.__version__,
        "load_average_at_end": os.getloadavg(),
        "repeats": REPEATS,
        "rows": rows,
        "numba_reference": numba,
    }
    dest = ROOT / "docs" / "benchmarks"
    dest.mkdir(parents=True, exist_ok=True)
    (dest / "kernel.json").write_text(json.dumps(out, indent=2))
    (dest / "kernel.md").write_text(render_markdown(out))
    print(render_markdown(out))


def render_markdown(out) -> str:
    L = [
        "# Kernel benchmark",
        "",
        f"{out['date_utc']}, {out['machine']}, {out['cpus']} CPUs, Python {out['python']}, JAX {out['jax']}; "
        f"median of {out['repeats']} after a compiling run; each case in its own process (peak RSS per case); "
        f"load average at the end {', '.join(f'{x:.1f}' for x in out['load_average_at_end'])}.",
        "Reproduce: `.venv/bin/python benchmarks/kernel_benchmark.py` (JSON: `docs/benchmarks/kernel.json`).",
        "",
        "## Forward (million lattice updates per second)",
        "",
        "| impl | scene | size x steps | dtype | devices | time (s) | MLUPS | vs homogeneous | vs 1 device | compile (s) | peak RSS (MB) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    rows = out["rows"]
    for r in rows:
        if r["mode"] != "forward":
            continue
        if "error" in r:
            L.append(
                f"| {r['impl']} | {r['kind']} | {r['nx']}x{r['ny']} x {r['steps']} | {r['dtype']} | {r.get('devices', 1)} | error | | | | | |"
            )
            continue
        L.append(
            f"| {r['impl']} | {r['kind']} | {r['nx']}x{r['ny']} x {r['steps']} | {r['dtype']} | {r.get('devices', 1)} | "
            f"{r['time_s']:.3f} | {r['mlups']:.0f} | {_f(r.get('ratio_to_homogeneous'))} | {_f(r.get('speedup_vs_one_device'))} | "
            f"{r['compile_s']:.2f} | {r['max_rss_mb']:.0f} |"
        )
    nb = out.get("numba_reference")
    if nb and "rows" in nb:
        L += [
            "",
            "Reference kernels in their own venv (`benchmarks/reference_kernels.py`, numba "
            f"{nb.get('numba')}, NumPy {nb.get('numpy')}), same run:",
            "",
            "| kernel | size x steps | dtype | MLUPS |",
            "|---|---|---|---|",
        ]
        for r in nb["rows"]:
            L.append(f"| {r['kernel']} | {r['nx']}x{r['ny']} x {r['steps']} | {r['dtype']} | {r['mlups']:.0f} |")
    elif nb:
        L += ["", f"numba reference failed: {nb.get('error', '')[:300]}"]
    L += [
        "",
        "## Gradients and JVP (840x630, float32, heterogeneous medium map, rigid window, 11 probes)",
        "",
        "| mode | steps | time (s) | ratio to forward | compile (s) | peak RSS (MB) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r["kind"] != "gradient":
            continue
        if "error" in r:
            L.append(f"| {r['mode']} | {r['steps']} | error | | | |")
            continue
        L.append(
            f"| {r['mode']} | {r['steps']} | {r['time_s']:.3f} | {_f(r.get('ratio_to_forward'))} | {r['compile_s']:.2f} | {r['max_rss_mb']:.0f} |"
        )
    for r in rows:
        if r.get("recompile_check") and "first_scene_s" in r:
            L += [
                "",
                f"Compile: a new {r['kind']} scene {r['nx']}x{r['ny']} through `simulate`: first call "
                f"{r['first_scene_s']:.2f} s (compile + run); the same scene with the transducer moved by 37 cells: "
                f"{r['moved_transducer_s']:.2f} s (run only: no recompile).",
            ]
        if r["mode"] == "vmap" and "time_s" in r:
            L += [
                "",
                f"vmap: {r['batch']} weight variants of {r['nx']}x{r['ny']} x {r['steps']} steps in one call "
                f"{r['time_s']:.2f} s vs one by one {r['loop_time_s']:.2f} s (x{r['speedup_vs_loop']:.2f}).",
            ]
    return "\n".join(L) + "\n"


def _f(x):
    return "" if x is None else f"{x:.2f}"


if __name__ == "__main__":
    main()
