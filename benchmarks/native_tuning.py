"""Tuning of the native kernels' temporal blocking (issue 15): forward MLUPS of the benchmark
cases of `difflattice bench` against the steps per sweep (DIFFLATTICE_NATIVE_LEVELS) and the
threads, with the numba loops of `reference_kernels.py` in the same run. Each point runs in its
own process; rounds interleave all points.

    .venv/bin/python benchmarks/native_tuning.py [--levels 1,2,4,8,16] [--threads 1,2] [--rounds 2]
        [--cases homogeneous:840x630x1000,homogeneous:2048x2048x200,full:840x630x1000] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def point(case: str, threads: int, levels: int | None) -> dict:
    name, size = case.split(":")
    nx, ny, steps = (int(v) for v in size.split("x"))
    env = dict(os.environ, DIFFLATTICE_NATIVE_THREADS=str(threads))
    if levels is None:  # numba
        kernel = "numba_serial" if threads == 1 else "numba_parallel"
        cmd = [
            sys.executable,
            str(ROOT / "benchmarks" / "reference_kernels.py"),
            "--kernel",
            kernel,
            "--size",
            size,
            "--dtypes",
            "float32",
            "--threads",
            str(threads),
        ]
    else:
        env["DIFFLATTICE_NATIVE_LEVELS"] = str(levels)
        spec = json.dumps([{"name": name, "nx": nx, "ny": ny, "steps": steps}, "native"])
        cmd = [sys.executable, "-m", "difflattice.apps.bench", "--child", spec]
    load = os.getloadavg()[0]
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if r.returncode != 0:
        return {"error": r.stderr[-400:], "load": load}
    out = json.loads(r.stdout.strip().splitlines()[-1])
    mlups = out["rows"][0]["mlups"] if "rows" in out else out["mlups"]
    return {"mlups": mlups, "load": load}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--levels", default="1,2,4,8,16")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--cases", default="homogeneous:840x630x1000,homogeneous:2048x2048x200,full:840x630x1000")
    ap.add_argument("--no-numba", action="store_true")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    levels = [int(v) for v in args.levels.split(",")]
    threads = [int(v) for v in args.threads.split(",")]
    points = []
    for case in args.cases.split(","):
        for t in threads:
            if not args.no_numba and case.startswith("homogeneous"):
                points.append((case, t, None))
            points += [(case, t, lv) for lv in levels]
    res: dict = {}
    for _ in range(args.rounds):
        for p in points:
            res.setdefault(p, []).append(point(*p))
            r = res[p][-1]
            print(
                json.dumps(
                    {"case": p[0], "threads": p[1], "impl": "numba" if p[2] is None else "native", "levels": p[2], **r}
                ),
                flush=True,
            )
    summary = []
    for (case, t, lv), runs in res.items():
        ok = [r["mlups"] for r in runs if "mlups" in r]
        summary.append(
            {
                "case": case,
                "threads": t,
                "impl": "numba" if lv is None else "native",
                "levels": lv,
                "mlups_median": statistics.median(ok) if ok else None,
                "mlups": ok,
                "load": [round(r["load"], 2) for r in runs],
            }
        )
    for s in summary:
        print(json.dumps(s))
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=2) + "\n")


if __name__ == "__main__":
    main()
