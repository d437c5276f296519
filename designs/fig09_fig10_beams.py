"""Paper Figs. 9 and 10 measured with the design tools: the -6 dB beam width of the Polaroid-like
line with and without the 5-degree, 125 mm cone (Fig. 9), and the on-axis gain of the parabolic
reflector with the transducer at its focus (Fig. 10), for rigid walls and for pressure-release
("soft", R = -1: the paper's speed-zero walls) walls. One command:

    .venv/bin/python designs/fig09_fig10_beams.py --out out/design/fig09_fig10 [--cells-per-wavelength 8]

Writes report.json, report.md, fig09_patterns.png, fig10_patterns.png, fig09_fields.png,
fig10_fields.png and the designs as scene files. Beams come from the Kirchhoff-Helmholtz
transform of the drive-frequency phasors on a contour around transducer and walls, at 0.2 m
(the paper's picture scale, near field of the horn's mouth) and 1 m (far field).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from difflattice import plots  # noqa: E402
from difflattice.design import HornLimits, ReflectorLimits, horn_design, pattern_metrics, reflector_design  # noqa: E402
from difflattice.design.export import write_scene  # noqa: E402
from difflattice.design.presets import FIG09_CONE, FIG10_PARABOLA, PAPER_FACE_M  # noqa: E402
from difflattice.design.report import fields_plot, machine_info, resolution_note, write_json  # noqa: E402

FACE_M = PAPER_FACE_M
CONE = FIG09_CONE
PARABOLA = FIG10_PARABOLA
# limits just around the paper's shapes: the grid and contour fit them snugly
CONE_LIMITS = HornLimits(
    throat_min_m=0.0365,
    throat_max_m=0.040,
    mouth_max_m=0.062,
    length_min_m=0.05,
    length_max_m=0.127,
    wall_min_m=0.002,
    wall_max_m=0.004,
)
PARABOLA_LIMITS = ReflectorLimits(
    focal_min_m=0.045, focal_max_m=0.055, aperture_min_m=0.18, aperture_max_m=0.20, wall_min_m=0.002, wall_max_m=0.004
)
RANGES_M = (0.2, 1.0)


def measure(problem, params):
    """Metrics at each range (gain re the bare transducer at the same range) and the patterns."""
    bare = jax.jit(lambda: problem.pattern(None, RANGES_M))()
    des = jax.jit(lambda p: problem.pattern(p, RANGES_M))(params)
    i0 = problem.angles_deg.index(0.0)
    out, pats = {}, {}
    for r, b, d in zip(RANGES_M, bare, des):
        kw = dict(reference_on_axis=float(np.abs(b[i0])), field_of_view_deg=90.0, sector_deg=problem.sector_deg)
        out[f"{r:g} m"] = {
            "bare": {k: float(v) for k, v in pattern_metrics(b, problem.angles_deg, **kw).items()},
            "with": {k: float(v) for k, v in pattern_metrics(d, problem.angles_deg, **kw).items()},
        }
        pats[r] = (np.asarray(b), np.asarray(d))
    return out, pats


def pattern_figure(problem, pats_by_wall, title, label):
    import matplotlib.pyplot as plt

    a = np.asarray(problem.angles_deg)
    sel = np.abs(a) <= 90
    fig, axs = plt.subplots(1, len(RANGES_M), figsize=(12, 4))
    for ax, r in zip(axs, RANGES_M):
        first = True
        for wall, pats in pats_by_wall.items():
            b, d = pats[r]
            ref = np.abs(b).max()
            if first:
                ax.plot(a[sel], 20 * np.log10(np.abs(b[sel]) / ref), "k-", label="bare transducer")
                first = False
            ax.plot(a[sel], 20 * np.log10(np.maximum(np.abs(d[sel]) / ref, 1e-6)), label=f"{label}, {wall} walls")
        ax.axhline(-6, color="gray", lw=0.5, ls=":")
        ax.set_xlim(-60, 60)
        ax.set_ylim(-40, 15)
        ax.set_xlabel("angle from the axis (deg)")
        ax.set_ylabel("level (dB re bare on-axis peak)")
        ax.set_title(f"{title}: {r:g} m from the transducer", fontsize=9)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("out/design/fig09_fig10"))
    ap.add_argument("--cells-per-wavelength", type=float, default=8.0)
    ap.add_argument("--walls", nargs="+", default=["soft"], help="soft (the paper's speed-zero walls) and/or rigid")
    ap.add_argument("--no-fields", action="store_true", help="skip the field pictures")
    args = ap.parse_args(argv)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    report = {"machine": machine_info(), "cells_per_wavelength": args.cells_per_wavelength, "fig09": {}, "fig10": {}}
    cases = (
        (
            "fig09",
            "Fig. 9 horn",
            "5-deg cone 125 mm",
            lambda w: horn_design(
                limits=CONE_LIMITS, face_m=FACE_M, cells_per_wavelength=args.cells_per_wavelength, wall=w, cycles=5.0
            ),
            CONE,
        ),
        (
            "fig10",
            "Fig. 10 reflector",
            "parabola f 50 mm, aperture 190 mm",
            lambda w: reflector_design(
                limits=PARABOLA_LIMITS,
                face_m=FACE_M,
                cells_per_wavelength=args.cells_per_wavelength,
                wall=w,
                cycles=10.0,
            ),
            PARABOLA,
        ),
    )
    md = ["# Paper Figs. 9-10 measured", ""]
    for key, title, label, build, params in cases:
        pats_by_wall = {}
        for wall in args.walls:
            pb = build(wall)
            m, pats = measure(pb, params)
            pats_by_wall[wall] = pats
            report[key][wall] = {"metrics": m, "resolution": resolution_note(pb), "params": params.as_dict()}
            write_scene(pb, params, out / f"{key}_{wall}.toml", title=f"{title} ({wall} walls)")
            if not args.no_fields:
                plots.save(
                    fields_plot(pb, {"bare transducer": None, f"{label}, {wall}": params}),
                    out / f"{key}_fields_{wall}.png",
                )
            print(
                f"{key} {wall}: "
                + "; ".join(
                    f"{r}: width {v['bare']['beam_width_deg']:.2f} -> {v['with']['beam_width_deg']:.2f} deg, "
                    f"gain {v['with']['on_axis_db']:+.2f} dB"
                    for r, v in m.items()
                ),
                flush=True,
            )
        plots.save(pattern_figure(pb, pats_by_wall, title, label), out / f"{key}_patterns.png")
        md += [
            f"## {title}: {label}",
            "",
            f"Resolution: {report[key][args.walls[0]]['resolution']}.",
            "",
            "| walls | range | -6 dB width bare (deg) | -6 dB width with (deg) | on-axis gain (dB) | side lobe with (dB) |",
            "|---|---|---|---|---|---|",
        ]
        for wall in args.walls:
            for r, v in report[key][wall]["metrics"].items():
                md.append(
                    f"| {wall} | {r} | {v['bare']['beam_width_deg']:.2f} | {v['with']['beam_width_deg']:.2f} | "
                    f"{v['with']['on_axis_db']:+.2f} | {v['with']['sidelobe_db']:.1f} |"
                )
        md += ["", f"![{key} patterns]({key}_patterns.png)", ""]
        md += [f"![{key} fields, {w} walls]({key}_fields_{w}.png)" for w in args.walls if not args.no_fields] + [""]
    report["wall_s"] = time.perf_counter() - t0
    write_json(out / "report.json", report)
    (out / "report.md").write_text("\n".join(md))
    print(f"wrote {out}/report.md in {report['wall_s']:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
