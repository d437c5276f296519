"""Pulse-echo in 3-D (issue 16): a wall at 0-30 deg incidence against the image source, a concave
corner and a vertical post; figures a person can read.

    .venv/bin/python benchmarks/pulse_echo_3d.py [--angles 0,10,20,30] [--cpw 20] [--scenes wall,corner,post]
                                                  [--out docs/benchmarks] [--no-figures]

For each wall angle: `apps.scenes3d.wall_scene` (an 8.6 mm disc, 40 kHz, 3-cycle burst, a rigid
wall 25.7 mm ahead, float32, 12-cell PML), run with the memory/time estimate printed first; the
A-scan (the transducer as receiver) against the continuum image source: arrival difference in
periods (phase at the drive frequency of the gated echo), level difference in dB (gated phasor
and envelope peak), and the echo level against angle (re normal incidence). The corner and the
post give their A-scans and echo levels (no closed-form reference). Figures: the echo level
against angle (lattice and image source), the A-scans, orthogonal slices through the transducer
axis of a snapshot while the echo returns, and a maximum-intensity projection of the peak |p|.
Writes `pulse_echo_3d.json` and `.md` (and PNGs) under `--out`, with the load average at start
and end (figures at a load above the core count: timings provisional; the accuracy figures do
not depend on load).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--angles", default="0,10,20,30")
    ap.add_argument("--cpw", type=float, default=20.0)
    ap.add_argument("--scenes", default="wall,corner,post")
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks"))
    ap.add_argument("--no-figures", action="store_true")
    args = ap.parse_args()

    import jax.numpy as jnp
    import numpy as np

    from difflattice.apps.scenes3d import (
        corner_scene,
        echo_metrics,
        image_source_reference,
        post_scene,
        pulse_echo,
        wall_scene,
    )
    from difflattice.solver import Sensors, simulate

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    load0 = list(os.getloadavg())
    kinds = [s.strip() for s in args.scenes.split(",") if s.strip()]
    rows, scans = [], {}
    if "wall" in kinds:
        for ang in [float(a) for a in args.angles.split(",")]:
            sc = wall_scene(ang, cells_per_wavelength=args.cpw)
            t0 = time.perf_counter()
            t, a = pulse_echo(sc, preflight="print")
            dt = time.perf_counter() - t0
            n = np.arange(1, sc.n_steps + 1)
            ref = image_source_reference(sc)
            m = echo_metrics(n, a, ref, sc.grid.omega, sc.gate_start_step)
            gate = n >= sc.gate_start_step
            ph = np.exp(1j * sc.grid.omega * n[gate])
            rows.append(
                {
                    "scene": sc.name,
                    "angle_deg": ang,
                    "shape": list(sc.grid.shape),
                    "n_steps": sc.n_steps,
                    "run_s": dt,
                    **m,
                    "echo_abs": float(abs(np.sum(a[gate] * ph))),
                    "image_abs": float(abs(np.sum(ref[gate] * ph))),
                }
            )
            scans[sc.name] = (t, a, ref, sc.gate_start_step)
            print(json.dumps(rows[-1]), flush=True)
    others = {"corner": corner_scene, "post": post_scene}
    for name in kinds:
        if name not in others:
            continue
        sc = others[name](cells_per_wavelength=args.cpw)
        t0 = time.perf_counter()
        t, a = pulse_echo(sc, preflight="print")
        n = np.arange(1, sc.n_steps + 1)
        gate = n >= sc.gate_start_step
        e = float(abs(np.sum(a[gate] * np.exp(1j * sc.grid.omega * n[gate]))))
        rows.append(
            {
                "scene": sc.name,
                "shape": list(sc.grid.shape),
                "n_steps": sc.n_steps,
                "run_s": time.perf_counter() - t0,
                "echo_abs": e,
            }
        )
        scans[sc.name] = (t, a, None, sc.gate_start_step)
        print(json.dumps(rows[-1]), flush=True)
    walls = [r for r in rows if "angle_deg" in r]
    if walls:
        e0 = next((r for r in walls if r["angle_deg"] == 0.0), walls[0])
        for r in walls:
            r["echo_db_re_normal"] = 20 * math.log10(r["echo_abs"] / e0["echo_abs"])
            r["image_db_re_normal"] = 20 * math.log10(r["image_abs"] / e0["image_abs"])
        for r in rows:
            if "angle_deg" not in r:
                r["echo_db_re_wall_normal"] = 20 * math.log10(r["echo_abs"] / e0["echo_abs"])
    load1 = list(os.getloadavg())
    res = {
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "cells_per_wavelength": args.cpw,
        "cpu_count": os.cpu_count(),
        "load_average_at_start": load0,
        "load_average_at_end": load1,
        "rows": rows,
    }
    (out / "pulse_echo_3d.json").write_text(json.dumps(res, indent=2) + "\n")
    md = [
        "# Pulse-echo in 3-D (issue 16)",
        "",
        f"{args.cpw:g} cells per wavelength, 40 kHz, 8.6 mm disc transducer (transmitter and receiver), rigid objects "
        f"25.7 mm ahead; {res['date_utc']}, load average {load0[0]:.2f} at start, {load1[0]:.2f} at end.",
        "",
        "| scene | incidence (deg) | arrival vs image source (periods) | level vs image source (dB) | envelope peak (dB) "
        "| echo re normal wall (dB): lattice / image | run (s) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        if "angle_deg" in r:
            md.append(
                f"| {r['scene']} | {r['angle_deg']:g} | {r['arrival_periods']:+.4f} | {r['level_db']:+.3f} | "
                f"{r['peak_db']:+.3f} | {r['echo_db_re_normal']:+.2f} / {r['image_db_re_normal']:+.2f} | {r['run_s']:.1f} |"
            )
        else:
            md.append(
                f"| {r['scene']} | | | | | {r.get('echo_db_re_wall_normal', float('nan')):+.2f} / (none) | {r['run_s']:.1f} |"
            )
    md += ["", "Reproduce: `.venv/bin/python benchmarks/pulse_echo_3d.py`.", ""]
    (out / "pulse_echo_3d.md").write_text("\n".join(md))
    if args.no_figures:
        return
    from difflattice import plots

    if walls:
        ang = [r["angle_deg"] for r in walls]
        plots.save(
            plots.echo_angle_plot(
                ang,
                {
                    "3-D lattice": ([r["echo_db_re_normal"] for r in walls], "o-"),
                    "image source": ([r["image_db_re_normal"] for r in walls], "k--"),
                },
            ),
            out / "pulse_echo_3d_angle.png",
        )
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(scans), 1, figsize=(8, 2.2 * len(scans)), squeeze=False)
    for ax, (name, (t, a, ref, gate)) in zip(axes[:, 0], scans.items()):
        ax.plot(t * 1e6, a, lw=0.8, label="3-D lattice")
        if ref is not None:
            ax.plot(t * 1e6, ref, "k--", lw=0.8, label="image source")
        ax.axvline(t[gate - 1] * 1e6, color="0.6", lw=0.5)
        ax.set_ylabel(name)
        ax.set_ylim(*(1.3 * np.array([-1, 1]) * np.abs(a[gate:]).max()))
    axes[0, 0].legend(fontsize=8)
    axes[-1, 0].set_xlabel("time (µs); the grey line starts the echo window")
    plots.save(fig, out / "pulse_echo_3d_ascans.png")
    # a field a person can look at: the 20 deg wall, slices through the transducer axis while the echo returns
    sc = wall_scene(20.0, cells_per_wavelength=args.cpw)
    every = max(1, sc.gate_start_step // 2)
    r = simulate(
        sc.grid, sc.medium, sc.source, Sensors(snapshot_every=every, p_max=True), n_steps=sc.n_steps, edges=sc.edges
    )
    k = min(len(r.chunk_steps) - 1, int(round((sc.gate_start_step + sc.n_steps) / 2 / every)) - 1)
    cx, cy, cz = (int(round(v)) for v in sc.transducer_centre_cells)
    planes = sc.grid.shape
    snaps = r.snapshots  # mid-planes: x = nx/2, y = ny/2, z = nz/2 (the axis lies in the last two)
    cells = sc.source.cells_array
    slices = {
        f"x-y plane through the axis (z = {planes[2] // 2})": (("x", "y"), snaps[2][k]),
        f"x-z plane through the axis (y = {planes[1] // 2})": (("x", "z"), snaps[1][k]),
        f"y-z plane (x = {planes[0] // 2})": (("y", "z"), snaps[0][k]),
    }
    marks = {
        f"x-y plane through the axis (z = {planes[2] // 2})": [cells[:, :2]],
        f"x-z plane through the axis (y = {planes[1] // 2})": [cells[:, [0, 2]]],
    }
    occ = np.asarray(sc.medium.rigid)
    outlines = {
        f"x-y plane through the axis (z = {planes[2] // 2})": occ[:, :, planes[2] // 2],
        f"x-z plane through the axis (y = {planes[1] // 2})": occ[:, planes[1] // 2, :],
        f"y-z plane (x = {planes[0] // 2})": occ[planes[0] // 2],
    }
    plots.save(
        plots.slices_3d(
            slices,
            sc.grid.dx_m,
            marks=marks,
            outlines=outlines,
            title=f"20 deg wall, step {r.chunk_steps[k]}: pressure on three planes",
        ),
        out / "pulse_echo_3d_slices.png",
    )
    plots.save(
        plots.max_intensity_projection(
            np.asarray(r.p_max),
            sc.grid.dx_m,
            axis=2,
            floor_db=-40,
            title="20 deg wall: peak |p| projected along z (dB)",
        ),
        out / "pulse_echo_3d_mip.png",
    )
    del jnp


if __name__ == "__main__":
    main()
