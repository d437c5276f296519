"""Where a fresh-process `difflattice fit` spends its time (issue 15): runs the fit in new
processes (cold and warm caches) under cProfile and prints the wall time and the main phases
(imports, tracing, lowering, XLA compilation or cache reads, the transfer simulation, the fit,
the report).

    .venv/bin/python benchmarks/startup_profile.py [--config fitting/polaroid_like.toml] [--runs 3]
        [--min-compile-s 0]   (the persistent cache's threshold; omitted: the library default)
"""

from __future__ import annotations

import argparse
import json
import os
import pstats
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PHASES = {  # profile entry (function name) -> phase
    "_find_and_load": "imports",
    "trace_to_jaxpr": "tracing",
    "lower_sharding_computation": "lowering",
    "compile_or_get_cached": "XLA compile / cache read",
    "free_field_transfer": "transfer simulation",
    "_fit": "fit (whole command)",
    "write_report": "report (aperture; waits for the figure worker)",
    "start_figures": "report: figures started (worker process)",
    "_field_image_args": "report: field image simulation (a thread beside the error budget)",
}


def phases(prof: str) -> dict:
    st = pstats.Stats(prof).stats
    out = {}
    for name, label in PHASES.items():
        # the outermost call of each function (its largest cumulative time)
        times = [v[3] for k, v in st.items() if k[2] == name]
        out[label] = round(max(times), 3) if times else None
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--config", default=str(ROOT / "fitting" / "polaroid_like.toml"))
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--min-compile-s", type=float, default=None)
    args = ap.parse_args()
    env = dict(os.environ)
    cache = tempfile.mkdtemp(prefix="dl-xla-")
    env["DIFFLATTICE_CACHE_DIR"] = cache  # cold at the first run
    if args.min_compile_s is not None:
        env["DIFFLATTICE_CACHE_MIN_COMPILE_S"] = str(args.min_compile_s)
    for run in range(args.runs):
        out = tempfile.mkdtemp(prefix="dl-fit-")
        prof = os.path.join(out, "fit.prof")
        load = os.getloadavg()[0]
        t0 = time.perf_counter()
        r = subprocess.run(
            [sys.executable, "-m", "cProfile", "-o", prof, "-m", "difflattice.cli", "fit", args.config, "--out", out],
            capture_output=True,
            text=True,
            env=env,
        )
        wall = time.perf_counter() - t0
        line = next(
            (ln for ln in r.stdout.splitlines() + r.stderr.splitlines() if "successful" in ln or "error" in ln), ""
        )
        print(
            json.dumps(
                {
                    "run": run,
                    "cache": "cold" if run == 0 else "warm",
                    "wall_s": round(wall, 2),
                    "load_avg": round(load, 2),
                    "rc": r.returncode,
                    **phases(prof),
                    "fit": line[-120:],
                }
            ),
            flush=True,
        )


if __name__ == "__main__":
    main()
