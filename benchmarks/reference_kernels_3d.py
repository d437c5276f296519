"""Reference kernels for the 3-D kernel benchmark (issue 16): numba 7-point leapfrog steps of the
homogeneous 3-D wave equation, measured in their own virtual environment (as
`reference_kernels.py` does in 2-D).

CLI (stable; `benchmarks/kernel_benchmark_3d.py` calls it as a subprocess, one case per process):

    python3 benchmarks/reference_kernels_3d.py --kernel numba_parallel --n 256 --steps 50 \
        [--dtype float32] [--threads 2] [--json OUT.json]

- Any Python 3 may start it. Unless it already runs inside `<repo>/.venv-bench`, it creates that
  venv if missing (`python3 -m venv .venv-bench && .venv-bench/bin/pip install numba numpy`), then
  re-executes itself with `.venv-bench/bin/python` and the same arguments. numba is never a
  dependency of difflattice. Set DIFFLATTICE_BENCH_VENV to use another venv directory.
- The last line of stdout is the result as one JSON object (also written to OUT.json): kernel,
  dtype, n, steps, time_s (median), times_s, compile_s, mlups, threads, numba, load_average_at_start,
  load_average_at_end, checksum (sum of the final field, float64), max_abs_field.

Scheme: p_new = (centre p - p_prev) + c2 (((((p[i+1] + p[i-1]) + p[j+1]) + p[j-1]) + p[k+1]) + p[k-1])
with c2 = 1/3 (Courant number 1/sqrt 3, squared) and centre = 2 - 6 c2 as run-time arguments, on the
interior of an n^3 array whose outer layer stays 0 (Dirichlet), unit impulse at the centre at t = 0,
p_prev = 0; in the arrays' dtype. Kernels: "numba_serial" (@njit) and "numba_parallel" (prange
over the outer index, `--threads` threads). Timing: a short warm-up run (numba compiles there:
`compile_s`), then the median of 3 timed runs from the same initial state. MLUPS = n^3 steps /
time / 1e6 (the outer layer counted, as difflattice counts its whole grid).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from reference_kernels import ensure_venv_and_reexec, log  # noqa: E402  (one venv, one re-exec)

C2 = 1.0 / 3.0
REPEATS = 3
WARMUP_STEPS = 2


def make_kernels():
    import numba as nb

    @nb.njit(cache=False)
    def serial(p, q, c2, centre, steps):
        n0, n1, n2 = p.shape
        for _ in range(steps):
            for i in range(1, n0 - 1):
                for j in range(1, n1 - 1):
                    for k in range(1, n2 - 1):
                        q[i, j, k] = (centre * p[i, j, k] - q[i, j, k]) + c2 * (
                            ((((p[i + 1, j, k] + p[i - 1, j, k]) + p[i, j + 1, k]) + p[i, j - 1, k]) + p[i, j, k + 1])
                            + p[i, j, k - 1]
                        )
            p, q = q, p
        return p, q

    @nb.njit(parallel=True, cache=False)
    def parallel(p, q, c2, centre, steps):
        n0, n1, n2 = p.shape
        for _ in range(steps):
            for i in nb.prange(1, n0 - 1):
                for j in range(1, n1 - 1):
                    for k in range(1, n2 - 1):
                        q[i, j, k] = (centre * p[i, j, k] - q[i, j, k]) + c2 * (
                            ((((p[i + 1, j, k] + p[i - 1, j, k]) + p[i, j + 1, k]) + p[i, j - 1, k]) + p[i, j, k + 1])
                            + p[i, j, k - 1]
                        )
            p, q = q, p
        return p, q

    return {"numba_serial": serial, "numba_parallel": parallel}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kernel", choices=("numba_serial", "numba_parallel"), default="numba_parallel")
    ap.add_argument("--n", type=int, default=256)
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--dtype", default="float32", choices=("float32", "float64"))
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    ensure_venv_and_reexec(__file__)
    import numba
    import numpy as np

    load0 = list(os.getloadavg())
    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    fn = make_kernels()[args.kernel]
    dt = np.dtype(args.dtype)
    c2 = dt.type(C2)
    centre = dt.type(2) - dt.type(6) * c2
    n = args.n

    def initial():
        p = np.zeros((n, n, n), dt)
        q = np.zeros((n, n, n), dt)
        p[n // 2, n // 2, n // 2] = 1
        return p, q

    p, q = initial()
    t0 = time.perf_counter()
    fn(p, q, c2, centre, WARMUP_STEPS)
    compile_s = time.perf_counter() - t0
    times = []
    final = None
    for _ in range(REPEATS):
        p, q = initial()
        t0 = time.perf_counter()
        final = fn(p, q, c2, centre, args.steps)[0]
        times.append(time.perf_counter() - t0)
    t = statistics.median(times)
    out = {
        "kernel": args.kernel,
        "dtype": args.dtype,
        "n": n,
        "steps": args.steps,
        "time_s": t,
        "times_s": times,
        "compile_s": compile_s,
        "mlups": n**3 * args.steps / t / 1e6,
        "threads": numba.get_num_threads(),
        "numba": numba.__version__,
        "load_average_at_start": load0,
        "load_average_at_end": list(os.getloadavg()),
        "checksum": float(np.sum(final, dtype=np.float64)),
        "max_abs_field": float(np.abs(final).max()),
    }
    log(json.dumps(out))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
