"""Paper Figs. 9 and 10, 2-D against axisymmetric (issue 12): the 5-degree, 125 mm cone horn and
the parabolic reflector (transducer at the focus) as a wedge / trough on the 2-D lattice and as a
cone / dish of revolution on the r-z lattice, at the same resolution, with the same transducer
diameter (a transparent line of cells in 2-D, a transparent disc of ring cells in r-z) and the same
rigid walls (the paper's speed-zero "soft" walls have no ring-volume form on the r-z lattice).
Reports the -6 dB beam widths and on-axis gains (re the bare transducer at the same range) side by
side, with the bare transducer's widths against the analytic line (sinc) and disc (jinc) patterns.

    .venv/bin/python designs/fig09_fig10_axisym.py --out out/design/axisym --cells-per-wavelength 8

Writes report.json and report.md under `--out`. `run(quick=True)` is a miniature (10 mm face,
scaled shapes, 6 cells per wavelength) for the test suite.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
from scipy.optimize import brentq  # noqa: E402
from scipy.special import j1  # noqa: E402

from difflattice.design import (  # noqa: E402
    HornLimits,
    HornParams,
    ReflectorLimits,
    ReflectorParams,
    horn_design,
    pattern_metrics,
    reflector_design,
)
from difflattice.design.presets import FIG09_CONE, FIG10_PARABOLA, PAPER_FACE_M  # noqa: E402
from difflattice.design.report import machine_info, resolution_note, write_json  # noqa: E402
from difflattice.lattice.medium import air  # noqa: E402

FULL = dict(
    face_m=PAPER_FACE_M,
    cone=FIG09_CONE,
    parabola=FIG10_PARABOLA,
    angle_step_deg=0.5,
    ranges_m=(0.2, 1.0),
    cone_limits=HornLimits(
        throat_min_m=0.0365,
        throat_max_m=0.040,
        mouth_max_m=0.062,
        length_min_m=0.05,
        length_max_m=0.127,
        wall_min_m=0.002,
        wall_max_m=0.004,
    ),
    parabola_limits=ReflectorLimits(
        focal_min_m=0.045,
        focal_max_m=0.055,
        aperture_min_m=0.18,
        aperture_max_m=0.20,
        wall_min_m=0.002,
        wall_max_m=0.004,
    ),
)
QUICK = dict(
    face_m=0.010,
    cone=HornParams(0.0105, 0.0105 + 2 * 0.030 * math.tan(math.radians(5.0)), 0.030, 0.0015, 0.0),
    parabola=ReflectorParams(0.012, 0.040, 0.0015),
    angle_step_deg=1.0,
    ranges_m=(0.3,),
    cone_limits=HornLimits(
        throat_min_m=0.0105,
        throat_max_m=0.011,
        mouth_max_m=0.0165,
        length_min_m=0.02,
        length_max_m=0.031,
        wall_min_m=0.0012,
        wall_max_m=0.0016,
    ),
    parabola_limits=ReflectorLimits(
        focal_min_m=0.011,
        focal_max_m=0.013,
        aperture_min_m=0.036,
        aperture_max_m=0.042,
        wall_min_m=0.0012,
        wall_max_m=0.0016,
    ),
)
LATTICES = ("2d", "rz")


def analytic_width_deg(face_m: float, frequency_hz: float, lattice: str) -> float:
    """-6 dB full width of a uniform line (sin x / x) or disc (2 J1(x) / x), x = k a sin(theta)."""
    k = 2 * math.pi * frequency_hz / air(20.0).speed_m_s
    ka = k * 0.5 * face_m
    f = (lambda x: math.sin(x) / x - 0.5) if lattice == "2d" else (lambda x: 2 * j1(x) / x - 0.5)
    x = brentq(f, 1e-6, 3.0)
    return 2 * math.degrees(math.asin(x / ka)) if x < ka else float("nan")


def measure(problem, params, ranges_m) -> dict:
    """Bare and with-shape metrics at each range (gain re the bare transducer at that range)."""
    bare = jax.jit(lambda: problem.pattern(None, ranges_m))()
    des = jax.jit(lambda p: problem.pattern(p, ranges_m))(params)
    i0 = problem.angles_deg.index(0.0)
    out = {}
    for r, b, d in zip(ranges_m, bare, des):
        kw = dict(reference_on_axis=float(np.abs(b[i0])), field_of_view_deg=90.0, sector_deg=problem.sector_deg)
        out[f"{r:g} m"] = {
            "bare": {k: float(v) for k, v in pattern_metrics(b, problem.angles_deg, **kw).items()},
            "with": {k: float(v) for k, v in pattern_metrics(d, problem.angles_deg, **kw).items()},
        }
    return out


def run(
    out: str | Path = "out/design/axisym",
    *,
    quick: bool = False,
    cells_per_wavelength: float | None = None,
    frequency_hz: float = 50e3,
    progress: bool = True,
) -> dict:
    """Measure both figures on both lattices; write report.json and report.md to `out`; return the report."""
    cfg = QUICK if quick else FULL
    cpw = cells_per_wavelength or (6.0 if quick else 8.0)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t_all = time.perf_counter()
    report = {
        "machine": machine_info(),
        "cells_per_wavelength": cpw,
        "frequency_hz": frequency_hz,
        "quick": quick,
        "face_m": cfg["face_m"],
        "walls": "rigid",
        "analytic_bare_width_deg": {},
        "fig09": {},
        "fig10": {},
    }
    common = dict(
        face_m=cfg["face_m"],
        frequency_hz=frequency_hz,
        cells_per_wavelength=cpw,
        wall="rigid",
        angle_step_deg=cfg["angle_step_deg"],
        reference=False,
    )
    for lat in LATTICES:
        report["analytic_bare_width_deg"][lat] = analytic_width_deg(cfg["face_m"], frequency_hz, lat)
        for key, build, params in (
            (
                "fig09",
                lambda lat=lat: horn_design(limits=cfg["cone_limits"], cycles=5.0, lattice=lat, **common),
                cfg["cone"],
            ),
            (
                "fig10",
                lambda lat=lat: reflector_design(limits=cfg["parabola_limits"], cycles=10.0, lattice=lat, **common),
                cfg["parabola"],
            ),
        ):
            t0 = time.perf_counter()
            pb = build()
            m = measure(pb, params, cfg["ranges_m"])
            report[key][lat] = {
                "metrics": m,
                "resolution": resolution_note(pb).split("; beam at")[0],
                "grid_shape": list(pb.grid.shape),
                "n_steps": pb.n_steps,
                "params": params.as_dict(),
                "wall_s": time.perf_counter() - t0,
            }
            if progress:
                print(
                    f"{key} {lat}: "
                    + "; ".join(
                        f"{r}: width {v['bare']['beam_width_deg']:.2f} -> {v['with']['beam_width_deg']:.2f} deg, "
                        f"gain {v['with']['on_axis_db']:+.2f} dB"
                        for r, v in m.items()
                    )
                    + f" ({time.perf_counter() - t0:.0f} s)",
                    flush=True,
                )
    report["wall_s"] = time.perf_counter() - t_all
    write_json(out / "report.json", report)
    (out / "report.md").write_text(markdown(report))
    return report


def markdown(rep: dict) -> str:
    a = rep["analytic_bare_width_deg"]
    lines = [
        f"# Figs. 9-10: 2-D against axisymmetric ({rep['cells_per_wavelength']:g} cells per wavelength, "
        f"{rep['frequency_hz'] / 1e3:g} kHz, face {rep['face_m'] * 1e3:g} mm, rigid walls)",
        "",
        "| case | range | -6 dB width 2-D (deg) | -6 dB width r-z (deg) | on-axis gain 2-D (dB) | on-axis gain r-z (dB) |",
        "|---|---|---|---|---|---|",
    ]
    names = {"fig09": "Fig. 9 cone horn", "fig10": "Fig. 10 parabolic reflector"}
    first = True
    for key in ("fig09", "fig10"):
        m2, mr = rep[key]["2d"]["metrics"], rep[key]["rz"]["metrics"]
        for r in m2:
            if first:
                lines.append(
                    f"| bare transducer (analytic line / disc at infinity: {a['2d']:.2f} / {a['rz']:.2f}) | {r} | "
                    f"{m2[r]['bare']['beam_width_deg']:.2f} | {mr[r]['bare']['beam_width_deg']:.2f} | 0 | 0 |"
                )
            w2, wr = m2[r]["with"], mr[r]["with"]
            lines.append(
                f"| {names[key]} | {r} | {w2['beam_width_deg']:.2f} | {wr['beam_width_deg']:.2f} | "
                f"{w2['on_axis_db']:+.2f} | {wr['on_axis_db']:+.2f} |"
            )
        first = False
    lines += [
        "",
        "Resolution: "
        + "; ".join(f"{k} {lat}: {rep[k][lat]['resolution']}" for k in ("fig09", "fig10") for lat in LATTICES)
        + ".",
        "",
        f"Total run time {rep['wall_s']:.0f} s.",
        "",
    ]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("out/design/axisym"))
    ap.add_argument("--cells-per-wavelength", type=float, default=8.0)
    ap.add_argument("--quick", action="store_true", help="the miniature of the test suite")
    args = ap.parse_args(argv)
    rep = run(args.out, quick=args.quick, cells_per_wavelength=args.cells_per_wavelength)
    print(f"wrote {args.out}/report.md in {rep['wall_s']:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
