"""Throughput of the 3-D lattice step (issue 16) against numba 7-point references, same session.

    .venv/bin/python benchmarks/kernel_benchmark_3d.py [--n 256] [--steps 20] [--rounds 2] [--no-write]

Cases, each in its own process (a fresh JAX or numba), interleaved over `--rounds` rounds (the
order alternates), each process timing the median of 3 runs after a compile/warm-up run:

- `jax_leapfrog`: difflattice, homogeneous air, rigid edges (the two-field leapfrog), float32;
- `jax_pml`: difflattice, homogeneous air, 12-cell PML on every side (split-field, 6 fields);
- `jax_wall_pml`: difflattice with a rigid wall as cut cells (K and three face-conductance maps)
  and PML: what a pulse-echo scene runs;
- `native_leapfrog`, `native_leapfrog_1t`, `native_wall_pml`: the same scenes on the native 3-D
  kernel (`solver/native/volume.cc`; two threads, one thread), issue 29; the `jax_*` cases run the
  JAX loop (`backend="jax"`) whatever the machine;
- `numba_serial`, `numba_parallel` (2 threads): `benchmarks/reference_kernels_3d.py` in its own
  venv `.venv-bench` (numba is never a dependency of difflattice).

MLUPS = n^3 x steps / median time / 1e6. Agreement: a 34^3 difflattice leapfrog with Dirichlet
(soft) edges (the native kernel where it is available: `backend="auto"`) against numba's interior of a 36^3 grid after 40 steps from the same impulse (the two
index the same cells). Writes `docs/benchmarks/kernel_3d.json` and `kernel_3d.md` (median of the
rounds' medians per case), with the load average at start and end: figures taken at a load
average above the core count are provisional.
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

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks"
JAX_CASES = ("jax_leapfrog", "jax_pml", "jax_wall_pml", "native_leapfrog", "native_leapfrog_1t", "native_wall_pml")

NUMBA_CASES = ("numba_serial", "numba_parallel")


def log(*a):
    print(*a, file=sys.stderr, flush=True)


def jax_case(case: str, n: int, steps: int) -> dict:
    """Run one difflattice case in this process; returns its row."""
    import jax
    import jax.numpy as jnp

    from difflattice.lattice import Edges, Medium
    from difflattice.lattice.geometry3d import HalfSpace, rasterise3d
    from difflattice.lattice.grid import make_grid
    from difflattice.solver import Stepper, run

    name = case
    if case == "native_leapfrog_1t":
        os.environ["DIFFLATTICE_NATIVE_THREADS"] = "1"
    backend = "native" if case.startswith("native") else "jax"
    case = case.replace("native_", "jax_").replace("_1t", "")  # the scene
    load0 = list(os.getloadavg())
    g = make_grid(frequency_hz=40e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(n, n, n), kind="3d")
    med = Medium(343.0, 1.2)
    edges = Edges.all("rigid") if case == "jax_leapfrog" else Edges.all("pml", thickness_cells=12)
    if case == "jax_wall_pml":
        wall = HalfSpace(jnp.array([0.8 * n, 0.5 * n, 0.5 * n]) * g.dx_m, jnp.array([-0.94, 0.34, 0.0]))
        med = Medium(343.0, 1.2, rigid=rasterise3d(wall, g))
    st = Stepper.build(g, med, edges=edges)
    st0 = st.init()
    st0 = st0.__class__(**{**st0.__dict__, "p": st0.p.at[n // 2, n // 2, n // 2].set(1.0)})  # both states carry P
    f = jax.jit(lambda s, s0: run(s, steps, state=s0, backend=backend).final)
    t0 = time.perf_counter()
    jax.block_until_ready(f(st, st0))
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        out = f(st, st0)
        jax.block_until_ready(out)
        times.append(time.perf_counter() - t0)
    t = statistics.median(times)
    p = out.pressure
    return {
        "case": name,
        "backend": backend,
        "n": n,
        "steps": steps,
        "dtype": "float32",
        "time_s": t,
        "times_s": times,
        "compile_s": compile_s,
        "mlups": n**3 * steps / t / 1e6,
        "jax": jax.__version__,
        "device": str(jax.devices()[0]),
        "load_average_at_start": load0,
        "load_average_at_end": list(os.getloadavg()),
        "max_abs_field": float(jnp.max(jnp.abs(p))),
    }


def agreement_fields(path: str) -> None:
    """A 34^3 difflattice leapfrog (soft edges: zero ghosts) from a centre impulse, 40 steps, saved."""
    import jax
    import numpy as np

    from difflattice.lattice import Edges, Medium
    from difflattice.lattice.grid import MAX_COURANT_3D, make_grid
    from difflattice.solver import Stepper, run

    jax.config.update("jax_enable_x64", True)
    n = 34
    g = make_grid(
        frequency_hz=40e3,
        cells_per_wavelength=20,
        c_max_m_s=343.0,
        shape=(n, n, n),
        kind="3d",
        courant=MAX_COURANT_3D,
        dtype="float64",
    )
    st = Stepper.build(g, Medium(343.0, 1.2), edges=Edges.all("soft"))
    s0 = st.init()
    s0 = s0.__class__(**{**s0.__dict__, "p": s0.p.at[(n + 2) // 2 - 1, (n + 2) // 2 - 1, (n + 2) // 2 - 1].set(1.0)})
    np.save(path, np.asarray(run(st, 40, state=s0).final.p))


def numba_agreement(path: str) -> None:
    """The numba serial kernel on 36^3 (Dirichlet outer layer), 40 steps, float64, saved (runs in
    .venv-bench)."""
    import importlib.util

    import numpy as np

    spec = importlib.util.spec_from_file_location("rk3", ROOT / "benchmarks" / "reference_kernels_3d.py")
    rk3 = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(rk3)
    serial = rk3.make_kernels()["numba_serial"]
    n = 36
    p = np.zeros((n, n, n))
    q = np.zeros((n, n, n))
    p[n // 2, n // 2, n // 2] = 1.0
    c2 = 1.0 / 3.0
    out = serial(p, q, c2, 2 - 6 * c2, 40)[0]
    np.save(path, out[1:-1, 1:-1, 1:-1])


def _run_json(cmd: list[str]) -> dict:
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=256)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--case", default=None, help="(internal) run one JAX case in this process")
    ap.add_argument("--agreement", default=None, help="(internal) write the agreement field here")
    ap.add_argument("--numba-agreement", default=None, help="(internal, in .venv-bench)")
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--cases", default=None, help="comma-separated subset of the cases (default: all)")
    args = ap.parse_args()
    if args.case:
        print(json.dumps(jax_case(args.case, args.n, args.steps)))
        return
    if args.agreement:
        agreement_fields(args.agreement)
        return
    if args.numba_agreement:
        numba_agreement(args.numba_agreement)
        return

    py = sys.executable
    bench_py = str(Path(os.environ.get("DIFFLATTICE_BENCH_VENV", ROOT / ".venv-bench")) / "bin" / "python")
    load_start = list(os.getloadavg())
    rows = []
    cases = list(JAX_CASES) + list(NUMBA_CASES)
    if args.cases:
        unknown = set(args.cases.split(",")) - set(cases)
        if unknown:
            raise SystemExit(f"unknown cases {sorted(unknown)}; known: {', '.join(cases)}")
        cases = [c for c in cases if c in args.cases.split(",")]
    for rnd in range(args.rounds):
        order = cases if rnd % 2 == 0 else cases[::-1]
        for case in order:
            log(f"round {rnd + 1}: {case}")
            if case in JAX_CASES:
                row = _run_json([py, __file__, "--case", case, "--n", str(args.n), "--steps", str(args.steps)])
            else:
                row = _run_json(
                    [
                        "python3",
                        str(ROOT / "benchmarks" / "reference_kernels_3d.py"),
                        "--kernel",
                        case,
                        "--n",
                        str(args.n),
                        "--steps",
                        str(args.steps),
                        "--threads",
                        "2",
                    ]
                )
                row["case"] = case
            row["round"] = rnd + 1
            log(json.dumps({k: row[k] for k in ("case", "mlups", "time_s")}))
            rows.append(row)
    import numpy as np

    tmp = ROOT / "out"
    tmp.mkdir(exist_ok=True)
    a, b = tmp / "agree3d_jax.npy", tmp / "agree3d_numba.npy"
    subprocess.run([py, __file__, "--agreement", str(a)], check=True)
    subprocess.run([bench_py, __file__, "--numba-agreement", str(b)], check=True)
    fa, fb = np.load(a), np.load(b)
    agreement = {
        "n_jax": 34,
        "n_numba": 36,
        "steps": 40,
        "dtype": "float64",
        "max_abs_diff": float(np.abs(fa - fb).max()),
        "max_abs_field": float(np.abs(fb).max()),
    }
    summary = {}
    for case in cases:
        ms = [r["mlups"] for r in rows if r["case"] == case]
        summary[case] = {"mlups_median": statistics.median(ms), "mlups_rounds": ms}
    load_end = list(os.getloadavg())
    out = {
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "machine": platform.machine(),
        "processor": platform.processor(),
        "cpu_count": os.cpu_count(),
        "n": args.n,
        "steps": args.steps,
        "rounds": args.rounds,
        "load_average_at_start": load_start,
        "load_average_at_end": load_end,
        "provisional": max(load_start[0], load_end[0]) > (os.cpu_count() or 1),
        "summary": summary,
        "agreement": agreement,
        "rows": rows,
    }
    print(json.dumps(out))
    if args.no_write:
        return
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "kernel_3d.json").write_text(json.dumps(out, indent=2) + "\n")
    lines = [
        "# 3-D kernel throughput (issue 16)",
        "",
        f"`{args.n}^3` cells x {args.steps} steps, float32, median of 3 per process, median over {args.rounds} "
        f"interleaved rounds; {out['date_utc']}, {os.cpu_count()} cores, load average "
        f"{load_start[0]:.2f} at start, {load_end[0]:.2f} at end"
        + (" (**provisional**: load above the core count; the machine was shared)" if out["provisional"] else "")
        + ".",
        "",
        "| case | MLUPS (median) | per round |",
        "|---|---:|---|",
    ]
    for case, s in summary.items():
        lines.append(f"| {case} | {s['mlups_median']:.1f} | {', '.join(f'{m:.1f}' for m in s['mlups_rounds'])} |")
    lines += [
        "",
        f"Agreement (34^3 difflattice leapfrog vs numba interior of 36^3, 40 steps, float64): max |diff| = "
        f"{agreement['max_abs_diff']:.2e} (field max {agreement['max_abs_field']:.2e}).",
        "",
        "Reproduce: `.venv/bin/python benchmarks/kernel_benchmark_3d.py`.",
        "",
    ]
    (OUT / "kernel_3d.md").write_text("\n".join(lines))


if __name__ == "__main__":
    main()
