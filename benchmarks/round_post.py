"""The corridor's round post on the lattice (issue 29): is its first echo its image source's?

    .venv/bin/python benchmarks/round_post.py [--cases post_6_hard,plane_6_hard,...] [--out DIR]

Each case is `data/scenes/corridor3d.toml` cut down to the transducer and one object between the
corridor's rigid floor and ceiling (sponges on the other sides), run with `difflattice simulate
FILE --out DIR/CASE --isolate NAME`: the object's echo isolated by a difference of runs and its
first arrival fitted against its lattice delay (`apps.echoes_isolated`; the model echo carries
the transducer's images in floor and ceiling). The cases:

- `post_6_hard`: the post (50 mm) with its centre 0.6 m ahead of the disc, 5.1 deg off its axis
  (as in the corridor), 6 cells per wavelength, hard rasterisation (the corridor's lattice);
- `post_6_smooth`, `post_6_standard`: the same with smooth (cut-cell) rasterisation, or on the
  seven-point stencil;
- `plane_6_hard`: a wall across the window in place of the post, its face where the post's is
  (the reference: the same guide, range and lattice, no curvature);
- `post_9_hard`, `post_9_smooth`: the post on 9 cells per wavelength;
- `post_far_6_hard`: the post where it stands in the corridor (1.31 m), 6 cells per wavelength.

Each case's scene file is `DIR/CASE.toml`, its run `DIR/CASE/`; a case whose
`DIR/CASE/echoes_isolated.json` exists is read, not run again. Writes
`DIR/round_post.json` (rows: case, cells per wavelength, rasterisation, stencil, round trip, the fitted
first arrival and its standard error in periods, separable, residual, level dB, the number of
arrivals fitted, run seconds) and `DIR/round_post.md`, with the load average at start and end.
Runs take 1-13 minutes each on the 2-core machine (all seven: ~50 minutes).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CORRIDOR = ROOT / "data" / "scenes" / "corridor3d.toml"
CASES = (
    "post_6_hard",
    "post_6_smooth",
    "post_6_standard",
    "plane_6_hard",
    "post_9_hard",
    "post_9_smooth",
    "post_far_6_hard",
)


def case_data(case: str) -> tuple[dict, str]:
    """(scene tables, the isolated object's name) of one case, from the corridor's file."""
    with open(CORRIDOR, "rb") as f:
        d = tomllib.load(f)
    kind, cpw, rasterise = case.rsplit("_", 2)
    far = kind.endswith("_far")
    post = next(o for o in d["objects"] if o["name"] == "post")
    d["objects"] = [post]
    d["edges"] = {"kind": "sponge", "thickness_cells": round(40 * int(cpw) / 6), "z_lo": "rigid", "z_hi": "rigid"}
    d["grid"]["cells_per_wavelength"] = float(cpw)
    if rasterise == "standard":
        d["grid"]["stencil"] = "standard"
    else:
        d["medium"]["rasterise"] = rasterise
    if far:  # where it stands in the corridor
        d["grid"]["size_m"] = [1.55, 0.45, 0.1086]
        d["run"]["duration_s"] = 0.0086
    else:  # 0.6 m ahead, as far off the axis (in angle) as in the corridor
        d["grid"]["size_m"] = [0.82, 0.45, 0.1086]
        post["centre_m"] = [0.6736, 0.246, 0.0]
        d["run"]["duration_s"] = 0.0045
    if kind == "plane":
        d["objects"] = [
            {
                "name": "block",
                "shape": "box",
                "material": "rigid",
                "centre_m": post["centre_m"],
                "size_m": [0.05, 0.5, 0.4],
            }
        ]
    return d, d["objects"][0]["name"]


def _load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def run_case(case: str, out: Path) -> dict:
    """Run one case (unless done) and read its isolated echo's row."""
    from difflattice.apps.scenes3d import data_to_toml

    d, name = case_data(case)
    where = out / case
    table = where / "echoes_isolated.json"
    seconds = None
    out.mkdir(parents=True, exist_ok=True)
    scene = out / f"{case}.toml"  # beside its run's directory (`simulate --out` takes a new or empty one)
    scene.write_text(data_to_toml(d, f"benchmarks/round_post.py case {case} (from data/scenes/corridor3d.toml)"))
    if not table.exists():
        cmd = [sys.executable, "-m", "difflattice.cli", "simulate", str(scene), "--out", str(where)]
        cmd += ["--isolate", name, "--no-animation", "--no-frames"]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        seconds = time.perf_counter() - t0
    e = next(r for r in json.loads(table.read_text())["echoes"] if r["surface"] == name)
    return {
        "case": case,
        "object": name,
        "cells_per_wavelength": d["grid"]["cells_per_wavelength"],
        "rasterise": d["medium"].get("rasterise", "hard"),
        "stencil": d["grid"].get("stencil", "wide"),
        "round_trip_m": e["path_m"],
        "first_arrival_periods": e["error_periods"],
        "sigma_periods": e["sigma_periods"],
        "separable": e["separable"],
        "residual_rel": e["by_estimator"]["fit"]["residual_rel"],
        "n_arrivals": len(e["by_estimator"]["fit"]["arrivals_periods"]),
        "level_db": e["level_db"],
        "run_s": seconds,
    }


def figure(cases: list[str], out: Path, path: Path) -> None:
    """Each case's isolated echo's envelope against its model echo's (each to its own peak), time
    in periods from the lattice delay."""
    import math

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from difflattice.apps import echoes3d
    from difflattice.apps import echoes_isolated as ei
    from difflattice.apps.scenes3d import load_scene_at
    from difflattice.solver.sources import ToneBurst

    fig, axes = plt.subplots(len(cases), 1, figsize=(8, 1.9 * len(cases)), sharex=True, squeeze=False)
    for ax, case in zip(axes[:, 0], cases):
        scene = load_scene_at(str(out / f"{case}.toml"), None)
        grid, _, t, a, centre, echoes, _ = ei._saved(scene, out / case / "echoes_isolated.npz")
        centre = ei._on_mirrors(scene, grid, centre)
        name = next(iter(echoes))
        cycles = float(scene.transducers[0].cycles)
        steps = cycles / grid.frequency_hz / grid.dt_s
        ref = np.asarray(ToneBurst(grid.frequency_hz, cycles)(t), float)[: int(math.ceil(steps)) + 2]
        wl = grid.dx_m * grid.cells_per_wavelength
        found = echoes3d.surfaces(scene, grid, centre)
        s = next(x for x in found if x["surface"] == name)
        mirrors = echoes3d.find_mirrors(scene, grid, centre, found)
        guides = echoes3d.find_guides(scene, grid, centre, echoes3d._reach(grid, cycles * wl))
        paths, weights, _ = ei.surface_paths(scene, grid, centre, s, mirrors, guides, cycles * wl)
        lag = ei.model_lag_steps(grid, ref, len(a), paths, weights, s["direction"], lattice=True)
        model = echoes3d.model_echo(grid, ref, len(a), paths, weights, s["direction"])
        lo, hi = int(lag - steps), int(lag + 3 * steps)
        x = (np.arange(lo, hi) - lag) * grid.dt_s * grid.frequency_hz
        for y, label in ((echoes[name], "lattice"), (model, "model echo")):
            env = echoes3d.envelope(y)[lo:hi]
            ax.plot(x, env / env.max(), label=label)
        ax.set_title(case, fontsize=9)
        ax.set_ylabel("envelope")
    axes[0, 0].legend(fontsize=8)
    axes[-1, 0].set_xlabel("periods after the lattice delay")
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated, of: " + ", ".join(CASES))
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks" / "round_post"))
    ap.add_argument("--figure", default=None, help="also draw the envelopes to this PNG (default: none)")
    args = ap.parse_args()
    cases = [c for c in args.cases.split(",") if c]
    unknown = set(cases) - set(CASES)
    if unknown:
        ap.error(f"--cases {sorted(unknown)}: no such case; give some of {', '.join(CASES)}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    start = _load()
    rows = [run_case(c, out) for c in cases]
    doc = {"what": __doc__.split("\n\n")[0], "load_start": start, "load_end": _load(), "rows": rows}
    (out / "round_post.json").write_text(json.dumps(doc, indent=1))
    lines = [
        "| case | cells/λ | rasterise | stencil | round trip m | first arrival (periods) | separable | residual | level dB |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['case']} | {r['cells_per_wavelength']:g} | {r['rasterise']} | {r['stencil']} | {r['round_trip_m']:.3f} | "
            f"{r['first_arrival_periods']:+.3f} ± {r['sigma_periods']:.3f} | {'yes' if r['separable'] else 'no'} | "
            f"{r['residual_rel']:.2f} | {r['level_db']:.1f} |"
        )
    lines.append(f"\nload average {start} at start, {doc['load_end']} at end")
    (out / "round_post.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    if args.figure:
        figure(cases, out, Path(args.figure))


if __name__ == "__main__":
    main()
