"""Gradient time against the forward time on the native kernels (issue 15): the kernel
benchmark's gradient scene (840x630, heterogeneous density, rigid window, 11 probes, a 104-cell
line source, float32, 1000 steps; loss = sum of probes^2), each mode in its own process (peak
RSS per mode), the modes interleaved over `--rounds` rounds, each process the median of 3 timed
calls after a compiling one; the 1-minute load average is recorded with every run.

    .venv/bin/python benchmarks/gradient_speed.py [--rounds 3] [--steps 1000] [--out docs/benchmarks/gradient_native]

Modes (backend "auto": the native kernels where they run the scene, else the JAX loop):
- loss: the forward run (the denominator of every ratio);
- grad_sources: weights and lags by JAX's reverse mode (a native run's derivative is the JAX loop's);
- grad_sources_lattice: adjoint="lattice": forward and backward runs on the native kernels;
- grad_medium_checkpointed / grad_medium_lattice: the speed map (checkpoint="sqrt" / the
  adjoint wave equation: native forward, JAX backward with recomputed fields);
- *_jax: the same on the JAX loop (backend="jax"), for reference.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))
import kernel_benchmark as kb  # noqa: E402

MODES = [
    ("loss", "auto"),
    ("grad_sources", "auto"),
    ("grad_sources_lattice", "auto"),
    ("grad_medium_checkpointed", "auto"),
    ("grad_medium_lattice", "auto"),
    ("loss", "jax"),
    ("grad_sources_lattice", "jax"),
]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--out", default=str(ROOT.parent / "docs" / "benchmarks" / "gradient_native"))
    args = ap.parse_args(argv)
    runs: dict[str, list[dict]] = {}
    for k in range(args.rounds):
        for mode, backend in MODES:
            spec = {"impl": "jax", "mode": mode, "kind": "gradient", "nx": 840, "ny": 630, "steps": args.steps}
            spec.update(dtype="float32", backend=backend)
            load = os.getloadavg()[0]
            row = kb._run_child(spec)
            row["load_avg"] = load
            print(
                json.dumps(
                    {
                        "round": k,
                        **{x: row.get(x) for x in ("mode", "backend", "time_s", "max_rss_mb", "load_avg", "error")},
                    }
                ),
                flush=True,
            )
            runs.setdefault(f"{mode}[{backend}]", []).append(row)
    table = {}
    for name, rs in runs.items():
        ok = [r for r in rs if "time_s" in r]
        if not ok:
            table[name] = {"error": rs[-1].get("error")}
            continue
        table[name] = {
            "time_s": statistics.median(r["time_s"] for r in ok),
            "per_round_s": [round(r["time_s"], 4) for r in ok],
            "max_rss_mb": max(r["max_rss_mb"] for r in ok),
            "compile_s": statistics.median(r["compile_s"] for r in ok),
            "load_avg": [r["load_avg"] for r in ok],
        }
    for name, v in table.items():
        fwd = table.get("loss[jax]" if name.endswith("[jax]") else "loss[auto]", {}).get("time_s")
        if "time_s" in v and fwd:
            v["ratio_to_forward"] = v["time_s"] / fwd
    fwd_native = table.get("loss[auto]", {}).get("time_s")
    for v in table.values():
        if "time_s" in v and fwd_native:
            v["ratio_to_native_forward"] = v["time_s"] / fwd_native
    out = {
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "steps": args.steps,
        "grid": "840x630",
        "dtype": "float32",
        "rounds": args.rounds,
        "cpus": os.cpu_count(),
        "modes": table,
    }
    dest = Path(args.out)
    dest.mkdir(parents=True, exist_ok=True)
    (dest / "gradient_speed.json").write_text(json.dumps(out, indent=2))
    lines = [
        "# Gradients against the forward run",
        "",
        f"{out['date_utc']}, 840x630 x {args.steps} steps, float32, {out['cpus']} CPUs; median over "
        f"{args.rounds} interleaved rounds (each the median of 3 calls in its own process). Ratios: to the "
        "forward run of the same backend, and to the native forward run.",
        "",
        "| mode [backend] | time (s) | per round (s) | / forward (same backend) | / native forward | peak RSS (MB) | load avg |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, v in table.items():
        if "time_s" not in v:
            lines.append(f"| {name} | error | | | | | |")
            continue
        lines.append(
            f"| {name} | {v['time_s']:.3f} | {', '.join(f'{x:.3f}' for x in v['per_round_s'])} | "
            f"{v.get('ratio_to_forward', float('nan')):.2f} | {v.get('ratio_to_native_forward', float('nan')):.2f} | "
            f"{v['max_rss_mb']:.0f} | {', '.join(f'{x:.2f}' for x in v['load_avg'])} |"
        )
    (dest / "gradient_speed.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
