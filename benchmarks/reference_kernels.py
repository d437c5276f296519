"""Reference kernels for the kernel benchmark (issue 5): NumPy and numba 5-point leapfrog steps
of the homogeneous 2-D wave equation, measured in their own virtual environment.

CLI (stable; `benchmarks/kernel_benchmark.py` calls it as a subprocess):

    python3 benchmarks/reference_kernels.py --json OUT.json [--quick] [--threads N] [--dtypes float32,float64]
    python3 benchmarks/reference_kernels.py --kernel numba_serial --size 840x630x1000 [--dtypes float32]
        [--threads N] [--repeats R]     (one case only: what `difflattice bench --reference` runs per process)

- Any Python 3 may start it. Unless it already runs inside `<repo>/.venv-bench`, it creates that
  venv if missing (`python3 -m venv .venv-bench && .venv-bench/bin/pip install numba numpy`),
  then re-executes itself with `.venv-bench/bin/python` and the same arguments. numba is never a
  dependency of difflattice. Set DIFFLATTICE_BENCH_VENV to use another venv directory.
- Exit status 0 on success. Progress goes to stderr; the last line of stdout is the result as one
  JSON object, also written to OUT.json (if given). Keys:
    date_utc, python, machine, processor, numpy, numba, numba_threading_layer, cpu_count,
    threads_parallel, quick, c2, repeats, warmup_steps, load_average_at_start,
    load_average_at_end, rows: [{kernel, dtype, nx, ny, steps, time_s (median), times_s,
    compile_s, mlups}], agreement: [{dtype, nx, ny, steps, max_abs_diff: {kernel: vs numpy_inplace},
    max_abs_field}], float32_vs_float64_max_abs_diff ({"NXxNYxSTEPS": max abs difference of the
    numba_serial fields}).
  kernel is one of "numpy_inplace", "numba_serial", "numba_parallel" and, with --kernel only,
  "numba_serial_rz", "numba_parallel_rz" (the axisymmetric lattice, below).

Scheme: p_new = 2 p - p_prev + c2 (p[i+1,j] + p[i-1,j] + p[i,j+1] + p[i,j-1] - 4 p), c2 = 0.5
(Courant number 1/sqrt(2), squared), p = 0 on the outermost ring (Dirichlet), unit impulse at
the centre at t = 0 with p_prev = 0. Every kernel evaluates it as
p_new = ((2 - 4 c2) p - p_prev) + c2 (((p[i+1,j] + p[i-1,j]) + p[i,j+1]) + p[i,j-1]), in that
order, in the arrays' dtype; c2 and 2 - 4 c2 are run-time arguments (so no kernel can drop the
centre term, which is 0 for c2 = 0.5, at compile time). The axisymmetric (rz) kernels run the
same update with the ring metric on the radial neighbours (`rz_serial`): rows are z, column j >= 1
is ring r = j - 1 (the axis at j = 1; column 0 a zero ghost, so the loop has no branch), and the
radial terms are weighted by the ring's face areas over its volume, mh = (r + 1) / (r + 1/2) and
ml = r / (r + 1/2), whose sum is 2 (so the centre term is the 2-D one): difflattice's rz leapfrog
in its ring form, the same arithmetic per cell (tests/core/test_bench_reference.py checks it
against difflattice's rz stepper). Sizes: 840x630 x 1000 steps and
2048x2048 x 200 steps (--quick: a tenth of the steps). Timing: one short warm-up run (numba
compiles there; its time is `compile_s`), then the median of 3 timed runs from the same initial
state. MLUPS = nx ny steps / time / 1e6. Agreement: the final fields of the numba kernels
against the NumPy one after the same steps.
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
VENV = Path(os.environ.get("DIFFLATTICE_BENCH_VENV", ROOT / ".venv-bench"))
C2 = 0.5
REPEATS = 3
WARMUP_STEPS = 10


def log(*a):
    print(*a, file=sys.stderr, flush=True)


def ensure_venv_and_reexec(script: str | Path | None = None) -> None:
    """Create .venv-bench if missing and re-run `script` (default: this one) inside it (never
    returns there)."""
    if Path(sys.prefix).resolve() == VENV.resolve():
        return
    py = VENV / "bin" / "python"
    if not py.exists():
        log(f"creating {VENV} (numba, numpy)")
        subprocess.run([sys.executable, "-m", "venv", str(VENV)], check=True)
        subprocess.run([str(VENV / "bin" / "pip"), "install", "-q", "numba", "numpy"], check=True)
    r = subprocess.run([str(py), str(Path(script or __file__).resolve()), *sys.argv[1:]])
    sys.exit(r.returncode)


# --- kernels ---------------------------------------------------------------------------------


def numpy_run(p, q, c2, centre, steps):
    """In place on the interior: q <- centre p - q + c2 (sum of the 4 neighbours), then swap.
    One preallocated interior-sized buffer; no other temporaries."""
    import numpy as np

    s = np.empty((p.shape[0] - 2, p.shape[1] - 2), p.dtype)
    P, Q = p, q
    for _ in range(steps):
        qi = Q[1:-1, 1:-1]
        qi *= -1
        np.multiply(P[1:-1, 1:-1], centre, out=s)
        qi += s
        np.add(P[2:, 1:-1], P[:-2, 1:-1], out=s)
        s += P[1:-1, 2:]
        s += P[1:-1, :-2]
        s *= c2
        qi += s
        P, Q = Q, P
    return P, Q  # (latest, previous)


def rz_metric(ny, dtype):
    """(ml, mh): the radial neighbours' weights per column of an rz reference field (column 0 a
    zero ghost, column j >= 1 ring r = j - 1): r / (r + 1/2) and (r + 1) / (r + 1/2), zero at 0."""
    import numpy as np

    r = np.arange(ny, dtype=np.float64) - 1.0
    v = np.maximum(r + 0.5, 0.5)
    ml = np.where(r >= 0, r / v, 0.0).astype(dtype)
    mh = np.where(r >= 0, (r + 1.0) / v, 0.0).astype(dtype)
    return ml, mh


def rz_serial(p, q, c2, centre, steps, ml, mh):
    """The axisymmetric leapfrog (plain Python; `make_numba_rz_kernels` compiles it): as `serial`
    with the radial neighbours weighted by the ring metric (`rz_metric`)."""
    nx, ny = p.shape
    for _ in range(steps):
        for i in range(1, nx - 1):
            for j in range(1, ny - 1):
                q[i, j] = (centre * p[i, j] - q[i, j]) + c2 * (
                    ((p[i + 1, j] + p[i - 1, j]) + mh[j] * p[i, j + 1]) + ml[j] * p[i, j - 1]
                )
        p, q = q, p
    return p, q


def make_numba_kernels():
    """Same arithmetic, same order as numpy_run. c2 and centre arrive as scalars of the array's
    dtype and no integer literal enters the update, so float32 stays float32 throughout."""
    import numba as nb

    @nb.njit(cache=False)
    def serial(p, q, c2, centre, steps):
        nx, ny = p.shape
        for _ in range(steps):
            for i in range(1, nx - 1):
                for j in range(1, ny - 1):
                    q[i, j] = (centre * p[i, j] - q[i, j]) + c2 * (
                        ((p[i + 1, j] + p[i - 1, j]) + p[i, j + 1]) + p[i, j - 1]
                    )
            p, q = q, p
        return p, q

    @nb.njit(parallel=True, cache=False)
    def parallel(p, q, c2, centre, steps):
        nx, ny = p.shape
        for _ in range(steps):
            for i in nb.prange(1, nx - 1):
                for j in range(1, ny - 1):
                    q[i, j] = (centre * p[i, j] - q[i, j]) + c2 * (
                        ((p[i + 1, j] + p[i - 1, j]) + p[i, j + 1]) + p[i, j - 1]
                    )
            p, q = q, p
        return p, q

    return serial, parallel


def make_numba_rz_kernels():
    """`rz_serial` compiled, and its row-parallel twin (numba's prange over z rows)."""
    import numba as nb

    @nb.njit(parallel=True, cache=False)
    def parallel(p, q, c2, centre, steps, ml, mh):
        nx, ny = p.shape
        for _ in range(steps):
            for i in nb.prange(1, nx - 1):
                for j in range(1, ny - 1):
                    q[i, j] = (centre * p[i, j] - q[i, j]) + c2 * (
                        ((p[i + 1, j] + p[i - 1, j]) + mh[j] * p[i, j + 1]) + ml[j] * p[i, j - 1]
                    )
            p, q = q, p
        return p, q

    return nb.njit(cache=False)(rz_serial), parallel


# --- driver ----------------------------------------------------------------------------------


def initial(nx, ny, dtype):
    import numpy as np

    p = np.zeros((nx, ny), dtype)
    q = np.zeros((nx, ny), dtype)
    p[nx // 2, ny // 2] = 1
    return p, q


def measure(name, fn, nx, ny, steps, dtype, repeats=REPEATS):
    """Warm-up (compile) run, then the median of REPEATS timed runs. Returns (row, final p)."""
    import numpy as np

    c2 = np.dtype(dtype).type(C2)
    centre = np.dtype(dtype).type(2) - np.dtype(dtype).type(4) * c2
    p, q = initial(nx, ny, dtype)
    t0 = time.perf_counter()
    fn(p, q, c2, centre, WARMUP_STEPS)
    compile_s = time.perf_counter() - t0
    times, final = [], None
    for _ in range(repeats):
        p, q = initial(nx, ny, dtype)
        t0 = time.perf_counter()
        out = fn(p, q, c2, centre, steps)
        times.append(time.perf_counter() - t0)
        final = out[0]
    t = statistics.median(times)
    row = {
        "kernel": name,
        "dtype": dtype,
        "nx": nx,
        "ny": ny,
        "steps": steps,
        "time_s": t,
        "times_s": times,
        "compile_s": compile_s if name != "numpy_inplace" else 0.0,
        "mlups": nx * ny * steps / t / 1e6,
    }
    log(json.dumps(row))
    return row, np.array(final, dtype=np.float64)


def one_case(args) -> dict:
    """A single kernel at a single size (`--kernel`, `--size NXxNYxSTEPS`, the first dtype)."""
    import numba

    load_start = list(os.getloadavg())
    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    nx, ny, steps = (int(v) for v in args.size.lower().split("x"))
    if args.kernel.endswith("_rz"):  # ny rings plus the ghost column
        serial_rz, parallel_rz = make_numba_rz_kernels()
        ml, mh = rz_metric(ny + 1, args.dtypes[0])
        k = serial_rz if args.kernel == "numba_serial_rz" else parallel_rz

        def fn(p, q, c2, centre, n):
            return k(p, q, c2, centre, n, ml, mh)

        row, _ = measure(args.kernel, fn, nx, ny + 1, steps, args.dtypes[0], repeats=args.repeats)
        row["ny"], row["mlups"] = ny, nx * ny * steps / row["time_s"] / 1e6  # the rings, not the ghost
    else:
        serial, parallel = make_numba_kernels()
        fn = {"numpy_inplace": numpy_run, "numba_serial": serial, "numba_parallel": parallel}[args.kernel]
        row, _ = measure(args.kernel, fn, nx, ny, steps, args.dtypes[0], repeats=args.repeats)
    row["threads"] = numba.get_num_threads() if args.kernel.startswith("numba_parallel") else 1
    return {
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "numba": numba.__version__,
        "load_average_at_start": load_start,
        "load_average_at_end": list(os.getloadavg()),
        "rows": [row],
    }


def bench(args) -> dict:
    import numba
    import numpy as np

    load_start = list(os.getloadavg())
    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    serial, parallel = make_numba_kernels()
    sizes = [(840, 630, 1000), (2048, 2048, 200)]
    if args.quick:
        sizes = [(nx, ny, s // 10) for nx, ny, s in sizes]
    rows, agreement, f32_64 = [], [], {}
    for nx, ny, steps in sizes:
        finals = {}
        for dtype in args.dtypes:
            fields = {}
            for name, fn in (("numpy_inplace", numpy_run), ("numba_serial", serial), ("numba_parallel", parallel)):
                row, fld = measure(name, fn, nx, ny, steps, dtype)
                rows.append(row)
                fields[name] = fld
            ref = fields["numpy_inplace"]
            agreement.append(
                {
                    "dtype": dtype,
                    "nx": nx,
                    "ny": ny,
                    "steps": steps,
                    "max_abs_field": float(np.abs(ref).max()),
                    "max_abs_diff": {
                        k: float(np.abs(v - ref).max()) for k, v in fields.items() if k != "numpy_inplace"
                    },
                }
            )
            finals[dtype] = fields["numba_serial"]
        if "float32" in finals and "float64" in finals:
            f32_64[f"{nx}x{ny}x{steps}"] = float(np.abs(finals["float32"] - finals["float64"]).max())
    try:
        layer = numba.threading_layer()
    except Exception:  # noqa: BLE001 (only known after a parallel run)
        layer = None
    return {
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "python": platform.python_version(),
        "machine": platform.machine(),
        "processor": platform.processor(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "numba_threading_layer": layer,
        "cpu_count": os.cpu_count(),
        "threads_parallel": numba.get_num_threads(),
        "quick": args.quick,
        "c2": C2,
        "repeats": REPEATS,
        "warmup_steps": WARMUP_STEPS,
        "load_average_at_start": load_start,
        "load_average_at_end": list(os.getloadavg()),
        "rows": rows,
        "agreement": agreement,
        "float32_vs_float64_max_abs_diff": f32_64,
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", default=None, help="write the result JSON here")
    ap.add_argument("--quick", action="store_true", help="a tenth of the steps")
    ap.add_argument("--threads", type=int, default=2, help="threads of the numba parallel kernel (default 2)")
    ap.add_argument("--dtypes", default="float32,float64")
    ap.add_argument(
        "--kernel",
        choices=["numpy_inplace", "numba_serial", "numba_parallel", "numba_serial_rz", "numba_parallel_rz"],
        default=None,
        help="run this kernel only, at --size (one case per process)",
    )
    ap.add_argument("--size", default="840x630x1000", help="NXxNYxSTEPS of --kernel")
    ap.add_argument("--repeats", type=int, default=REPEATS, help="timed runs of --kernel (median)")
    args = ap.parse_args()
    args.dtypes = [d.strip() for d in args.dtypes.split(",") if d.strip()]
    ensure_venv_and_reexec()
    out = one_case(args) if args.kernel else bench(args)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
