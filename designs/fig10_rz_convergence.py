"""Resolution study of the paper's Fig. 10 reflector on the r-z lattice (issue 12): the dish's -6 dB
width and on-axis gain at 0.2 m and 1 m against cells per wavelength, for both spatial stencils.
One JSON line per (stencil, resolution) on stdout and in `--out`.

    .venv/bin/python designs/fig10_rz_convergence.py --cells-per-wavelength 8 16 24 32 \
        --out docs/design/fig10_rz_convergence.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
sys.path.insert(0, str(Path(__file__).resolve().parent))
import fig09_fig10_axisym as study  # noqa: E402  (the study's configuration and measure)

from difflattice.design.problem import reflector_design  # noqa: E402


def one(cpw: float, stencil: str) -> dict:
    cfg = study.FULL
    t0 = time.perf_counter()
    pb = reflector_design(
        limits=cfg["parabola_limits"],
        cycles=10.0,
        lattice="rz",
        stencil=stencil,
        face_m=cfg["face_m"],
        frequency_hz=50e3,
        cells_per_wavelength=cpw,
        wall="rigid",
        angle_step_deg=cfg["angle_step_deg"],
        reference=False,
    )
    m = study.measure(pb, cfg["parabola"], cfg["ranges_m"])
    return {
        "cpw": cpw,
        "stencil": stencil,
        "grid": list(pb.grid.shape),
        "n_steps": pb.n_steps,
        "wall_s": time.perf_counter() - t0,
        "metrics": {
            r: {
                "width_bare": v["bare"]["beam_width_deg"],
                "width": v["with"]["beam_width_deg"],
                "gain_db": v["with"]["on_axis_db"],
            }
            for r, v in m.items()
        },
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cells-per-wavelength", type=float, nargs="+", default=[8.0, 16.0, 24.0, 32.0])
    ap.add_argument("--stencils", nargs="+", default=["standard", "isotropic"], choices=["standard", "isotropic"])
    ap.add_argument("--out", type=Path, default=None, help="also append the lines to this file")
    a = ap.parse_args(argv)
    for cpw in a.cells_per_wavelength:
        for st in a.stencils:
            line = json.dumps(one(cpw, st))
            print(line, flush=True)
            if a.out:
                with a.out.open("a") as f:
                    f.write(line + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
