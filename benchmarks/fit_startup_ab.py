"""Fresh-process fit times, side by side (issue 30): `difflattice fit CONFIG` in new processes for
one or more source trees (variants), interleaved round by round, with empty XLA caches ("cold",
a new cache directory per run: the first run on a machine) and with warm caches (one directory
per variant, filled by a first run that is not counted). Writes JSON and a markdown table of the
medians; every run records the wall time, the CPU time of the process and its children, the load
average before it and the fit's printed result line (so the variants can be seen to agree).

    .venv/bin/python benchmarks/fit_startup_ab.py --variant new=src --variant old=/path/to/other/src \
        [--config fitting/polaroid_like.toml] [--rounds 3] [--modes cold,warm] [--out docs/benchmarks/fit_startup]

Each variant runs as `python -m difflattice.cli fit` with PYTHONPATH=<its src> (the native
kernels are built once per source hash beforehand by the variant's own first run). A variant
`NAME=SRC:ENV=VALUE[,ENV=VALUE]` also sets environment variables for its runs, e.g.
`noprog=src:DIFFLATTICE_PROGRAM_CACHE=0` (JAX's cache only, without `fit.program_cache`).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULT = re.compile(r"fit: (?:successful|stationary|[a-z_ ]+) in \d+ steps; (D = [^;]*; RMS [^;]*; chi2_red [0-9.]+)")


def run_once(src: str, config: str, cache: str) -> dict:
    src, _, extra = src.partition(":")
    env = dict(os.environ, PYTHONPATH=str(Path(src).resolve()), DIFFLATTICE_CACHE_DIR=cache)
    env.update(kv.split("=", 1) for kv in extra.split(",") if kv)
    out = tempfile.mkdtemp(prefix="dl-fit-ab-")
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run(
        [sys.executable, "-m", "difflattice.cli", "fit", config, "--out", out, "--overwrite"],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    m = RESULT.search(p.stderr + p.stdout)
    return {
        "wall_s": round(wall, 3),
        "cpu_s": round(cpu, 3),
        "load_1min": load,
        "exit": p.returncode,
        "result": m.group(1) if m else None,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variant", action="append", required=True, help="NAME=SRC_DIR (repeatable)")
    ap.add_argument("--config", default="fitting/polaroid_like.toml")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--modes", default="cold,warm", help="which of cold,warm to run (default both)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks" / "fit_startup"))
    args = ap.parse_args()
    variants = dict(v.split("=", 1) for v in args.variant)
    modes = [m for m in ("cold", "warm") if m in args.modes.split(",")]
    warm = {name: tempfile.mkdtemp(prefix=f"dl-xla-{name}-") for name in variants}
    for name, src in variants.items():  # fill the warm caches (and build the native kernels)
        run_once(src, args.config, warm[name])
    runs: list[dict] = []
    for rnd in range(args.rounds):
        for mode in modes:
            for name, src in variants.items():
                cache = tempfile.mkdtemp(prefix="dl-xla-cold-") if mode == "cold" else warm[name]
                r = run_once(src, args.config, cache) | {"variant": name, "mode": mode, "round": rnd}
                print(json.dumps(r), flush=True)
                runs.append(r)
    summary = []
    for mode in modes:
        for name in variants:
            rs = [r for r in runs if r["variant"] == name and r["mode"] == mode]
            summary.append(
                {
                    "variant": name,
                    "mode": mode,
                    "median_wall_s": statistics.median(r["wall_s"] for r in rs),
                    "median_cpu_s": statistics.median(r["cpu_s"] for r in rs),
                    "walls_s": [r["wall_s"] for r in rs],
                    "results": sorted({str(r["result"]) for r in rs}),
                }
            )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "config": args.config,
        "variants": variants,
        "rounds": args.rounds,
        "cpu_count": os.cpu_count(),
        "load_average_at_end": os.getloadavg(),
    }
    (out / "fit_startup.json").write_text(json.dumps({"meta": meta, "summary": summary, "runs": runs}, indent=2))
    lines = [
        f"Fresh-process `difflattice fit {args.config}`: medians of {args.rounds} interleaved rounds "
        f"({meta['date_utc']}, {os.cpu_count()} CPUs; load averages per run in fit_startup.json)",
        "",
        "| variant | caches | median wall s | median CPU s | walls s |",
        "|---|---|---:|---:|---|",
    ]
    for s in summary:
        walls = ", ".join(f"{w:.2f}" for w in s["walls_s"])
        lines.append(f"| {s['variant']} | {s['mode']} | {s['median_wall_s']:.2f} | {s['median_cpu_s']:.2f} | {walls} |")
    lines += ["", "Result lines:"] + [f"- {s['variant']} ({s['mode']}): {'; '.join(s['results'])}" for s in summary]
    (out / "fit_startup.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
